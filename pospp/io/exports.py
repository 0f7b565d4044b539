"""Export a run's trajectory and trigger events for downstream tools (``pospp export``).

Formats (layouts in docs/formats.md, "Exports"):

- **sbet**: the Applanix SBET binary layout lidar and photogrammetry software reads: no
  header, one record of 17 little-endian float64 per epoch: GPS seconds of week [s],
  latitude, longitude [rad], ellipsoidal height [m], velocity x, y, z [m/s], roll, pitch,
  platform heading, wander angle [rad], body acceleration x, y, z [m/s^2], body angular rate
  x, y, z [rad/s]. pospp writes the local-level frame with wander angle 0, so x, y, z are
  north, east, down and platform heading is the true heading (true heading = platform heading
  - wander angle); body accelerations and rates are not in a run's tables and are written as
  0 (as other exporters do).
- **csv**: every column of the trajectory (or events) table, GPS week and seconds of week
  first, then the UTC time as ISO 8601 text, then ``time_ns``.
- **geojson** (RFC 7946): one FeatureCollection: the track (LineString), each straight leg
  (LineString), and each trigger event (Point); coordinates [lon, lat, ellipsoidal height].
- **kml**: the same features as KML Placemarks, clamped to the ground (KML heights are above
  the geoid, pospp's above the ellipsoid); each feature's properties are the Placemark's
  ``ExtendedData`` fields (``<Data name="heading_deg">``), which GIS tools read as attribute
  columns.

``--events`` (``data="events"``) gives the sensor's pose at each trigger: sbet and csv one
record per event, geojson and kml one Point per event and nothing else.

GPS time: GPS = UTC + leap seconds (18 s since 2017-01-01, ``LEAP_SECONDS``); weeks counted
from 1980-01-06T00:00:00 UTC. Stamps in a run are UTC nanoseconds as logged.
"""

from __future__ import annotations

import datetime as dt
import json
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from pospp.io import parquet_tables, run_folder
from pospp.io.files import atomic_path
from pospp.io.run_lock import locked

if TYPE_CHECKING:  # pandas where an export is made: a run reads DEFAULT_NAMES, not pandas
    import pandas as pd

__all__ = ["EXPORT_FORMATS", "FORMATS", "LEAP_SECONDS", "SBET_FIELDS", "ExportFormat",
           "export_run", "gps_week_seconds", "sbet_records", "write_csv", "write_geojson",
           "write_kml", "write_sbet"]

SOLUTIONS = ("best", "compensated", "smoothed", "forward")

SBET_FIELDS = (
    "gps_sow_s", "lat_rad", "lon_rad", "height_m", "vx_mps", "vy_mps", "vz_mps", "roll_rad",
    "pitch_rad", "platform_heading_rad", "wander_rad", "ax_mps2", "ay_mps2", "az_mps2",
    "wx_radps", "wy_radps", "wz_radps",
)
"""The 17 float64 of one SBET record, in file order (x, y, z = north, east, down here)."""

_GPS_EPOCH_UNIX_S = 315_964_800  # 1980-01-06T00:00:00Z
_WEEK_NS = 604_800 * 1_000_000_000
LEAP_SECONDS: tuple[tuple[str, int], ...] = (
    ("1981-07-01", 1), ("1982-07-01", 2), ("1983-07-01", 3), ("1985-07-01", 4),
    ("1988-01-01", 5), ("1990-01-01", 6), ("1991-01-01", 7), ("1992-07-01", 8),
    ("1993-07-01", 9), ("1994-07-01", 10), ("1996-01-01", 11), ("1997-07-01", 12),
    ("1999-01-01", 13), ("2006-01-01", 14), ("2009-01-01", 15), ("2012-07-01", 16),
    ("2015-07-01", 17), ("2017-01-01", 18),
)
"""GPS - UTC [s] from each UTC date on (IERS Bulletin C; none announced after 2017)."""
_LEAP_FROM_NS = np.array([int(dt.datetime.fromisoformat(d).replace(tzinfo=dt.UTC).timestamp())
                          * 1_000_000_000 for d, _ in LEAP_SECONDS], np.int64)
_LEAP_S = np.array([n for _, n in LEAP_SECONDS], np.int64)


