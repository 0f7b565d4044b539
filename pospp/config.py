"""Pipeline configuration: TOML -> frozen dataclasses, validated with clear errors.

Every section of a pipeline file (pipelines/*.toml) maps to one frozen dataclass below; every
key is a field with a unit suffix. Unknown sections or keys, and values of the wrong type,
raise :class:`ConfigError` naming the file, the key, what was expected and what was found.
Omitted keys take the documented defaults, so an empty file is a valid configuration.

Choices are string enums (``enum.StrEnum``: each member equals its string, so ``cfg.pairs.mode
== "adjacent"`` holds), listed once here; the per-grade defaults are one table,
:data:`GRADE_DEFAULTS`.
"""

from __future__ import annotations

import dataclasses
import json
import os
import tomllib
import typing
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pospp.calib.segment import LegThresholds
from pospp.config_schema import (
    MAX_CONFIG_BYTES,
    ConfigError,
    Limits,
    check_value,
    convert_value,
    out_of_range,
    short_repr,
)
from pospp.config_schema import key as _key
from pospp.io.files import NotRegularFileError, open_regular

if TYPE_CHECKING:  # the stages' option types (imported where used: `pospp --help` stays light)
    from pospp.calib.pairs import PairPolicy
    from pospp.calib.replay import ReplayOptions
    from pospp.nav.filter import FilterOptions
    from pospp.nav.tuning import ImuTuning


MAX_LOG_S = 1.0e7
"""Longest log time any key may name [s] (116 days): ``[input] start_s / end_s`` beyond it
overflowed the int64 nanosecond stamps (9.2e9 s) and were silently ignored."""
MAX_LEG_S = 86400.0
"""Longest leg, replay horizon or leg tolerance [s] (a day)."""
MAX_REPLAY_RATE_HZ = 10.0
"""Highest ``[replay] sample_rate_hz`` [Hz]: B minus A is smooth on the Schuler period and on
the least squares' ``noise_step_s``; 1000 Hz took 5.5 GB on the sample."""


class SensorFrame(StrEnum):
    """Axes of the logged IMU."""

    FLU = "flu"  # ROS REP-103
    FRD = "frd"


class Grade(StrEnum):
    """IMU grade: the filter tuning preset and the per-grade defaults (:data:`GRADE_DEFAULTS`)."""

    FLIGHT = "flight"
    VEHICLE = "vehicle"
    TACTICAL = "tactical"
    MEMS = "mems"
    CONSUMER = "consumer"


class ReplayReference(StrEnum):
    """Solution of algorithm A that B starts from and is compared with."""

    SMOOTHED = "smoothed"
    FORWARD = "forward"


class AccelCompensation(StrEnum):
    """Accelerometer bias in B: A's estimate removed, or raw (as the paper)."""

    FILTER = "filter"
    NONE = "none"


class PairMode(StrEnum):
    ADJACENT = "adjacent"
    ALL = "all"


class Formulation(StrEnum):
    BODY = "body"
    PAPER = "paper"


class Transition(StrEnum):
    NUMERICAL = "numerical"
    CLOSED_FORM = "closed_form"


class NoiseModel(StrEnum):
    GYRO_RW = "gyro_rw"
    WHITE = "white"


class NullImuNoise(StrEnum):
    MEASURED = "measured"
    GRADE = "grade"


class CompensationMode(StrEnum):
    SMOOTHED = "smoothed"
    CAUSAL = "causal"
    PER_LEG = "per_leg"
    CONSTANT = "constant"


@dataclass(frozen=True)
class InputConfig:
    """[input]: topics of the MCAP file and the IMU mounting."""

    imu_topic: str = _key("/imu/data", min_len=1, max_len=256)
    fix_topic: str = _key("/gnss/fix", min_len=1, max_len=256)
    vel_topic: str = _key("/gnss/vel", min_len=1, max_len=256)
    sensor_frame: SensorFrame = SensorFrame.FLU
    """Axes of the logged IMU: "flu" (ROS REP-103) or "frd"."""
    mounting_rpy_deg: tuple[float, float, float] = _key((0.0, 0.0, 0.0), ge=-360.0, le=360.0)
    """Extra rotation of the IMU case w.r.t. the body (roll, pitch, yaw of sensor in body)."""
    start_s: float | None = _key(None, ge=0.0, le=MAX_LOG_S)
    """Process from this many seconds after the first IMU sample (None: from the start)."""
    end_s: float | None = _key(None, gt=0.0, le=MAX_LOG_S)
    max_chunk_mib: float = _key(256.0, ge=1.0, le=65536.0)
    """Largest decompressed MCAP chunk the reader accepts [MiB] (bounds its memory)."""
    events_topic: str = _key("/events", max_len=256)
    """Trigger events (``sensor_msgs/msg/TimeReference``, camera or lidar): the sensor's pose
    at each goes to events.parquet; "" = none (an absent topic is noted, not an error)."""


