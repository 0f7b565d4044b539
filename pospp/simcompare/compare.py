"""Step-wise comparison of a measured flight with its simulation (docs/compare_sim.md).

At each step, every statistic's gap g = measured - simulated is tested against sigma_g =
sqrt(sigma_m^2 + sigma_s^2) (two-sided, Student t with Welch-Satterthwaite degrees of
freedom, normal for A's own sigmas) with a Holm-Bonferroni correction over all statistics at
family-wise level ``alpha`` (default 0.01). The most significant gap (largest |g| / sigma_g)
is the target. Every library effect that moves the target and is not yet in the model is
fitted by weighted least squares on its linear statistics (slopes: identity or a trial
simulation, :mod:`pospp.simcompare.effects`; then secant iterations on the simulated
statistics for effects with ``refine``, or a grid over a parameter for effects with
``grid``); a candidate whose trial flight A cannot process is dropped. An effect is
admissible when its fitted u differs from zero (chi-square test, level ``alpha`` / number of
candidates); since a weighted least-squares fit's chi-square u^T H^T W H u is at most the
sum of its statistics' z^2 (a projection), a candidate whose fit statistics' z^2 sum stays
below that test's bound is dropped before any trial simulation. A joint effect
(``SimEffect.joint``: the lever arm and the GNSS time offset) is fitted on the measured log
instead, and names what its reading finds. Each admissible effect is added with its fitted
size and the flight re-simulated; the one with the least -2 log-likelihood of the gaps
after, sum z^2 + ln(sigma_after^2 / sigma_before^2) (plus 2 per parameter, as AIC), over the
statistics that some candidate of the step moves is kept (:func:`_score`), and
the gaps after are recorded. A multi-parameter effect adds only its components at least
``MIN_COMPONENT_Z`` sigma from zero (the others are reported as 0 with their sigma). A
target that no admissible effect explains, or whose gap the added effect does not shrink, is
``unexplained`` and left out of later targets (a step of its own, which does not count
against ``max_steps``). The loop stops when no target is left or ``max_steps`` effects have
been added.

A random effect whose realization over one flight is one draw of a slow process (the gyro
random drift, which over a few minutes is a random constant bias that A leaves in its
attitude, lever arm and bias trend) makes the statistics that are a signed mean of it one draw
too (``SimEffect.ensemble``): their expectation does not move, their batch-means sigmas (blocks
of one flight) do not see the spread between draws. A model with such an effect is therefore
also simulated with ``ENSEMBLE_DRAWS`` other seeds (:func:`ensemble_spread`), and those
statistics' sigmas, measured and simulated (under the model the measured flight is one more
draw), are at least their spread over the draws, with its degrees of freedom
(:func:`with_spread`; :mod:`pospp.simcompare.ensemble`). The spread is carried to the later
steps. Where the base model's drift widens a statistic that an effect is fitted on at least
``MASK_FACTOR`` times, the comparison says that this flight cannot tell that effect from the
drift's realisation there (``Comparison.masked``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy import stats as sps

from pospp.sim.gnss import GnssModel
from pospp.sim.sensors import ImuErrorModel
from pospp.simcompare.base_model import BaseParameter
from pospp.simcompare.effects import LIBRARY, EffectContext, JointFit, SimEffect
from pospp.simcompare.ensemble import (
    Masked,
    SimulateFn,
    ensemble_spread,
    masked_by_drift,
    masked_lines,
    with_spread,
)
from pospp.simcompare.stats import STAT_UNITS, FlightStats, Stat

__all__ = ["ALPHA", "Comparison", "Gap", "compare_flights", "gaps"]

ALPHA = 0.01
"""Family-wise significance level of the gap tests (Holm-Bonferroni)."""
MIN_COMPONENT_Z = 2.0
"""A multi-parameter effect adds only the components of its fit at least this many sigma
from zero (the others stay 0: e.g. the horizontal accelerometer ramps, which A's bias
estimate hardly sees)."""


@dataclass(frozen=True)
class Gap:
    """Measured minus simulated for one statistic, its sigma, z, Holm-adjusted p."""

    statistic: str
    measured: float
    simulated: float
    gap: float
    sigma: float
    z: float
    p_adjusted: float
    significant: bool


def _pvalue(m: Stat, s: Stat, z: float) -> float:
    vm, vs = m.sigma ** 2, s.sigma ** 2
    if not (np.isfinite(m.dof) and np.isfinite(s.dof)):
        return float(2.0 * sps.norm.sf(abs(z)))
    den = (vm ** 2 / max(m.dof, 1.0) if vm else 0.0) + (vs ** 2 / max(s.dof, 1.0) if vs else 0.0)
    dof = (vm + vs) ** 2 / den if den > 0 else 1.0
    return float(2.0 * sps.t.sf(abs(z), dof))


def gaps(measured: FlightStats, simulated: FlightStats, *, alpha: float = ALPHA,
         spread: dict[str, Stat] | None = None) -> dict[str, Gap]:
    """Every statistic's gap with its Holm-Bonferroni test at family-wise level ``alpha``;
    ``spread``: the model's spread between draws (:func:`ensemble_spread`), a floor of both
    sides' sigmas (:func:`with_spread`)."""
    measured, simulated = with_spread(measured, spread), with_spread(simulated, spread)
    out: dict[str, Gap] = {}
    raw: dict[str, float] = {}
    for name in STAT_UNITS:
        m, s = measured.stats.get(name), simulated.stats.get(name)
        if m is None or s is None:
            continue
        g = m.value - s.value
        sig = float(np.hypot(m.sigma, s.sigma))
        if not (np.isfinite(g) and np.isfinite(sig) and sig > 0):
            continue
        z = g / sig
        raw[name] = _pvalue(m, s, z)
        out[name] = Gap(name, m.value, s.value, g, sig, z, np.nan, False)
    order = sorted(raw, key=raw.__getitem__)
    n = len(order)
    running = 0.0
    stop = False
    for i, name in enumerate(order):
        running = max(running, min(1.0, (n - i) * raw[name]))
        sig = (not stop) and running <= alpha
        stop = stop or not sig
        old = out[name]
        out[name] = Gap(name, old.measured, old.simulated, old.gap, old.sigma, old.z, running,
                        sig)
    return out


