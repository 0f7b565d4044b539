"""Regenerate, or check, every figure the docs quote from the bundled sample run.

    python docs/_make_figures.py                # run the sample, rewrite the quoted figures
    python docs/_make_figures.py --check        # exit 1 naming every quote that disagrees
    python docs/_make_figures.py --run DIR      # use an existing sample run (evaluated here)

The figures come from a fresh run of ``pospp run sample_data/sample_flight.mcap -p
pipelines/sample.toml`` and ``pospp evaluate RUN --truth sample_data/sample_flight.truth.parquet
--skip-s 300``, read through ``pospp.open_run`` (docs/api.md). Each quote is a pattern in a
doc (:data:`QUOTES`): its groups are the figures, rewritten in place (``--check`` compares).
The PNG figures the docs show (:data:`PNGS`) are drawn again; each carries the figures it shows
in its PNG text metadata (``pospp-figures``), which ``--check`` compares with the run, so a
stale picture fails too. The report's screenshot (``report_answer.png``) needs chromium
(``.ci/run`` installs it); without it the old screenshot is kept and checked.
tests/e2e/test_first_hour_walk.py runs ``--check`` against its sample run in CI.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_data" / "sample_flight.mcap"
TRUTH = REPO / "sample_data" / "sample_flight.truth.parquet"
BIAS = REPO / "sample_data" / "sample_flight.bias.parquet"
PIPELINE = REPO / "pipelines" / "sample.toml"
SKIP_S = 300.0
"""``pospp evaluate --skip-s`` of the quoted evaluation [s]."""
NUMBER_WORDS = ("no", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine",
                "ten")
META_KEY = "pospp-figures"
"""PNG text chunk holding the figures a picture shows (JSON)."""


@dataclass(frozen=True)
class Quote:
    """A place a doc quotes figures: ``pattern``'s groups are the figures ``keys``."""

    doc: str
    pattern: str
    keys: tuple[str, ...]


QUOTES: tuple[Quote, ...] = (
    Quote("README.md", r"summary:\s+(\w+)\s+straight\s+legs\s+\(([\d, and]+)\s+deg\)",
          ("n_legs_word", "headings")),
    Quote("README.md", r"(\w+)\s+pairs\s+used\s+\(condition\s+numbers\s+(\d+\s+to\s+\d+)\)",
          ("n_pairs_word", "cond_range")),
    Quote("README.md", r"`gyro_bias_x = ([^`]+)`,\s+`gyro_bias_y = ([^`]+) deg/h`",
          ("bias_x", "bias_y")),
    Quote("README.md", r"averages\s+([-+\d.]+ / [-+\d.]+)\s+over\s+the\s+legs", ("truth_bias",)),
    Quote("README.md", r"FLU\s+axes[^`]*`y = ([^`]+) deg/h`", ("bias_sensor_y",)),
    Quote("README.md", r"after\s+compensation:\s+([\d.]+ -> [\d.]+)\s+m/s\s+and\s+"
                       r"([\d.]+ -> [\d.]+)\s+m\s+\(", ("dv", "dp")),
    Quote("README.md", r"errors:\s+([\d.]+)\s+arcsec\s+tilt,\s+([\d.]+)\s+arcsec\s+heading,"
                       r"\s+([\d.]+)\s+cm\s+horizontal", ("tilt", "heading", "horizontal_cm")),
    Quote("README.md", r"leaves\s+B's\s+300\s+s\s+error\s+at\s+([\d.]+)\s+m/s\s+and\s+"
                       r"([\d.]+)\s+m\s+here", ("dv_after", "dp_after")),
    Quote("docs/report.md", r"B-minus-A\s+drops\s+from\s+([\d.]+)\s+m/s\s+RMS\s+to\s+([\d.]+)\s+"
                            r"m/s\s+when\s+each\s+leg\s+is\s+predicted\s+from\s+the\s+others,\s+"
                            r"against\s+([\d.]+)\s+m/s\s+in-sample",
          ("gap_uncalibrated", "gap_heldout", "gap_fit")),
    Quote("docs/report.md", r"in-sample\s+horizon\s+figure\s+\(([\d.]+ -> [\d.]+)\s+m/s\s+on\s+"
                            r"the\s+sample\)", ("dv",)),
    Quote("docs/report.md", r"\(sample:\s+sigma\s+(\d+)\s+arcsec\)", ("phi_z_sigma",)),
)
"""Every figure the docs quote from the sample run."""


def _g(value: float, digits: int) -> str:
    """``value`` to ``digits`` significant digits, without an exponent."""
    if not math.isfinite(value) or value == 0:
        return f"{value:g}"
    dec = max(0, digits - 1 - math.floor(math.log10(abs(value))))
    return f"{round(value, dec):.{dec}f}"


