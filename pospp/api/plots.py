"""The report's figures of one run as matplotlib figures (``run.plot.leg_errors()``).

Each method draws from the run's tables alone with :mod:`pospp.report.figures` (the functions
that draw report.html) on a plain ``matplotlib.figure.Figure``: matplotlib is imported at the
first plot, pyplot's global backend is left alone (a notebook shows the figure as it shows its
own), and ``fig.savefig("x.png")`` writes a file.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pospp.report import figures

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from pospp.api.run import Run

__all__ = ["RunPlots"]

_BACKEND = "figure"


class RunPlots:
    """Figures of one :class:`pospp.api.run.Run` (returned, never written or shown)."""

    def __init__(self, run: Run) -> None:
        self._run = run

    def leg_errors(self, quantity: str = "velocity") -> Figure:
        """B minus A on each leg before and after compensation, north and east;
        ``quantity`` "velocity" [m/s] or "position" [m]."""
        if quantity not in ("velocity", "position"):
            raise ValueError(f"quantity: expected 'velocity' or 'position', got {quantity!r}")
        return figures.leg_error_curves(self._run.leg_errors, quantity, backend=_BACKEND)

    def trajectory_map(self) -> Figure:
        """The smoothed (or forward) track in local east/north km, legs coloured, numbered."""
        return figures.trajectory_map(self._run.trajectory(None), self._run.legs,
                                      backend=_BACKEND)

    def calibration(self) -> Figure:
        """Every pair's and the joint fit's calibrated values with their 1-sigma bars."""
        return figures.calibration_bars(self._run.calibration, backend=_BACKEND)

    def sigmas(self) -> Figure:
        """A's position, velocity and attitude 1-sigma over time (trajectory sigmas)."""
        return figures.trajectory_sigmas(self._run.trajectory(None), backend=_BACKEND)

    def diagnosis(self) -> Figure:
        """The gap per leg before and after the diagnosis's effects (diagnosis_curves)."""
        return figures.diagnosis_curves(self._run.table("diagnosis_curves"), backend=_BACKEND)

    def biases(self) -> Figure:
        """A's estimated gyro (and accelerometer) biases over time, body FRD, beside the
        calibrated constant gyro bias."""
        s = self._run.summary
        calibrated = {f"gyro_bias_{ax}": (s[f"gyro_bias_{ax}_dph"],
                                          s[f"gyro_bias_{ax}_sigma_dph"])
                      for ax in "xyz" if s.get(f"gyro_bias_{ax}_dph") is not None
                      and s.get(f"gyro_bias_{ax}_sigma_dph") is not None}
        biases = self._run.biases if self._run.has("biases") else None
        return figures.sensor_errors(biases, calibrated, span_s=s.get("duration_s"),
                                     backend=_BACKEND)
