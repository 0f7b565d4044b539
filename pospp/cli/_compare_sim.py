"""``pospp compare-sim``'s terminal output: progress lines on stderr and the result's lines
(the sizes in the tables' units and signs: tests/e2e/test_compare_sim.py reads them back)."""

from __future__ import annotations

import sys
import time
from typing import Any

import click

__all__ = ["StepLines", "compare_sim_lines"]


class StepLines:
    """compare-sim's progress on stderr: a line per step with the seconds since the start
    (:meth:`step`); on a terminal also a transient line per simulated flight
    (:meth:`flight`, overwritten)."""

    def __init__(self) -> None:
        self._t0 = time.perf_counter()
        self._tty = sys.stderr.isatty()
        self._open = False

    def _text(self, line: str) -> str:
        return f"  [{time.perf_counter() - self._t0:6.1f} s] {line}"

    def flight(self, k: int) -> None:
        if self._tty:
            sys.stderr.write("\r\x1b[K" + self._text(f"simulated flight {k}"))
            sys.stderr.flush()
            self._open = True

    def step(self, line: str) -> None:
        self.close()
        click.echo(self._text(line), err=True)

    def close(self) -> None:
        if self._open:
            sys.stderr.write("\r\x1b[K")
            sys.stderr.flush()
            self._open = False


def compare_sim_lines(comp: Any) -> list[str]:
    """compare-sim's result as printed: the base model's levels that differ from the prior,
    the gaps, each step (size in the table's units and signs) with its reading."""
    out = []
    fitted = [b for b in comp.base_fit if b.fitted]
    differ = [b for b in fitted if b.differs]
    if fitted:
        out.append(f"base model fitted to the log (step 0): {len(fitted)} levels, "
                   f"{len(differ)} differ from the prior")
        out += [f"  {b.text()}" for b in differ]
    if comp.a_tuning:
        out.append(f"  {comp.a_tuning}")
    n_sig = sum(g.significant for g in comp.base.values())
    out.append(f"base model: {n_sig} of {len(comp.base)} statistics differ significantly")
    for s in comp.steps:
        b, a = s.before[s.target], s.after.get(s.target, s.before[s.target])
        size = ", ".join(f"{p} {v:+.4g} +- {e:.2g} {u}" for p, v, e, u in
                         zip(s.params, s.size, s.sigma, s.param_units(), strict=True))
        if s.candidate:
            size = f"(best candidate {s.candidate}: {size}, did not shrink it)"
        out.append(f"step {s.step}: {s.target}: {s.effect} {size}; z {b.z:+.2f} -> "
                   f"{a.z:+.2f}")
        out += [f"  {p} {v:+.4g} +- {e:.2g} {u}" for p, v, e, u in s.extra
                if not p.startswith("correlation")]
        if s.note:
            out.append(f"  {s.note}")
    out.append(f"left significant: {sum(g.significant for g in comp.final.values())}")
    return out