@dataclass(frozen=True)
class Step:
    """One step: the target statistic, the effect added (or "unexplained"), its fitted
    parameters (reported units) and the gaps before and after."""

    step: int
    target: str
    effect: str
    params: tuple[str, ...]
    size: tuple[float, ...]
    sigma: tuple[float, ...]
    unit: str
    before: dict[str, Gap]
    after: dict[str, Gap]
    candidate: str = ""
    """For an ``unexplained`` step with parameters: the best candidate, whose fit (params,
    size, sigma, after) did not shrink the target."""
    units: tuple[str, ...] = ()
    """The unit of each parameter (``unit`` split at " | " when it names one per parameter)."""
    note: str = ""
    """The reading in words (a joint effect's: both readings where the flight cannot tell
    them apart)."""
    extra: tuple[tuple[str, float, float, str], ...] = ()
    """Further rows (parameter, value, sigma, unit): a joint effect's combination and
    correlations."""

    def param_units(self) -> tuple[str, ...]:
        """The unit of each parameter."""
        if self.units:
            return self.units
        parts = [u.strip() for u in self.unit.split("|")]
        return tuple(parts) if len(parts) == len(self.params) else (self.unit,) * len(
            self.params)


@dataclass(frozen=True)
class Comparison:
    """The whole comparison: the gaps of the base model, the steps, the final models."""

    base: dict[str, Gap]
    steps: tuple[Step, ...]
    imu_model: ImuErrorModel
    gnss_model: GnssModel
    final: dict[str, Gap]
    effects_added: tuple[str, ...] = field(default=())
    base_fit: tuple[BaseParameter, ...] = field(default=())
    """Step 0: the base model's levels fitted to the log (:mod:`pospp.simcompare.base_model`;
    empty when the comparison started from given models)."""
    masked: tuple[Masked, ...] = field(default=())
    """The statistics, and the effects fitted on them, that the base model's drift widens
    beyond what this flight can tell apart (:func:`pospp.simcompare.ensemble.masked_by_drift`)."""
    a_tuning: str = ""
    """How A was tuned for the measured and every simulated flight where not as configured
    (:func:`pospp.compare_sim.compare_log`); "" as configured."""


