"""Pipeline configuration: defaults, shipped configs, and errors that name the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from pospp.config import ConfigError, PipelineConfig, config_from_dict, load_config

PIPELINES = Path(__file__).resolve().parents[2] / "pipelines"


def test_empty_config_is_the_defaults():
    assert config_from_dict({}) == PipelineConfig()


@pytest.mark.parametrize("path", sorted(PIPELINES.rglob("*.toml")), ids=lambda p: p.name)
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


# ---------------------------------------------------------------- ranges (issue 13 item 4)


@pytest.mark.parametrize(
    ("data", "needle"),
    [  # each of these was a traceback or a silent "ok" (issue 13)
        ({"filter": {"output_rate_hz": 0}}, "filter.output_rate_hz: expected a value >= 0.01"),
        ({"filter": {"output_rate_hz": -10}}, "filter.output_rate_hz: expected a value >= 0.01"),
        ({"outputs": {"mcap_rate_hz": 0}}, "outputs.mcap_rate_hz: expected a value >= 0.01"),
        ({"replay": {"sample_rate_hz": 0}}, "replay.sample_rate_hz: expected a value >= 0.01"),
        ({"replay": {"horizon_s": -300}}, "replay.horizon_s: expected a value >= 1"),
        ({"replay": {"transition_step": 0}}, "replay.transition_step: expected a value >= 1"),
        ({"gnss": {"gate_probability": 1.0}}, "gnss.gate_probability: expected a value >= 0.5, "
                                              "<= 0.999999"),
        ({"gnss": {"lever_arm_m": [0.0, 1e9, 0.0]}}, "gnss.lever_arm_m[1]: expected a value"),
        ({"input": {"max_chunk_mib": 0}}, "input.max_chunk_mib: expected a value >= 1"),
        ({"input": {"start_s": 100.0, "end_s": 50.0}}, "input.end_s: expected a value > "
                                                       "input.start_s"),
        ({"input": {"imu_topic": ""}}, "input.imu_topic: expected a string of 1 to 256"),
        ({"legs": {"min_duration_s": 10**400}}, "legs.min_duration_s: expected a finite"),
        ({"imu": {"gyro_gm_tau_s": float("inf")}}, "imu.gyro_gm_tau_s: expected a finite"),
    ],
)
def test_out_of_range_value_names_the_key_and_the_limit(data, needle):
    with pytest.raises(ConfigError) as err:
        config_from_dict(data, source="x.toml")
    assert needle in str(err.value) and str(err.value).startswith("x.toml")


@pytest.mark.parametrize(
    ("data", "needle"),
    [  # each of these was accepted (issue 38 item 5)
        ({"input": {"start_s": 9.3e9}}, "input.start_s: expected a value >= 0, <= 1e+07"),
        ({"replay": {"horizon_s": 1e-300}}, "replay.horizon_s: expected a value >= 1"),
        ({"filter": {"output_rate_hz": 1e-300}}, "filter.output_rate_hz: expected a value >= "),
        ({"imu": {"gyro_gm_tau_s": 1e-300}}, "imu.gyro_gm_tau_s: expected a value >= 1"),
        ({"gnss": {"pos_sigma_floor_m": 1e300}}, "gnss.pos_sigma_floor_m: expected a value"),
        ({"replay": {"sample_rate_hz": 1000}}, "replay.sample_rate_hz: expected a value"),
        ({"pairs": {"noise_step_s": 1e-300}}, "pairs.noise_step_s: expected a value >= 0.1"),
    ],
)
def test_nonsense_values_are_refused_naming_the_physical_range(data, needle):
    with pytest.raises(ConfigError) as err:
        config_from_dict(data, source="x.toml")
    assert needle in str(err.value), str(err.value)


def _number_keys():
    """(section class, key) of every numeric key (float or int, lists of numbers too)."""
    import typing

    for section, cls in typing.get_type_hints(PipelineConfig).items():
        if section == "name":
            continue
        for name, tp in typing.get_type_hints(cls).items():
            args = typing.get_args(tp) or (tp,)
            if float in args or int in args or typing.get_origin(tp) is tuple:
                yield cls, name


@pytest.mark.parametrize(("cls", "key"), list(_number_keys()),
                         ids=lambda x: getattr(x, "__name__", x))
def test_every_number_has_a_physical_range(cls, key):
    """A lower and an upper bound on every number (issue 38 item 5): an open end let
    ``start_s = 9.3e9`` overflow the nanosecond stamps and ``horizon_s = 1e-300`` pass."""
    from pospp.config_schema import limits_of

    lim = limits_of(cls, key)
    assert (lim.gt is not None or lim.ge is not None) and (lim.lt is not None or
                                                           lim.le is not None), (key, lim)
    assert (lim.gt or 0.0) > -1e12 and (lim.le or lim.lt) < 1e15, (key, lim)


def test_a_config_made_in_python_lists_its_out_of_range_keys():
    from dataclasses import replace

    cfg = PipelineConfig()
    assert cfg.problems() == []
    bad = replace(cfg, replay=replace(cfg.replay, horizon_s=1e-300),
                  input=replace(cfg.input, start_s=9.3e9))
    texts = bad.problems()
    assert any(t.startswith("replay.horizon_s: expected a value >= 1") for t in texts), texts
    assert any(t.startswith("input.start_s: expected a value >= 0, <= 1e+07") for t in texts)


def test_a_named_pipe_as_the_pipeline_file_is_refused_at_once(tmp_path, make_fifo):
    fifo = make_fifo(tmp_path / "pipe.toml")
    with pytest.raises(ConfigError, match="pipe.toml: is a named pipe"):
        load_config(fifo)  # used to block until a writer came (forever from the CLI)


def _numeric_keys():
    import typing

    for section, cls in typing.get_type_hints(PipelineConfig).items():
        if section == "name":
            continue
        for name, tp in typing.get_type_hints(cls).items():
            if typing.get_origin(tp) is not tuple and float in (typing.get_args(tp) or (tp,)):
                yield section, name


@pytest.mark.parametrize(("section", "key"), list(_numeric_keys()))
def test_every_number_must_be_finite(section, key):
    with pytest.raises(ConfigError, match=rf"x.toml: {section}\.{key}: expected a finite"):
        config_from_dict({section: {key: float("nan")}}, source="x.toml")


def test_a_huge_string_is_refused_with_a_short_message():
    huge = "x" * 20_000_000  # the check is on the length: 200 MB behaves the same
    with pytest.raises(ConfigError) as err:
        config_from_dict({"name": huge}, source="x.toml")
    assert "name: expected a string of 0 to 256 characters" in str(err.value)
    assert len(str(err.value)) < 200
    with pytest.raises(ConfigError) as err:
        config_from_dict({"legs": {"min_duration_s": huge}}, source="x.toml")
    assert len(str(err.value)) < 200


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        (b'name = "caf\xe9"\n', "not UTF-8 text (byte 11)"),
        (b"a = " + b"[" * 5000 + b"]" * 5000 + b"\n", "nested too deeply"),
        (b"name = '" + b"x" * (2 << 20) + b"'\n", "larger than 1048576 bytes"),
        (b"[filter]\noutput_rate_hz = nan\n", "filter.output_rate_hz: expected a finite"),
    ],
    ids=["latin1", "nested", "2MiB", "nan"],
)
def test_unreadable_pipeline_file_is_one_clear_error(tmp_path, content, needle):
    p = tmp_path / "bad.toml"
    p.write_bytes(content)
    with pytest.raises(ConfigError) as err:
        load_config(p)
    assert str(err.value).startswith(str(p)) and needle in str(err.value)
    assert "\n" not in str(err.value)


def test_max_chunk_mib_defaults_to_256():
    assert PipelineConfig().input.max_chunk_mib == 256.0
    assert config_from_dict({"input": {"max_chunk_mib": 1}}).input.max_chunk_mib == 1.0
