"""What changed between two runs, or two batch roots, and is that within tolerance (``pospp diff``).

Per flight (a run folder; for two roots, the folders of the same name), two kinds of rows of
table ``diff`` (docs/formats.md):

- headline: ``status`` and the leg and pair counts (equal or not), every calibrated bias of
  the summary and its sigma (``<name>_dph`` with a ``<name>_sigma_dph`` partner: a change of at
  most ``bias_sigma_fraction`` of A's sigma is within), and B's errors at the horizon
  (``dv_*_mps``, ``dp_*_m``);
- trajectory, per solution, over the epochs both hold: position as the 3-D distance
  |r_B - r_A| (local NED of A, ``pospp.earth.llh_difference_ned_m``), velocity as
  |v_B - v_A|, attitude as the angle of the rotation between the two attitudes
  (``pospp.rotation.angle_between_rad``, never element-wise Euler); max and RMS over the
  epochs; and the epochs themselves (the same set in both, or not).

A flight in one root only is a row of its own (not within: the archive changed). A is the
baseline: tolerances scale with A's sigmas. Tolerances come from :class:`Tolerances` (defaults:
1 cm, 1 mm/s, 1 arcsec, a tenth of a bias sigma) or a TOML file with a ``[tolerance]`` table.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from pospp import earth, rotation
from pospp.api.run import SOLUTIONS, Run, open_run
from pospp.io import parquet_tables, run_folder
from pospp.io.manifest import MANIFEST, is_run_name, read_manifest
from pospp.units import ARCSEC_RAD

__all__ = ["DiffResult", "Tolerances", "diff_paths", "diff_runs", "load_tolerances"]

COLUMNS = [c.name for c in parquet_tables.TABLES["diff"]]


@dataclass(frozen=True)
class Tolerances:
    """The largest change taken as "unchanged" (each >= 0; TOML keys of ``[tolerance]``)."""

    position_m: float = 0.01
    """Trajectory position, 3-D distance [m]."""
    velocity_mps: float = 0.001
    """Trajectory velocity, |v_B - v_A| [m/s]."""
    attitude_arcsec: float = 1.0
    """Trajectory attitude, rotation angle between the two [arcsec]."""
    bias_sigma_fraction: float = 0.1
    """A calibrated bias and its sigma, as a fraction of A's sigma [1]."""
    horizon_error_mps: float = 0.001
    """B's velocity error at the horizon, before and after compensation [m/s]."""
    horizon_error_m: float = 0.01
    """B's position error at the horizon, before and after compensation [m]."""


def load_tolerances(path: str | Path) -> Tolerances:
    """:class:`Tolerances` from a TOML file's ``[tolerance]`` table (keys left out keep their
    default).

    Raises
    ------
    pospp.config.ConfigError
        Unreadable file, unknown key, or a value that is not a number >= 0 (names the key).
    """
    from pospp.config import ConfigError

    shown = run_folder.display_path(path)
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError(f"{shown}: cannot read the tolerances ({exc})") from None
    table = data.get("tolerance", {})
    extra = sorted(set(data) - {"tolerance"})
    known = {f.name for f in fields(Tolerances)}
    unknown = [f"tolerance.{k}" for k in table if k not in known]
    if extra or unknown or not isinstance(table, dict):
        raise ConfigError(f"{shown}: unknown key(s) {', '.join(extra + unknown)}; the "
                          f"[tolerance] table takes {', '.join(sorted(known))}")
    for k, v in table.items():
        if isinstance(v, bool) or not isinstance(v, int | float) or not v >= 0:
            raise ConfigError(f"{shown}: tolerance.{k} = {v!r}: expected a number >= 0")
    return Tolerances(**{k: float(v) for k, v in table.items()})


@dataclass(frozen=True)
class DiffResult:
    """The rows of table ``diff`` and what they say."""

    table: pd.DataFrame
    a: Path
    b: Path
    tolerances: Tolerances

    @property
    def within(self) -> bool:
        """True when every row is within its tolerance (``pospp diff`` exits 0)."""
        return bool(self.table.within.all())

    def flights(self, *, changed: bool) -> list[str]:
        """Flights with (``changed``) or without a row out of tolerance."""
        ok = self.table.groupby("flight", sort=True).within.all()
        return [str(f) for f, w in ok.items() if bool(w) != changed]

    def only_in(self, side: str) -> list[str]:
        """Flights present only in root ``side`` ("a" or "b")."""
        other = "b" if side == "a" else "a"
        t = self.table
        hit = (t["item"] == "flight") & (t[f"text_{side}"] == "present") & \
            (t[f"text_{other}"] == "absent")
        return [str(f) for f in t.flight[hit]]


def _row(flight: str, item: str, *, solution: str = "", a: float = math.nan,
         b: float = math.nan, text_a: str = "", text_b: str = "", max_diff: float = math.nan,
         rms_diff: float = math.nan, tol: float = 0.0, unit: str = "", within: bool,
         note: str = "") -> dict[str, Any]:
    return dict(zip(COLUMNS, (flight, item, solution, a, b, text_a, text_b, max_diff,
                              rms_diff, tol, unit, bool(within), "" if within else note),
                    strict=True))