def _wls(h: NDArray, g: NDArray, w: NDArray):
    a = h.T @ (h * w[:, None])
    if not np.all(np.isfinite(a)) or np.linalg.matrix_rank(a) < h.shape[1]:
        return None
    cov = np.linalg.inv(a)
    u = cov @ (h.T @ (w * g))
    return u, cov, float(u @ a @ u)


def _refine(effect: SimEffect, names: list[str], at: tuple[list[int], NDArray], h: NDArray,
            g: NDArray, w: NDArray, fit, base: FlightStats, simulate: SimulateFn,
            imu: ImuErrorModel, gnss: GnssModel, ctx: EffectContext):
    """Fit u on the simulated statistic itself, not on its slope at zero: Broyden's secant
    method. With S(u) the simulated fit statistics of the model with u added and S(0) the
    base's, solve S(u) - S(0) = g (weighted least squares) by simulating at the current
    u_k, updating the slope along the last step (H += (dS - H du) du^T / du^T du) and
    stepping u_{k+1} = u_k + WLS(H, g - (S(u_k) - S(0))), for ``effect.refine`` iterations
    at most (stops when the step is below a tenth of its sigma). ``at = (cols, u_rest)``: the
    fitted parameters' indices and the full parameter vector they are set in (zeros, or a
    grid value). Returns the iterate with the least weighted residual sum(w r^2): (that
    residual, u, the covariance (H^T W H)^-1 of the local slope there, the chi-square of u
    against zero); the residual is NaN when no iterate was simulated. The chi-square is the
    drop of the weighted residual from u = 0 (sum w g^2) to the iterate's, a likelihood-ratio
    test (u^T H^T W H u for a linear response; the secant's slope is noise where its last
    step is below the statistic's sigma: docs/decisions.md "compare-sim's secant
    refinement")."""
    cols, u_rest = at
    s0 = np.array([base.stats[s].value for s in names])
    u_prev, s_prev = np.zeros(len(cols)), s0
    u_k, cov_k, _ = fit
    res_zero = float(np.sum(w * g * g))
    best = None
    for _ in range(effect.refine):
        full = np.array(u_rest, dtype=float)
        full[cols] = u_k
        sim = simulate(*effect.apply(imu, gnss, full, ctx))
        s_k = np.array([sim.stats[s].value if s in sim.stats else np.nan for s in names])
        if not np.all(np.isfinite(s_k)):
            break
        du, ds = u_k - u_prev, s_k - s_prev
        moved = du @ du > 0 and max(float(np.sum(w * ds * ds)),
                                    float(np.sum(w * (h @ du) ** 2))) >= 1.0
        if moved:  # a secant over less than the statistics' sigma is their noise
            h = h + np.outer(ds - h @ du, du) / (du @ du)
        r = g - (s_k - s0)
        a = h.T @ (h * w[:, None])
        if not np.all(np.isfinite(a)) or np.linalg.matrix_rank(a) < h.shape[1]:
            break
        cov_k = np.linalg.inv(a)
        res = float(np.sum(w * r * r))
        if best is None or res < best[0]:
            best = (res, u_k.copy(), cov_k, res_zero - res)
        step = cov_k @ (h.T @ (w * r))
        if np.all(np.abs(step) < 0.1 * np.sqrt(np.diag(cov_k))):
            break
        if moved:
            u_prev, s_prev = u_k, s_k
        u_k = u_k + step
    return (np.nan, *fit) if best is None else best