@dataclass(frozen=True)
class SensorConfig:
    """[sensor]: the imaging sensor (camera, lidar) whose pose is wanted at each trigger event.

    Exterior orientation: ``r_s = r_imu + C_nb lever_arm_m`` and ``C_ns = C_nb C_bs`` with
    ``C_bs`` the boresight rotation (z-y-x roll, pitch, yaw of the sensor frame s in the body
    frame b, FRD).
    """

    lever_arm_m: tuple[float, float, float] = _key((0.0, 0.0, 0.0), ge=-100.0, le=100.0)
    """Sensor origin in the body frame FRD, from the IMU's centre [m]."""
    boresight_rpy_deg: tuple[float, float, float] = _key((0.0, 0.0, 0.0), ge=-360.0,
                                                         le=360.0)
    """Roll, pitch, yaw of the sensor frame in the body frame (z-y-x) [deg]."""


@dataclass(frozen=True)
class ImuConfig:
    """[imu]: the IMU grade and optional overrides of its noise model (filter tuning)."""

    grade: Grade = Grade.FLIGHT
    """Preset: "flight", "vehicle", "tactical", "mems" or "consumer"."""
    gyro_bias_sigma_dph: float | None = _key(None, ge=0.0, le=36000.0)
    gyro_arw_dpsh: float | None = _key(None, ge=0.0, le=100.0)
    gyro_gm_sigma_dph: float | None = _key(None, ge=0.0, le=36000.0)
    gyro_gm_tau_s: float | None = _key(None, ge=1.0, le=1.0e7)
    accel_bias_sigma_ug: float | None = _key(None, ge=0.0, le=1.0e6)
    accel_vrw_mpsph: float | None = _key(None, ge=0.0, le=100.0)
    accel_gm_sigma_ug: float | None = _key(None, ge=0.0, le=1.0e6)
    accel_gm_tau_s: float | None = _key(None, ge=1.0, le=1.0e7)

    def tuning(self) -> ImuTuning:
        """The filter tuning of this section: the ``grade`` preset
        (:func:`pospp.nav.tuning.tuning_preset`) with every key that is not ``None``
        overriding the preset value."""
        from pospp.nav.tuning import tuning_preset

        overrides = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                     if f.name != "grade"}
        return tuning_preset(self.grade, **overrides)


@dataclass(frozen=True)
class GnssConfig:
    """[gnss]: antenna lever arm and measurement screening."""

    lever_arm_m: tuple[float, float, float] = _key((0.0, 0.0, 0.0), ge=-100.0, le=100.0)
    """Antenna position in the body frame FRD [m]."""
    estimate_lever_arm: bool = False
    pos_sigma_floor_m: float | None = _key(None, ge=1.0e-4, le=1000.0)
    """Least GNSS position sigma the filter uses [m]; omitted: the [imu] grade's default
    (``GNSS_SIGMA_FLOORS_BY_GRADE``)."""
    vel_sigma_floor_mps: float | None = _key(None, ge=1.0e-5, le=100.0)
    """Least GNSS velocity sigma the filter uses [m/s]; omitted: the grade's default."""
    use_velocity: bool = True
    gate_probability: float = _key(0.9999, ge=0.5, le=0.999999)


@dataclass(frozen=True)
class FilterConfig:
    """[filter]: algorithm A."""

    output_rate_hz: float = _key(10.0, ge=0.01, le=1000.0)
    smoother: bool = True
    static_alignment_s: float = _key(120.0, ge=0.0, le=3600.0)
    """Longest static period used for coarse alignment at the start [s]."""
    max_imu_gap_s: float = _key(0.5, ge=1.0e-3, le=600.0)
    """Longest IMU gap bridged (and logged); a longer one is an error naming its time [s]."""
    gate_reset_s: float = _key(30.0, ge=1.0, le=3600.0)
    """After this long of gated GNSS records, the next one resets the covariance block [s]."""
    estimate_scale_factors: bool = False
    """Add gyro and accelerometer scale-factor states to algorithm A."""


