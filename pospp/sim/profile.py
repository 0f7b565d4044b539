"""Mission profiles: TOML list of segments -> timed plan of smooth control schedules.

A profile (``pospp/presets/*.toml`` or any file) is::

    name = "flight"
    [start]
    lat_deg = 40.0
    lon_deg = 116.0
    height_m = 60.0          # above the WGS-84 ellipsoid
    heading_deg = 60.0       # yaw, clockwise from north
    [options]
    turn_bank = "coordinated"  # or "none" (ground vehicles: zero bank)
    blend_s = 5.0              # default roll-in / blend time of turns and climbs
    [[segment]]
    type = "static"
    duration_s = 600.0
    ...

Segment types and keys (all optional keys shown in brackets):

- ``static``: duration_s. Speed must be zero.
- ``accelerate``: to_speed_mps, duration_s (the whole segment is one smooth ramp).
- ``straight``: duration_s or length_m [kind = "transit" | "survey", label, wander keys]. A
  straight level leg at the current speed; recorded as a true leg.
- ``turn``: angle_deg (signed, positive clockwise = right) or to_heading_deg [direction =
  "shortest" | "right" | "left"], rate_dps [blend_s]. Heading rate ramps up over blend_s,
  holds, ramps down; bank follows (coordinated: tan(bank) = speed x rate / g).
- ``climb``: rate_mps (positive up; negative or to a lower height descends), to_height_m or
  delta_m [blend_s]. The climb slope tan(gamma) = rate / speed ramps in and out (pitch =
  flight-path angle gamma).
- ``survey``: legs, heading_deg, leg_duration_s (number or list) or leg_length_m,
  turn_rate_dps [turn_direction = "alternate" | "right" | "left", first_turn = "right" |
  "left", blend_s, label]. A turn onto the line heading, then back-and-forth legs joined by
  180 degree turns. The wander keys apply to every line.

Wander keys (``straight`` and ``survey``, default off): ``heading_wander_deg`` with
``heading_wander_period_s``, and ``speed_wander_mps`` with ``speed_wander_period_s``. The leg's
heading (speed) then is the nominal value plus A sin(2 pi u / P) with u the time into the leg,
tapered in and out with smootherstep (:class:`pospp.sim.ramps.WanderSchedule`), so the legs
are no longer ideal (the measured logs' 1-3 deg heading wander and speed changes,
docs/results.md) while every derivative the IMU needs stays continuous, and the heading and
speed are back to nominal at the leg's end. The leg keeps its nominal heading, speed and
length in the leg table, plus the wander settings.

Every schedule (speed, heading rate, climb slope) is a sum of C2 smoothstep ramps
(:mod:`pospp.sim.ramps`), so the joins have continuous first and second derivatives. Angles
here are degrees only at the TOML edge; the plan is SI and radians.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from pospp.sim.ramps import RampSchedule, WanderSchedule
from pospp.units import G0_MPS2

__all__ = [
    "MissionProfile",
    "MissionPlan",
    "PlannedLeg",
    "PlannedSegment",
    "load_profile",
    "parse_profile",
    "plan_mission",
    "preset_names",
]

_WANDER_KEYS = {"heading_wander_deg", "heading_wander_period_s", "speed_wander_mps",
                "speed_wander_period_s"}

_SEGMENT_KEYS: dict[str, tuple[set[str], set[str]]] = {
    # type: (required keys, optional keys) -- "one of" groups are checked in the planner
    "static": ({"duration_s"}, {"label"}),
    "accelerate": ({"to_speed_mps", "duration_s"}, {"label"}),
    "straight": (set(), {"duration_s", "length_m", "kind", "label", "speed_mps",
                         *_WANDER_KEYS}),
    "turn": ({"rate_dps"}, {"angle_deg", "to_heading_deg", "direction", "blend_s", "label"}),
    "climb": ({"rate_mps"}, {"to_height_m", "delta_m", "blend_s", "label"}),
    "survey": (
        {"legs", "heading_deg", "turn_rate_dps"},
        {"leg_duration_s", "leg_length_m", "turn_direction", "first_turn", "blend_s", "label",
         "speed_mps", "height_m", *_WANDER_KEYS},
    ),
}


@dataclass(frozen=True)
class MissionProfile:
    """A parsed mission profile (validated keys, values as written in TOML).

    Attributes
    ----------
    name : str
    lat_deg, lon_deg, height_m, heading_deg : float
        Start position (WGS-84) and heading (clockwise from north).
    turn_bank : str
        ``"coordinated"`` or ``"none"``.
    blend_s : float
        Default blend (roll-in) time [s].
    segments : tuple of dict
        The ``[[segment]]`` tables in order.
    imu_rate_hz : float or None
        Suggested IMU rate (the caller may override).
    """

    name: str
    lat_deg: float
    lon_deg: float
    height_m: float
    heading_deg: float
    turn_bank: str = "coordinated"
    blend_s: float = 5.0
    segments: tuple[Mapping[str, Any], ...] = ()
    imu_rate_hz: float | None = None

    def as_dict(self) -> dict[str, Any]:
        """The profile as a TOML-like dict (for params JSON)."""
        return {
            "name": self.name,
            "start": {"lat_deg": self.lat_deg, "lon_deg": self.lon_deg,
                      "height_m": self.height_m, "heading_deg": self.heading_deg},
            "options": {"turn_bank": self.turn_bank, "blend_s": self.blend_s},
            "imu_rate_hz": self.imu_rate_hz,
            "segment": [dict(s) for s in self.segments],
        }


def preset_names() -> list[str]:
    """Names of the bundled mission presets (``pospp/presets/*.toml`` except IMU grades)."""
    root = resources.files("pospp").joinpath("presets")
    return sorted(
        p.name[:-5] for p in root.iterdir() if p.name.endswith(".toml") and p.name != "imu.toml"
    )


def parse_profile(data: Mapping[str, Any], *, source: str = "<dict>") -> MissionProfile:
    """Validate a profile dict (as read from TOML) into a :class:`MissionProfile`."""
    unknown = set(data) - {"name", "start", "options", "segment", "imu_rate_hz", "description"}
    if unknown:
        raise ValueError(f"{source}: unknown top-level key(s) {sorted(unknown)}")
    start = data.get("start")
    need = ("lat_deg", "lon_deg", "height_m", "heading_deg")
    if not isinstance(start, Mapping) or any(k not in start for k in need):
        raise ValueError(f"{source}: [start] must give {list(need)}, got {start!r}")
    opts = dict(data.get("options", {}))
    bad_opts = set(opts) - {"turn_bank", "blend_s"}
    if bad_opts:
        raise ValueError(f"{source}: unknown [options] key(s) {sorted(bad_opts)}")
    turn_bank = opts.get("turn_bank", "coordinated")
    if turn_bank not in ("coordinated", "none"):
        raise ValueError(f"{source}: options.turn_bank must be 'coordinated' or 'none', "
                         f"got {turn_bank!r}")
    segs = data.get("segment", [])
    if not segs:
        raise ValueError(f"{source}: no [[segment]] tables")
    for i, s in enumerate(segs):
        typ = s.get("type")
        if typ not in _SEGMENT_KEYS:
            raise ValueError(f"{source}: segment {i}: type must be one of "
                             f"{sorted(_SEGMENT_KEYS)}, got {typ!r}")
        req, opt = _SEGMENT_KEYS[typ]
        missing = req - set(s)
        extra = set(s) - req - opt - {"type"}
        if missing or extra:
            raise ValueError(f"{source}: segment {i} ({typ}): missing {sorted(missing)}, "
                             f"unknown {sorted(extra)}")
    rate = data.get("imu_rate_hz")
    return MissionProfile(
        name=str(data.get("name", source)),
        lat_deg=float(start["lat_deg"]),
        lon_deg=float(start["lon_deg"]),
        height_m=float(start["height_m"]),
        heading_deg=float(start["heading_deg"]),
        turn_bank=turn_bank,
        blend_s=float(opts.get("blend_s", 5.0)),
        segments=tuple(dict(s) for s in segs),
        imu_rate_hz=None if rate is None else float(rate),
    )


def load_profile(path_or_preset: str | Path) -> MissionProfile:
    """Read a mission profile from a TOML file, or a bundled preset by name.

    Parameters
    ----------
    path_or_preset : str or Path
        An existing ``.toml`` path, or one of :func:`preset_names` (``flight``, ``vehicle``,
        ``grid``, ``sample``).
    """
    p = Path(path_or_preset)
    if p.suffix == ".toml" or p.exists():
        if not p.is_file():
            raise FileNotFoundError(f"mission profile {str(p)!r} not found")
        with open(p, "rb") as fh:
            return parse_profile(tomllib.load(fh), source=str(p))
    name = str(path_or_preset)
    res = resources.files("pospp").joinpath("presets", f"{name}.toml")
    if name == "imu" or not res.is_file():
        raise ValueError(f"unknown mission preset {name!r}; presets: {preset_names()} "
                         "(or give a path to a .toml file)")
    return parse_profile(tomllib.loads(res.read_text()), source=f"preset {name}")


# --------------------------------------------------------------------------- planning


@dataclass(frozen=True)
class PlannedSegment:
    """One timed segment of the plan (SI/radians; degrees only in ``as_dict``)."""

    type: str
    label: str
    start_s: float
    end_s: float
    heading_start_rad: float
    heading_end_rad: float
    speed_start_mps: float
    speed_end_mps: float
    height_start_m: float
    height_end_m: float
    extra: Mapping[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready record with unit-suffixed keys (mirrors the reference params layout)."""
        d = {
            "type": self.type, "label": self.label, "start_s": self.start_s,
            "end_s": self.end_s, "duration_s": self.end_s - self.start_s,
            "heading_start_deg": round(math.degrees(self.heading_start_rad) % 360.0, 9) % 360.0,
            "heading_end_deg": round(math.degrees(self.heading_end_rad) % 360.0, 9) % 360.0,
            "speed_start_mps": self.speed_start_mps, "speed_end_mps": self.speed_end_mps,
            "height_start_m": self.height_start_m, "height_end_m": self.height_end_m,
        }
        d.update(self.extra)
        return d


@dataclass(frozen=True)
class PlannedLeg:
    """A true straight, level, constant-speed leg (nominal heading and speed; with wander, the
    true heading and speed wander about them by the amplitudes below)."""

    leg_id: int
    kind: str
    label: str
    start_s: float
    end_s: float
    heading_rad: float
    speed_mps: float
    height_m: float
    heading_wander_rad: float = 0.0
    heading_wander_period_s: float = 0.0
    speed_wander_mps: float = 0.0
    speed_wander_period_s: float = 0.0

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s


@dataclass(frozen=True)
class MissionPlan:
    """Smooth control schedules of a mission.

    Attributes
    ----------
    profile : MissionProfile
    duration_s : float
    speed : RampSchedule
        Horizontal ground speed [m/s].
    heading_rate : RampSchedule
        Heading (yaw) rate [rad/s]; heading = heading0 + its integral.
    slope : RampSchedule
        Climb slope k = tan(gamma) of the flight-path angle gamma (positive climbing):
        v_D = -speed k, so a climb at constant speed changes height by exactly
        speed x k x (hold + blend).
    heading0_rad : float
    segments : tuple of PlannedSegment
    legs : tuple of PlannedLeg
    heading_wander : WanderSchedule or None
        Added to the heading [rad] (its derivatives to the heading rate); None: no wander.
    speed_wander : WanderSchedule or None
        Added to the speed [m/s]; None: no wander.
    """

    profile: MissionProfile
    duration_s: float
    speed: RampSchedule
    heading_rate: RampSchedule
    slope: RampSchedule
    heading0_rad: float
    segments: tuple[PlannedSegment, ...]
    legs: tuple[PlannedLeg, ...]
    heading_wander: WanderSchedule | None = None
    speed_wander: WanderSchedule | None = None


def _wrap_pi(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


class _Planner:
    def __init__(self, prof: MissionProfile) -> None:
        self.prof = prof
        self.t = 0.0
        self.speed = 0.0
        self.heading = math.radians(prof.heading_deg)
        self.height = prof.height_m
        self.speed_ramps: list[tuple[float, float, float]] = []
        self.rate_ramps: list[tuple[float, float, float]] = []
        self.slope_ramps: list[tuple[float, float, float]] = []
        self.segments: list[PlannedSegment] = []
        self.legs: list[PlannedLeg] = []
        self.heading_wander: list[tuple[float, float, float, float]] = []
        self.speed_wander: list[tuple[float, float, float, float]] = []

    def _push(self, typ: str, label: str, dur: float, *, speed_end: float | None = None,
              heading_end: float | None = None, height_end: float | None = None,
              **extra: Any) -> None:
        seg = PlannedSegment(
            typ, label, self.t, self.t + dur, self.heading,
            self.heading if heading_end is None else heading_end, self.speed,
            self.speed if speed_end is None else speed_end, self.height,
            self.height if height_end is None else height_end, extra,
        )
        self.segments.append(seg)
        self.t = seg.end_s
        self.heading = seg.heading_end_rad
        self.speed = seg.speed_end_mps
        self.height = seg.height_end_m

    def static(self, s: Mapping[str, Any], where: str) -> None:
        if self.speed != 0.0:
            raise ValueError(f"{where}: static needs speed 0, current speed {self.speed} m/s "
                             "(add an accelerate segment to stop)")
        self._push("static", s.get("label", "static"), _positive(s, "duration_s", where))

    def accelerate(self, s: Mapping[str, Any], where: str) -> None:
        dur = _positive(s, "duration_s", where)
        to = float(s["to_speed_mps"])
        if to < 0.0:
            raise ValueError(f"{where}: to_speed_mps must be >= 0, got {to}")
        self.speed_ramps.append((self.t, dur, to - self.speed))
        self._push("accelerate", s.get("label", "accelerate"), dur, speed_end=to,
                   to_speed_mps=to)

    def straight(self, s: Mapping[str, Any], where: str, *, kind: str | None = None,
                 label: str | None = None) -> None:
        if self.speed <= 0.0:
            raise ValueError(f"{where}: straight leg needs a speed > 0 (add accelerate first)")
        if "speed_mps" in s and abs(float(s["speed_mps"]) - self.speed) > 1e-9:
            raise ValueError(f"{where}: speed_mps {s['speed_mps']} differs from the current "
                             f"speed {self.speed} m/s; use an accelerate segment")
        if ("duration_s" in s) == ("length_m" in s):
            raise ValueError(f"{where}: straight needs exactly one of duration_s, length_m")
        dur = (_positive(s, "duration_s", where) if "duration_s" in s
               else _positive(s, "length_m", where) / self.speed)
        kind = kind or s.get("kind", "transit")
        label = label or s.get("label", "straight")
        hw, hp = _wander(s, "heading_wander_deg", "heading_wander_period_s", where)
        sw, sp = _wander(s, "speed_wander_mps", "speed_wander_period_s", where)
        if sw >= self.speed:
            raise ValueError(f"{where}: speed_wander_mps {sw} must be below the leg speed "
                             f"{self.speed} m/s")
        if hw >= 90.0:
            raise ValueError(f"{where}: heading_wander_deg {hw} must be below 90 deg")
        extra: dict[str, Any] = {}
        if hw:
            self.heading_wander.append((self.t, dur, math.radians(hw), hp))
            extra.update(heading_wander_deg=hw, heading_wander_period_s=hp)
        if sw:
            self.speed_wander.append((self.t, dur, sw, sp))
            extra.update(speed_wander_mps=sw, speed_wander_period_s=sp)
        self.legs.append(PlannedLeg(len(self.legs), kind, label, self.t, self.t + dur,
                                    self.heading, self.speed, self.height,
                                    math.radians(hw), hp if hw else 0.0, sw,
                                    sp if sw else 0.0))
        self._push("straight", label, dur, leg_kind=kind, length_m=dur * self.speed, **extra)

    def turn(self, s: Mapping[str, Any], where: str, *, label: str | None = None) -> None:
        rate = math.radians(_positive(s, "rate_dps", where))
        if ("angle_deg" in s) == ("to_heading_deg" in s):
            raise ValueError(f"{where}: turn needs exactly one of angle_deg, to_heading_deg")
        if "angle_deg" in s:
            angle = math.radians(float(s["angle_deg"]))
        else:
            d = _wrap_pi(math.radians(float(s["to_heading_deg"])) - self.heading)
            direction = s.get("direction", "shortest")
            if direction == "right" and d < 0:
                d += 2.0 * math.pi
            elif direction == "left" and d > 0:
                d -= 2.0 * math.pi
            elif direction not in ("shortest", "right", "left"):
                raise ValueError(f"{where}: direction must be shortest/right/left, "
                                 f"got {direction!r}")
            angle = d
        if angle == 0.0:
            return
        blend = float(s.get("blend_s", self.prof.blend_s))
        t_total = abs(angle) / rate  # time at full rate if the blends were instant
        blend = min(blend, t_total)
        hold = t_total - blend
        sign = math.copysign(1.0, angle)
        self.rate_ramps.append((self.t, blend, sign * rate))
        self.rate_ramps.append((self.t + blend + hold, blend, -sign * rate))
        bank = 0.0
        if self.prof.turn_bank == "coordinated":
            bank = math.degrees(math.atan(self.speed * sign * rate / _G_BANK_MPS2))
        self._push("turn", label or s.get("label", "turn"), hold + 2.0 * blend,
                   heading_end=self.heading + angle, angle_deg=math.degrees(angle),
                   rate_dps=math.degrees(rate), roll_in_s=blend, bank_deg=bank)

    def climb(self, s: Mapping[str, Any], where: str) -> None:
        if self.speed <= 0.0:
            raise ValueError(f"{where}: climb needs a speed > 0")
        rate = abs(float(s["rate_mps"]))
        if rate == 0.0:
            raise ValueError(f"{where}: rate_mps must be non-zero")
        if ("to_height_m" in s) == ("delta_m" in s):
            raise ValueError(f"{where}: climb needs exactly one of to_height_m, delta_m")
        delta = (float(s["to_height_m"]) - self.height if "to_height_m" in s
                 else float(s["delta_m"]))
        if delta == 0.0:
            return
        sign = math.copysign(1.0, delta)
        slope = sign * rate / self.speed
        blend = float(s.get("blend_s", self.prof.blend_s))
        t_total = abs(delta) / rate
        blend = min(blend, t_total)
        hold = t_total - blend
        self.slope_ramps.append((self.t, blend, slope))
        self.slope_ramps.append((self.t + blend + hold, blend, -slope))
        self._push("climb", s.get("label", "climb"), hold + 2.0 * blend,
                   height_end=self.height + delta, rate_mps=sign * rate, delta_m=delta,
                   gamma_deg=math.degrees(math.atan(slope)))

    def survey(self, s: Mapping[str, Any], where: str) -> None:
        n = int(s["legs"])
        if n < 1:
            raise ValueError(f"{where}: legs must be >= 1, got {n}")
        if ("leg_duration_s" in s) == ("leg_length_m" in s):
            raise ValueError(f"{where}: survey needs exactly one of leg_duration_s, leg_length_m")
        key = "leg_duration_s" if "leg_duration_s" in s else "leg_length_m"
        vals = s[key]
        vals = [float(v) for v in (vals if isinstance(vals, list) else [vals] * n)]
        if len(vals) != n:
            raise ValueError(f"{where}: {key} lists {len(vals)} values for {n} legs")
        label = s.get("label", "survey")
        rate = float(s["turn_rate_dps"])
        blend = s.get("blend_s", self.prof.blend_s)
        line = math.radians(float(s["heading_deg"]))
        self.turn({"to_heading_deg": math.degrees(line), "rate_dps": rate, "blend_s": blend},
                  where, label=f"{label}: onto line heading")
        mode = s.get("turn_direction", "alternate")
        first = s.get("first_turn", "right")
        if mode not in ("alternate", "right", "left") or first not in ("right", "left"):
            raise ValueError(f"{where}: turn_direction alternate/right/left and first_turn "
                             f"right/left, got {mode!r}, {first!r}")
        side = 1.0 if (first if mode == "alternate" else mode) == "right" else -1.0
        wander = {k: s[k] for k in _WANDER_KEYS if k in s}
        for k, v in enumerate(vals):
            leg = {"duration_s": v} if key == "leg_duration_s" else {"length_m": v}
            leg.update(wander)
            self.straight(leg, where, kind="survey", label=f"{label} line {k + 1}")
            if k < n - 1:
                self.turn({"angle_deg": side * 180.0, "rate_dps": rate, "blend_s": blend},
                          where, label=f"{label}: 180 deg turn")
                if mode == "alternate":
                    side = -side


_G_BANK_MPS2 = G0_MPS2
"""Gravity used in the coordinated-turn bank law tan(bank) = v r / g (a definition)."""


def _wander(s: Mapping[str, Any], amp_key: str, period_key: str,
            where: str) -> tuple[float, float]:
    """(amplitude, period_s) of one wander; (0, 0) when off. Both keys or neither."""
    if (amp_key in s) != (period_key in s):
        raise ValueError(f"{where}: give both {amp_key} and {period_key} or neither")
    if amp_key not in s:
        return 0.0, 0.0
    amp = float(s[amp_key])
    if not amp >= 0.0:
        raise ValueError(f"{where}: {amp_key} must be >= 0, got {amp}")
    return amp, _positive(s, period_key, where)


def _positive(s: Mapping[str, Any], key: str, where: str) -> float:
    v = float(s[key])
    if not v > 0.0:
        raise ValueError(f"{where}: {key} must be > 0, got {v}")
    return v


def plan_mission(profile: MissionProfile) -> MissionPlan:
    """Expand a profile into timed segments, true legs and smooth control schedules."""
    pl = _Planner(profile)
    for i, s in enumerate(profile.segments):
        where = f"profile {profile.name!r} segment {i} ({s['type']})"
        getattr(pl, s["type"])(s, where)
    return MissionPlan(
        profile=profile,
        duration_s=pl.t,
        speed=RampSchedule.build(0.0, pl.speed_ramps),
        heading_rate=RampSchedule.build(0.0, pl.rate_ramps),
        slope=RampSchedule.build(0.0, pl.slope_ramps),
        heading0_rad=math.radians(profile.heading_deg),
        segments=tuple(pl.segments),
        legs=tuple(pl.legs),
        heading_wander=(WanderSchedule.build(pl.heading_wander) if pl.heading_wander
                        else None),
        speed_wander=WanderSchedule.build(pl.speed_wander) if pl.speed_wander else None,
    )