def _grid_fit(effect: SimEffect, names: list[str], g: NDArray, w: NDArray, base: FlightStats,
              simulate: SimulateFn, imu: ImuErrorModel, gnss: GnssModel, ctx: EffectContext):
    """Fit of an effect with a parameter the statistics are far from linear in (``grid``:
    its index and trial values, SI): at each value, the other parameters' slopes by one trial
    simulation each (with the grid parameter at that value) and their weighted least squares,
    re-simulated (for an effect with ``refine``: the best of the secant iterations from it,
    :func:`_refine`); the value whose re-simulation leaves the least weighted residual
    sum(w r^2) of the fit statistics is kept. Its sigma: the
    Delta chi^2 = 1 half-width of the parabola through the residuals at the best value and
    its two neighbours (NaN at the grid's ends)."""
    p = len(effect.params)
    assert effect.grid is not None  # called for effects with a grid only
    jg, values = effect.grid
    free = [j for j in range(p) if j != jg and j not in effect.fixed]
    fits = []
    for v in values:
        try:
            fits.append(_grid_point(effect, v, names, g, w, base, simulate, imu, gnss, ctx))
        except ValueError:  # a trial flight A cannot process: this value is out
            fits.append(None)
    ok = [i for i, f in enumerate(fits) if f is not None]
    if not ok:
        return None
    i = min(ok, key=lambda i: fits[i][0])
    uf, covf, chi = fits[i][1]
    u = np.zeros(p)
    u[free], u[jg] = uf, values[i]
    cov = np.zeros((p, p))
    cov[np.ix_(free, free)] = covf
    cov[jg, jg] = np.nan
    if 0 < i < len(values) - 1 and fits[i - 1] is not None and fits[i + 1] is not None:
        c = np.polyfit(values[i - 1:i + 2], [fits[k][0] for k in (i - 1, i, i + 1)], 2)[0]
        cov[jg, jg] = 1.0 / c if c > 0 else np.nan  # res = c (v - v0)^2 + ...: Delta 1
    return u, cov, chi


def _grid_point(effect: SimEffect, v: float, names: list[str], g: NDArray, w: NDArray,
                base: FlightStats, simulate: SimulateFn, imu: ImuErrorModel, gnss: GnssModel,
                ctx: EffectContext):
    """One value of :func:`_grid_fit`: (re-simulated weighted residual, WLS fit) or None."""
    p = len(effect.params)
    assert effect.grid is not None and effect.trial is not None  # _fit checked both
    jg = effect.grid[0]
    free = [j for j in range(p) if j != jg and j not in effect.fixed]
    h = np.zeros((len(names), len(free)))
    for k, j in enumerate(free):
        u = np.zeros(p)
        u[jg], u[j] = v, effect.trial[j]
        sim = simulate(*effect.apply(imu, gnss, u, ctx))
        h[:, k] = [(sim.stats[s].value - base.stats[s].value) / effect.trial[j] for s in names]
    fit = _wls(h, g, w)
    if fit is None:
        return None
    u = np.zeros(p)
    u[jg] = v
    if effect.refine:  # secant iterations from the trial slope; their best iterate
        res, *fit = _refine(effect, names, (free, u), h, g, w, fit, base, simulate, imu,
                            gnss, ctx)
        if np.isfinite(res):
            return res, tuple(fit)
    u[free] = fit[0]
    sim = simulate(*effect.apply(imu, gnss, u, ctx))  # the fit, re-simulated
    r = g - np.array([sim.stats[s].value - base.stats[s].value if s in sim.stats
                      else np.nan for s in names])
    res = float(np.sum(w * r * r))
    return (res if np.isfinite(res) else np.inf), fit


