"""pospp export: SBET, CSV, GeoJSON and KML, each read back by something pospp did not write.

SBET has no library on PyPI (``pip index versions sbet`` / ``pysbet``: none), so the test
reads it with a reader written here from the published description (Applanix via the
LiDAR360 manual and the NAVO ``FilePOSOutput.h``: 17 float64 per record, time of week, lat,
lon [rad], altitude, x/y/z velocity, roll, pitch, platform heading, wander angle, 3 body
accelerations, 3 body rates; true heading = platform heading - wander angle). GeoJSON is
checked by the ``geojson`` package (RFC 7946 validation), KML by the standard library's XML
parser, CSV by the ``csv`` module. GPS time is checked on known instants.
"""

from __future__ import annotations

import csv
import datetime as dt
import json
import xml.etree.ElementTree as ET

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from pospp.cli import main
from pospp.io import exports, parquet_tables, run_folder

geojson = pytest.importorskip("geojson", reason="dev dependency geojson (RFC 7946 checks)")

T0_NS = 1_717_200_000_000_000_000  # 2024-06-01T00:00:00Z


def _unix_ns(text: str) -> int:
    return int(dt.datetime.fromisoformat(text).replace(tzinfo=dt.UTC).timestamp()) * 10**9


@pytest.mark.parametrize(("utc", "week", "sow"), [
    ("2024-06-01T00:00:00", 2316, 518418.0),  # Saturday: 6 days + 18 leap seconds
    ("1980-01-06T00:00:00", 0, 0.0),          # the GPS epoch, no leap second yet
    ("2017-01-01T00:00:00", 1930, 18.0),      # Sunday 00:00 UTC, right after the 18th leap s
    ("2016-12-31T23:59:59", 1930, 16.0),      # 17 leap seconds carry it into week 1930
])
def test_gps_week_and_seconds_of_week_of_known_instants(utc, week, sow):
    w, s = exports.gps_week_seconds([_unix_ns(utc)])
    assert int(w[0]) == week
    assert s[0] == pytest.approx(sow, abs=1e-9)


def _track(n: int = 200, rate_hz: float = 10.0) -> pd.DataFrame:
    """A straight eastward track at 50 m/s with known attitude (heading 90 deg)."""
    t = T0_NS + np.arange(n) * int(1e9 / rate_hz)
    lat0, lon0 = 47.0, 8.0
    east_m = 50.0 * np.arange(n) / rate_hz
    r_n = 6378137.0 / np.sqrt(1 - 0.00669437999014 * np.sin(np.radians(lat0)) ** 2)
    return pd.DataFrame({
        "time_ns": t, "solution": "smoothed", "lat_deg": np.full(n, lat0),
        "lon_deg": lon0 + np.degrees(east_m / (r_n * np.cos(np.radians(lat0)))),
        "height_m": np.full(n, 1000.0), "vn_mps": 0.0, "ve_mps": 50.0, "vd_mps": -1.0,
        "roll_deg": 2.0, "pitch_deg": -3.0, "yaw_deg": 90.0,
        "north_sigma_m": 0.05, "east_sigma_m": 0.05, "down_sigma_m": 0.1,
        "vn_sigma_mps": 0.01, "ve_sigma_mps": 0.01, "vd_sigma_mps": 0.01,
        "roll_sigma_deg": 0.002, "pitch_sigma_deg": 0.002, "yaw_sigma_deg": 0.01,
    })


def _read_sbet(path) -> np.ndarray:
    """Reader from the published description (not pospp's): 17 little-endian doubles."""
    raw = path.read_bytes()
    assert len(raw) % (17 * 8) == 0
    return np.frombuffer(raw, dtype="<f8").reshape(-1, 17)


def test_sbet_records_hold_known_values(tmp_path):
    tr = _track()
    rec = _read_sbet(exports.write_sbet(tmp_path / "t.out", tr))
    assert rec.shape == (200, 17)
    np.testing.assert_allclose(rec[:, 0], 518418.0 + np.arange(200) * 0.1, atol=1e-9)
    np.testing.assert_allclose(np.degrees(rec[:, 1]), 47.0, atol=1e-12)
    np.testing.assert_allclose(np.degrees(rec[:, 2]), tr.lon_deg, atol=1e-12)
    np.testing.assert_allclose(rec[:, 3], 1000.0)
    np.testing.assert_allclose(rec[:, 4:7], [[0.0, 50.0, -1.0]] * 200)  # north, east, down
    np.testing.assert_allclose(np.degrees(rec[:, 7:9]), [[2.0, -3.0]] * 200, atol=1e-12)
    true_heading = np.degrees(rec[:, 9] - rec[:, 10])  # platform heading - wander angle
    np.testing.assert_allclose(true_heading, 90.0, atol=1e-12)
    assert np.all(rec[:, 11:] == 0.0)


