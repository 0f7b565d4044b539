"""End to end: MCAP bytes in, Parquet tables, trajectory MCAP and report out (issue 6).

The good case runs the bundled sample flight (sample_data/, made by pospp's simulator with a
known truth) through the CLI exactly as the README says, then checks the tables against their
schemas, against the truth (pospp evaluate) and for determinism. The bad cases are cut from the
same log and damaged in one way each; every one must end with a clear error naming file,
topic and time, or a completed run that says plainly why no calibration was produced, and
must never lose or half-write a table.
"""

from __future__ import annotations

import importlib.util
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from pospp.cli import main
from pospp.io import parquet_tables
from pospp.io.files import sha256_file
from pospp.io.mcap_reader import read_flight_log
from pospp.io.mcap_writer import write_flight_log

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_data" / "sample_flight.mcap"
SAMPLE_TRUTH = REPO / "sample_data" / "sample_flight.truth.parquet"
SAMPLE_PIPELINE = REPO / "pipelines" / "sample.toml"
TABLES = ("trajectory", "legs", "pairs", "calibration", "leg_errors", "diagnosis", "messages",
          "summary")


def _cli(*args: str) -> tuple[int, str]:
    res = CliRunner().invoke(main, list(args), catch_exceptions=False)
    return res.exit_code, res.output


@pytest.fixture(scope="module")
def sample_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("run") / "sample"
    code, text = _cli("run", str(SAMPLE), "-p", str(SAMPLE_PIPELINE), "-o", str(out),
                      "--threads", "2")
    assert code == 0, text
    assert "status: ok" in text and "legs: 4" in text
    return out


@pytest.mark.slow
def test_sample_run_writes_every_table_with_its_schema(sample_run):
    for name in TABLES:
        path = sample_run / f"{name}.parquet"
        assert path.is_file(), name
        meta = parquet_tables.read_metadata(path)
        assert meta["schema_name"] == name
        assert meta["input_sha256"] == sha256_file(SAMPLE)
        assert meta["config"]["name"] == "sample"
        assert parquet_tables.schema(name).names[0] in parquet_tables.read_table(path)
    assert (sample_run / "report.html").stat().st_size > 50_000
    assert not list(sample_run.glob(".*.tmp")), "a temporary file was left behind"


@pytest.mark.slow
def test_sample_run_calibrates_and_improves(sample_run):
    s = parquet_tables.read_table(sample_run / "summary.parquet").iloc[0]
    assert s.status == "ok" and s.n_legs == 4 and s.n_pairs_used >= 2
    # the calibration must shrink B's error at the horizon; the random drift (Gauss-Markov,
    # 0.5 deg/h, 300 s) of the paper_flight grade bounds how much (docs/calibration.md)
    assert s.dv_after_mps < s.dv_before_mps / 2.5
    assert s.dp_after_m < s.dp_before_m / 2.5
    cal = parquet_tables.read_table(sample_run / "calibration.parquet")
    body = cal[(cal.pair_id == -1) & (cal.formulation == "body")].set_index("parameter")
    # injected: constant [1, -1, 1] deg/h plus the drift's realisation (sample_data/README.md):
    # signs right and within the drift's size
    assert body.loc["gyro_bias_x", "value"] == pytest.approx(1.0, abs=0.6)
    assert body.loc["gyro_bias_y", "value"] == pytest.approx(-1.0, abs=0.6)
    legs = parquet_tables.read_table(sample_run / "legs.parquet")
    np.testing.assert_allclose(np.sort(legs.heading_deg.to_numpy()), [20, 20, 110, 200],
                               atol=0.5)


@pytest.mark.slow
def test_sample_run_against_the_truth(sample_run):
    code, text = _cli("evaluate", str(sample_run), "--truth", str(SAMPLE_TRUTH),
                      "--skip-s", "300")
    assert code == 0, text
    ev = parquet_tables.read_table(sample_run / "evaluation.parquet")
    sm = ev[ev.solution == "smoothed"].set_index("metric").value
    # issue 4 targets (1.5 h flight): tilt < 10 arcsec, heading < 60 arcsec, position < 0.1 m
    assert sm["roll_pitch_rms"] < 10.0
    assert sm["heading_rms"] < 60.0
    assert sm["horizontal_rms"] < 0.1
    assert (sample_run / "evaluation.png").is_file()


