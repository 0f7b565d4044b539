"""Pipeline configuration: defaults, shipped configs, and errors that name the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from pospp.config import ConfigError, PipelineConfig, config_from_dict, load_config

PIPELINES = Path(__file__).resolve().parents[2] / "pipelines"


def test_empty_config_is_the_defaults():
    assert config_from_dict({}) == PipelineConfig()


@pytest.mark.parametrize("path", sorted(PIPELINES.glob("*.toml")), ids=lambda p: p.name)
def test_shipped_pipelines_load(path):
    cfg = load_config(path)
    assert cfg.name == path.stem


@pytest.mark.parametrize(
    ("data", "needle"),
    [
        ({"legz": {}}, "unknown section or key 'legz'"),
        ({"legs": {"min_duration": 300}}, "legs.min_duration: unknown key"),
        ({"legs": {"min_duration_s": "long"}}, "legs.min_duration_s: expected a number"),
        ({"imu": {"grade": "navigation"}}, "imu.grade: expected one of"),
        ({"gnss": {"lever_arm_m": [1.0, 2.0]}}, "gnss.lever_arm_m: expected a list of 3"),
        ({"filter": {"smoother": 1}}, "filter.smoother: expected true or false"),
        ({"legs": 5}, "[legs] must be a table"),
    ],
)
def test_bad_config_names_the_key(data, needle):
    with pytest.raises(ConfigError) as err:
        config_from_dict(data, source="x.toml")
    assert needle in str(err.value) and str(err.value).startswith("x.toml")


def test_bad_toml_file_is_named(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("[legs\nmin_duration_s = 3")
    with pytest.raises(ConfigError, match="bad.toml: not valid TOML"):
        load_config(p)
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "missing.toml")


def test_config_json_is_canonical():
    a = config_from_dict({"legs": {"min_duration_s": 200.0}, "name": "x"})
    b = config_from_dict({"name": "x", "legs": {"min_duration_s": 200}})
    assert a.to_json() == b.to_json()


def test_grade_defaults_fill_only_what_is_omitted():
    mems = config_from_dict({"imu": {"grade": "mems"}})
    assert (mems.gnss.pos_sigma_floor_m, mems.gnss.vel_sigma_floor_mps) == (0.2, 0.5)
    assert mems.legs.min_duration_s == 30.0
    explicit = config_from_dict({"imu": {"grade": "mems"},
                                 "gnss": {"pos_sigma_floor_m": 0.05},
                                 "legs": {"min_duration_s": 60.0}})
    assert explicit.gnss.pos_sigma_floor_m == 0.05 and explicit.gnss.vel_sigma_floor_mps == 0.5
    assert explicit.legs.min_duration_s == 60.0
    flight = PipelineConfig()
    assert (flight.gnss.pos_sigma_floor_m, flight.legs.min_duration_s) == (0.01, 300.0)
