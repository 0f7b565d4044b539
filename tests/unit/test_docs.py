"""Generated documentation stays in sync with the code it documents."""

from __future__ import annotations

import importlib.util
from pathlib import Path

DOCS = Path(__file__).resolve().parents[2] / "docs"


def _maker():
    spec = importlib.util.spec_from_file_location("make_cli_docs", DOCS / "_make_cli_docs.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_cli_reference_is_in_sync():
    assert (DOCS / "cli.md").read_text() == _maker().cli_markdown(), \
        "docs/cli.md is stale: run python docs/_make_cli_docs.py"


def test_pipeline_reference_is_in_sync():
    assert (DOCS / "pipelines.md").read_text() == _maker().pipelines_markdown(), \
        "docs/pipelines.md is stale: run python docs/_make_cli_docs.py"