@pytest.mark.slow
def test_trajectory_mcap_reads_back(sample_run):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(sample_run / "trajectory.mcap", "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        topics = {ch.topic for ch in reader.get_summary().channels.values()}
        first = next(reader.iter_decoded_messages(topics=["/pospp/fix"]))
    assert topics == {"/pospp/fix", "/pospp/pose", "/tf", "/pospp/odom", "/pospp/legs"}
    truth = parquet_tables.read_reference_trajectory(SAMPLE_TRUTH)
    assert first.decoded_message.latitude == pytest.approx(np.degrees(truth.lat_rad[0]),
                                                           abs=1e-5)


@pytest.mark.slow
def test_outputs_are_deterministic(sample_run, tmp_path):
    # and independent of the threads making the loops' A re-runs (sample_run: 2 threads)
    again = tmp_path / "again"
    code, text = _cli("run", str(SAMPLE), "-p", str(SAMPLE_PIPELINE), "-o", str(again),
                      "--threads", "1")
    assert code == 0, text
    _assert_same_tables(sample_run, again)


def _assert_same_tables(run_a, run_b, names=TABLES):
    """The runs' tables are equal bit for bit (the summary's timings aside)."""
    for name in names:
        a = parquet_tables.read_table(run_a / f"{name}.parquet")
        b = parquet_tables.read_table(run_b / f"{name}.parquet")
        if name == "summary":
            timing = [c for c in a.columns if c == "wall_time_s" or c.startswith("stage_")]
            a, b = a.drop(columns=timing), b.drop(columns=timing)
        pd.testing.assert_frame_equal(a, b, check_exact=True, obj=name)


# ------------------------------------------------------------------------------ bad inputs


@pytest.fixture(scope="module")
def sample_log():
    return read_flight_log(SAMPLE)


def _window(log, t_end_s: float):
    t0 = int(log.imu.time_ns[0])

    def keep(obj):
        m = obj.time_ns < t0 + int(t_end_s * 1e9)
        return replace(obj, **{k: v[m] for k, v in vars(obj).items()
                               if isinstance(v, np.ndarray) and v.shape[:1] == m.shape})

    return keep(log.imu), keep(log.fix), keep(log.vel)


def _failed_run(path: Path, out: Path) -> tuple[str, pd.DataFrame]:
    code, text = _cli("run", str(path), "-p", str(SAMPLE_PIPELINE), "-o", str(out))
    assert code == 1, text  # docs/cli.md: 1 = the run failed
    summary = parquet_tables.read_table(out / "summary.parquet").iloc[0]
    assert summary.status == "failed"
    return text, parquet_tables.read_table(out / "messages.parquet")


def test_missing_gnss_topic_is_named(sample_log, tmp_path):
    imu, fix, vel = _window(sample_log, 120.0)
    path = tmp_path / "no_gnss.mcap"
    write_flight_log(path, imu, fix, vel, fix_topic="/other/fix")
    out = tmp_path / "out"
    code, text = _cli("run", str(path), "-p", str(SAMPLE_PIPELINE), "-o", str(out))
    assert code == 2, text  # a topic the configuration names and the log lacks: usage
    assert parquet_tables.read_table(out / "summary.parquet").status.iloc[0] == "failed"
    msgs = parquet_tables.read_table(out / "messages.parquet")
    assert "'/gnss/fix'" in text and "no_gnss.mcap" in text and "/other/fix" in text
    assert (msgs.severity == "error").any()


def test_nan_imu_sample_is_named_with_its_time(sample_log, tmp_path):
    imu, fix, vel = _window(sample_log, 120.0)
    w = imu.w_ib_b_radps.copy()
    w[5000, 1] = np.nan
    path = tmp_path / "nan.mcap"
    write_flight_log(path, replace(imu, w_ib_b_radps=w), fix, vel)
    text, _ = _failed_run(path, tmp_path / "out")
    assert "nan.mcap" in text and "/imu/data" in text and str(int(imu.time_ns[5000])) in text


def test_imu_in_degrees_per_second_is_caught(sample_log, tmp_path):
    imu, fix, vel = _window(sample_log, 600.0)
    path = tmp_path / "degps.mcap"
    write_flight_log(path, replace(imu, w_ib_b_radps=np.degrees(imu.w_ib_b_radps),
                                   f_ib_b_mps2=imu.f_ib_b_mps2 / 9.80665), fix, vel)
    text, _ = _failed_run(path, tmp_path / "out")
    assert "degps.mcap" in text and "/imu/data" in text


def _tables_of(folder: Path) -> dict[str, str]:
    """Table name -> the input SHA-256 its metadata names, for every table in ``folder``."""
    return {p.stem: parquet_tables.read_metadata(p)["input_sha256"]
            for p in folder.glob("*.parquet")}


def test_truncated_file_ends_non_ok_and_keeps_no_table_of_the_earlier_run(sample_log,
                                                                          tmp_path):
    """Issue 16 item 2: a truncated re-run into a folder says where the file ends, is never
    "ok", and its folder holds only its own tables (none of the first run's)."""
    imu, fix, vel = _window(sample_log, 400.0)
    good = tmp_path / "good.mcap"
    write_flight_log(good, imu, fix, vel)
    out = tmp_path / "out"
    code, text = _cli("run", str(good), "-p", str(SAMPLE_PIPELINE), "-o", str(out))
    # 400 s of static and climb: A runs, no leg is found, and the run says so plainly
    assert code == 4, text  # partial (issue 39 item 4)
    s = parquet_tables.read_table(out / "summary.parquet").iloc[0]
    assert s.status == "partial" and "no straight" in s.calibration_reason
    assert set(_tables_of(out).values()) == {sha256_file(good)}
    cut = tmp_path / "cut.mcap"
    data = good.read_bytes()
    cut.write_bytes(data[: len(data) // 3])
    code, text = _cli("run", str(cut), "-p", str(SAMPLE_PIPELINE), "-o", str(out), "--force")
    msgs = parquet_tables.read_table(out / "messages.parquet")
    assert (msgs.severity == "error").any()
    assert msgs.text.str.contains("cut.mcap").any()
    assert not list(out.glob(".*.tmp")) and not list(tmp_path.glob(".out.pospp-*"))
    # every table in the folder is the cut file's: nothing of the first run is left
    tables = _tables_of(out)
    assert "summary" in tables and "messages" in tables
    assert set(tables.values()) == {sha256_file(cut)}, tables
    status = parquet_tables.read_table(out / "summary.parquet").status.iloc[0]
    assert status != "ok"
    if importlib.util.find_spec("pospp.qc") is None:
        pytest.skip("needs the QC stage (pospp.qc, issue 13 item 1) that turns the reader's "
                    "FlightLog.complete = False into a non-ok status")
    # a truncated log is never a finished run: failed, or degraded with the reason named
    assert status in ("failed", "degraded") and code in (1, 3), (status, code, text)


def test_duplicate_gnss_stamps_and_a_jump_are_reported(sample_log, tmp_path):
    imu, fix, vel = _window(sample_log, 400.0)
    lat = fix.lat_rad.copy()
    lat[200] += 5000.0 / 6.4e6  # a 5 km jump
    t = fix.time_ns.copy()
    t[100] = t[99]  # a duplicate stamp
    path = tmp_path / "jump.mcap"
    write_flight_log(path, imu, replace(fix, lat_rad=lat, time_ns=t), vel)
    out = tmp_path / "out"
    code, text = _cli("run", str(path), "-p", str(SAMPLE_PIPELINE), "-o", str(out))
    # the run completes, degraded: the QC names the jump (issue 13 item 1)
    assert code == 3 and "gnss_jumps" in text and "jumps by 49" in text, text
    msgs = parquet_tables.read_table(out / "messages.parquet")
    assert msgs.text.str.contains("duplicate").any()
    rejected = msgs[(msgs.stage == "navigate") & msgs.text.str.contains("position")]
    assert (rejected.time_ns == fix.time_ns[200]).any(), msgs.to_string()


def test_batch_records_every_outcome_and_skips_finished(sample_log, tmp_path):
    imu, fix, vel = _window(sample_log, 300.0)
    arch = tmp_path / "archive"
    arch.mkdir()
    write_flight_log(arch / "a.mcap", imu, fix, vel)
    (arch / "b.mcap").write_bytes(b"not an mcap file")
    root = tmp_path / "out"
    code, text = _cli("batch", str(arch), "-p", str(SAMPLE_PIPELINE), "-o", str(root), "-j",
                      "1")
    assert code == 1, text  # one flight failed
    man = parquet_tables.read_table(root / "manifest.parquet").set_index("file")
    assert man.loc[str(arch / "a.mcap"), "status"] == "partial"
    assert man.loc[str(arch / "b.mcap"), "status"] == "failed"
    assert "b.mcap" in man.loc[str(arch / "b.mcap"), "error"]
    code, text = _cli("batch", str(arch), "-p", str(SAMPLE_PIPELINE), "-o", str(root), "-j",
                      "1")
    man = parquet_tables.read_table(root / "manifest.parquet").set_index("file")
    assert man.loc[str(arch / "a.mcap"), "status"] == "partial"  # its result, kept
    assert man.loc[str(arch / "a.mcap"), "action"] == "skipped"


def test_unknown_config_key_is_named(tmp_path):
    bad = tmp_path / "bad.toml"
    shutil.copy(SAMPLE_PIPELINE, bad)
    with open(bad, "a") as fh:
        fh.write("\n[filtre]\nsmoother = true\n")
    code, text = _cli("run", str(SAMPLE), "-p", str(bad), "-o", str(tmp_path / "o"))
    assert code == 2 and "filtre" in text and "bad.toml" in text


def test_rerun_into_a_folder_leaves_no_stale_table(sample_log, tmp_path):
    """A folder first used for a run with a diagnosis, then (--force) for a run without legs,
    holds only the second run's tables (a report would otherwise mix the two)."""
    out = tmp_path / "out"
    imu, fix, vel = _window(sample_log, 300.0)
    path = tmp_path / "short.mcap"
    write_flight_log(path, imu, fix, vel)
    code, text = _cli("run", str(path), "-p", str(SAMPLE_PIPELINE), "-o", str(out))
    assert code == 4, text  # partial: no legs
    # stand-ins for an earlier run's diagnosis table (pospp's name, another input's hash)
    parquet_tables.write_table(out / "legs.parquet", {
        "leg_id": [0], "start_ns": [0], "end_ns": [1], "duration_s": [1.0],
        "heading_deg": [0.0], "speed_mps": [1.0], "height_m": [0.0]}, "legs",
        metadata={"input_sha256": "an earlier run"})
    (out / "diagnosis.parquet").write_bytes(b"an earlier run's diagnosis")
    code, text = _cli("run", str(path), "-p", str(SAMPLE_PIPELINE), "-o", str(out))
    assert code == 2 and "--force" in text  # an earlier run is replaced only when asked
    code, text = _cli("run", str(path), "-p", str(SAMPLE_PIPELINE), "-o", str(out), "--force")
    assert code == 4, text
    legs = parquet_tables.read_table(out / "legs.parquet")
    assert len(legs) == 0
    assert set(_tables_of(out).values()) == {sha256_file(path)}
    assert not (out / "diagnosis.parquet").exists()


@pytest.mark.slow
def test_batch_on_a_dask_scheduler(sample_log, tmp_path):
    """The Dask path: the same manifest through a (local, in-process) distributed scheduler."""
    distributed = pytest.importorskip("dask.distributed")
    from pospp.batch import run_batch
    from pospp.config import load_config

    imu, fix, vel = _window(sample_log, 300.0)
    files = []
    for name in ("x", "y"):
        files.append(tmp_path / f"{name}.mcap")
        write_flight_log(files[-1], imu, fix, vel)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        rows = run_batch(files, load_config(SAMPLE_PIPELINE), tmp_path / "out",
                         scheduler=cluster.scheduler_address)
    assert [r.status for r in rows] == ["partial", "partial"]
    man = parquet_tables.read_table(tmp_path / "out" / "manifest.parquet")
    assert sorted(man.file) == sorted(str(f) for f in files)


# ------------------------------------------------------------------ a stage's failures


@pytest.fixture(scope="module")
def small_config():
    """The sample pipeline, three null realisations, no report or trajectory MCAP."""
    from pospp.config import load_config

    cfg = load_config(SAMPLE_PIPELINE)
    return replace(cfg, pairs=replace(cfg.pairs, null_realisations=3),
                   outputs=replace(cfg.outputs, report=False, mcap=False))


@pytest.mark.slow
def test_a_failed_compensation_pass_fails_the_run_in_its_stage(small_config, tmp_path,
                                                               monkeypatch):
    # an unexpected error in the compensated A pass fails the run: a failed run folder that
    # says why and in which stage, and no thread of the run's loops left behind
    import threading

    from pospp import pipeline

    def broken(*args, **kwargs):
        raise RuntimeError("injected: the compensated pass broke")

    monkeypatch.setattr(pipeline, "compensated", broken)
    before = threading.active_count()
    with pytest.raises(RuntimeError, match="injected"):
        pipeline.process_flight(SAMPLE, small_config, tmp_path / "out", threads=2)
    assert threading.active_count() == before
    summary = parquet_tables.read_table(tmp_path / "out" / "summary.parquet").iloc[0]
    msgs = parquet_tables.read_table(tmp_path / "out" / "messages.parquet")
    assert summary.status == "failed"
    assert msgs.text.str.contains("injected: the compensated pass broke").any()
    assert summary.stage_compensate_s >= 0 and pd.isna(summary.get("stage_diagnose_s"))


@pytest.mark.slow
def test_a_failed_diagnosis_re_run_is_a_partial_run(small_config, tmp_path, monkeypatch):
    # the diagnosis's re-runs failing with a ValueError: the stage's "no diagnosis" (partial)
    from pospp import diagnosis_stage, pipeline

    def broken(*args, **kwargs):
        raise ValueError("injected: A failed on the re-run base")

    monkeypatch.setattr(diagnosis_stage, "diagnosis_reruns", broken)
    outcome = pipeline.process_flight(SAMPLE, small_config, tmp_path / "out", threads=2)
    assert outcome.status == "partial"
    assert outcome.messages.text.str.contains(
        "no diagnosis: injected: A failed on the re-run base").any()


@pytest.mark.slow
def test_sensor_families_that_cannot_be_fitted_are_said(monkeypatch, tmp_path):
    """When the sensor families' fit fails (here: A made to fail on the log with the named
    effects removed), the run says which families were not evaluated instead of reading as a
    diagnosis that looked and found nothing; the sample's own run has no such note."""
    import pospp.sensor_stage as sensor_stage

    def fails(*_args, **_kwargs):
        raise ValueError("A diverged")

    monkeypatch.setattr(sensor_stage, "_without_time_offset", fails)
    out = tmp_path / "run"
    code, text = _cli("run", str(SAMPLE), "-p", str(SAMPLE_PIPELINE), "-o", str(out))
    assert code == 0, text
    m = pd.read_parquet(out / "messages.parquet")
    said = m[(m.stage == "diagnose") & m.text.str.startswith("not evaluated")]
    assert len(said) == 1 and (said.severity == "warning").all()
    assert all(f in said.text.iloc[0] for f in ("accel_bias_change", "gyro_bias_change"))
