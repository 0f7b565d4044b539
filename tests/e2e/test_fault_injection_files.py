"""Fault injection on files and commands (issue 13 items 3, 4, 5): nothing of the user's is lost,
no command ends in a traceback.

Every case injects one fault measured from outside in issue 13 (an output folder holding the
input or the user's files, names that escape the archive or do not decode, a second batch, a
full disk, an unreachable scheduler, a kill -9 at a seeded moment) and asserts a clear one-line
error or a non-ok status, and that the user's other files are byte for byte untouched (SHA-256
before and after). The flights are 60 s cut from the bundled sample log (made by pospp's
simulator); the run's correctness is not the point here, its files are.
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import signal
import struct
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pospp import pipeline
from pospp.cli import main
from pospp.config import load_config
from pospp.io import parquet_tables, run_folder
from pospp.io.files import sha256_file
from pospp.io.mcap_reader import read_flight_log
from pospp.io.mcap_writer import write_flight_log

REPO = Path(__file__).resolve().parents[2]
PARTIAL = 4
"""Exit status of a run (or batch) whose worst status is partial (pospp.cli.EXIT_CODES)."""
SAMPLE = REPO / "sample_data" / "sample_flight.mcap"
PIPELINE = REPO / "pipelines" / "sample.toml"


def _cli(*args: str) -> tuple[int, str, str]:
    res = CliRunner().invoke(main, list(args), catch_exceptions=False)
    return res.exit_code, res.stdout, res.stderr


def _hashes(folder: Path) -> dict[str, str]:
    """Relative path -> SHA-256 of every file under ``folder``."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _one_clear_line(code: int, stderr: str, expected_code: int, *needles: str) -> None:
    lines = stderr.strip().splitlines()
    assert code == expected_code, (code, stderr)
    assert len(lines) == 1 and lines[0].startswith("pospp: error: "), stderr
    assert "Traceback" not in stderr
    for n in needles:
        assert n in lines[0], (n, lines[0])


@pytest.fixture(scope="module")
def flight(tmp_path_factory) -> Path:
    """60 s of the sample flight (static start: a 'partial' run in about 2 s)."""
    log = read_flight_log(SAMPLE)
    t_end = int(log.imu.time_ns[0]) + 60 * 10**9

    def keep(obj):
        m = obj.time_ns < t_end
        return replace(obj, **{k: v[m] for k, v in vars(obj).items()
                               if isinstance(v, np.ndarray) and v.shape[:1] == m.shape})

    path = tmp_path_factory.mktemp("flight") / "flight.mcap"
    write_flight_log(path, keep(log.imu), keep(log.fix), keep(log.vel))
    return path


@pytest.fixture(scope="module")
def quick_config():
    """The sample pipeline without report and trajectory MCAP (0.2 s a run instead of 2 s)."""
    cfg = load_config(PIPELINE)
    return replace(cfg, outputs=replace(cfg.outputs, report=False, mcap=False))


def _assert_one_complete_run(folder: Path, *, status: str | None = None) -> dict:
    """``folder`` is one whole run: marker, summary, and every table of the marker's input."""
    marker = run_folder.read_marker(folder)
    assert marker is not None, sorted(os.listdir(folder))
    assert (folder / "summary.parquet").is_file() and (folder / "messages.parquet").is_file()
    for p in folder.glob("*.parquet"):
        assert parquet_tables.read_metadata(p)["input_sha256"] == marker["input_sha256"], p
    summary = parquet_tables.read_table(folder / "summary.parquet").iloc[0]
    assert summary.status == marker["status"]
    if status is not None:
        assert marker["status"] == status
    assert not [n for n in os.listdir(folder) if not run_folder.is_pospp_file(n)]
    return marker


# ------------------------------------------------------------------------ output folders


