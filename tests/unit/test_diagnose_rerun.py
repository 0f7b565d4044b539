"""rerun.signature_at's local derivatives, re-used within one local step (A's response here a
known function of the antenna lever arm, so that what is re-run and what comes out is exact)."""

from types import SimpleNamespace

import numpy as np
import pytest

from pospp.diagnose import rerun
from pospp.diagnose.effects import effect_by_id

CONFIGURED_M = np.array([0.3, -0.1, 0.5])
TRUE_M = CONFIGURED_M - np.array([0.9, 0.0, 0.05])  # the flight's antenna (p: configured - true)
N_SAMPLES = (7, 5)  # two legs
H_M = rerun.LOCAL_STEP_FRACTION * effect_by_id("lever_arm").plausible_si


def _legs_response(lever_m: np.ndarray, quadratic: float) -> list[np.ndarray]:
    """B minus A per leg, (M, 2) [m/s], for A run with ``lever_m``: linear in the lever
    arm's error plus ``quadratic`` times its square (A's gate, in kind)."""
    dl = lever_m - TRUE_M
    out = []
    for k, m in enumerate(N_SAMPLES):
        a = np.cos(np.arange(m * 2 * 3) * (k + 1.3)).reshape(m, 2, 3)
        out.append(a @ dl + quadratic * np.full((m, 2), dl @ dl))
    return out


GAINS = object()  # the removed state's recorded gains (what the local steps must replay)


@pytest.fixture
def calls(monkeypatch):
    made: list[np.ndarray] = []
    quadratic = [0.0]

    def response(log_p, nav, calib_run, config, navigate, lever_b_m=None, **a_options):
        # the removed state is run first, recording its gains; every step replays them
        assert a_options == ({"record_gains": True} if not made else {"replay": GAINS}) or (
            len(a_options) == 1 and a_options.get("record_gains") is False)
        made.append(np.asarray(lever_b_m, dtype=float))
        flight = _legs_response(CONFIGURED_M, quadratic[0])  # (B - A)[flight]
        return [r - f for r, f in zip(_legs_response(lever_b_m, quadratic[0]), flight,
                                      strict=True)], GAINS if a_options.get("record_gains") \
            else None

    monkeypatch.setattr(rerun, "_response_and_gains", response)
    return made, quadratic


def _at(p, jacobians=None):
    config = SimpleNamespace(gnss=SimpleNamespace(lever_arm_m=CONFIGURED_M))
    return rerun.signature_at(None, None, None, config, "lever_arm", np.asarray(p),
                              navigate=None, jacobians=jacobians)


def test_local_derivatives_reused_within_one_step_and_remade_beyond(calls):
    made, _ = calls
    jac: rerun.Jacobians = {}
    p0 = np.array([0.9, 0.0, 0.0])
    _at(p0, jac)
    assert len(made) == 4 and np.allclose(jac["lever_arm"][0], p0)  # removed + 3 local steps
    near = p0 + np.array([0.0, 0.3, 0.8]) * H_M
    made.clear()
    sig = _at(near, jac)
    assert len(made) == 1 and np.allclose(made[0], CONFIGURED_M - near)  # the removed state only
    made.clear()
    fresh = _at(near)  # all four runs at the new estimate
    assert len(made) == 4
    for a, b in zip(sig, fresh, strict=True):  # A linear in the lever arm: J is J anywhere
        np.testing.assert_allclose(a, b, atol=1e-12)
    made.clear()
    _at(p0 + np.array([0.0, 0.0, 1.5]) * H_M, jac)  # beyond one local step: J re-made
    assert len(made) == 4


def test_reused_derivatives_keep_the_secant_at_the_estimate(calls):
    """A non-linear: the secant along p (what a fit along it reads) is the response from zero
    to p, re-made at p even when J is re-used."""
    made, quadratic = calls
    quadratic[0] = 0.4
    jac: rerun.Jacobians = {}
    p0 = np.array([0.9, 0.0, 0.05])
    _at(p0 + np.array([0.05, 0.0, 0.0]), jac)
    sig = _at(p0, jac)
    # the flight minus the removed state: the effect's whole response, read along u = p / |p|
    u = p0 / np.linalg.norm(p0)
    removed = [r - f for r, f in zip(_legs_response(CONFIGURED_M - p0, 0.4),
                                     _legs_response(CONFIGURED_M, 0.4), strict=True)]
    for s, r in zip(sig, removed, strict=True):
        np.testing.assert_allclose(s @ p0, -r, atol=1e-12)
        np.testing.assert_allclose(s @ u, -r / np.linalg.norm(p0), atol=1e-12)
