"""The batch manifest and its root (issue 37 item 4, issue 38 items 9 and 14).

The flights here are stand-ins: ``process_one`` is replaced by a function that writes a run
folder's marker and summary (or kills its own worker), so each case runs in milliseconds;
tests/e2e/test_first_hour_walk.py runs real flights, a kill -9 of the batch and its re-run.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

import pospp.batch
from pospp.batch import find_flight_logs, run_batch, workers
from pospp.batch.outcome import FlightOutcome, read_rows, write_rows
from pospp.cli import main
from pospp.config import PipelineConfig
from pospp.io import run_folder
from pospp.io.manifest import ManifestError, is_run_name

CONFIG = PipelineConfig()


def fake_process_one(mcap_path, config_dict, out_root, force=False, run_name=None,
                     flights_at_once=None, threads=None, queued=False) -> FlightOutcome:
    """A flight in a millisecond: its folder gets a marker; "kill" in the name kills the
    worker (after leaving a staging folder, as a run killed mid-way does)."""
    folder = Path(out_root) / run_name
    if "kill" in Path(mcap_path).name:
        stage = run_folder.new_staging(folder)
        (stage / "summary.parquet").write_bytes(b"half")
        os.kill(os.getpid(), signal.SIGKILL)
    folder.mkdir(parents=True, exist_ok=True)
    run_folder.write_marker(folder, input_file=mcap_path, input_sha256="s", config_json="{}",
                            status="degraded")
    return FlightOutcome(run_folder.display_path(mcap_path), "s", "degraded", 0.0, None,
                         run_dir=run_name, action="resumed" if queued else "ran")


@pytest.fixture
def fake(monkeypatch):
    monkeypatch.setattr(pospp.batch, "process_one", fake_process_one)
    monkeypatch.setattr(workers, "process_one", fake_process_one)


def _flights(folder: Path, *names: str) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    for n in names:
        (folder / n).write_bytes(b"mcap")
    return [folder / n for n in names]


def test_manifest_keeps_result_and_action_in_the_words_of_pospp_run(tmp_path, fake):
    files = _flights(tmp_path / "arch", "a.mcap", "b.mcap")
    rows = run_batch(files, CONFIG, tmp_path / "root", workers=1)
    assert [(r.status, r.action) for r in rows] == [("degraded", "ran")] * 2
    back = read_rows(tmp_path / "root")
    assert {r.status for r in back.values()} == {"degraded"}
    assert {r.action for r in back.values()} == {"ran"}


def test_old_manifest_words_are_read_as_results(tmp_path):
    write_rows(tmp_path, [FlightOutcome("/a.mcap", "s", "done", 1.0, None, run_dir="a"),
                          FlightOutcome("/b.mcap", "s", "skipped", 1.0, None, run_dir="b")],
               CONFIG)
    back = read_rows(tmp_path)
    assert back["/a.mcap"].status == "ok" and back["/b.mcap"].status is None


def test_another_tools_manifest_is_refused_and_not_rewritten(tmp_path, fake):
    root = tmp_path / "root"
    root.mkdir()
    pq.write_table(pa.table({"file": ["x.bag"], "status": ["archived"]}), root / "manifest.parquet")
    before = (root / "manifest.parquet").read_bytes()
    files = _flights(tmp_path / "arch", "a.mcap")
    with pytest.raises(ManifestError, match="not a pospp manifest"):
        run_batch(files, CONFIG, root, workers=1)
    res = CliRunner().invoke(main, ["batch", str(files[0]), "-o", str(root)])
    assert res.exit_code == 2 and "another tool" in res.stderr and "\n" not in res.stderr.strip()
    assert (root / "manifest.parquet").read_bytes() == before
    assert not (root / "a").exists()


def test_a_damaged_manifest_is_refused_not_rebuilt(tmp_path, fake):
    root = tmp_path / "root"
    run_batch(_flights(tmp_path / "arch1", "f.mcap"), CONFIG, root, workers=1)
    (root / "manifest.parquet").write_bytes(b"PAR1 garbage")
    damaged = (root / "manifest.parquet").read_bytes()
    with pytest.raises(ManifestError, match="damaged.*move it aside"):
        run_batch(_flights(tmp_path / "arch2", "f.mcap"), CONFIG, root, workers=1)
    assert (root / "manifest.parquet").read_bytes() == damaged
    assert run_folder.read_marker(root / "f")["input_file"] == str(tmp_path / "arch1" / "f.mcap")


def test_without_a_manifest_the_markers_keep_each_folder_to_its_input(tmp_path, fake):
    """The manifest moved aside: a same-stem flight of another archive gets a folder of its
    own, the earlier flight's folder is not replaced."""
    root = tmp_path / "root"
    run_batch(_flights(tmp_path / "arch1", "f.mcap"), CONFIG, root, workers=1)
    (root / "manifest.parquet").rename(tmp_path / "aside.parquet")
    other = _flights(tmp_path / "arch2", "f.mcap")
    rows = run_batch(other, CONFIG, root, workers=1)
    assert rows[0].run_dir.startswith("f-") and len(rows[0].run_dir) == len("f-") + 8
    assert run_folder.read_marker(root / "f")["input_file"] == str(tmp_path / "arch1" / "f.mcap")
    back = read_rows(root)  # rebuilt: both flights, each with its folder and result
    assert {r.run_dir for r in back.values()} == {"f", rows[0].run_dir}
    assert back[str(tmp_path / "arch1" / "f.mcap")].status == "degraded"