def sample_figures(run_dir: Path) -> dict[str, str]:
    """Every quoted figure, as the docs write it, from a sample run (evaluated)."""
    import pospp
    from pospp.report.summary import pm_text

    run = pospp.open_run(run_dir)
    s, legs, pairs = run.summary, run.legs, run.pairs
    used = pairs[pairs.used.astype(bool)]
    ev = run.evaluation
    ev = ev[ev.solution == "smoothed"].set_index("metric").value
    bias = pd.read_parquet(BIAS)
    inside = np.zeros(len(bias), bool)
    t_ns = bias.time_ns.to_numpy()
    for leg in legs.itertuples():
        inside |= (t_ns >= leg.start_ns) & (t_ns <= leg.end_ns)
    cal = run.calibration
    phi_z = cal[(cal.pair_id == -1) & (cal.parameter == "phi_z")
                & (cal.formulation == s["calibration_formulation"])]
    headings = [f"{h:.0f}" for h in legs.heading_deg]

    def word(n: int) -> str:
        return NUMBER_WORDS[n] if n < len(NUMBER_WORDS) else str(n)

    return {
        "n_legs_word": word(len(legs)),
        "headings": ", ".join(headings[:-1]) + f" and {headings[-1]}" if len(headings) > 1
        else "".join(headings),
        "n_pairs_word": word(len(used)),
        "cond_range": f"{used.cond_scaled.min():.0f} to {used.cond_scaled.max():.0f}",
        "bias_x": pm_text(s["gyro_bias_x_dph"], s["gyro_bias_x_sigma_dph"]),
        "bias_y": pm_text(s["gyro_bias_y_dph"], s["gyro_bias_y_sigma_dph"]),
        "bias_sensor_y": pm_text(s["gyro_bias_sensor_y_dph"], s["gyro_bias_sensor_y_sigma_dph"]),
        "truth_bias": f"{bias.gyro_bias_x_dph[inside].mean():.2f} / "
                      f"{bias.gyro_bias_y_dph[inside].mean():.2f}",
        "dv": f"{_g(s['dv_before_mps'], 3)} -> {_g(s['dv_after_mps'], 3)}",
        "dp": f"{_g(s['dp_before_m'], 3)} -> {_g(s['dp_after_m'], 3)}",
        "dv_after": _g(s["dv_after_mps"], 3),
        "dp_after": _g(s["dp_after_m"], 3),
        "tilt": _g(ev["roll_pitch_rms"], 2),
        "heading": _g(ev["heading_rms"], 2),
        "horizontal_cm": _g(100 * ev["horizontal_rms"], 2),
        "gap_uncalibrated": _g(s["gap_uncalibrated_mps"], 2),
        "gap_heldout": _g(s["gap_heldout_mps"], 2),
        "gap_fit": _g(s["gap_fit_mps"], 2),
        "phi_z_sigma": f"{float(phi_z.sigma.iloc[0]):.0f}" if len(phi_z) else "n/a",
    }


# ------------------------------------------------------------------------------- the PNGs


def _leg_end_figures(run_dir: Path) -> dict[str, list[float]]:
    """What the leg-error picture shows: B's horizontal velocity error at each leg's end,
    before and after compensation [m/s]."""
    import pospp

    le = pospp.open_run(run_dir).leg_errors
    out = {}
    for (leg, stage), g in le.groupby(["leg_id", "stage"]):
        last = g.sort_values("t_s").iloc[-1]
        out.setdefault(str(leg), [math.nan, math.nan])[stage == "after"] = float(
            round(math.hypot(last.dvn_mps, last.dve_mps), 4))
    return out


def _answer_figures(run_dir: Path) -> dict[str, str]:
    f = sample_figures(run_dir)
    return {k: f[k] for k in ("bias_x", "bias_y", "dv")}


def _draw_leg_errors(run_dir: Path, path: Path) -> None:
    import pospp

    fig = pospp.open_run(run_dir).plot.leg_errors("velocity")
    fig.savefig(path, dpi=80, metadata={META_KEY: json.dumps(_leg_end_figures(run_dir))})


def _shoot_answer(run_dir: Path, path: Path) -> None:
    """Screenshot of the report's top (headless chromium), its figures in the metadata."""
    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        print(f"  {path.name} kept: no chromium to draw it (.ci/run installs it)")
        return
    with tempfile.TemporaryDirectory() as tmp:
        shot = Path(tmp) / "shot.png"
        subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu",
                        "--hide-scrollbars", f"--user-data-dir={tmp}/profile",
                        "--window-size=1100,700", f"--screenshot={shot}",
                        (run_dir / "report.html").as_uri()], check=True, capture_output=True,
                       timeout=120)
        info = PngInfo()
        info.add_text(META_KEY, json.dumps(_answer_figures(run_dir)))
        Image.open(shot).save(path, pnginfo=info)


