"""Smooth scalar schedules built from non-overlapping quintic smoothstep ramps.

A schedule x(t) starts at ``x0`` and changes by ``delta_i`` over each ramp
``[t_i, t_i + T_i]`` along the C2 "smootherstep"

    S(u) = 10 u^3 - 15 u^4 + 6 u^5,  u = (t - t_i) / T_i in [0, 1],

so S'(0) = S'(1) = S''(0) = S''(1) = 0: x, x' and x'' are continuous everywhere, and the IMU
built from such schedules sees no impossible jerks. Values, the first two derivatives and the
running integral of x are all closed-form (the integral of S over [0, 1] is 1/2), so heading is
exactly the integral of the heading-rate schedule. Units are whatever the caller's are (the
simulator uses rad/s for heading rate, m/s for speed, rad for flight-path angle); times in s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray


def smoothstep(u: NDArray) -> NDArray:
    """S(u) = 10 u^3 - 15 u^4 + 6 u^5 for u in [0, 1] (clip u first)."""
    return u**3 * (10.0 + u * (-15.0 + 6.0 * u))


def smoothstep_d1(u: NDArray) -> NDArray:
    """dS/du = 30 u^2 (1 - u)^2."""
    return 30.0 * u**2 * (1.0 - u) ** 2


def smoothstep_d2(u: NDArray) -> NDArray:
    """d2S/du2 = 60 u (1 - u) (1 - 2 u)."""
    return 60.0 * u * (1.0 - u) * (1.0 - 2.0 * u)


def smoothstep_integral(u: NDArray) -> NDArray:
    """Integral of S from 0 to u: 5/2 u^4 - 3 u^5 + u^6 (equals 1/2 at u = 1)."""
    return u**4 * (2.5 + u * (-3.0 + u))


@dataclass(frozen=True)
class RampSchedule:
    """x(t) = x0 + sum_i delta_i S((t - t_i) / T_i), ramps sorted and non-overlapping.

    Attributes
    ----------
    x0 : float
        Value before the first ramp.
    start_s, duration_s, delta : ndarray, shape (M,)
        Ramp start times [s], lengths [s] (> 0) and value changes.
    """

    x0: float
    start_s: NDArray
    duration_s: NDArray
    delta: NDArray

    def __post_init__(self) -> None:
        t0 = np.asarray(self.start_s, dtype=float)
        dur = np.asarray(self.duration_s, dtype=float)
        if t0.shape != dur.shape or t0.shape != np.shape(self.delta):
            raise ValueError("start_s, duration_s and delta must have the same shape")
        if (dur <= 0.0).any():
            raise ValueError(f"ramp durations must be > 0 s, got min {dur.min()!r}")
        if t0.size > 1 and (t0[1:] < t0[:-1] + dur[:-1] - 1e-9).any():
            k = int(np.argmax(t0[1:] < t0[:-1] + dur[:-1] - 1e-9))
            raise ValueError(
                f"ramps overlap: ramp {k + 1} starts at {t0[k + 1]} s before ramp {k} ends at "
                f"{t0[k] + dur[k]} s"
            )

    @classmethod
    def build(cls, x0: float, ramps: list[tuple[float, float, float]]) -> RampSchedule:
        """From a list of (start_s, duration_s, delta); zero-delta ramps are dropped."""
        ramps = sorted((r for r in ramps if r[2] != 0.0), key=lambda r: r[0])
        arr = np.array(ramps, dtype=float).reshape(-1, 3)
        return cls(float(x0), arr[:, 0].copy(), arr[:, 1].copy(), arr[:, 2].copy())

    def _locate(self, t: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        """Index of the last ramp started (-1: none yet), that index clipped to >= 0, and
        u = (t - t_i) / T_i clipped to [0, 1] (0 before the first ramp). Needs >= 1 ramp."""
        i = np.searchsorted(self.start_s, t, side="right") - 1
        ic = np.maximum(i, 0)
        u = np.clip((t - self.start_s[ic]) / self.duration_s[ic], 0.0, 1.0)
        u = np.where(i >= 0, u, 0.0)
        return i, ic, u

    def _values_before(self) -> NDArray:
        """Value at the start of each ramp."""
        return self.x0 + np.concatenate([[0.0], np.cumsum(self.delta)[:-1]])

    def evaluate(self, t_s: ArrayLike) -> tuple[NDArray, NDArray, NDArray]:
        """x, dx/dt, d2x/dt2 at times ``t_s``."""
        t = np.asarray(t_s, dtype=float)
        if self.start_s.size == 0:
            return np.full(t.shape, self.x0), np.zeros(t.shape), np.zeros(t.shape)
        i, ic, u = self._locate(t)
        on = i >= 0
        d = np.where(on, self.delta[ic], 0.0)
        dur = self.duration_s[ic]
        x = np.where(on, self._values_before()[ic], self.x0) + d * smoothstep(u)
        x1 = d * smoothstep_d1(u) / dur
        x2 = d * smoothstep_d2(u) / dur**2
        return x, x1, x2

    def integral(self, t_s: ArrayLike, t_ref_s: float = 0.0) -> NDArray:
        """Integral of x from ``t_ref_s`` to ``t_s`` (closed form)."""
        t = np.asarray(t_s, dtype=float)
        return self._integral_from_minus_inf(t) - self._integral_from_minus_inf(
            np.asarray(t_ref_s, dtype=float)
        )

    def _integral_from_minus_inf(self, t: NDArray) -> NDArray:
        # integral of (x - x0) from -inf, plus x0 * t; each ramp adds delta * (T * I(u) + ...)
        if self.start_s.size == 0:
            return self.x0 * t
        before = self._values_before() - self.x0  # offset (x - x0) at each ramp start
        # accumulated integral of (x - x0) at each ramp start
        ends = self.start_s + self.duration_s
        acc = np.zeros(self.start_s.size)
        if self.start_s.size > 1:
            # over [t_k, t_{k+1}]: ramp k contributes before_k*T_k + delta_k*T_k/2, then flat
            seg = (
                before[:-1] * self.duration_s[:-1]
                + self.delta[:-1] * self.duration_s[:-1] * 0.5
                + (before[:-1] + self.delta[:-1]) * (self.start_s[1:] - ends[:-1])
            )
            acc[1:] = np.cumsum(seg)
        i, ic, u = self._locate(t)
        on = i >= 0
        dur = self.duration_s[ic]
        tau = t - self.start_s[ic]
        ramp_part = np.where(
            tau <= dur,
            before[ic] * tau + self.delta[ic] * dur * smoothstep_integral(u),
            before[ic] * dur + self.delta[ic] * dur * 0.5 + (before[ic] + self.delta[ic])
            * (tau - dur),
        )
        return np.where(on, acc[ic] + ramp_part, 0.0) + self.x0 * t


@dataclass(frozen=True)
class WanderSchedule:
    """Smooth sinusoidal wander on non-overlapping windows, zero outside them.

    On window i (``[t_i, t_i + T_i]``), with u = t - t_i::

        x(t) = A_i sin(2 pi u / P_i) c_i(u),   c_i(u) = S(u / tau_i) S((T_i - u) / tau_i),

    S the smootherstep above (clipped to [0, 1]) and tau_i = min(P_i / 2, T_i / 4) the taper
    time. c rises from 0 to 1 over the first tau_i and falls back over the last, with zero first
    and second derivatives at both ends, so x, x' and x'' are continuous everywhere and x
    returns to exactly 0 at the window's end (the next segment starts from the nominal value).
    Between the tapers x is the plain sinusoid of amplitude A_i. Units are the caller's.

    Attributes
    ----------
    start_s, duration_s, amplitude, period_s : ndarray, shape (M,)
        Window starts [s], lengths T [s] (> 0), amplitudes A and periods P [s] (> 0).
    """

    start_s: NDArray
    duration_s: NDArray
    amplitude: NDArray
    period_s: NDArray

    def __post_init__(self) -> None:
        arrs = [np.asarray(getattr(self, k), dtype=float).reshape(-1)
                for k in ("start_s", "duration_s", "amplitude", "period_s")]
        if len({a.shape for a in arrs}) != 1:
            raise ValueError("start_s, duration_s, amplitude and period_s must match in shape")
        if (arrs[1] <= 0).any() or (arrs[3] <= 0).any():
            raise ValueError("wander windows need duration_s > 0 and period_s > 0")
        if arrs[0].size > 1 and ((np.diff(arrs[0]) < 0).any()
                                 or (arrs[0][1:] < arrs[0][:-1] + arrs[1][:-1] - 1e-9).any()):
            raise ValueError("wander windows must be sorted and must not overlap")
        for k, a in zip(("start_s", "duration_s", "amplitude", "period_s"), arrs, strict=True):
            object.__setattr__(self, k, a)

    @classmethod
    def build(cls, windows: list[tuple[float, float, float, float]]) -> WanderSchedule:
        """From a list of (start_s, duration_s, amplitude, period_s); zero amplitudes dropped."""
        w = sorted((x for x in windows if x[2] != 0.0), key=lambda x: x[0])
        arr = np.array(w, dtype=float).reshape(-1, 4)
        return cls(*(arr[:, k].copy() for k in range(4)))

    def evaluate(self, t_s: ArrayLike) -> tuple[NDArray, NDArray, NDArray]:
        """x, dx/dt, d2x/dt2 at times ``t_s``."""
        t = np.asarray(t_s, dtype=float)
        zero = np.zeros(t.shape)
        if self.start_s.size == 0:
            return zero, zero.copy(), zero.copy()
        i = np.clip(np.searchsorted(self.start_s, t, side="right") - 1, 0, None)
        dur, amp, per = self.duration_s[i], self.amplitude[i], self.period_s[i]
        u = t - self.start_s[i]
        inside = (u >= 0.0) & (u <= dur)
        u = np.clip(u, 0.0, dur)
        tau = np.minimum(0.5 * per, 0.25 * dur)
        a = np.clip(u / tau, 0.0, 1.0)
        b = np.clip((dur - u) / tau, 0.0, 1.0)
        sa, sb = smoothstep(a), smoothstep(b)
        da, db = smoothstep_d1(a) / tau, -smoothstep_d1(b) / tau
        dda, ddb = smoothstep_d2(a) / tau**2, smoothstep_d2(b) / tau**2
        c, c1, c2 = sa * sb, da * sb + sa * db, dda * sb + 2.0 * da * db + sa * ddb
        w = 2.0 * np.pi / per
        g, g1, g2 = amp * np.sin(w * u), amp * w * np.cos(w * u), -amp * w * w * np.sin(w * u)
        x = np.where(inside, g * c, 0.0)
        x1 = np.where(inside, g1 * c + g * c1, 0.0)
        x2 = np.where(inside, g2 * c + 2.0 * g1 * c1 + g * c2, 0.0)
        return x, x1, x2