@dataclass(frozen=True)
class GradeDefaults:
    """The keys whose default depends on the ``[imu] grade`` (an explicit value wins)."""

    pos_sigma_floor_m: float
    """``[gnss]``: a MEMS filter trusts the receivers' nominal sigmas too much: on the measured
    logs the innovation gate then locks the GNSS out (docs/results.md); navigation grades keep
    the receivers' sigmas."""
    vel_sigma_floor_mps: float
    leg_min_duration_s: float
    """``[legs] min_duration_s``: the paper's 5 min for the flight and vehicle grades; for
    tactical and MEMS the shortest flown leg whose pair calibration of the horizontal body gyro
    bias has a sigma below a third of the grade's turn-on bias and errors within 3 sigma of the
    injected value (simulated back-and-forth legs, docs/results.md "Shortest usable leg")."""
    leg_duration_tolerance_s: float
    """``[legs] duration_tolerance_s``: a leg flown for min_duration_s is detected 3-5 s
    shorter; legs shorter than 20 s detected hold a single epoch of the gyro random-walk least
    squares (10 s spacing) and calibrate nothing."""
    leg_settle_s: float
    """``[legs] settle_s``: 60 s for navigation and tactical grades (A's unconverged state at a
    leg start is not noise: docs/diagnose.md); 0 for MEMS (the quadrotor's first leg)."""


_LEG = LegThresholds()
LEG_SETTLE_NAVIGATION_S = 60.0  # [legs] settle_s of the navigation and tactical grades [s]
_NAVIGATION = GradeDefaults(0.01, 0.005, _LEG.min_duration_s, _LEG.duration_tolerance_s,
                            LEG_SETTLE_NAVIGATION_S)
_MEMS = GradeDefaults(0.2, 0.5, 30.0, 5.0, 0.0)
GRADE_DEFAULTS: dict[Grade, GradeDefaults] = {
    Grade.FLIGHT: _NAVIGATION,
    Grade.VEHICLE: _NAVIGATION,
    Grade.TACTICAL: GradeDefaults(0.01, 0.005, 30.0, 5.0, LEG_SETTLE_NAVIGATION_S),
    Grade.MEMS: _MEMS,
    Grade.CONSUMER: _MEMS,
}
"""The per-grade defaults, one row per ``[imu] grade`` (the one table)."""

GNSS_SIGMA_FLOORS_BY_GRADE: dict[str, tuple[float, float]] = {
    g.value: (d.pos_sigma_floor_m, d.vel_sigma_floor_mps) for g, d in GRADE_DEFAULTS.items()}
"""View of :data:`GRADE_DEFAULTS`: (pos_sigma_floor_m, vel_sigma_floor_mps) per grade."""
LEG_MIN_DURATION_BY_GRADE_S: dict[str, float] = {
    g.value: d.leg_min_duration_s for g, d in GRADE_DEFAULTS.items()}
"""View of :data:`GRADE_DEFAULTS`: ``[legs] min_duration_s`` per grade [s]."""
LEG_DURATION_TOLERANCE_BY_GRADE_S: dict[str, float] = {
    g.value: d.leg_duration_tolerance_s for g, d in GRADE_DEFAULTS.items()}
"""View of :data:`GRADE_DEFAULTS`: ``[legs] duration_tolerance_s`` per grade [s]."""