def _num(v: Any) -> float:
    try:
        return math.nan if v is None else float(v)
    except (TypeError, ValueError):
        return math.nan


def _numeric_row(flight: str, item: str, a: float, b: float, tol: float, unit: str
                 ) -> dict[str, Any]:
    both_nan = math.isnan(a) and math.isnan(b)
    d = abs(b - a)
    within = both_nan or (not math.isnan(d) and d <= tol)
    return _row(flight, item, a=a, b=b, text_a=f"{a:.6g}", text_b=f"{b:.6g}", max_diff=d,
                rms_diff=d, tol=tol, unit=unit, within=within,
                note=f"{item} {a:.4g} -> {b:.4g} {unit} (|B - A| {d:.3g} > {tol:.3g})")


HEADLINE_COUNTS = ("n_legs", "n_pairs_used")
"""Summary counts compared exactly."""
HORIZON_ERRORS: dict[str, Callable[[Tolerances], float]] = {
    "dv_before_mps": lambda t: t.horizon_error_mps, "dv_after_mps": lambda t: t.horizon_error_mps,
    "dp_before_m": lambda t: t.horizon_error_m, "dp_after_m": lambda t: t.horizon_error_m}
"""Summary errors at the horizon and their tolerance."""


def _headline_rows(flight: str, a: Run, b: Run, tol: Tolerances) -> list[dict[str, Any]]:
    sa, sb = a.summary, b.summary
    rows = [_row(flight, "status", text_a=a.status, text_b=b.status, within=a.status == b.status,
                 note=f"status {a.status} -> {b.status}")]
    for k in HEADLINE_COUNTS:
        va, vb = _num(sa.get(k)), _num(sb.get(k))
        rows.append(_numeric_row(flight, k, va, vb, 0.0, ""))
    for k in sorted(set(sa) | set(sb)):
        stem = k[: -len("_dph")]
        sigma_key = f"{stem}_sigma_dph"
        if k.endswith("_sigma_dph") or not k.endswith("_dph") or sigma_key not in (set(sa) |
                                                                                   set(sb)):
            continue
        sigma_a = _num(sa.get(sigma_key))
        t = tol.bias_sigma_fraction * (sigma_a if np.isfinite(sigma_a) else 0.0)
        for key in (k, sigma_key):
            rows.append(_numeric_row(flight, key, _num(sa.get(key)), _num(sb.get(key)), t,
                                     "deg/h"))
    for k, t_of in HORIZON_ERRORS.items():
        rows.append(_numeric_row(flight, k, _num(sa.get(k)), _num(sb.get(k)), t_of(tol),
                                 sa.units.get(k, "")))
    return rows


def _solution_rows(flight: str, sol: str, ta: pd.DataFrame, tb: pd.DataFrame,
                   tol: Tolerances) -> list[dict[str, Any]]:
    m = ta.merge(tb, on="time_ns", suffixes=("_a", "_b"))
    n_a, n_b, n = len(ta), len(tb), len(m)
    rows = [_row(flight, "epochs", solution=sol, a=n_a, b=n_b, text_a=str(n_a),
                 text_b=str(n_b), max_diff=float(max(n_a, n_b) - n), rms_diff=float(n_a - n_b),
                 within=n_a == n_b == n,
                 note=f"{sol}: {n_a} -> {n_b} epochs, {n} in common")]
    if n == 0:
        return rows

    def col(name: str, side: str) -> np.ndarray:
        return m[f"{name}_{side}"].to_numpy(dtype=float)

    rad = np.radians
    dpos = earth.llh_difference_ned_m(rad(col("lat_deg", "b")), rad(col("lon_deg", "b")),
                                      col("height_m", "b"), rad(col("lat_deg", "a")),
                                      rad(col("lon_deg", "a")), col("height_m", "a"))
    dvel = np.column_stack([col(c, "b") - col(c, "a") for c in ("vn_mps", "ve_mps", "vd_mps")])
    rpy = [np.column_stack([rad(col(c, s)) for c in ("roll_deg", "pitch_deg", "yaw_deg")])
           for s in ("a", "b")]
    datt = rotation.angle_between_rad(rotation.dcm_from_euler(rpy[0]),
                                      rotation.dcm_from_euler(rpy[1])) / ARCSEC_RAD
    for item, d, t, unit in (("position", np.linalg.norm(dpos, axis=1), tol.position_m, "m"),
                             ("velocity", np.linalg.norm(dvel, axis=1), tol.velocity_mps, "m/s"),
                             ("attitude", datt, tol.attitude_arcsec, "arcsec")):
        dmax, rms = float(np.nanmax(d)), float(np.sqrt(np.nanmean(d ** 2)))
        rows.append(_row(flight, item, solution=sol, max_diff=dmax, rms_diff=rms, tol=t,
                         unit=unit, within=bool(dmax <= t),
                         note=f"{sol} {item}: max {dmax:.3g} {unit}, RMS {rms:.3g} {unit} "
                              f"(> {t:.3g})"))
    return rows