def test_csv_has_gps_week_and_seconds_of_week(tmp_path):
    path = exports.write_csv(tmp_path / "t.csv", _track(20))
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 20
    assert rows[0]["gps_week"] == "2316"
    assert float(rows[3]["gps_sow_s"]) == pytest.approx(518418.3, abs=1e-6)
    assert rows[0]["utc"] == "2024-06-01T00:00:00.000000Z"
    assert float(rows[5]["lat_deg"]) == pytest.approx(47.0, abs=1e-10)
    assert int(rows[5]["time_ns"]) == T0_NS + 5 * 10**8


def _legs() -> pd.DataFrame:
    return pd.DataFrame({"leg_id": [0, 1], "start_ns": [T0_NS + 10**9, T0_NS + 11 * 10**9],
                         "end_ns": [T0_NS + 9 * 10**9, T0_NS + 19 * 10**9],
                         "duration_s": [8.0, 8.0], "heading_deg": [90.0, 90.0],
                         "speed_mps": [50.0, 50.0], "height_m": [1000.0, 1000.0]})


def _events(track: pd.DataFrame) -> pd.DataFrame:
    ev = track.iloc[[5, 50, 150]].copy()
    ev.insert(1, "event_id", np.arange(3))
    ev.insert(3, "inside", True)
    return ev.reset_index(drop=True)


def test_geojson_is_valid_rfc7946_with_track_legs_and_events(tmp_path):
    tr = _track()
    path = exports.write_geojson(tmp_path / "t.geojson", tr, _legs(), _events(tr))
    checked = geojson.loads(path.read_text())  # the library rounds to 1e-6 deg on load
    assert checked.is_valid, checked.errors()
    doc = json.loads(path.read_text())
    kinds = [f["properties"]["kind"] for f in doc["features"]]
    assert kinds == ["track", "leg", "leg", "event", "event", "event"]
    track = doc["features"][0]["geometry"]
    assert track["type"] == "LineString" and len(track["coordinates"]) == 200
    lon, lat, h = track["coordinates"][7]
    assert (lon, lat, h) == pytest.approx((tr.lon_deg[7], 47.0, 1000.0), abs=1e-12)
    leg0 = doc["features"][1]
    assert len(leg0["geometry"]["coordinates"]) == 81  # 1 s .. 9 s at 10 Hz, both ends
    ev = doc["features"][4]
    assert ev["geometry"]["coordinates"] == pytest.approx([tr.lon_deg[50], 47.0, 1000.0])
    assert ev["properties"]["gps_sow_s"] == pytest.approx(518423.0)


def test_kml_parses_with_the_track_and_events(tmp_path):
    tr = _track()
    path = exports.write_kml(tmp_path / "t.kml", tr, _legs(), _events(tr))
    ns = {"k": "http://www.opengis.net/kml/2.2"}
    root = ET.parse(path).getroot()
    marks = root.findall(".//k:Placemark", ns)
    assert len(marks) == 6
    coords = marks[0].find(".//k:LineString/k:coordinates", ns).text.split()
    assert len(coords) == 200
    lon, lat, h = map(float, coords[7].split(","))
    assert lon == pytest.approx(tr.lon_deg[7], abs=1e-9) and lat == pytest.approx(47.0)
    assert marks[5].find(".//k:Point", ns) is not None


