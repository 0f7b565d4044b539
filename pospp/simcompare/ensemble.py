"""A random effect is one draw: the spread of a statistic between draws of a model, and what a
drift in the base model hides (docs/compare_sim.md, "A random effect is one draw").

A gyro Gauss-Markov drift with a correlation time of minutes is, over one flight, one random
bias per axis and its slow change. A leaves it in its attitude, lever arm, bias trends and its
estimate pass's scale factors, whose sign and size are this flight's draw; the batch-means
sigmas of those statistics (blocks of one flight) do not see how much they change between
draws. A model with such a drift is simulated with other seeds too (:func:`ensemble_spread`)
and those statistics' sigmas, measured and simulated, are at least their spread
(:func:`with_spread`): under the model the measured flight is one more draw.

Where that spread is several times the flights' own sigmas, an effect fitted on the
statistic cannot be told from the drift's realisation on this flight below the widened sigma
(:func:`masked_by_drift`): a gyro scale factor and the drift's change over the turns both move
A's gyro-bias and scale-factor estimates there. The comparison says so rather than naming
either.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from pospp.sim.gnss import GnssModel
from pospp.sim.sensors import ImuErrorModel
from pospp.simcompare.effects import SimEffect
from pospp.simcompare.stats import STAT_UNITS, FlightStats, Stat

__all__ = ["ENSEMBLE_DRAWS", "MASK_FACTOR", "Masked", "SimulateFn", "ensemble_spread",
           "masked_by_drift", "masked_lines", "with_spread"]

ENSEMBLE_DRAWS = 4
"""Other seeds a model with an ``ensemble`` effect is simulated with; with the comparison's own
simulation, ``ENSEMBLE_DRAWS`` degrees of freedom of each statistic's spread."""
MASK_FACTOR = 2.0
"""A statistic is reported as masked by the base model's drift when the spread between draws
widens its gap's sigma at least this many times (the smallest effect it can show at least
doubles)."""


class SimulateFn(Protocol):
    """simulate(imu, gnss, draw) -> the simulated flight's statistics: draw 0 with the
    comparison's own seed (common random numbers across its steps), draw k > 0 another seed."""

    def __call__(self, imu: ImuErrorModel, gnss: GnssModel, draw: int = 0) -> FlightStats: ...


def ensemble_spread(simulate: SimulateFn, imu: ImuErrorModel, gnss: GnssModel,
                    sim0: FlightStats, names: tuple[str, ...],
                    draws: int = ENSEMBLE_DRAWS) -> dict[str, Stat]:
    """Spread of the statistics ``names`` between draws of the model (SI, as the statistic):
    the model simulated with ``draws`` other seeds (a draw A cannot process is left out), and
    per statistic the sample standard deviation of its values over those and ``sim0`` (the
    comparison's own draw), as Stat(0, std, n - 1); only statistics with at least 3 values."""
    runs = [sim0]
    for k in range(1, draws + 1):
        try:
            runs.append(simulate(imu, gnss, k))
        except ValueError:  # a draw A cannot process (e.g. cannot align)
            continue
    out: dict[str, Stat] = {}
    for name in (n for n in names if n in sim0.stats):
        v = np.array([r.stats[name].value for r in runs if name in r.stats])
        v = v[np.isfinite(v)]
        if v.size >= 3:
            out[name] = Stat(0.0, float(np.std(v, ddof=1)), float(v.size - 1))
    return out


def with_spread(fs: FlightStats, spread: dict[str, Stat] | None) -> FlightStats:
    """The statistics with each sigma at least its spread between draws (then with the
    spread's degrees of freedom): sigma = max(sigma, spread)."""
    if not spread:
        return fs
    out = dict(fs.stats)
    for name, e in spread.items():
        st = out.get(name)
        if st is not None and e.sigma > st.sigma:
            out[name] = Stat(st.value, e.sigma, e.dof)
    return FlightStats(out, fs.hf_peak_hz)


@dataclass(frozen=True)
class Masked:
    """A statistic whose gap the base model's drift widens: ``sigma_own`` = sqrt(sigma_m^2 +
    sigma_s^2) of the two flights' own sigmas, ``sigma_drift`` the same with each floored
    by the spread between draws (the statistic's SI unit); ``effects``: the library effects
    fitted on it, which this flight cannot tell from the drift's realisation within
    ``sigma_drift``."""

    statistic: str
    sigma_own: float
    sigma_drift: float
    effects: tuple[str, ...]

    def text(self) -> str:
        """The row's statement (sim_comparison.parquet's note at step 0)."""
        return (f"widened by the spread between draws of the base model (its gyro drift) to "
                f"{self.sigma_drift:.3g} {STAT_UNITS[self.statistic]} "
                f"({self.sigma_drift / self.sigma_own:.1f} x the flights' own "
                f"{self.sigma_own:.3g}): {' / '.join(self.effects)} cannot be told from a "
                "draw of the base model within it on this flight")


def masked_lines(masked: tuple[Masked, ...]) -> list[str]:
    """One statement per effect that the base model's drift masks, with its statistics
    (console, sim_model.toml's header)."""
    by: dict[str, list[Masked]] = {}
    for m in masked:
        for e in m.effects:
            by.setdefault(e, []).append(m)

    def unit(m: Masked) -> str:
        return "" if STAT_UNITS[m.statistic] == "-" else f" {STAT_UNITS[m.statistic]}"

    return [f"{e}: this flight cannot tell it from a draw of the base model (its gyro drift) "
            "within the spread between draws, sigma of the gap "
            + ", ".join(f"{m.statistic} {m.sigma_drift:.3g}{unit(m)} "
                        f"({m.sigma_drift / m.sigma_own:.1f} x the flights' own)" for m in ms)
            for e, ms in by.items()]


def masked_by_drift(measured: FlightStats, simulated: FlightStats, spread: dict[str, Stat],
                    library: tuple[SimEffect, ...]) -> tuple[Masked, ...]:
    """The statistics that some library effect is fitted on (``fit_stats``) whose gap's
    sigma the spread between draws widens by at least ``MASK_FACTOR``, in ``spread``'s
    order."""
    out = []
    for name, e in spread.items():
        m, s = measured.stats.get(name), simulated.stats.get(name)
        effects = tuple(x.name for x in library if name in x.fit_stats)
        if m is None or s is None or not effects:
            continue
        own = float(np.hypot(m.sigma, s.sigma))
        wide = float(np.hypot(max(m.sigma, e.sigma), max(s.sigma, e.sigma)))
        if own > 0 and np.isfinite(wide) and wide >= MASK_FACTOR * own:
            out.append(Masked(name, own, wide, effects))
    return tuple(out)