def test_output_folder_holding_the_input_is_refused(flight, tmp_path):
    own = tmp_path / "dir"
    own.mkdir()
    inp = own / "trajectory.mcap"  # a name pospp would write
    inp.write_bytes(flight.read_bytes())
    (tmp_path / "link").symlink_to(own)
    before = _hashes(tmp_path)
    for extra in ((), ("--force",)):
        for target in (own, tmp_path / "link"):
            code, out, err = _cli("run", str(inp), "-p", str(PIPELINE), "-o", str(target),
                                  *extra)
            _one_clear_line(code, err, 2, "contains the input trajectory.mcap")
    assert _hashes(tmp_path) == before


def test_folder_with_the_users_files_is_refused_even_with_force(flight, tmp_path):
    user = tmp_path / "mine"
    user.mkdir()
    for name in ("evaluation.parquet", "diagnosis.parquet", "report.html", "notes.txt"):
        (user / name).write_text(f"the user's {name}")
    before = _hashes(tmp_path)
    for extra in ((), ("--force",)):
        code, out, err = _cli("run", str(flight), "-p", str(PIPELINE), "-o", str(user), *extra)
        _one_clear_line(code, err, 2, "not a pospp run folder", "notes.txt")
    assert _hashes(tmp_path) == before
    assert not list(tmp_path.glob(".mine.pospp-*"))


def test_run_folder_with_a_foreign_file_is_refused_even_with_force(flight, quick_config,
                                                                   tmp_path):
    out = tmp_path / "run"
    pipeline.process_flight(flight, quick_config, out)
    (out / "my_notes.txt").write_text("kept")
    before = _hashes(tmp_path)
    code, _, err = _cli("run", str(flight), "-p", str(PIPELINE), "-o", str(out), "--force")
    _one_clear_line(code, err, 2, "did not write", "my_notes.txt")
    assert _hashes(tmp_path) == before


def test_commands_that_add_to_a_run_refuse_other_folders(flight, tmp_path):
    user = tmp_path / "mine"
    user.mkdir()
    (user / "summary.parquet").write_bytes(b"the user's own summary.parquet")
    (user / "report.html").write_text("the user's page")
    truth = tmp_path / "truth.parquet"
    truth.write_bytes(b"x")
    before = _hashes(tmp_path)
    for args in (("report", str(user)), ("diagnose", str(user)),
                 ("evaluate", str(user), "--truth", str(truth))):
        code, _, err = _cli(*args)
        _one_clear_line(code, err, 2, "not a pospp run folder")
    assert _hashes(tmp_path) == before


def test_failed_rerun_says_failed_and_keeps_no_table_of_the_earlier_run(flight, tmp_path):
    out = tmp_path / "run"
    code, _, err = _cli("run", str(flight), "-p", str(PIPELINE), "-o", str(out))
    assert code == PARTIAL, err
    assert (out / "trajectory.parquet").is_file() and (out / "report.html").is_file()
    bad = tmp_path / "other.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n" + bytes(np.random.default_rng(13).integers(0, 256, 4000,
                                                                               np.uint8)))
    code, _, err = _cli("run", str(bad), "-p", str(PIPELINE), "-o", str(out), "--force")
    _one_clear_line(code, err, 1, "other.mcap")
    _assert_one_complete_run(out, status="failed")
    assert sorted(p.name for p in out.iterdir()) == [run_folder.MARKER, "messages.parquet",
                                                     "summary.parquet"]
    assert parquet_tables.read_metadata(out / "summary.parquet")["input_sha256"] == \
        sha256_file(bad)


# -------------------------------------------------------------------------- kill -9