def _fit_names(effect: SimEffect, gap: dict[str, Gap],
               censoring: dict[str, Gap] | None = None) -> list[str]:
    """The statistics an effect's fit uses: its ``fit_first`` when the flight has them, its
    ``fit_censored`` when one of them differs significantly in ``censoring`` (default
    ``gap``), else its ``fit_stats`` (those with a gap). ``censoring``: the gaps on the two
    flights' own sigmas, without a drift's spread between draws: whether A's gate censors
    the measured records is this flight's fact, while the spread says whether the gap can
    be one draw (docs/decisions.md "The coloured GNSS error's censored fit")."""
    censored = [s for s in effect.fit_censored if s in gap]
    by = gap if censoring is None else censoring
    return ([s for s in effect.fit_first if s in gap]
            or (censored if any(s in by and by[s].significant for s in censored) else [])
            or [s for s in effect.fit_stats if s in gap])


def _fit(effect: SimEffect, gap: dict[str, Gap], base: FlightStats, simulate: SimulateFn,
         imu: ImuErrorModel, gnss: GnssModel, ctx: EffectContext,
         censoring: dict[str, Gap] | None = None):
    """Weighted least squares of the effect's parameters on its fit statistics' gaps:
    (u, cov, chi-square of u against zero), or None when they do not determine u.

    Slopes: the identity (``trial`` None), one trial simulation per parameter (per grid
    value of an effect with a ``grid``: :func:`_grid_fit`), or, for an
    effect with ``screen``, the identity to choose the parameters at least
    ``MIN_COMPONENT_Z`` sigma from zero and a trial simulation for those only, fitted on
    their own statistics (the others keep the identity fit's sigma and a value of 0); with
    ``trial_at_fit``, each trial at
    the size the identity fit reads (the statistics need not be linear far from it).
    ``censoring``: as :func:`_fit_names`.
    """
    names = _fit_names(effect, gap, censoring)
    if not names:
        return None
    p = len(effect.params)
    g = np.array([gap[s].gap for s in names])
    w = 1.0 / np.array([gap[s].sigma for s in names]) ** 2
    eye = np.eye(len(effect.fit_stats), p)[[effect.fit_stats.index(s) for s in names]]
    if effect.trial is None:
        return _wls(eye, g, w)
    cols = list(range(p))
    cov0 = u0 = None
    if effect.screen:
        fit0 = _wls(eye, g, w)
        if fit0 is None:
            return None
        u0, cov0, _ = fit0
        cols = [j for j in range(p) if abs(u0[j]) >= MIN_COMPONENT_Z * np.sqrt(cov0[j, j])]
        if not cols:
            return None
        # the chosen parameters' own estimates only: another component's estimate moves
        # with them by a cross-coupling that one trial draw does not reproduce, and its A
        # sigma can be far smaller (A's vertical accelerometer trend, 3.9e-8 m/s^3, took
        # 92 % of the weight of an x ramp's fit and read 21 900 ug/h as 3 400)
        own = [k for k, s in enumerate(names) if effect.fit_stats.index(s) in cols]
        names, g, w = [names[k] for k in own], g[own], w[own]
    if effect.grid is not None:
        return _grid_fit(effect, names, g, w, base, simulate, imu, gnss, ctx)
    h = np.zeros((len(names), len(cols)))
    for k, j in enumerate(cols):
        u = np.zeros(p)
        # the trial at the size the identity fit reads (effect.trial_at_fit), else fixed
        u[j] = u0[j] if effect.trial_at_fit and u0 is not None else effect.trial[j]
        sim = simulate(*effect.apply(imu, gnss, u, ctx))
        h[:, k] = [(sim.stats[s].value - base.stats[s].value) / u[j] for s in names]
    fit = _wls(h, g, w)
    if fit is not None and effect.refine:
        fit = _refine(effect, names, (cols, np.zeros(p)), h, g, w, fit, base, simulate, imu,
                      gnss, ctx)[1:]
    if fit is None or cov0 is None:
        return fit
    uc, covc, chi = fit
    u = np.zeros(p)
    u[cols] = uc
    cov = np.diag(np.diag(cov0))
    cov[np.ix_(cols, cols)] = covc
    return u, cov, chi


