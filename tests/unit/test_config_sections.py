"""Config sections give their stages' options (issue 17 item 4): every [legs] key is a field of
the segmentation's LegThresholds with the same default, and the join raises on a key the stage
does not have."""

from __future__ import annotations

import dataclasses

import pytest

from pospp.calib.segment import LegThresholds
from pospp.config import GRADE_DEFAULTS, Grade, LegsConfig, PipelineConfig, config_from_dict


def test_legs_section_is_the_segmentation_options():
    stage = {f.name: f.default for f in dataclasses.fields(LegThresholds)}
    for f in dataclasses.fields(LegsConfig):
        assert f.name in stage, f"[legs] {f.name} is not a LegThresholds field"
        if f.default is not None:  # None: the [imu] grade's default
            assert f.default == stage[f.name], f.name
    cfg = config_from_dict({"imu": {"grade": "mems"}, "legs": {"min_speed_mps": 5.0}})
    th = cfg.legs.thresholds()
    assert isinstance(th, LegThresholds)
    assert (th.min_duration_s, th.duration_tolerance_s, th.min_speed_mps) == (
        GRADE_DEFAULTS[Grade.MEMS].leg_min_duration_s,
        GRADE_DEFAULTS[Grade.MEMS].leg_duration_tolerance_s, 5.0)
    # flight: the paper's values, and the pipeline's settling time after A's start
    assert PipelineConfig().legs.thresholds() == dataclasses.replace(
        LegThresholds(), settle_s=GRADE_DEFAULTS[Grade.FLIGHT].leg_settle_s)


def test_unset_grade_keys_are_refused_outside_a_pipeline_config():
    with pytest.raises(ValueError, match="min_duration_s"):
        LegsConfig().thresholds()


def test_config_gives_the_filter_options_and_tuning():
    cfg = config_from_dict({"imu": {"grade": "tactical", "gyro_gm_tau_s": 100.0},
                            "filter": {"gate_reset_s": 12.0}})
    opt = cfg.filter_options()
    assert opt.gate_reset_s == 12.0
    assert opt.pos_sigma_floor_m == GRADE_DEFAULTS[Grade.TACTICAL].pos_sigma_floor_m
    assert cfg.imu.tuning().gyro_gm_tau_s == 100.0


def test_replay_and_pairs_sections_are_their_stages_options():
    from pospp.calib.pairs import PairPolicy
    from pospp.calib.replay import ReplayOptions

    cfg = config_from_dict({"replay": {"horizon_s": 200.0, "accel_compensation": "none"},
                            "pairs": {"mode": "all", "min_dheading_deg": 45.0}})
    assert cfg.replay.options() == ReplayOptions(accel_compensation="none", horizon_s=200.0)
    assert cfg.pairs.policy() == PairPolicy(mode="all", min_dheading_deg=45.0)
    # every [replay] key but the pipeline's own 'reference' is a ReplayOptions field with
    # the same default
    stage = {f.name: f.default for f in dataclasses.fields(ReplayOptions)}
    for f in dataclasses.fields(type(cfg.replay)):
        if f.name != "reference":
            assert f.name in stage and stage[f.name] == f.default, f.name