def _run_folder(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    tr = pd.concat([_track().assign(solution="forward"), _track()], ignore_index=True)
    meta = {"input_sha256": "0" * 64, "config": {}}
    parquet_tables.write_table(run / "trajectory.parquet", tr, "trajectory", metadata=meta)
    parquet_tables.write_table(run / "legs.parquet", _legs(), "legs", metadata=meta)
    parquet_tables.write_table(run / "events.parquet", _events(_track()), "events",
                               metadata=meta)
    run_folder.write_marker(run, input_file=tmp_path / "in.mcap", input_sha256="0" * 64,
                            config_json="{}", status="ok")
    return run


def test_cli_export_every_format_into_the_run_folder(tmp_path):
    run = _run_folder(tmp_path)
    # the CLI takes every row of the registry and names them all when given another
    res = CliRunner().invoke(main, ["export", str(run), "--format", "shp"])
    assert res.exit_code == 2 and all(f in res.output for f in exports.FORMATS), res.output
    for fmt, form in exports.EXPORT_FORMATS.items():
        name = f"trajectory.{form.extension}"
        res = CliRunner().invoke(main, ["export", str(run), "--format", fmt, "--rate", "2"])
        assert res.exit_code == 0, res.output
        assert (run / name).is_file() and run_folder.is_pospp_file(name)
    assert {f"trajectory.{e}" for e in ("out", "csv", "geojson", "kml")} <= exports.DEFAULT_NAMES
    rec = _read_sbet(run / "trajectory.out")
    assert rec.shape[0] == 40  # 10 Hz thinned to 2 Hz
    np.testing.assert_allclose(np.diff(rec[:, 0]), 0.5)
    res = CliRunner().invoke(main, ["export", str(run), "--format", "sbet", "--events",
                                    "-o", str(tmp_path / "cam.out")])
    assert res.exit_code == 0, res.output
    ev = _read_sbet(tmp_path / "cam.out")
    np.testing.assert_allclose(ev[:, 0], 518418.0 + np.array([0.5, 5.0, 15.0]), atol=1e-9)


def test_cli_export_errors_are_one_line(tmp_path):
    run = _run_folder(tmp_path)
    res = CliRunner().invoke(main, ["export", str(run), "--format", "csv", "--solution",
                                    "compensated"])
    assert res.exit_code != 0 and "compensated" in res.output and "Traceback" not in res.output
    res = CliRunner().invoke(main, ["export", str(tmp_path), "--format", "csv"])
    assert res.exit_code != 0 and "Traceback" not in res.output


def test_kml_properties_are_extended_data_fields(tmp_path):
    """Issue 39 item 12: each property a <Data name=...> field (GIS tools read them as
    attribute columns), not a JSON blob in the description."""
    tr = _track()
    path = exports.write_kml(tmp_path / "t.kml", tr, _legs(), _events(tr))
    ns = {"k": "http://www.opengis.net/kml/2.2"}
    marks = ET.parse(path).getroot().findall(".//k:Placemark", ns)
    fields = [{d.get("name"): d.find("k:value", ns).text
               for d in m.findall("k:ExtendedData/k:Data", ns)} for m in marks]
    assert [f["kind"] for f in fields] == ["track", "leg", "leg", "event", "event", "event"]
    assert float(fields[1]["heading_deg"]) == 90.0 and fields[1]["leg_id"] == "0"
    assert float(fields[4]["gps_sow_s"]) == pytest.approx(518423.0)
    assert all(m.find("k:description", ns) is None for m in marks)


@pytest.mark.parametrize("fmt", ["geojson", "kml"])
def test_events_flag_with_geojson_and_kml_gives_the_events_alone(tmp_path, fmt):
    """Issue 39 item 12: --events with --format geojson/kml was ignored silently (the track
    came out); it now gives one Point per event and nothing else."""
    run = _run_folder(tmp_path)
    res = CliRunner().invoke(main, ["export", str(run), "--format", fmt, "--events"])
    assert res.exit_code == 0, res.output
    out = run / f"events.{fmt}"
    assert out.is_file() and run_folder.is_pospp_file(out.name)
    assert res.output.strip().splitlines()[-1] == f"pospp export: ok ({out})"
    if fmt == "geojson":
        feats = json.loads(out.read_text())["features"]
        kinds = [f["properties"]["kind"] for f in feats]
        points = [f["geometry"]["type"] for f in feats]
    else:
        ns = {"k": "http://www.opengis.net/kml/2.2"}
        marks = ET.parse(out).getroot().findall(".//k:Placemark", ns)
        kinds = [m.find("k:ExtendedData/k:Data[@name='kind']/k:value", ns).text for m in marks]
        points = ["Point" if m.find("k:Point", ns) is not None else "other" for m in marks]
    assert kinds == ["event"] * 3 and points == ["Point"] * 3


def test_gpx_track_and_waypoints_read_back(tmp_path):
    # GPX 1.1 read back with the standard library's XML parser against the tables written
    tr = _track()
    ns = {"g": "http://www.topografix.com/GPX/1/1"}
    path = exports.write_gpx(tmp_path / "t.gpx", tr)
    root = ET.parse(path).getroot()
    assert root.tag == "{http://www.topografix.com/GPX/1/1}gpx" and root.get("version") == "1.1"
    pts = root.findall("g:trk/g:trkseg/g:trkpt", ns)
    assert len(pts) == len(tr)
    np.testing.assert_allclose([float(p.get("lat")) for p in pts], tr["lat_deg"], atol=1e-9)
    np.testing.assert_allclose([float(p.get("lon")) for p in pts], tr["lon_deg"], atol=1e-9)
    np.testing.assert_allclose([float(p.find("g:ele", ns).text) for p in pts], tr["height_m"],
                               atol=1e-3)
    t = pd.to_datetime([p.find("g:time", ns).text for p in pts]).as_unit("ns").asi8
    np.testing.assert_array_equal(t, tr["time_ns"].to_numpy(np.int64) // 1000 * 1000)  # us
    assert "ellipsoidal" in root.find("g:metadata/g:desc", ns).text
    ev = _events(tr)
    wpts = ET.parse(exports.write_gpx(tmp_path / "e.gpx", ev)).getroot().findall("g:wpt", ns)
    assert [w.find("g:name", ns).text for w in wpts] == [f"event {i}" for i in ev["event_id"]]
    np.testing.assert_allclose([float(w.get("lat")) for w in wpts], ev["lat_deg"], atol=1e-9)