def _trajectory_rows(flight: str, a: Run, b: Run, tol: Tolerances) -> list[dict[str, Any]]:
    ta = a.trajectory(None) if a.has("trajectory") else None
    tb = b.trajectory(None) if b.has("trajectory") else None
    if ta is None and tb is None:
        return []
    rows = []
    have_a = set() if ta is None else set(ta.solution)
    have_b = set() if tb is None else set(tb.solution)
    for sol in [s for s in SOLUTIONS if s in have_a | have_b]:
        if sol not in have_a or sol not in have_b:
            ia, ib = sol in have_a, sol in have_b
            rows.append(_row(flight, "solution", solution=sol, text_a=_present(ia),
                             text_b=_present(ib), within=False,
                             note=f"solution {sol} only in {'A' if ia else 'B'}"))
            continue
        assert ta is not None and tb is not None
        rows += _solution_rows(flight, sol, ta[ta.solution == sol], tb[tb.solution == sol], tol)
    return rows


def _present(flag: bool) -> str:
    return "present" if flag else "absent"


def diff_runs(a: Run, b: Run, tolerances: Tolerances | None = None, *, flight: str = ""
              ) -> pd.DataFrame:
    """The ``diff`` rows of one flight: run ``b`` against the baseline run ``a``."""
    tol = tolerances or Tolerances()
    rows = _headline_rows(flight, a, b, tol) + _trajectory_rows(flight, a, b, tol)
    return pd.DataFrame(rows, columns=COLUMNS)


def _root_runs(root: Path) -> dict[str, Path]:
    """Folder name -> run folder of every flight of a batch root with a run."""
    table = read_manifest(root)
    assert table is not None
    names = [n for n in table.run_dir.dropna() if is_run_name(n)]
    return {n: root / n for n in sorted(set(names))
            if run_folder.read_marker(root / n) is not None}


def _kind(path: Path) -> str:
    if run_folder.read_marker(path) is not None:
        return "run"
    if (path / MANIFEST).is_file() and read_manifest(path) is not None:
        return "root"
    if not path.is_dir():
        raise FileNotFoundError(f"{run_folder.display_path(path)}: no such folder")
    raise run_folder.RunFolderError(f"{run_folder.display_path(path)}: neither a pospp run "
                                    f"folder nor a batch root (no marker, no {MANIFEST})")


def diff_paths(a: str | Path, b: str | Path, tolerances: Tolerances | None = None
               ) -> DiffResult:
    """Compare two run folders, or two batch roots (flights matched by folder name); ``a``
    is the baseline.

    Raises
    ------
    pospp.io.run_folder.RunFolderError
        A path is neither a run folder nor a batch root, or one is a run and the other a root.
    """
    pa_, pb_ = Path(a), Path(b)
    tol = tolerances or Tolerances()
    kinds = (_kind(pa_), _kind(pb_))
    if kinds[0] != kinds[1]:
        raise run_folder.RunFolderError(
            f"cannot compare a {kinds[0]} ({run_folder.display_path(pa_)}) with a {kinds[1]} "
            f"({run_folder.display_path(pb_)}): give two run folders or two batch roots")
    if kinds[0] == "run":
        return DiffResult(diff_runs(open_run(pa_), open_run(pb_), tol), pa_, pb_, tol)
    ra, rb = _root_runs(pa_), _root_runs(pb_)
    parts = []
    for name in sorted(set(ra) | set(rb)):
        if name not in ra or name not in rb:
            parts.append(pd.DataFrame([_row(name, "flight", text_a=_present(name in ra),
                                            text_b=_present(name in rb), within=False,
                                            note=f"only in {'A' if name in ra else 'B'}")],
                                      columns=COLUMNS))
            continue
        head = pd.DataFrame([_row(name, "flight", text_a="present", text_b="present",
                                  within=True)], columns=COLUMNS)
        parts += [head, diff_runs(open_run(ra[name]), open_run(rb[name]), tol, flight=name)]
    table = (pd.concat(parts, ignore_index=True) if parts
             else pd.DataFrame(columns=COLUMNS).astype({"within": bool}))
    return DiffResult(table, pa_, pb_, tol)


def write_diff(result: DiffResult, out_dir: str | Path) -> tuple[Path, Path]:
    """Write ``OUT/diff.parquet`` and ``OUT/diff.html`` (each atomically); returns both."""
    from pospp.api.diff_text import diff_html
    from pospp.io.files import atomic_path

    out = Path(out_dir)
    meta = {"a": run_folder.display_path(result.a), "b": run_folder.display_path(result.b),
            "tolerances": asdict(result.tolerances)}
    table = parquet_tables.write_table(out / "diff.parquet", result.table, "diff", metadata=meta)
    page = out / "diff.html"
    with atomic_path(page) as tmp:
        Path(tmp).write_text(diff_html(result), encoding="utf-8")
    return table, page