@dataclass(frozen=True)
class LegsConfig:
    """[legs]: straight uniform leg thresholds, the fields of
    :class:`pospp.calib.segment.LegThresholds` (its defaults; :meth:`thresholds` gives the
    stage's options). Omitted, ``min_duration_s`` and ``duration_tolerance_s`` take the
    ``[imu] grade``'s defaults: flight and vehicle 300 s and 15 s, tactical and mems 30 s and
    5 s (:data:`GRADE_DEFAULTS`); explicit values win.
    """

    min_duration_s: float | None = _key(None, ge=1.0, le=MAX_LEG_S)
    duration_tolerance_s: float | None = _key(None, ge=0.0, le=MAX_LEG_S)
    max_duration_s: float = _key(_LEG.max_duration_s, ge=1.0, le=MAX_LEG_S)
    max_heading_rate_dps: float = _key(_LEG.max_heading_rate_dps, ge=1.0e-4, le=360.0)
    max_heading_spread_deg: float = _key(_LEG.max_heading_spread_deg, ge=1.0e-3,
                                         le=180.0)
    max_speed_std_mps: float = _key(_LEG.max_speed_std_mps, ge=1.0e-4, le=100.0)
    max_acceleration_mps2: float = _key(_LEG.max_acceleration_mps2, ge=1.0e-4, le=100.0)
    max_vertical_speed_mps: float = _key(_LEG.max_vertical_speed_mps, ge=1.0e-4,
                                         le=1000.0)
    min_speed_mps: float = _key(_LEG.min_speed_mps, ge=0.0, le=3000.0)
    trim_s: float = _key(_LEG.trim_s, ge=0.0, le=3600.0)
    smoothing_s: float = _key(_LEG.smoothing_s, ge=0.0, le=3600.0)
    settle_s: float | None = _key(None, ge=0.0, le=MAX_LOG_S)
    """A leg starts at least this long after A's first epoch [s] (A's alignment error is not
    noise: docs/diagnose.md); omitted: the grade's default (:data:`GRADE_DEFAULTS`)."""

    def thresholds(self) -> LegThresholds:
        """The leg segmentation's options (every key of this section; a key
        :class:`LegThresholds` does not have raises TypeError, so a rename cannot be lost).
        The grade defaults are filled in by :class:`PipelineConfig`."""
        values = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        if any(values[k] is None for k in ("min_duration_s", "duration_tolerance_s",
                                           "settle_s")):
            raise ConfigError("legs: min_duration_s / duration_tolerance_s / settle_s unset (a "
                              "LegsConfig "
                              "outside a PipelineConfig has no [imu] grade to default from)")
        return LegThresholds(**values)


@dataclass(frozen=True)
class ReplayConfig:
    """[replay]: algorithm B."""

    reference: ReplayReference = ReplayReference.SMOOTHED
    """A solution B starts from and is compared with: "smoothed" (default) or "forward"."""
    accel_compensation: AccelCompensation = AccelCompensation.FILTER
    """"filter": remove A's accelerometer bias estimate; "none": raw, as the paper."""
    sample_rate_hz: float = _key(1.0, ge=0.01, le=MAX_REPLAY_RATE_HZ)
    sigma_floor_mps: float = _key(0.005, ge=1.0e-6, le=10.0)
    horizon_s: float = _key(300.0, ge=1.0, le=MAX_LEG_S)
    transition_step: int = _key(10, ge=1, le=100000)

    def options(self) -> ReplayOptions:
        """The calibration stage's B settings: every key but ``reference`` (TypeError if one is
        not a :class:`ReplayOptions` field: a rename cannot be lost)."""
        from pospp.calib.replay import ReplayOptions
        values = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        del values["reference"]
        return ReplayOptions(**{**values, "accel_compensation": str(self.accel_compensation)})


@dataclass(frozen=True)
class PairsConfig:
    """[pairs]: pairing policy and calibration."""

    mode: PairMode = PairMode.ADJACENT
    max_cond_scaled: float = _key(1.0e4, gt=1.0, le=1.0e12)
    min_dheading_deg: float = _key(30.0, ge=0.0, le=180.0)
    formulation: Formulation = Formulation.BODY
    """Formulation used for compensation: "body" or "paper" (both are always reported)."""
    transition: Transition = Transition.NUMERICAL
    """"numerical" (F(t) along B) or "closed_form" (paper Eq. 10/13 with corrected signs)."""
    noise: NoiseModel = NoiseModel.GYRO_RW
    """Residual model of the least squares: "gyro_rw" (B's error driven by the gyro random
    walk and the grade's Gauss-Markov drift; docs/calibration.md) or "white"."""
    noise_step_s: float = _key(10.0, ge=0.1, le=3600.0)
    """Spacing of the samples the correlated-noise least squares uses [s]."""
    estimate_gyro_z: bool = False
    """Also estimate the vertical body gyro bias (weakly observable on level legs)."""
    null_realisations: int = _key(10, ge=0, le=1000)
    """Null realisations of B minus A (docs/diagnose.md): the calibration's covariance and the
    diagnosis's null. 0: the formal covariance and nominal F (cries wolf on GNSS noise)."""
    null_reruns: bool = False
    """The null from A re-run on noisy logs, not from A's gains (docs/diagnose.md: slower)."""
    diagnose_alpha: float = _key(0.05, ge=1.0e-6, lt=0.5)
    """Significance level of the diagnosis's tests (candidates Bonferroni-corrected per step;
    on null flights "none" in at least 1 - alpha of runs: docs/diagnose.md)."""
    null_imu_noise: NullImuNoise = NullImuNoise.MEASURED
    """Null's white IMU noise: "measured" (second differences) or "grade"; [imu] drifts both."""
    rerun_imu_rate_hz: float = _key(50.0, ge=0.0, le=10000.0)
    """IMU rate [Hz] A and B re-run at for the null realisations and the diagnosis's re-run
    signatures: the flight's increments summed (docs/diagnose.md, "The null at a lower IMU
    rate"). 0, or above half the flight's rate: the flight's rate."""

    def policy(self) -> PairPolicy:
        """The calibration stage's pairing policy (:class:`pospp.calib.pairs.PairPolicy`)."""
        from pospp.calib.pairs import PairPolicy

        return PairPolicy(mode=str(self.mode), max_cond_scaled=self.max_cond_scaled,
                          min_dheading_deg=self.min_dheading_deg,
                          formulation=str(self.formulation), transition=str(self.transition))


