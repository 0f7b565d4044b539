"""Effect families with a shape basis (issue 34): the shapes on the hinge basis against their
closed forms, the family fit naming the shape it was made of, and what a sensor-bias change
does to B against B re-run on perturbed increments (the one strapdown kernel) and the Schuler
closed form."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from _synthetic import survey_flight

from pospp.calib.replay import ImuIncrements, replay_leg, solution_a_from_trajectory
from pospp.diagnose.sensor_families import (
    InnovationDesign,
    accel_response_along_b,
    fit_sensor_families,
    gyro_response_along_b,
)
from pospp.diagnose.shapes import (
    HOUR_S,
    SETTLING_GRID_S,
    all_variants,
    basis_size,
    change_at,
    change_basis,
    knots_s,
    step_times_s,
    time_shape,
)
from pospp.effects_catalog import CATALOG, SHAPES, catalog_entry, shape_unit
from pospp.units import DEG_PER_H_RADPS, G0_MPS2, UG_MPS2


def test_every_family_shape_is_catalogued_with_its_unit():
    names = {s.name for s in SHAPES}
    assert len(names) == len(SHAPES)
    for e in CATALOG:
        assert set(e.shapes) <= names, e.name
    assert shape_unit("accel_bias_change", "ramp") == ("ug_per_h", pytest.approx(UG_MPS2))
    assert shape_unit("gyro_bias_change", "step")[0] == "deg_per_h"
    assert catalog_entry("accel_bias_change").shapes[0] == "settling"  # the one first coded
    with pytest.raises(ValueError, match="shape"):
        shape_unit("lever_arm", "ramp")


def test_shapes_on_the_basis_are_their_closed_forms():
    knots = knots_s(600.0, 2700.0)
    assert knots.size == 7 and knots[0] == 600.0 and np.all(np.diff(knots) <= 300.0 + 1e-9)
    taus = step_times_s(knots)
    assert taus[0] > 600.0 and taus[-1] < 2700.0 and np.all(np.diff(taus) <= 60.0 + 1e-9)
    t = np.linspace(0.0, 2700.0, 2701)
    h = change_basis(t, knots)
    assert h.shape == (t.size, basis_size(knots)) == (t.size, knots.size + taus.size)
    (ramp,) = time_shape("ramp").variants(knots, 2700.0)
    np.testing.assert_allclose(h @ ramp.weights[:, 0], np.maximum(t - 600.0, 0) / HOUR_S,
                               atol=1e-12)
    steps = time_shape("step").variants(knots, 2700.0)
    assert [v.parameter for v in steps] == list(taus)
    s = h @ steps[12].weights[:, 0]  # a true step at its time
    np.testing.assert_array_equal(s, (t >= taus[12]).astype(float))
    nodes = np.append(knots, 2700.0)
    for v, tau in zip(time_shape("settling").variants(knots, 2700.0), SETTLING_GRID_S,
                      strict=True):
        exact = np.exp(-nodes / tau) - np.exp(-nodes[0] / tau)
        np.testing.assert_allclose(change_at(nodes, knots, v.weights)[:, 0], exact,
                                   atol=1e-12)  # the interpolant is exact at the knots
    (walk,) = time_shape("walk").variants(knots, 2700.0)
    assert walk.weights.shape == (basis_size(knots), 7)
    np.testing.assert_array_equal(walk.weights[7:], 0.0)  # the hinges alone


SCALE = {"accel_bias_change": 1e-3, "gyro_bias_change": 2.4e-7}
"""SI size of a coefficient whose synthetic response is of order one (about the families'
plausible sizes, 100 ug and 0.05 deg/h: the observability screen keeps them)."""


def _columns(resp: np.ndarray, w: np.ndarray) -> np.ndarray:
    """A shape's columns (n, A q) of whole responses (n, K, A), axis-major."""
    return np.concatenate([resp[:, :, a] @ w for a in range(resp.shape[2])], axis=1)