@pytest.mark.parametrize("planted", ["../victim", "/abs/victim", ".f.pospp-staging-1-aa", ".."])
def test_a_folder_name_read_from_the_manifest_is_never_trusted(tmp_path, fake, planted):
    root = tmp_path / "root"
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "keep.txt").write_text("the user's")
    flight = _flights(tmp_path / "arch", "f.mcap")[0]
    root.mkdir()
    write_rows(root, [FlightOutcome(str(flight), "s", "ok", 1.0, None, run_dir=planted)], CONFIG)
    rows = run_batch([flight], CONFIG, root, workers=1)
    assert rows[0].run_dir == "f" and (root / "f").is_dir()
    assert sorted(os.listdir(victim)) == ["keep.txt"]
    assert not is_run_name(planted)


def test_staging_folders_of_killed_runs_are_removed(tmp_path, fake):
    root = tmp_path / "root"
    root.mkdir()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    left = root / f".g.pospp-staging-{dead.pid}-abcd1234"
    left.mkdir()
    (left / "trajectory.parquet").write_bytes(b"half")
    mine = root / f".h.pospp-staging-{os.getpid()}-abcd1234"  # a live process's: kept
    mine.mkdir()
    run_batch(_flights(tmp_path / "arch", "f.mcap"), CONFIG, root, workers=1)
    assert not left.exists() and mine.exists()


def test_a_killed_worker_fails_its_flight_alone_named_and_the_batch_goes_on(tmp_path, fake):
    files = _flights(tmp_path / "arch", "a.mcap", "kill_me.mcap", "c.mcap", "d.mcap")
    root = tmp_path / "root"
    rows = run_batch(files, CONFIG, root, workers=2)
    by = {Path(r.file).name: r for r in rows}
    assert [by[n].status for n in ("a.mcap", "c.mcap", "d.mcap")] == ["degraded"] * 3
    killed = by["kill_me.mcap"]
    assert killed.status == "failed" and "killed by SIGKILL" in killed.error
    assert "the worker process" in killed.error and killed.run_dir == "kill_me"
    assert not [p for p in os.listdir(root) if "pospp-staging" in p]  # its leftover removed
    assert read_rows(root)[str(files[1])].status == "failed"


def test_upper_case_mcap_files_are_found_and_the_root_left_out(tmp_path):
    arch = tmp_path / "arch"
    _flights(arch, "A.MCAP", "b.mcap", "c.Mcap", "notes.txt")
    _flights(arch / "out" / "run", "trajectory.mcap")
    (arch / "dir.mcap").mkdir()
    found = find_flight_logs([arch], arch / "out")
    assert [p.name for p in found] == ["A.MCAP", "b.mcap", "c.Mcap"]


def test_batch_root_on_a_symlink_loop_fails_at_once(tmp_path):
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    f = _flights(tmp_path / "arch", "a.mcap")[0]
    res = CliRunner().invoke(main, ["batch", str(f), "-o", str(loop / "root")])
    assert res.exit_code == 2 and "symbolic link loop" in res.stderr
    res = CliRunner().invoke(main, ["run", str(f), "-o", str(loop)])
    assert res.exit_code == 2 and "symbolic link loop" in res.stderr


def test_a_failed_flight_keeps_a_one_line_error_without_the_class_path(tmp_path):
    from pospp.batch.flight import process_one

    bad = tmp_path / "arch" / "bad.mcap"
    bad.parent.mkdir()
    bad.write_bytes(b"not an mcap file\nsecond line")
    out = process_one(str(bad), CONFIG.to_dict(), str(tmp_path / "root"), run_name="bad")
    assert out.status == "failed" and out.action == "ran"
    assert "\n" not in out.error and "bad.mcap" in out.error
    assert "Error:" not in out.error and "pospp." not in out.error, out.error