def _candidate(e: SimEffect, measured: FlightStats, cur: dict[str, Gap], sim: FlightStats,
               simulate: SimulateFn, imu: ImuErrorModel, gnss: GnssModel, ctx: EffectContext,
               spread: dict[str, Stat] | None, moved: set[str], n_cands: int, alpha: float):
    """One candidate of a step: fitted, tested, added and re-simulated (module docstring).
    Returns (score, effect, u, cov, imu, gnss, sim, gaps after, spread after) or None (not
    admissible, or a flight A cannot process)."""
    jf: JointFit | None = None
    if e.joint is not None:  # confounded effects, jointly on the measured log
        jf = e.joint(ctx)
        if jf is None:
            return None
        u, cov = jf.u, jf.cov
    else:
        own = gaps(measured, sim, alpha=alpha) if spread and e.fit_censored else None
        names = _fit_names(e, cur, own)
        if sum(cur[n].z ** 2 for n in names) < sps.chi2.isf(alpha / max(n_cands, 1),
                                                            len(e.params)):
            return None  # no fit on these gaps can be admissible: no trial simulation
        try:
            fit = _fit(e, cur, sim, simulate, imu, gnss, ctx, own)
        except ValueError:  # a trial flight A cannot process (e.g. cannot align)
            return None
        if fit is None:
            return None
        u, cov, chi_u = fit
        if sps.chi2.sf(chi_u, len(u)) > alpha / max(n_cands, 1):
            return None
        var = np.broadcast_to(np.asarray(e.variance, dtype=bool), u.shape)
        u = np.where(var, np.clip(u, 0.0, None), u)  # an added variance is >= 0
        if not np.any(u):  # a variance below the base model's is no effect
            return None
        if len(u) > 1:  # components within MIN_COMPONENT_Z sigma of zero are not added
            keep = np.abs(u) >= MIN_COMPONENT_Z * np.sqrt(np.diag(cov))
            if e.grid is not None:  # a grid parameter (a correlation time) is a choice
                keep[e.grid[0]] = True
            u = np.where(keep, u, 0.0)
        if not e.plausible(u, cov):
            return None
    imu2, gnss2 = e.apply(imu, gnss, u, ctx)
    try:
        sim2 = simulate(imu2, gnss2)
    except ValueError:
        return None
    if e.ensemble:  # the model's own spread between draws (module docstring)
        spread = ensemble_spread(simulate, imu2, gnss2, sim2, e.ensemble)
    after = gaps(measured, sim2, alpha=alpha, spread=spread)
    score = _score(after, cur, moved, int(np.count_nonzero(u)))
    return score, e, u, cov, imu2, gnss2, sim2, after, spread, jf


def _score(after: dict[str, Gap], before: dict[str, Gap], moved: set[str], k: int) -> float:
    """A candidate's score (least wins): -2 log-likelihood of the gaps after, over the
    statistics ``moved``, relative to the sigmas before, plus 2 per parameter (AIC):
    sum z^2 + ln(sigma_after^2 / sigma_before^2) + 2 k. The log term charges an effect that
    widens the sigmas (a random drift's spread between draws) for what it does not explain
    (docs/decisions.md "Candidates scored by their log-likelihood")."""
    score = 2.0 * k
    for n, g in after.items():
        if n in moved:
            score += g.z ** 2
            if n in before and before[n].sigma > 0:
                score += float(np.log(g.sigma ** 2 / before[n].sigma ** 2))
    return score


Progress = Callable[[str], None]
"""progress(line): one line per step of the comparison (the CLI prints them)."""


def _describe(e: SimEffect, u: NDArray, cov: NDArray, jf: JointFit | None) -> dict:
    """The Step fields naming the effect added: the joint fit's naming when it has one."""
    if jf is not None:
        return {"effect": jf.effect, "params": jf.params, "size": jf.size, "sigma": jf.sigma,
                "unit": " | ".join(dict.fromkeys(jf.units)), "units": jf.units,
                "note": jf.note, "extra": jf.extra}
    size, sig = e.size(u, cov)
    return {"effect": e.name, "params": e.params, "size": tuple(size), "sigma": tuple(sig),
            "unit": e.unit}