def gps_week_seconds(time_ns: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """UTC nanoseconds (Unix epoch) -> (GPS week, GPS seconds of week [s]).

    ``gps_ns = utc_ns - 1980-01-06 + leap(utc)``; week = gps_ns // 604800 s.
    """
    t = np.asarray(time_ns, dtype=np.int64)
    gps_ns = t - np.int64(_GPS_EPOCH_UNIX_S) * 1_000_000_000
    if np.any(gps_ns < 0):
        raise ValueError("gps_week_seconds: a stamp before the GPS epoch 1980-01-06: "
                         f"{int(t.min())} ns")
    k = np.searchsorted(_LEAP_FROM_NS, t, side="right")
    gps_ns = gps_ns + np.where(k > 0, _LEAP_S[np.maximum(k - 1, 0)], 0) * 1_000_000_000
    week, rem = np.divmod(gps_ns, _WEEK_NS)
    return week, rem * 1e-9


def sbet_records(table: pd.DataFrame) -> np.ndarray:
    """(N, 17) float64 SBET records from a trajectory or events table (docs/formats.md)."""
    _, sow = gps_week_seconds(table["time_ns"].to_numpy(np.int64))
    rec = np.zeros((len(table), len(SBET_FIELDS)))
    rec[:, 0] = sow
    rec[:, 1] = np.radians(table["lat_deg"].to_numpy(float))
    rec[:, 2] = np.radians(table["lon_deg"].to_numpy(float))
    rec[:, 3] = table["height_m"].to_numpy(float)
    rec[:, 4:7] = table[["vn_mps", "ve_mps", "vd_mps"]].to_numpy(float)
    rec[:, 7:10] = np.radians(table[["roll_deg", "pitch_deg", "yaw_deg"]].to_numpy(float))
    return rec


def write_sbet(path: str | Path, table: pd.DataFrame) -> Path:
    """Write ``table`` as an SBET file (17 little-endian float64 per record, no header)."""
    out = Path(path)
    with atomic_path(out) as tmp:
        Path(tmp).write_bytes(sbet_records(table).astype("<f8").tobytes())
    return out


def _with_gps_time(table: pd.DataFrame) -> pd.DataFrame:
    import pandas as pd

    t = table["time_ns"].to_numpy(np.int64)
    week, sow = gps_week_seconds(t)
    utc = pd.to_datetime(t, unit="ns", utc=True).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
    front = pd.DataFrame({"gps_week": week, "gps_sow_s": sow, "utc": utc})
    return pd.concat([front, table.reset_index(drop=True)], axis=1)


def write_csv(path: str | Path, table: pd.DataFrame) -> Path:
    """Write ``table`` as CSV with GPS week, seconds of week and UTC text in front."""
    out = Path(path)
    with atomic_path(out) as tmp:
        _with_gps_time(table).to_csv(tmp, index=False, float_format="%.10f")
    return out


def _utc_text(ns: int) -> str:
    import pandas as pd

    return pd.Timestamp(int(ns), unit="ns", tz="UTC").strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def _features(track: pd.DataFrame | None, legs: pd.DataFrame | None,
              events: pd.DataFrame | None) -> list[dict[str, Any]]:
    """GeoJSON features (track, legs, events) as plain dicts (no track: the events alone)."""
    def line(rows: pd.DataFrame) -> dict[str, Any]:
        return {"type": "LineString",
                "coordinates": rows[["lon_deg", "lat_deg", "height_m"]].to_numpy().tolist()}

    feats: list[dict[str, Any]] = []
    if track is not None:
        t = track["time_ns"].to_numpy(np.int64)
        feats.append({"type": "Feature", "geometry": line(track), "properties": {
            "kind": "track", "solution": str(track["solution"].iloc[0]),
            "start_utc": _utc_text(t[0]), "end_utc": _utc_text(t[-1])}})
    for leg in ([] if legs is None or track is None else legs.itertuples()):
        assert track is not None
        rows = track[(t >= leg.start_ns) & (t <= leg.end_ns)]
        if len(rows) < 2:
            continue
        feats.append({"type": "Feature", "geometry": line(rows), "properties": {
            "kind": "leg", "leg_id": int(leg.leg_id), "heading_deg": float(leg.heading_deg),
            "speed_mps": float(leg.speed_mps), "duration_s": float(leg.duration_s),
            "start_utc": _utc_text(leg.start_ns), "end_utc": _utc_text(leg.end_ns)}})
    if events is not None:
        ev = events[events["inside"].to_numpy(bool)]
        _, sow = gps_week_seconds(ev["time_ns"].to_numpy(np.int64))
        for e, s in zip(ev.itertuples(), sow, strict=True):
            feats.append({"type": "Feature", "geometry": {
                "type": "Point", "coordinates": [e.lon_deg, e.lat_deg, e.height_m]},
                "properties": {"kind": "event", "event_id": int(e.event_id),
                               "utc": _utc_text(e.time_ns), "gps_sow_s": float(s),
                               "roll_deg": e.roll_deg, "pitch_deg": e.pitch_deg,
                               "yaw_deg": e.yaw_deg}})
    return feats


def write_geojson(path: str | Path, track: pd.DataFrame | None,
                  legs: pd.DataFrame | None = None, events: pd.DataFrame | None = None) -> Path:
    """Write the track, the legs and the events as one GeoJSON FeatureCollection."""
    out = Path(path)
    doc = {"type": "FeatureCollection", "features": _features(track, legs, events)}
    with atomic_path(out) as tmp:
        Path(tmp).write_text(json.dumps(doc), encoding="utf-8")
    return out


def write_kml(path: str | Path, track: pd.DataFrame | None,
              legs: pd.DataFrame | None = None, events: pd.DataFrame | None = None) -> Path:
    """Write the same features as KML 2.2 Placemarks (clamped to the ground)."""
    ns = "http://www.opengis.net/kml/2.2"
    kml = ET.Element("kml", xmlns=ns)
    doc = ET.SubElement(kml, "Document")
    ET.SubElement(doc, "name").text = "pospp trajectory"
    for f in _features(track, legs, events):
        p = f["properties"]
        pm = ET.SubElement(doc, "Placemark")
        ET.SubElement(pm, "name").text = {"track": "track", "leg": f"leg {p.get('leg_id')}",
                                          "event": f"event {p.get('event_id')}"}[p["kind"]]
        data = ET.SubElement(pm, "ExtendedData")
        for key, value in p.items():
            field = ET.SubElement(data, "Data", name=key)
            ET.SubElement(field, "value").text = str(value)
        g = f["geometry"]
        geom = ET.SubElement(pm, "LineString" if g["type"] == "LineString" else "Point")
        ET.SubElement(geom, "altitudeMode").text = "clampToGround"
        coords = g["coordinates"] if g["type"] == "LineString" else [g["coordinates"]]
        ET.SubElement(geom, "coordinates").text = " ".join(
            f"{c[0]:.9f},{c[1]:.9f},{c[2]:.3f}" for c in coords)
    out = Path(path)
    with atomic_path(out) as tmp:
        ET.ElementTree(kml).write(tmp, encoding="utf-8", xml_declaration=True)
    return out


GPX_NS = "http://www.topografix.com/GPX/1/1"


def write_gpx(path: str | Path, table: pd.DataFrame) -> Path:
    """Write ``table`` as GPX 1.1: a trajectory as one track segment of points, events (a
    table with ``event_id``) as waypoints named ``event N``; each point's ``ele`` is the
    WGS-84 ellipsoidal height [m] (GPX means height above mean sea level: the file's
    ``desc`` says which) and ``time`` UTC."""
    ET.register_namespace("", GPX_NS)
    q = f"{{{GPX_NS}}}"
    gpx = ET.Element(f"{q}gpx", version="1.1", creator="pospp")
    meta = ET.SubElement(gpx, f"{q}metadata")
    ET.SubElement(meta, f"{q}desc").text = (
        "pospp trajectory; ele: WGS-84 ellipsoidal height [m], not above mean sea level")
    events = "event_id" in table.columns
    parent = gpx if events else ET.SubElement(ET.SubElement(gpx, f"{q}trk"), f"{q}trkseg")
    lat, lon = table["lat_deg"].to_numpy(float), table["lon_deg"].to_numpy(float)
    h, t = table["height_m"].to_numpy(float), table["time_ns"].to_numpy(np.int64)
    ids = table["event_id"].to_numpy() if events else np.zeros(len(table), dtype=int)
    for i in range(len(table)):
        pt = ET.SubElement(parent, f"{q}wpt" if events else f"{q}trkpt",
                           lat=f"{lat[i]:.9f}", lon=f"{lon[i]:.9f}")
        ET.SubElement(pt, f"{q}ele").text = f"{h[i]:.3f}"
        ET.SubElement(pt, f"{q}time").text = _utc_text(int(t[i]))
        if events:
            ET.SubElement(pt, f"{q}name").text = f"event {int(ids[i])}"
    out = Path(path)
    with atomic_path(out) as tmp:
        ET.ElementTree(gpx).write(tmp, encoding="utf-8", xml_declaration=True)
    return out


@dataclass(frozen=True)
class ExportFormat:
    """One export format: a row of :data:`EXPORT_FORMATS`.

    ``records``: ``write(path, rows)`` of one table's rows (a solution's epochs, or the
    events), thinned by ``--rate``; otherwise ``write(path, track, legs, events)`` of map
    features (the track and legs None for ``--events``)."""

    extension: str
    """File extension of the default output name ``RUN_DIR/<trajectory|events>.<ext>``."""
    records: bool
    write: Callable[..., Path]


EXPORT_FORMATS: dict[str, ExportFormat] = {
    "sbet": ExportFormat("out", True, write_sbet),  # SBET files are *.out, as POSPac names them
    "csv": ExportFormat("csv", True, write_csv),
    "geojson": ExportFormat("geojson", False, write_geojson),
    "kml": ExportFormat("kml", False, write_kml),
    "gpx": ExportFormat("gpx", True, write_gpx),
}
"""The export formats by name (docs/formats.md, "Exports"): a new one is a row here, its
writer, its test and its doc line."""

FORMATS = tuple(EXPORT_FORMATS)
DEFAULT_NAMES = frozenset(f"{data}.{f.extension}" for f in EXPORT_FORMATS.values()
                          for data in ("trajectory", "events"))
"""The files ``export_run`` writes into a run folder when no output is given."""


def _thin(table: pd.DataFrame, rate_hz: float | None) -> pd.DataFrame:
    """Every k-th row, k = round(1 / (rate_hz * median interval)) (all when None)."""
    if rate_hz is None or len(table) < 2:
        return table
    dt_s = float(np.median(np.diff(table["time_ns"].to_numpy(np.int64)))) * 1e-9
    return table.iloc[::max(1, int(round(1.0 / (rate_hz * dt_s))))]


def select_solution(traj: pd.DataFrame, solution: str = "best") -> pd.DataFrame:
    """Rows of one solution of a trajectory table ("best": compensated > smoothed > forward)."""
    have = list(dict.fromkeys(traj["solution"]))
    name = next((k for k in SOLUTIONS[1:] if k in have), None) if solution == "best" \
        else solution
    if name not in have:
        raise ValueError(f"solution {solution!r} not in the run; it has {have}")
    return traj[traj["solution"] == name].reset_index(drop=True)


@locked("pospp export")
def export_run(run_dir: str | Path, fmt: str, *, rate_hz: float | None = None,
               out: str | Path | None = None, solution: str = "best",
               data: str = "trajectory", force: bool = False) -> Path:
    """``pospp export``: a run folder's trajectory (or events) in ``fmt``.

    Parameters
    ----------
    run_dir : path-like
        A finished pospp run folder.
    fmt : str
        A key of :data:`EXPORT_FORMATS`.
    rate_hz : float, optional
        Thin the trajectory to about this rate (every k-th epoch); events are never thinned.
    out : path-like, optional
        Output file (default ``RUN_DIR/<data>.<fmt>``, "out" for SBET as POSPac names it):
        never the run's input or another file of a run folder, an existing file only with
        ``force`` (:func:`pospp.io.run_folder.check_output_file`). The run folder's lock is
        held throughout.
    solution : {"best", "compensated", "smoothed", "forward"}
    data : {"trajectory", "events"}
        The track, or the sensor's pose at each trigger (events.parquet). For geojson and
        kml, "trajectory" is the track, the legs and the events there are; "events" the
        events alone, one Point each.
    force : bool
        Replace an existing ``out`` outside run folders.
    """
    if fmt not in FORMATS:
        raise ValueError(f"format: expected one of {list(FORMATS)}, got {fmt!r}")
    if data not in ("trajectory", "events"):
        raise ValueError(f"data: expected 'trajectory' or 'events', got {data!r}")
    if rate_hz is not None and not rate_hz > 0:
        raise ValueError(f"rate_hz: expected a value > 0, got {rate_hz!r}")
    run = run_folder.require_run_folder(run_dir)

    def table(name: str, *, required: bool) -> pd.DataFrame | None:
        p = run / f"{name}.parquet"
        if not p.is_file():
            if required:
                raise FileNotFoundError(f"{run}: the run has no {name}.parquet"
                                        + (" (no trigger events in its input)"
                                           if name == "events" else " (it failed)"))
            return None
        return parquet_tables.read_table(p)

    form = EXPORT_FORMATS[fmt]
    target = run_folder.check_output_file(
        out if out is not None else run / f"{data}.{form.extension}", run=run,
        own_names=DEFAULT_NAMES, force=force)
    if data == "events":
        events = table("events", required=True)
        return form.write(target, events) if form.records else \
            form.write(target, None, None, events)
    track = _thin(select_solution(table("trajectory", required=True), solution), rate_hz)
    if form.records:
        return form.write(target, track)
    return form.write(target, track, table("legs", required=False),
                      table("events", required=False))