def _killed_run(flight: Path, config, out: Path, kill_at: int, *, exchange: bool) -> int:
    """Run the pipeline in a forked child that SIGKILLs itself right after its ``kill_at``-th
    rename (each table's os.replace, the marker's, the swap's exchange or two renames);
    returns the number of renames the child made."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # child: no pytest teardown, no cleanup, exactly like kill -9
        try:
            os.close(r)
            count = [0]

            def hook(real):
                def wrapped(a, b, **kw):
                    result = real(a, b, **kw)
                    count[0] += 1
                    os.write(w, b".")
                    if count[0] == kill_at:
                        os.kill(os.getpid(), signal.SIGKILL)
                    return result
                return wrapped

            os.replace, os.rename = hook(os.replace), hook(os.rename)
            if exchange:
                run_folder._exchange = hook(run_folder._exchange)
            else:  # the portable swap: two renames and a recovery step
                run_folder._exchange = lambda a, b: False
            pipeline.process_flight(flight, config, out, force=True)
        finally:
            os._exit(0)
    os.close(w)
    reached = 0
    while chunk := os.read(r, 64):
        reached += len(chunk)
    os.close(r)
    os.waitpid(pid, 0)
    return reached


@pytest.mark.parametrize("exchange", [True, False], ids=["renameat2", "two_renames"])
def test_kill_9_at_seeded_moments_leaves_one_complete_run(flight, quick_config, tmp_path,
                                                          exchange):
    """A run killed after any of its renames leaves the previous run whole, or the new one
    when the swap was done; the next run cleans the leftovers and does the right thing."""
    out = tmp_path / "run"
    old_cfg = replace(quick_config, name="previous")
    pipeline.process_flight(flight, old_cfg, out)
    old = _assert_one_complete_run(out)
    n = _killed_run(flight, quick_config, out, 10**6, exchange=exchange)  # not killed: count
    assert n >= 6  # tables, summary, marker (+ the swap's renames)
    rng = np.random.default_rng(1313)
    moments = sorted({1, n, *rng.choice(np.arange(2, n), 2, replace=False).tolist()})
    new_cfg_hash = run_folder.config_sha256(quick_config.to_json())
    for k in moments:
        pipeline.process_flight(flight, old_cfg, out, force=True)  # the previous run, again
        assert _killed_run(flight, quick_config, out, k, exchange=exchange) == k
        run_folder.recover(out)  # what the next run does first
        marker = _assert_one_complete_run(out)
        assert marker["config_sha256"] in (old["config_sha256"], new_cfg_hash), k
        # only the swap's last rename makes the new run visible
        assert (marker["config_sha256"] == new_cfg_hash) == (k == n), k
        # the next run does the right thing: replaces it whole, no leftover beside it
        pipeline.process_flight(flight, quick_config, out, force=True)
        assert _assert_one_complete_run(out)["config_sha256"] == new_cfg_hash
        assert sorted(p.name for p in tmp_path.iterdir()) == ["run"], k


def test_kill_9_of_the_cli_leaves_one_complete_run(flight, tmp_path):
    """The real command in a subprocess, killed at a seeded moment after it started staging."""
    out = tmp_path / "run"
    code, _, err = _cli("run", str(flight), "-p", str(PIPELINE), "-o", str(out))
    assert code == PARTIAL, err
    before = _hashes(out)
    delay_s = float(np.random.default_rng(7).uniform(0.0, 1.0))
    proc = subprocess.Popen([sys.executable, "-m", "pospp.cli", "run", str(flight), "-p",
                             str(PIPELINE), "-o", str(out), "--force"], cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        t0 = time.monotonic()
        while not list(tmp_path.glob(".run.pospp-staging-*")) and proc.poll() is None \
                and time.monotonic() - t0 < 120:
            time.sleep(0.02)
        time.sleep(delay_s)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    _assert_one_complete_run(out)
    if proc.returncode == -signal.SIGKILL and _hashes(out) != before:
        assert run_folder.read_marker(out)["status"] == "partial"  # the new run, whole
    code, _, err = _cli("run", str(flight), "-p", str(PIPELINE), "-o", str(out), "--force")
    assert code == PARTIAL, err
    _assert_one_complete_run(out, status="partial")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


# ------------------------------------------------------------------------------ batch


def _manifest(root: Path):
    return parquet_tables.read_table(root / "manifest.parquet").set_index("file")


def test_batch_names_are_safe_and_unique_and_the_manifest_keeps_every_flight(flight,
                                                                             tmp_path):
    arch = tmp_path / "archive"
    for sub in ("a", "b"):
        (arch / sub).mkdir(parents=True)
        (arch / sub / "flight.mcap").write_bytes(flight.read_bytes())  # same stem twice
    (arch / "a" / "...mcap").write_bytes(flight.read_bytes())  # stem ".."
    raw = os.fsencode(arch / "b") + b"/caf\xe9.mcap"  # not UTF-8
    with open(raw, "wb") as fh:
        fh.write(b"not an mcap file")
    user = tmp_path / "user_file.txt"
    user.write_text("the user's")
    before = _hashes(arch) | {"user": hashlib.sha256(user.read_bytes()).hexdigest()}
    root = tmp_path / "out"
    code, out, err = _cli("batch", str(arch), "-p", str(PIPELINE), "-o", str(root), "-j", "2")
    assert code == 1, (out, err)  # the not-an-MCAP file failed; the batch went on
    assert "Traceback" not in out + err
    names = sorted(p.name for p in root.iterdir() if p.is_dir())
    assert names == ["a__%2E%2E", "a__flight", "b__caf%E9", "b__flight"], names
    man = _manifest(root)
    assert len(man) == 4 and sorted(man.run_dir) == names
    assert (man.status == "failed").sum() == 1 and man.error.str.contains("caf").any()
    for name in ("a__%2E%2E", "a__flight", "b__flight"):
        _assert_one_complete_run(root / name, status="partial")
    # a batch over a subset updates its rows and keeps the others
    code, out, err = _cli("batch", str(arch / "a" / "flight.mcap"), "-p", str(PIPELINE), "-o",
                          str(root), "-j", "1")
    assert code == PARTIAL, (out, err)
    man2 = _manifest(root)
    assert sorted(man2.index) == sorted(man.index)
    assert man2.loc[str(arch / "a" / "flight.mcap"), "status"] == "partial"  # its result
    assert man2.loc[str(arch / "a" / "flight.mcap"), "action"] == "skipped"
    assert man2.loc[str(arch / "a" / "flight.mcap"), "run_dir"] == "a__flight"
    assert (man2.drop(index=str(arch / "a" / "flight.mcap")).status ==
            man.drop(index=str(arch / "a" / "flight.mcap")).status).all()
    assert sorted(p.name for p in root.iterdir() if p.is_dir()) == names
    assert before == _hashes(arch) | {"user": hashlib.sha256(user.read_bytes()).hexdigest()}


def test_idempotent_skip_needs_marker_and_summary_to_match(flight, tmp_path):
    from pospp.batch import run_batch

    cfg = load_config(PIPELINE)
    quick = replace(cfg, outputs=replace(cfg.outputs, report=False, mcap=False))
    root = tmp_path / "out"
    assert [r.status for r in run_batch([flight], quick, root, workers=1)] == ["partial"]
    again = run_batch([flight], quick, root, workers=1)
    assert [(r.status, r.action) for r in again] == [("partial", "skipped")]
    other = replace(quick, name="other")  # another configuration: re-run, not skipped
    assert [r.status for r in run_batch([flight], other, root, workers=1)] == ["partial"]
    # a marker that names another input (a mixed folder) is never skipped
    marker = run_folder.read_marker(root / "flight")
    run_folder.write_marker(root / "flight", input_file=flight, input_sha256="0" * 64,
                            config_json=other.to_json(), status=marker["status"])
    assert [r.status for r in run_batch([flight], other, root, workers=1)] == ["partial"]


def test_second_batch_on_one_root_is_refused_naming_the_holder(flight, tmp_path):
    root = tmp_path / "out"
    with run_folder.BatchLock(root):
        code, out, err = _cli("batch", str(flight), "-p", str(PIPELINE), "-o", str(root))
        _one_clear_line(code, err, 2, f"pid {os.getpid()}", "another pospp batch")
    assert not (root / "flight").exists()


def test_full_disk_while_writing_the_manifest_is_a_clear_error(flight, tmp_path, monkeypatch):
    real = parquet_tables.write_table

    def full(path, data, schema_name, **kw):
        if schema_name == "manifest":
            raise OSError(28, "No space left on device")
        return real(path, data, schema_name, **kw)

    monkeypatch.setattr(parquet_tables, "write_table", full)
    root = tmp_path / "out"
    code, out, err = _cli("batch", str(flight), "-p", str(PIPELINE), "-o", str(root), "-j",
                          "1")
    _one_clear_line(code, err, 1, "manifest.parquet", "No space left on device")
    _assert_one_complete_run(root / "flight", status="partial")  # the flight's own outcome


def test_unreachable_scheduler_is_one_line_after_a_bounded_time(flight, tmp_path):
    pytest.importorskip("dask.distributed")
    code, out, err = _cli("batch", str(flight), "-p", str(PIPELINE), "-o",
                          str(tmp_path / "out"), "--scheduler", "tcp://127.0.0.1:9",
                          "--scheduler-timeout-s", "1")
    _one_clear_line(code, err, 1, "cannot reach the Dask scheduler tcp://127.0.0.1:9")


def test_workers_die_with_their_parent():
    """A process-pool worker (initialised as run_batch does) ends when its parent is killed."""
    from pospp.batch.workers import _die_with_parent

    r, w = os.pipe()
    middle = os.fork()
    if middle == 0:  # the batch process
        try:
            worker = os.fork()
            if worker == 0:
                _die_with_parent(os.getppid())
                os.write(w, f"{os.getpid()}\n".encode())
                time.sleep(60)
            time.sleep(60)
        finally:
            os._exit(0)
    os.close(w)
    worker_pid = int(os.read(r, 64).decode().strip())
    os.close(r)
    os.kill(middle, signal.SIGKILL)
    os.waitpid(middle, 0)
    t0 = time.monotonic()
    state = "?"
    while time.monotonic() - t0 < 10:
        try:
            state = Path(f"/proc/{worker_pid}/stat").read_text().split(") ")[1][0]
        except (FileNotFoundError, ProcessLookupError):
            state = "gone"
        if state in ("gone", "Z", "X"):
            break
        time.sleep(0.05)
    assert state in ("gone", "Z", "X"), f"the worker {worker_pid} outlived its parent"


# --------------------------------------------------------------------- no traceback


@pytest.mark.parametrize(
    ("toml", "needle"),
    [("[filter]\noutput_rate_hz = 0\n", "filter.output_rate_hz"),
     ("[outputs]\nmcap_rate_hz = 0\n", "outputs.mcap_rate_hz"),
     ("[replay]\nsample_rate_hz = 0\n", "replay.sample_rate_hz"),
     ("[filter]\noutput_rate_hz = -10\n", "filter.output_rate_hz"),
     ("[replay]\nhorizon_s = -300\n", "replay.horizon_s"),
     # issue 38 item 13: each of these ended in "internal error" or an error naming no key
     *[(f"[{s}]\n{k} = {v}\n", f"{s}.{k}") for s, k, v in (
         ("imu", "gyro_bias_sigma_dph", "1e300"), ("imu", "gyro_arw_dpsh", "1e300"),
         ("imu", "gyro_gm_sigma_dph", "1e300"), ("imu", "gyro_gm_tau_s", "1e-300"),
         ("imu", "accel_bias_sigma_ug", "1e300"), ("imu", "accel_vrw_mpsph", "1e300"),
         ("imu", "accel_gm_sigma_ug", "1e300"), ("imu", "accel_gm_tau_s", "1e-300"),
         ("gnss", "pos_sigma_floor_m", "1e300"), ("gnss", "vel_sigma_floor_mps", "1e300"),
         ("legs", "trim_s", "1e300"), ("legs", "smoothing_s", "1e300"),
         ("replay", "sample_rate_hz", "1e-300"))]],
)
def test_bad_config_value_is_one_line_and_exit_2(flight, tmp_path, toml, needle):
    p = tmp_path / "bad.toml"
    p.write_text(toml)
    code, out, err = _cli("run", str(flight), "-p", str(p), "-o", str(tmp_path / "o"))
    _one_clear_line(code, err, 2, "bad.toml", needle)
    assert not (tmp_path / "o").exists()


def test_usage_error_is_one_line_and_exit_2(tmp_path):
    code, out, err = _cli("run", str(tmp_path / "missing.mcap"), "-o", str(tmp_path / "o"))
    _one_clear_line(code, err, 2, "missing.mcap", "does not exist")


def test_debug_shows_the_traceback(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("[filter]\noutput_rate_hz = 0\n")
    res = CliRunner().invoke(main, ["--debug", "run", str(SAMPLE), "-p", str(p), "-o",
                                    str(tmp_path / "o")])
    assert res.exit_code != 0 and type(res.exception).__name__ == "ConfigError"


def test_batch_root_inside_the_archive_does_not_take_its_own_outputs(flight, tmp_path):
    arch = tmp_path / "archive"
    arch.mkdir()
    (arch / "f.mcap").write_bytes(flight.read_bytes())
    for _ in range(2):
        code, out, err = _cli("batch", str(arch), "-p", str(PIPELINE), "-o", str(arch / "out"),
                              "-j", "1")
        assert code == PARTIAL, (out, err)
    assert (arch / "out" / "f" / "trajectory.mcap").is_file()
    man = _manifest(arch / "out")
    assert list(man.index) == [str(arch / "f.mcap")] and man.status.iloc[0] == "partial"
    assert man.action.iloc[0] == "skipped"


def test_run_folder_names_are_safe_unique_and_short():
    from pospp.batch import MAX_RUN_NAME_LEN, run_folder_names

    paths = ["/x/a/b.mcap", "/x/a__b.mcap", "/x/...mcap", "/x/.hidden.mcap", "/x/a b%.MCAP",
             "/x/" + "q" * 300 + ".mcap", os.fsdecode(b"/x/caf\xe9.mcap"), "/x/../y/z.mcap"]
    names = run_folder_names(paths)
    assert len(set(names.values())) == len(paths)  # unique, the two "a__b" included
    for name in names.values():
        assert name.isascii() and "/" not in name and not name.startswith(".")
        assert name not in (".", "..") and 0 < len(name) <= MAX_RUN_NAME_LEN
    assert names["/x/../y/z.mcap"] == "y__z"  # relative to the common folder, "/"
    assert names["/x/...mcap"] == "x__%2E%2E" and names["/x/a b%.MCAP"] == "x__a%20b%25"


# ----------------------------------------------------------- issue 38: run folder safety


def _hold_lock(folder: Path) -> int:
    """Another process's lock on a run folder, as pospp takes it (``flock`` on the folder):
    a descriptor of its own, so pospp's lock conflicts with it as with another process's."""
    fd = os.open(folder, os.O_RDONLY)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    return fd


def test_files_put_into_the_folder_during_a_run_stop_the_swap(flight, quick_config,
                                                              tmp_path):
    """A file put into OUT while the run works was deleted with the previous run at the swap
    (issue 38 item 6): the folder is checked again at the swap, nothing is replaced."""
    out = tmp_path / "run"
    pipeline.process_flight(flight, quick_config, out)
    before = _hashes(out)

    def meddle(stage: str, fraction: float) -> None:
        if stage == "qc":
            (out / "notes.txt").write_text("the user's notes, written during the run")

    with pytest.raises(run_folder.RunFolderError, match="notes.txt"):
        pipeline.process_flight(flight, replace(quick_config, name="new"), out, force=True,
                                progress=meddle)
    assert (out / "notes.txt").read_text().startswith("the user's notes")
    after = _hashes(out)
    del after["notes.txt"]
    assert after == before  # the previous run, whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # no staging left


def test_a_second_run_into_the_same_new_folder_is_refused_while_the_first_works(
        flight, quick_config, tmp_path):
    """Two runs into one new folder replaced each other, both exit 0 (issue 38 item 6): the
    first holds the folder's lock for the whole run, the second is refused at once."""
    out = tmp_path / "new"
    refused: list[str] = []

    def second(stage: str, fraction: float) -> None:
        if stage == "calibrate":
            try:
                pipeline.process_flight(flight, quick_config, out)
            except run_folder.RunFolderError as exc:
                refused.append(str(exc))

    first = pipeline.process_flight(flight, replace(quick_config, name="first"), out,
                                    progress=second)
    assert refused and f"another pospp command (pid {os.getpid()})" in refused[0]
    marker = _assert_one_complete_run(out)
    assert marker["config_sha256"] == run_folder.config_sha256(
        replace(quick_config, name="first").to_json()) and first.status == "partial"