def compare_flights(measured: FlightStats, simulate: SimulateFn, imu: ImuErrorModel,
                    gnss: GnssModel, *, library: tuple[SimEffect, ...] = LIBRARY,
                    alpha: float = ALPHA, max_steps: int = 4,
                    context: EffectContext | None = None,
                    progress: Progress | None = None,
                    base_ensemble: tuple[str, ...] = ()) -> Comparison:
    """The step-wise comparison (module docstring).

    Parameters
    ----------
    measured : FlightStats
    simulate : callable(imu_model, gnss_model, draw=0) -> FlightStats
        Simulates the flight with the given models (draw 0: always the same seed; draw k:
        another seed, for :func:`ensemble_spread`) and returns its statistics.
    imu, gnss : the base simulation models (step 0's fit, or the configured grade).
    context : EffectContext, optional
        What the effects need beyond the models (default: the measured IMU's vibration line
        only; no joint estimate of the lever arm and the time offset).
    progress : callable(line), optional
        Told what each step does.
    base_ensemble : tuple of str
        Statistics that are one draw of a random effect already in the base model (step
        0's gyro drift): their spread between draws of the base model floors their sigmas
        from the start (:func:`ensemble_spread`).
    """
    say = progress or (lambda line: None)
    ctx = context or EffectContext(hf_peak_hz=measured.hf_peak_hz)
    sim = simulate(imu, gnss)
    # the base model: batch means and A's sigmas, and the draws' spread of its drift
    spread = ensemble_spread(simulate, imu, gnss, sim, base_ensemble) if base_ensemble \
        else None
    cur = gaps(measured, sim, alpha=alpha, spread=spread)
    base = cur
    masked = masked_by_drift(measured, sim, spread, library) if spread else ()
    say(f"base model simulated: {sum(g.significant for g in cur.values())} of {len(cur)} "
        "statistics differ significantly")
    for line in masked_lines(masked):
        say(line)
    steps: list[Step] = []
    added: list[str] = []  # the library's effects in the model
    named: list[str] = []  # what their steps named (a joint effect names what it found)
    dropped: set[str] = set()
    k = 0
    while len(added) < max_steps:
        targets = sorted((g for g in cur.values() if g.significant and g.statistic not in dropped),
                         key=lambda g: -abs(g.z))
        if not targets:
            break
        k += 1
        target = targets[0].statistic
        cands = [e for e in library if target in e.explains and e.name not in added]
        say(f"step {k}: target {target} (z {cur[target].z:+.1f}); candidates "
            f"{', '.join(e.name for e in cands) or 'none'}")
        # the statistics the choice is about: those some candidate moves (the others only
        # add noise to the score)
        moved = {st for e in cands for st in e.explains}
        tried = [c for c in (_candidate(e, measured, cur, sim, simulate, imu, gnss, ctx, spread,
                                        moved, len(cands), alpha) for e in cands)
                 if c is not None]
        if not tried:
            steps.append(Step(k, target, "unexplained", (), (), (), "", cur, cur))
            dropped.add(target)
            continue
        _, e, u, cov, imu2, gnss2, sim2, after, spread2, jf = min(tried, key=lambda x: x[0])
        d = _describe(e, u, cov, jf)
        if target in after and abs(after[target].z) >= abs(cur[target].z):
            # the best effect did not shrink its target: not kept
            # the model is unchanged: "after" is "before"
            d["candidate"] = d.pop("effect")
            steps.append(Step(k, target, "unexplained", before=cur, after=cur, **d))
            dropped.add(target)
            continue
        steps.append(Step(k, target, before=cur, after=after, **d))
        added.append(e.name)
        named.append(d["effect"])
        imu, gnss, sim, cur, spread = imu2, gnss2, sim2, after, spread2
    return Comparison(base, tuple(steps), imu, gnss, cur, tuple(named), masked=masked)