@dataclass(frozen=True)
class CompensationConfig:
    """[compensation]."""

    rerun_filter: bool = True
    """Re-run algorithm A with the calibrated gyro bias removed (the compensated trajectory)."""
    mode: CompensationMode = CompensationMode.SMOOTHED
    """How B is re-run: "smoothed" (the gyro error's history from the fit and A's forward
    estimates: docs/calibration.md section 5), "causal" (A's forward estimate fused with the
    constant), "per_leg" (the constant plus the drift's mean over each leg) or "constant"."""


@dataclass(frozen=True)
class OutputsConfig:
    """[outputs]."""

    mcap: bool = True
    """Write the best trajectory to trajectory.mcap (ROS 2 NavSatFix, PoseStamped, /tf,
    Odometry, a Path per leg, run metadata; docs/formats.md)."""
    mcap_rate_hz: float = _key(2.0, ge=0.01, le=1000.0)
    """Rate of trajectory.mcap [Hz] (at most the [filter] output rate; the Parquet table keeps
    the full output rate)."""
    report: bool = True
    diagnose: bool = True


@dataclass(frozen=True)
class PipelineConfig:
    """A whole pipeline configuration."""

    name: str = "default"
    input: InputConfig = field(default_factory=InputConfig)
    imu: ImuConfig = field(default_factory=ImuConfig)
    gnss: GnssConfig = field(default_factory=GnssConfig)
    filter: FilterConfig = field(default_factory=FilterConfig)
    legs: LegsConfig = field(default_factory=LegsConfig)
    replay: ReplayConfig = field(default_factory=ReplayConfig)
    pairs: PairsConfig = field(default_factory=PairsConfig)
    compensation: CompensationConfig = field(default_factory=CompensationConfig)
    outputs: OutputsConfig = field(default_factory=OutputsConfig)
    sensor: SensorConfig = field(default_factory=SensorConfig)

    def __post_init__(self) -> None:
        # omitted grade-dependent keys ([legs] min_duration_s / duration_tolerance_s, [gnss]
        # sigma floors) take the [imu] grade's row of GRADE_DEFAULTS
        grade = self.imu.grade
        if grade not in GRADE_DEFAULTS:
            raise ConfigError(f"imu.grade: expected one of {[g.value for g in Grade]}, "
                              f"got {grade!r}")
        d = GRADE_DEFAULTS[Grade(grade)]
        for section, key, value in (("legs", "min_duration_s", d.leg_min_duration_s),
                                    ("legs", "duration_tolerance_s", d.leg_duration_tolerance_s),
                                    ("legs", "settle_s", d.leg_settle_s),
                                    ("gnss", "pos_sigma_floor_m", d.pos_sigma_floor_m),
                                    ("gnss", "vel_sigma_floor_mps", d.vel_sigma_floor_mps)):
            sec = getattr(self, section)
            if getattr(sec, key) is None:
                object.__setattr__(self, section, dataclasses.replace(sec, **{key: value}))

    def filter_options(self) -> FilterOptions:
        """Algorithm A's :class:`pospp.nav.filter.FilterOptions` of this configuration.

        From ``[gnss]`` pos_sigma_floor_m, vel_sigma_floor_mps, use_velocity, gate_probability
        and ``[filter]`` smoother, max_imu_gap_s, gate_reset_s, static_alignment_s (->
        ``alignment.max_static_alignment_s``); everything else keeps its default. The lever
        arm, its estimation and the output rate are arguments of
        :func:`pospp.nav.filter.run_integrated_navigation` (``[gnss]`` lever_arm_m,
        estimate_lever_arm, ``[filter]`` output_rate_hz); the tuning is ``imu.tuning()``.
        """
        from pospp.nav.alignment import AlignmentOptions
        from pospp.nav.filter import FilterOptions

        g, f = self.gnss, self.filter
        assert g.pos_sigma_floor_m is not None and g.vel_sigma_floor_mps is not None
        return FilterOptions(
            pos_sigma_floor_m=g.pos_sigma_floor_m, vel_sigma_floor_mps=g.vel_sigma_floor_mps,
            use_velocity=g.use_velocity, gate_probability=g.gate_probability,
            smoother=f.smoother,
            alignment=AlignmentOptions(max_static_alignment_s=f.static_alignment_s),
            max_imu_gap_s=f.max_imu_gap_s, gate_reset_s=f.gate_reset_s,
        )

    def problems(self) -> list[str]:
        """Every key outside its range, one text each ("replay.horizon_s: expected a value >=
        1, <= 86400, got -300.0"): what the loader refuses, for a configuration made in
        Python (``dataclasses.replace`` skips the loader; the QC ``config`` check asks)."""
        out = [text for name in typing.get_type_hints(PipelineConfig) if name != "name"
               for text in out_of_range(getattr(self, name), name)]
        s, e = self.input.start_s, self.input.end_s
        if s is not None and e is not None and not e > s:
            out.append(f"input.end_s: expected a value > input.start_s = {s:g}, got {e:g}")
        return out

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def to_json(self) -> str:
        """Canonical JSON (sorted keys): hashed for caching and stored in output metadata."""
        return json.dumps(self.to_dict(), sort_keys=True)


