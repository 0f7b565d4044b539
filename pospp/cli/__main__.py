"""``python -m pospp.cli``: the ``pospp`` console script."""

from pospp.cli import entry

entry()