def test_a_full_disk_during_force_keeps_the_previous_run(flight, tmp_path, monkeypatch):
    """A full disk during ``--force`` replaced a good run with a 3-file failed stub (issue 38
    item 7): a run that fails without a verdict on its input keeps the previous one."""
    out = tmp_path / "run"
    code, _, err = _cli("run", str(flight), "-p", str(PIPELINE), "-o", str(out))
    assert code == PARTIAL, err
    before = _hashes(out)
    real = parquet_tables.write_table

    def full(path, data, schema_name, **kw):
        if schema_name in ("trajectory", "messages"):  # the run's tables and a failed stub's
            raise OSError(28, "No space left on device", str(path))
        return real(path, data, schema_name, **kw)

    monkeypatch.setattr(parquet_tables, "write_table", full)
    code, _, err = _cli("run", str(flight), "-p", str(PIPELINE), "-o", str(out), "--force")
    _one_clear_line(code, err, 1, "No space left on device", "the previous run is kept")
    assert _hashes(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flight.mcap", "run"] or \
        sorted(p.name for p in tmp_path.iterdir()) == ["run"]


@pytest.fixture(scope="module")
def finished_run(flight, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("finished") / "run"
    code, _, err = _cli("run", str(flight), "-p", str(PIPELINE), "-o", str(out))
    assert code == PARTIAL, err
    return out


@pytest.mark.parametrize("command", ["export", "compare-sim"])
def test_outputs_of_export_and_compare_sim_never_replace_the_run_or_its_input(
        command, finished_run, flight, tmp_path):
    """``export -o`` and ``compare-sim -o`` overwrote the run's input log, its
    trajectory.parquet or its marker, exit 0 (issue 38 item 8): the rules of ``run`` hold."""
    other = tmp_path / "mine.csv"
    other.write_text("the user's file")
    watched = {"input": flight, "other": other,
               **{p.name: p for p in finished_run.iterdir()}}
    before = {k: hashlib.sha256(p.read_bytes()).hexdigest() for k, p in watched.items()}
    args = (["export", str(finished_run), "--format", "csv"] if command == "export"
            else ["compare-sim", str(finished_run)])
    for target, needle in ((flight, "is the run's input log"),
                           (finished_run / "trajectory.parquet", "is in the pospp run folder"),
                           (finished_run / run_folder.MARKER, "is in the pospp run folder"),
                           (other, "exists; use --force")):
        code, _, err = _cli(*args, "-o", str(target))
        _one_clear_line(code, err, 2, needle)
    assert before == {k: hashlib.sha256(p.read_bytes()).hexdigest() for k, p in watched.items()}
    if command == "export":  # an existing file of the user's: with --force only
        code, _, err = _cli(*args, "-o", str(other), "--force")
        assert code == 0, err
        assert other.read_text().startswith("gps_week")


@pytest.mark.parametrize("command", ["run", "diagnose", "evaluate", "report", "export",
                                     "compare-sim"])
def test_commands_that_write_a_run_wait_for_no_one(command, finished_run, flight, tmp_path):
    """``diagnose`` or ``evaluate`` while ``run --force`` replaced the folder left the old
    flight's diagnosis in the new run (issue 38 item 10): every command that writes a run
    folder holds its lock; a second is refused at once, naming the holder."""
    truth = tmp_path / "truth.parquet"
    truth.write_bytes(b"x")
    args = {"run": ["run", str(flight), "-p", str(PIPELINE), "-o", str(finished_run),
                    "--force"],
            "diagnose": ["diagnose", str(finished_run)],
            "evaluate": ["evaluate", str(finished_run), "--truth", str(truth)],
            "report": ["report", str(finished_run)],
            "export": ["export", str(finished_run), "--format", "csv"],
            "compare-sim": ["compare-sim", str(finished_run)]}[command]
    before = _hashes(finished_run)
    fd = _hold_lock(finished_run)
    try:
        code, _, err = _cli(*args)
    finally:
        os.close(fd)
    _one_clear_line(code, err, 2, f"another pospp command (pid {os.getpid()}) is writing "
                    "this run folder")
    assert _hashes(finished_run) == before


def test_a_named_pipe_as_the_log_or_the_pipeline_is_refused(flight, tmp_path, make_fifo):
    """A FIFO as ``-p`` or as the log blocked forever (issue 38 item 12)."""
    for name, args in (("pipe.toml", lambda f: ("run", str(flight), "-p", str(f), "-o",
                                                 str(tmp_path / "o1"))),
                       ("pipe.mcap", lambda f: ("run", str(f), "-p", str(PIPELINE), "-o",
                                                 str(tmp_path / "o2")))):
        code, _, err = _cli(*args(make_fifo(tmp_path / name)))
        _one_clear_line(code, err, 2, f"{name}: is a named pipe (FIFO), not a regular file")
    assert not (tmp_path / "o1").exists() and not (tmp_path / "o2").exists()


def test_an_error_caused_by_a_corrupt_chunk_names_the_corruption(flight, tmp_path):
    """A corrupt chunk, skipped, leaves a 29 s hole; algorithm A then stops on the IMU gap,
    and the one-line error named only that symptom (issue 38 item 13)."""
    data = bytearray(flight.read_bytes())
    pos, chunks = 8, []
    while pos + 9 <= len(data):  # the top-level records (MCAP spec: opcode u8, length u64)
        op, ln = struct.unpack_from("<BQ", data, pos)
        chunks += [(pos, ln)] if op == 0x06 else []
        pos += 9 + ln
    off, ln = chunks[1]
    data[off + 9 + ln // 2] ^= 0xFF
    bad = tmp_path / "damaged.mcap"
    bad.write_bytes(bytes(data))
    code, _, err = _cli("run", str(bad), "-p", str(PIPELINE), "-o", str(tmp_path / "o"))
    _one_clear_line(code, err, 1, f"damaged.mcap is damaged at byte {off}: corrupt chunk at "
                    f"byte {off} skipped", "; then algorithm A failed: imu: gap of")


def test_an_unknown_converter_option_is_a_usage_error(tmp_path):
    """``convert --option foo=1`` was an internal error (TypeError) (issue 38 item 13)."""
    code, _, err = _cli("convert", str(tmp_path), "-o", str(tmp_path / "x.mcap"), "--format",
                        "comma2k19", "--option", "foo=1")
    _one_clear_line(code, err, 2, "--option: format 'comma2k19' has no option 'foo'; its "
                    "options: ")
    assert not (tmp_path / "x.mcap").exists()


def test_a_named_pipe_in_an_archive_fails_that_flight_only(flight, tmp_path, make_fifo):
    """A FIFO named ``*.mcap`` in an archive blocked the batch forever (issue 38 item 12)."""
    arch = tmp_path / "archive"
    arch.mkdir()
    (arch / "good.mcap").write_bytes(flight.read_bytes())
    make_fifo(arch / "pipe.mcap")
    code, out, err = _cli("batch", str(arch), "-p", str(PIPELINE), "-o", str(tmp_path / "out"),
                          "-j", "1")
    assert code == 1, (out, err)
    man = _manifest(tmp_path / "out")
    assert man.loc[str(arch / "pipe.mcap"), "status"] == "failed"
    assert "is a named pipe (FIFO), not a regular file" in man.loc[str(arch / "pipe.mcap"),
                                                                   "error"]
    assert man.loc[str(arch / "good.mcap"), "status"] == "partial"