def config_from_dict(data: dict[str, Any], *, source: str = "<dict>") -> PipelineConfig:
    """Build and validate a :class:`PipelineConfig` from parsed TOML."""
    hints = typing.get_type_hints(PipelineConfig)
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        if key not in hints:
            raise ConfigError(
                f"{source}: unknown section or key {key!r}; expected one of {sorted(hints)}"
            )
        if key == "name":
            kwargs["name"] = convert_value(value, str, f"{source}: name")
            Limits().check(kwargs["name"], f"{source}: name")
            continue
        cls = hints[key]
        if not isinstance(value, dict):
            raise ConfigError(f"{source}: [{key}] must be a table, got {short_repr(value)}")
        sub_hints = typing.get_type_hints(cls)
        sub: dict[str, Any] = {}
        for k, v in value.items():
            where = f"{source}: {key}.{k}"
            if k not in sub_hints:
                raise ConfigError(f"{where}: unknown key; expected one of {sorted(sub_hints)}")
            sub[k] = convert_value(v, sub_hints[k], where)
            check_value(cls, k, sub[k], where)
        kwargs[key] = cls(**sub)
    inp = kwargs.get("input")
    if inp is not None and inp.start_s is not None and inp.end_s is not None \
            and not inp.end_s > inp.start_s:
        raise ConfigError(f"{source}: input.end_s: expected a value > input.start_s = "
                          f"{inp.start_s:g}, got {inp.end_s:g}")
    return PipelineConfig(**kwargs)


def load_config(path: str | Path) -> PipelineConfig:
    """Read a pipeline TOML file."""
    p = Path(path)
    shown = os.fsencode(p).decode("utf-8", "backslashreplace")
    try:
        with open_regular(p) as fh:  # a FIFO or a device: refused, never read forever
            raw = fh.read(MAX_CONFIG_BYTES + 1)
    except FileNotFoundError:
        raise ConfigError(f"{shown}: pipeline file not found") from None
    except NotRegularFileError as exc:
        raise ConfigError(str(exc)) from None
    except OSError as exc:
        raise ConfigError(f"{shown}: cannot read the pipeline file: {exc.strerror}") from None
    if len(raw) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{shown}: pipeline file larger than {MAX_CONFIG_BYTES} bytes; "
                          "a pipeline file is a few kB of TOML")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{shown}: not UTF-8 text (byte {exc.start}); TOML must be "
                          "UTF-8") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{shown}: not valid TOML: {exc}") from None
    except RecursionError:
        raise ConfigError(f"{shown}: not valid TOML: nested too deeply") from None
    return config_from_dict(data, source=shown)
