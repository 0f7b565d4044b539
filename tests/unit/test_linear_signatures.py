"""The lever arm's, the GNSS time offset's and the accelerometer warm-up's signatures from
A's own gains (pospp.diagnose.linear_signatures) against A re-run on the perturbed log, on
the independent simulator's null flight (../shared/reference_cases/flight_null_200hz): the
re-runs go through the whole non-linear filter, smoother and B, the linear system through
A's recorded gains alone, so the agreement checks the records' errors (signs, frames, the
lever arm's rotation and the antenna's velocity), the warm-up's input and its alignment
tilt, and the response's layout together."""

from __future__ import annotations

from functools import partial

import numpy as np
import pytest
from test_diagnose_null_reference import _flight

from pospp import flight_stages as fs
from pospp.diagnose.effects import ACCEL_SETTLING_S
from pospp.diagnose.linear_signatures import linear_signatures
from pospp.diagnose.rerun import _response, restamped, warmed
from pospp.null_stage import linear_effect_signatures, linear_null_model, null_noise

pytestmark = pytest.mark.reference


@pytest.fixture(scope="module")
def case(reference_cases):
    log, nav, run, _, cfg = _flight(reference_cases, "flight_null_200hz")
    model = linear_null_model(log, nav, run, cfg, null_noise(log, nav, run, cfg))
    return log, nav, run, cfg, model


def _rel(sig: list, fd: list) -> float:
    a = np.concatenate([x.ravel() for x in sig])
    b = np.concatenate([x.ravel() for x in fd])
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def test_linear_signatures_are_a_rerun_derivatives(case):
    log, nav, run, cfg, model = case
    lin = linear_signatures(model, nav.smoothed.trajectory, cfg.gnss.lever_arm_m)
    staged = linear_effect_signatures(log, nav, run, cfg)  # what the diagnosis takes here
    assert sorted(staged) == ["accel_bias_change", "lever_arm", "time_offset"]
    assert all(np.array_equal(a, b) for e in lin for a, b in zip(lin[e], staged[e], strict=True))
    a_run = partial(fs.navigate, config=cfg, options=fs.rerun_options(cfg))
    lever0 = np.asarray(cfg.gnss.lever_arm_m, dtype=float)
    h = 0.05  # m: A's response to the lever arm is linear there (its gate open)
    for j in range(3):
        fd = [r / h for r in _response(log, nav, run, cfg, a_run, lever0 + h * np.eye(3)[j])]
        # measured 1.2-3.7 %: the re-runs' gains move with the lever arm, the linear ones not
        assert _rel([s[:, :, j] for s in lin["lever_arm"]], fd) < 0.06, j
    tau = 0.004  # s, central difference: the records move by less than an IMU epoch
    fd = [(p - m) / (2 * tau) for p, m in zip(
        _response(restamped(log, tau), nav, run, cfg, a_run),
        _response(restamped(log, -tau), nav, run, cfg, a_run), strict=True)]
    assert _rel([s[:, :, 0] for s in lin["time_offset"]], fd) < 0.10  # measured 4.7 %
    db = 20e-6 * 9.80665  # m/s^2: 20 ug, A's gate open
    for j in range(2):
        fd = [r / db for r in _response(warmed(log, db * np.eye(2)[j], ACCEL_SETTLING_S),
                                        nav, run, cfg, a_run)]
        # measured 3.2 and 1.3 %; without the alignment's tilt 18 and 41 %
        assert _rel([s[:, :, j] for s in staged["accel_bias_change"]], fd) < 0.06, j


def test_no_linear_signature_where_a_gated_in_excess(reference_cases):
    # flight_time_offset_200hz: its 15 ms offset makes A gate 62 GNSS records where its model
    # allows 4; A is not linear there, and the diagnosis re-runs it
    log, nav, run, _, cfg = _flight(reference_cases, "flight_time_offset_200hz")
    assert linear_effect_signatures(log, nav, run, cfg) == {}


def test_the_null_flights_diagnosis_starts_without_re_running_a(case, monkeypatch):
    # the speed of the method, not a timing: where A's gate is open and its lever-arm estimate
    # is within 3 of its sigmas of the configured one, the diagnosis's first signatures are
    # all A's linear response and the re-runs' base is never made
    import pospp.diagnose.rerun as rerun
    from pospp import diagnosis_stage

    log, nav, run, cfg, model = case
    calls = []
    real = rerun._response_and_gains
    monkeypatch.setattr(rerun, "_response_and_gains",
                        lambda *a, **k: calls.append("A re-run") or real(*a, **k))
    real_base = diagnosis_stage.rerun_base
    monkeypatch.setattr(diagnosis_stage, "rerun_base",
                        lambda *a, **k: calls.append("base") or real_base(*a, **k))
    est = fs.lever_arm_estimate(log, nav, cfg)
    start = diagnosis_stage.diagnosis_reruns(run, cfg, log=log, nav=nav, lever_estimate=est,
                                             null_model=model)
    assert start.sigs is not None
    assert sorted(start.sigs) == ["accel_bias_change", "lever_arm", "time_offset"]
    assert calls == [] and start.at == {}
