"""What every command says on the terminal besides its result: the exit status of a status
word, the one status line each command ends with, the stage bar (with numba's first-use
compilation said once), and the diagnosis's rows in words.
"""

from __future__ import annotations

import math
import sys
import threading
from typing import Any

import click

EXIT_CODES = {"ok": 0, "failed": 1, "usage": 2, "degraded": 3, "partial": 4, "changed": 3}
"""Exit status of every command: 0 ok, 1 failed (a run or flight that failed, any other
error), 2 usage or configuration error (bad option, pipeline file, or an output folder pospp
must not write into), 3 degraded (the run completed but a quality check failed; ``pospp diff``:
changed beyond tolerance), 4 partial (the run completed but a stage produced nothing, e.g. no
calibration)."""

STATUS_RANK = {"ok": 0, "unchanged": 0, "partial": 1, "changed": 2, "degraded": 2, "failed": 3}
"""The worse of two statuses has the higher rank (as ``pospp.qc.check_record.STATUS_ORDER``)."""


def worst_status(*statuses: str | None) -> str:
    """The worst of ``statuses`` (an unknown word counts as failed; none at all: ok)."""
    known = [s or "failed" for s in statuses]
    return max(known, key=lambda s: STATUS_RANK.get(s, 3), default="ok")


def exit_code_for_status(*statuses: str | None) -> int:
    """The exit status of one or more statuses: that of the worst of them."""
    worst = worst_status(*statuses)
    return EXIT_CODES.get(worst, 0 if worst == "unchanged" else EXIT_CODES["failed"])


def status_line(command: str, status: str, detail: str = "") -> None:
    """The last line of every command: ``pospp COMMAND: STATUS (detail)`` on stdout."""
    click.echo(f"pospp {command}: {status}" + (f" ({detail})" if detail else ""))


class StageBar:
    """A progress bar over a command's stages (stderr; silent when not a terminal). The first
    time numba compiles a kernel in this process (a fresh install's first run: about a
    minute), the bar says so, once."""

    COMPILING = "compiling numba kernels (first run only, cached after)"

    def __init__(self) -> None:
        from tqdm import tqdm

        self._bar = tqdm(total=100, unit="%", file=sys.stderr, leave=False,
                         disable=not sys.stderr.isatty(), bar_format="{l_bar}{bar}| {desc}")
        self._stage = ""
        self._compiling = False
        self._lock = threading.Lock()
        self._listener = _listen_for_compilation(self.compiling) if not self._bar.disable \
            else None

    def __call__(self, stage: str, fraction: float) -> None:
        with self._lock:
            self._stage = stage
            self._bar.set_description_str(self._text())
            self._bar.update(round(100 * fraction) - self._bar.n)

    def compiling(self) -> None:
        """numba started compiling: say so on the bar (once per process)."""
        with self._lock:
            if self._compiling:
                return
            self._compiling = True
            self._bar.set_description_str(self._text())

    def _text(self) -> str:
        return f"{self._stage} ({self.COMPILING})" if self._compiling else self._stage

    def close(self) -> None:
        if self._listener is not None:
            from numba.core import event

            event.unregister("numba:compile", self._listener)
        self._bar.close()


_SAID = threading.Event()
"""Set once numba's first compilation has been said in this process."""


def _listen_for_compilation(say: Any) -> Any:
    """Register a numba event listener calling ``say()`` at the first compilation of this
    process (numba fires ``numba:compile`` only when it compiles, not on a cache hit)."""
    if _SAID.is_set():
        return None
    try:
        from numba.core import event
    except ImportError:  # pragma: no cover - numba is a dependency
        return None

    class _First(event.Listener):
        def on_start(self, ev: Any) -> None:
            if not _SAID.is_set():
                _SAID.set()
                say()

        def on_end(self, ev: Any) -> None:
            pass

    listener = _First()
    event.register("numba:compile", listener)
    return listener


def diagnosis_step_line(s: Any) -> str:
    """One row of a diagnosis (``pospp.diagnose.results.DiagnosisStep``) in words: the effect
    with its size, or on the closing row what the final lack-of-fit test says."""
    gaps = (f"gap {s.gap_before_mps:.4f} -> {s.gap_after_mps:.4f} m/s, held-out "
            f"{s.heldout_gap_before_mps:.4f} -> {s.heldout_gap_after_mps:.4f} m/s")
    if s.effect == "none":
        return (f"step {s.step}: no missing effect found (lack of fit p = {s.p_value:.3g}); "
                f"gap {s.gap_before_mps:.4f} m/s, held-out {s.heldout_gap_before_mps:.4f} m/s")
    if s.effect == "unexplained":
        return (f"step {s.step}: unexplained: a structured gap no candidate effect explains "
                f"(lack of fit p = {s.p_value:.3g}); {gaps}")
    size = (f"value {s.value:+.4g} +- {s.sigma:.3g} {s.unit}"
            if math.isfinite(s.value) and math.isfinite(s.sigma) else "size not estimated")
    return f"step {s.step}: {s.effect}: {size}, p = {s.p_value:.3g}; {gaps}"