def _of(y: np.ndarray, resp: dict, knots) -> InnovationDesign:
    return InnovationDesign.of_responses(y, resp, knots, 2700.0,
                                         np.linspace(600.0, 2700.0, y.size // 3))


def _design(rng, a_true: np.ndarray, knots, n: int = 3000) -> InnovationDesign:
    return _of(*_responses(rng, a_true, knots, n), knots)


def _responses(rng, a_true: np.ndarray, knots, n: int = 3000) -> tuple[np.ndarray, dict]:
    """Whitened 'innovations' y = J a + N(0, 1) with smooth random responses J (per family
    (n, K + S, 2)); ``a_true`` (K + S, 2) the accelerometer's basis coefficients in units of
    SCALE."""
    k = basis_size(knots)
    tt = np.linspace(0.0, 1.0, n)
    base = np.stack([np.sin(2 * np.pi * (j + 1) * tt + rng.uniform(0, 6)) for j in range(4 * k)],
                    axis=1)
    mix = rng.normal(size=(4 * k, 2 * k * 2))
    j = (base @ mix).reshape(n, k, 2, 2)  # (n, K, axes, families)
    resp = {f: j[..., i] / SCALE[f] for i, f in enumerate(SCALE)}
    y = np.einsum("nka,ka->n", j[..., 0], a_true) + rng.normal(size=n)
    return y, resp


FAMS = ("accel_bias_change", "gyro_bias_change")
SHAPE_NAMES = {f: catalog_entry(f).shapes for f in FAMS}


@pytest.mark.parametrize("shape,index", [("ramp", 0), ("step", 3), ("settling", 2)])
def test_the_family_fit_names_the_shape_it_was_made_of(shape, index):
    knots = knots_s(600.0, 2700.0)
    v = time_shape(shape).variants(knots, 2700.0)[index]
    c = np.array([[0.06, -0.04]])  # SI per hinge unit: large against the unit noise
    a_true = v.weights @ c
    rng = np.random.default_rng(7)
    named, tested, ratio, holds = fit_sensor_families(_design(rng, a_true, knots), FAMS,
                                                      SHAPE_NAMES, 0.05)
    assert ratio < 1.5 and holds  # white noise of unit variance
    assert [f.effect for f in named] == ["accel_bias_change"]
    f = named[0]
    assert f.shape == shape and f.shape_parameters == v.parameter_text
    unit = shape_unit("accel_bias_change", shape)[1]
    np.testing.assert_allclose(f.values, c[0] * SCALE["accel_bias_change"] / unit,
                               atol=4 * f.sigmas.max())
    assert f.p_value < 1e-6 and f.delta_bic < 0
    np.testing.assert_allclose(f.basis_si, a_true * SCALE["accel_bias_change"],
                               atol=5 * np.sqrt(f.basis_cov_si.max()))


def test_the_family_fit_names_nothing_on_noise_at_its_level():
    knots = knots_s(600.0, 2700.0)
    named = 0
    for seed in range(40):
        rng = np.random.default_rng(100 + seed)
        found, tested, *_ = fit_sensor_families(
            _design(rng, np.zeros((basis_size(knots), 2)), knots), FAMS, SHAPE_NAMES, 0.05)
        named += bool(found)
        assert {f.effect for f in tested} == set(FAMS)
    assert named <= 2  # level 0.05 family-wise, Bonferroni over the variants: conservative


def test_a_candidate_on_the_step_s_gram_matrix_is_the_direct_least_squares():
    """Each candidate is fitted from the step's projected Gram matrix (Frisch-Waugh-Lovell):
    its coefficients, their covariance block and the RSS equal the direct least squares of
    the innovations on the model's columns plus the candidate's, with a model already
    holding another family's columns (the second step of the naming)."""
    from pospp.diagnose.sensor_families import _candidate, _Step

    knots = knots_s(600.0, 2700.0)
    rng = np.random.default_rng(5)
    y, resp = _responses(rng, rng.normal(scale=0.05, size=(basis_size(knots), 2)), knots)
    d = _of(y, resp, knots)
    (ramp,) = time_shape("ramp").variants(knots, 2700.0)
    base_x = _columns(resp["gyro_bias_change"], ramp.weights)
    c0, rss0, k0, _ = np.linalg.lstsq(base_x, d.y, rcond=None)
    base = np.zeros((d.jty.size, 2))  # the gyro's ramp as combinations of the design's columns
    base[d.columns["gyro_bias_change"][0]] = np.kron(np.eye(2), ramp.weights)
    step = _Step.of(d, FAMS, base, float(rss0[0]), int(k0))
    for v in time_shape("settling").variants(knots, 2700.0)[:3] + [ramp]:
        got = _candidate(d, step, "accel_bias_change", v, screened=False)
        assert got is not None
        x1 = np.concatenate([base_x, _columns(resp["accel_bias_change"], v.weights)], axis=1)
        c, rss, k1, _ = np.linalg.lstsq(x1, d.y, rcond=None)
        inv = np.linalg.inv(x1.T @ x1)
        np.testing.assert_allclose(got["c"], c[2:], rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(got["inv"], inv[2:, 2:], rtol=1e-7)
        assert got["rss"] == pytest.approx(float(rss[0]), rel=1e-10) and got["k"] == k1 == 4


@pytest.fixture(scope="module")
def flight():
    return survey_flight(headings_deg=(0.0, 180.0), leg_duration_s=240.0, rate_hz=50.0,
                         lead_in_s=400.0)


def _b_error(flight, imu, accel_bias_history=None):
    """B minus the truth on each leg, A = the truth (with an accelerometer-bias estimate)."""
    ref = solution_a_from_trajectory(flight.truth, v_sigma_n_mps=np.full(3, 0.01),
                                     accel_bias_b_mps2=accel_bias_history)
    return [replay_leg(imu, ref, leg) for leg in flight.legs]


def test_accelerometer_change_along_b_matches_b_re_run_and_the_schuler_closed_form(flight):
    # an accelerometer ramp r (body x, y) in the increments; A holds the true bias, as A's
    # tilt and bias estimate do at each leg start, so B carries b(t) - b(t0) from there
    imu = flight.imu
    t_mid = 0.5 * (imu.t_s[1:] + imu.t_s[:-1])
    r = np.array([900.0, -400.0]) * UG_MPS2 / HOUR_S
    bias = np.zeros((t_mid.size, 3))
    bias[:, 0:2] = t_mid[:, None] * r
    pert = ImuIncrements(imu.t_s, imu.dtheta_b_rad, imu.dv_b_mps + bias * np.diff(imu.t_s)[:, None])
    hist = np.zeros((flight.truth.t_s.size, 3))
    hist[:, 0:2] = flight.truth.t_s[:, None] * r
    clean = _b_error(flight, imu)  # no bias in the increments, none in A
    for rep, rep0 in zip(_b_error(flight, pert, hist), clean, strict=True):
        t = rep.t0_s + rep.t_s
        change = t[:, None] * r
        pred = accel_response_along_b(rep, change, change[0])
        got = rep.dv_n_mps[:, 0:2] - rep0.dv_n_mps[:, 0:2]
        assert np.sqrt(np.mean((pred - got) ** 2)) < 0.01 * np.sqrt(np.mean(got**2))
        # Schuler: dv'' = r_n - w_s^2 dv, dv = r_n (1 - cos w_s t) / w_s^2 (Earth rate aside)
        w_s = np.sqrt(G0_MPS2 / 6.371e6)
        r_n = rep.c_nb0[0:2, 0:2] @ r
        closed = np.outer((1 - np.cos(w_s * rep.t_s)) / w_s**2, r_n)
        assert np.sqrt(np.mean((pred - closed) ** 2)) < 0.03 * np.sqrt(np.mean(closed**2))


def test_gyro_change_along_b_matches_b_re_run(flight):
    imu = flight.imu
    t_mid = 0.5 * (imu.t_s[1:] + imu.t_s[:-1])
    rate = np.array([0.05, -0.03]) * DEG_PER_H_RADPS / HOUR_S  # deg/h per hour
    bias = np.zeros((t_mid.size, 3))
    bias[:, 0:2] = t_mid[:, None] * rate
    pert = dataclasses.replace(imu, dtheta_b_rad=imu.dtheta_b_rad
                               + bias * np.diff(imu.t_s)[:, None])
    for rep, rep0 in zip(_b_error(flight, pert), _b_error(flight, imu), strict=True):
        change = (rep.t0_s + rep.t_s)[:, None] * rate
        pred = gyro_response_along_b(rep, change, change[0])
        got = rep.dv_n_mps[:, 0:2] - rep0.dv_n_mps[:, 0:2]
        assert np.sqrt(np.mean((pred - got) ** 2)) < 0.01 * np.sqrt(np.mean(got**2))


def test_every_variant_of_a_family_is_tried():
    knots = knots_s(0.0, 1800.0)
    v = all_variants(SHAPE_NAMES["accel_bias_change"], knots, 1800.0)
    assert [x.shape for x in v].count("settling") == len(SETTLING_GRID_S)
    assert [x.shape for x in v].count("step") == step_times_s(knots).size
    assert {x.shape for x in v} == {"settling", "step", "ramp", "walk"}


def test_long_run_ratio_of_white_and_ar1_noise():
    from pospp.diagnose.sensor_families import long_run_ratio

    rng = np.random.default_rng(5)
    n = 30000
    t = np.arange(n, dtype=float)  # one record per second: lags up to 60
    assert long_run_ratio(rng.normal(size=(n, 3)), t, 60.0) == pytest.approx(1.0, abs=0.1)
    e = rng.normal(size=(n, 3))
    x = np.zeros_like(e)
    for k in range(1, n):  # AR(1), rho 0.5: (1 + rho) / (1 - rho) = 3, Bartlett's to 60: 2.93
        x[k] = 0.5 * x[k - 1] + e[k]
    assert long_run_ratio(x, t, 60.0) == pytest.approx(2.93, rel=0.1)


def test_correlated_innovations_are_corrected_and_a_wrong_scale_names_nothing():
    # smooth residuals (each component an AR(1) over the records, rho 0.95, unit variance):
    # the F tests alone would name a walk, divided by the long-run variance ratio they do not
    knots = knots_s(600.0, 2700.0)
    y0, resp0 = _responses(np.random.default_rng(9), np.zeros((basis_size(knots), 2)), knots)
    e = np.random.default_rng(10).normal(size=(y0.size // 3, 3))
    x = np.zeros_like(e)
    for k in range(1, e.shape[0]):
        x[k] = 0.95 * x[k - 1] + np.sqrt(1 - 0.95**2) * e[k]
    named, tested, ratio, holds = fit_sensor_families(_of(x.ravel(), resp0, knots), FAMS,
                                                      SHAPE_NAMES, 0.05)
    assert holds and ratio > 20 and not named  # (1 + rho) / (1 - rho) = 39, Bartlett 300 s: 34
    assert any(f.statistic * ratio > 10 for f in tested)  # uncorrected: far beyond the level
    # A's S ten times the innovations' variance (its model does not hold): a ramp that would
    # be named at unit scale is not
    v = time_shape("ramp").variants(knots, 2700.0)[0]
    a = v.weights @ np.array([[0.06, -0.04]])
    y, resps = _responses(np.random.default_rng(7), a, knots)
    assert fit_sensor_families(_of(y, resps, knots), FAMS, SHAPE_NAMES, 0.05)[0]
    resp = resps["accel_bias_change"] * SCALE["accel_bias_change"]
    y = y - np.einsum("nka,ka->n", resp, a)
    quiet = _of(0.3 * y + np.einsum("nka,ka->n", resp, a), resps, knots)
    named, _, _, holds = fit_sensor_families(quiet, FAMS, SHAPE_NAMES, 0.05)
    assert not holds and not named


def test_the_families_need_imu_noise_within_a_model_band():
    # A's likelihood needs A's noise model: IMU white noise read from the samples at most
    # NOISE_BAND times the configured (the simulator's 100 Hz MEMS with vibration: 125)
    from types import SimpleNamespace

    from pospp.config import config_from_dict
    from pospp.flight_stages import imu_tuning
    from pospp.sensor_stage import NOISE_BAND, imu_noise_holds
    from pospp.types import ImuSamples

    cfg = config_from_dict({"imu": {"grade": "vehicle"}})
    si = imu_tuning(cfg).noise()
    rng = np.random.default_rng(1)
    n, dt = 60000, 0.01
    t_ns = (np.arange(n) * dt * 1e9).astype(np.int64)

    def log(scale):  # white rates / specific force of density scale x the configured
        w = rng.normal(size=(n, 3)) * scale * si.gyro_arw_radpsqrts / np.sqrt(dt)
        f = rng.normal(size=(n, 3)) * scale * si.accel_vrw_mpspsqrts / np.sqrt(dt)
        f[:, 2] -= 9.8
        return SimpleNamespace(imu=ImuSamples(t_ns, w, f))

    assert imu_noise_holds(log(1.0), cfg)
    assert not imu_noise_holds(log(2.0 * NOISE_BAND), cfg)


def test_a_family_the_innovations_cannot_reveal_is_not_tested():
    # the workflow's observability screen: directions in which a plausible coefficient does
    # not stand 2 noise sigmas out are dropped (a gravity field over a flight along one line
    # read 3900 +- 2900 arcsec and moved the refit by 4.3 sigma before it)
    knots = knots_s(600.0, 2700.0)
    y, resp = _responses(np.random.default_rng(3), np.zeros((basis_size(knots), 2)), knots)
    weak = {**resp, "accel_bias_change": resp["accel_bias_change"] * 1e-6}
    named, tested, *_ = fit_sensor_families(_of(y, weak, knots), FAMS, SHAPE_NAMES, 0.05)
    assert {f.effect for f in tested} == {"gyro_bias_change"}


def test_a_large_ramp_below_the_screen_at_its_plausible_rate_is_named_a_ramp():
    """The screen asks whether the family can be seen at a plausible size; the shape is then
    chosen among the one-coefficient shapes fitted in full and the walk in its screened
    directions. Here a ramp at the plausible rate stands below the screen's bar (eigenvalue
    < 4) while the walk's many knot coefficients pass it, and the flight holds a ramp 30
    times the plausible rate: named `ramp` with its rate (before, the screen kept the walk
    alone and the family was named `walk` whatever the shape)."""
    from pospp.diagnose.sensor_families import SCREEN_EIGENVALUE, _plausible

    knots = knots_s(600.0, 2700.0)
    fam = "accel_bias_change"
    y0, resps = _responses(np.random.default_rng(11), np.zeros((basis_size(knots), 2)), knots)
    ramp, walk = (time_shape(s).variants(knots, 2700.0)[0] for s in ("ramp", "walk"))

    def lam_max(resp, v):
        cols = _columns(resp, v.weights)
        return float(np.linalg.eigvalsh(cols.T @ cols).max()) * _plausible(fam, v) ** 2

    resp = resps[fam]
    scale = np.sqrt(SCREEN_EIGENVALUE / np.sqrt(lam_max(resp, ramp) * lam_max(resp, walk)))
    resp = resp * scale
    assert lam_max(resp, ramp) < SCREEN_EIGENVALUE <= lam_max(resp, walk)
    c_si = 30.0 * _plausible(fam, ramp) * np.array([1.0, -0.5])  # per hinge unit, x and y
    y = _columns(resp, ramp.weights) @ c_si + np.random.default_rng(12).normal(size=y0.size)
    named, *_ = fit_sensor_families(_of(y, {**resps, fam: resp}, knots), FAMS, SHAPE_NAMES,
                                    0.05)
    assert [f.effect for f in named] == [fam]
    assert named[0].shape == "ramp"
    unit = shape_unit(fam, "ramp")[1]
    np.testing.assert_allclose(named[0].values, c_si / unit, atol=4 * named[0].sigmas.max())