PNGS: dict[str, tuple[Callable[[Path, Path], None], Callable[[Path], object]]] = {
    "docs/img/sample_leg_errors.png": (_draw_leg_errors, _leg_end_figures),
    "docs/img/report_answer.png": (_shoot_answer, _answer_figures),
}
"""Picture -> (how to draw it from a run, the figures it shows)."""


def _png_figures(path: Path) -> object:
    from PIL import Image

    text = Image.open(path).text.get(META_KEY)  # type: ignore[attr-defined]
    return None if text is None else json.loads(text)


def _same(a: object, b: object) -> bool:
    """Figures equal; floats to 1e-3 of their size (another CPU's last bits)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float):
        return math.isclose(a, b, rel_tol=1e-3, abs_tol=1e-4) or (math.isnan(a) and math.isnan(b))
    return a == b


# ------------------------------------------------------------------------- check, write


def _matches(quote: Quote) -> list[re.Match[str]]:
    return list(re.finditer(quote.pattern, (REPO / quote.doc).read_text()))


def check(run_dir: Path) -> list[str]:
    """What disagrees between the docs and the run (empty: every figure agrees)."""
    figures = sample_figures(run_dir)
    bad = []
    for q in QUOTES:
        found = _matches(q)
        if not found:
            bad.append(f"{q.doc}: the sentence of {', '.join(q.keys)} is gone (pattern "
                       f"{q.pattern!r}); update QUOTES in docs/_make_figures.py")
        for m in found:
            for i, key in enumerate(q.keys, start=1):
                got = " ".join(m.group(i).split())
                if got != figures[key]:
                    line = (REPO / q.doc).read_text().count("\n", 0, m.start(i)) + 1
                    bad.append(f"{q.doc}:{line}: {key} says {got!r}, the run gives "
                               f"{figures[key]!r}")
    for name, (_, shows) in PNGS.items():
        want, got = shows(run_dir), _png_figures(REPO / name)
        if not _same(json.loads(json.dumps(want)), got):
            bad.append(f"{name}: shows {got}, the run gives {want}")
    return bad


def write(run_dir: Path) -> list[str]:
    """Rewrite every quoted figure and draw every picture again; returns what changed."""
    figures = sample_figures(run_dir)
    changed = []
    for doc in sorted({q.doc for q in QUOTES}):
        path = REPO / doc
        text = path.read_text()
        for q in (q for q in QUOTES if q.doc == doc):
            def sub(m: re.Match[str], q: Quote = q) -> str:
                out, last = [], m.start()
                for i, key in enumerate(q.keys, start=1):
                    out += [m.string[last:m.start(i)], figures[key]]
                    last = m.end(i)
                return "".join(out) + m.string[last:m.end()]
            new = re.sub(q.pattern, sub, text)
            if new != text:
                changed.append(f"{doc}: {', '.join(q.keys)}")
            text = new
        path.write_text(text)
    for name, (draw, _) in PNGS.items():
        draw(run_dir, REPO / name)
        changed.append(name)
    return changed


def sample_run(out: Path) -> Path:
    """Run the sample into ``out`` and evaluate it (the README's two commands)."""
    from pospp.api.studies import evaluate_run
    from pospp.config import load_config
    from pospp.pipeline import process_flight

    process_flight(SAMPLE, load_config(PIPELINE), out, force=True)
    evaluate_run(out, TRUTH, skip_s=SKIP_S)
    return out


def evaluated(run_dir: Path) -> Path:
    """``run_dir`` with the README's evaluation (made when it has none with this skip)."""
    from pospp.api.studies import evaluate_run

    ev = run_dir / "evaluation.parquet"
    if not ev.is_file() or not (pd.read_parquet(ev).skip_s == SKIP_S).all():
        evaluate_run(run_dir, TRUTH, skip_s=SKIP_S)
    return run_dir


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="compare, write nothing")
    ap.add_argument("--run", type=Path, default=None, help="an existing sample run folder")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        run = evaluated(args.run) if args.run else sample_run(Path(tmp) / "sample")
        if args.check:
            bad = check(run)
            for line in bad:
                print(line)
            print(f"{len(bad)} quoted figure(s) disagree with the run" if bad
                  else "every quoted figure agrees with the run")
            return 1 if bad else 0
        for line in write(run):
            print(f"  {line}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
