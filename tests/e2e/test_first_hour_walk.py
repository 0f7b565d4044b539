"""A new user's first hour, end to end (issue 39), and an archive re-processed and compared
(issue 37): the README's commands and the docs' examples as written, on a fresh folder.

One walk, in the order a new user takes it, sharing one sample run: ``pospp run`` of the
sample, ``pospp compare-sim`` then ``run --force`` into the same folder, ``evaluate``, every
figure the docs quote checked against this run (docs/_make_figures.py), ``diagnose``,
``export`` in every format, ``report``; a batch of a two-flight archive, a second batch with a
changed configuration against it (``--baseline``), ``pospp diff``, docs/api.md's worked example
run as written, a batch killed with SIGKILL and re-run; every measured log of ../shared/data
converted and run with the command docs/realdata.md gives (skipped when absent). Each command's
exit code and last line (``pospp COMMAND: STATUS``) are checked.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import shlex
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

import pospp
from pospp.cli import EXIT_CODES, main
from pospp.io.mcap_reader import read_flight_log
from pospp.io.mcap_writer import write_flight_log

REPO = Path(__file__).resolve().parents[2]
SHARED = REPO.parent / "shared"
STATUS_LINE = re.compile(r"^pospp ([a-z-]+): (ok|degraded|partial|failed|unchanged|changed)"
                         r"(?: \((.*)\))?$")
pytestmark = pytest.mark.slow


def _cli(*args: str) -> tuple[int, str, str]:
    res = CliRunner().invoke(main, list(args), prog_name="pospp")
    assert "Traceback" not in res.output, res.output
    return res.exit_code, res.stdout, res.stderr


def _status(command: str, code: int, out: str) -> tuple[str, str]:
    """The status line (the last line on stdout) of ``command``: its word and detail; the
    exit code is the word's (EXIT_CODES)."""
    m = STATUS_LINE.match(out.strip().splitlines()[-1])
    assert m and m.group(1) == command, out[-500:]
    word = m.group(2)
    assert code == EXIT_CODES.get(word, 0), (code, word)
    return word, m.group(3) or ""


def _readme_command(pattern: str) -> list[str]:
    """A ``pospp ...`` command quoted in README.md (its first match), as arguments."""
    text = " ".join((REPO / "README.md").read_text().split())
    m = re.search(rf"`pospp ({pattern}[^`]*)`", text)
    assert m, pattern
    return shlex.split(m.group(1))


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    """A fresh folder with the repository's sample data and pipelines, and ../shared, as
    cwd for the whole module."""
    root = tmp_path_factory.mktemp("first_hour")
    here = root / "pospp"
    here.mkdir()
    for name in ("sample_data", "pipelines", "docs"):
        (here / name).symlink_to(REPO / name)
    if SHARED.is_dir():
        (root / "shared").symlink_to(SHARED)
    old = os.getcwd()
    os.chdir(here)
    try:
        yield here
    finally:
        os.chdir(old)


@pytest.fixture(scope="module")
def sample(walk) -> Path:
    """The README's first command, then compare-sim and ``run --force`` into the same folder,
    then the README's evaluate: the sample run every later step reads."""
    code, out, err = _cli(*_readme_command("run sample_data/sample_flight.mcap"))
    word, detail = _status("run", code, out)
    assert word == "ok" and detail.endswith("out/sample"), err
    assert "gyro_bias_x" in out and "body axes FRD" in out and "IMU's axes (FLU" in out
    code, out, err = _cli("compare-sim", "out/sample")
    assert _status("compare-sim", code, out)[0] == "ok", err
    assert (walk / "out" / "sample" / "sim_model.toml").is_file()
    code, out, err = _cli(*_readme_command("run sample_data/sample_flight.mcap"), "--force")
    assert _status("run", code, out)[0] == "ok", err  # issue 39 item 1
    code, out, err = _cli(*_readme_command("evaluate out/sample"))
    assert _status("evaluate", code, out)[0] == "ok", err
    return walk / "out" / "sample"


def test_every_quoted_figure_agrees_with_the_run(sample):
    spec = importlib.util.spec_from_file_location("make_figures", REPO / "docs" /
                                                  "_make_figures.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["make_figures"] = mod
    spec.loader.exec_module(mod)
    bad = mod.check(sample)
    assert not bad, "\n".join(bad) + "\nregenerate: python docs/_make_figures.py"


def test_open_run_round_trips_every_table_of_the_sample(sample, tmp_path):
    from pospp.io import parquet_tables

    run = pospp.open_run(sample)
    assert set(run.tables()) >= {"trajectory", "legs", "pairs", "calibration", "leg_errors",
                                 "summary", "qc", "diagnosis", "diagnosis_curves", "messages",
                                 "biases", "evaluation"}
    for name in run.tables():
        df = run.table(name)
        back = parquet_tables.write_table(tmp_path / f"{name}.parquet", df, name, metadata={})
        import pyarrow.parquet as pq

        original, again = pq.read_table(sample / f"{name}.parquet"), pq.read_table(back)
        assert again.schema.equals(original.schema, check_metadata=False), name
        assert again.equals(original), name


def test_diagnose_export_report(sample, walk):
    code, out, err = _cli("diagnose", "out/sample")
    assert _status("diagnose", code, out)[0] == "ok", err
    assert "nan" not in out.lower() and out.startswith("step 1: ")
    for fmt, ext in (("sbet", "out"), ("csv", "csv"), ("geojson", "geojson"), ("kml", "kml")):
        code, out, err = _cli("export", "out/sample", "--format", fmt)
        word, detail = _status("export", code, out)
        assert word == "ok" and detail.endswith(f"trajectory.{ext}"), err
    code, out, err = _cli("export", "out/sample", "--format", "kml", "--events")
    assert code == 1 and "no trigger events" in err and len(err.strip().splitlines()) == 1
    code, out, err = _cli("report", "out/sample")
    assert _status("report", code, out)[0] == "ok"


def _cut(src: Path, dst: Path, seconds: float) -> Path:
    """The first ``seconds`` of a flight log (a static start: a 'partial' run)."""
    log = read_flight_log(src)
    t_end = int(log.imu.time_ns[0]) + int(seconds * 1e9)

    def keep(obj):
        m = obj.time_ns < t_end
        return replace(obj, **{k: v[m] for k, v in vars(obj).items()
                               if isinstance(v, np.ndarray) and v.shape[:1] == m.shape})

    write_flight_log(dst, keep(log.imu), keep(log.fix), keep(log.vel))
    return dst


def _quick_sample_pipeline(extra: str = "") -> str:
    """pipelines/sample.toml without its report, trajectory MCAP, diagnosis and null
    realisations (a third of the run's time; what the archive test compares does not need
    them), plus ``extra``."""
    text = (REPO / "pipelines" / "sample.toml").read_text()
    outputs = "[outputs]\nmcap = true\nreport = true\ndiagnose = true"
    assert text.count(outputs) == 1 and text.count("[pairs]\n") == 1
    text = text.replace(outputs, "[outputs]\nmcap = false\nreport = false\ndiagnose = false")
    return text.replace("[pairs]\n", "[pairs]\nnull_realisations = 0\n") + extra


@pytest.fixture(scope="module")
def archives(sample, walk):
    """Two versions of a sample archive (the sample flight and a 60 s cut of it): a batch,
    then a batch with the causal compensation switched to the constant bias, against the
    first (``--baseline``)."""
    arch = walk / "archive"
    (arch / "cut").mkdir(parents=True)
    (arch / "survey.mcap").symlink_to(REPO / "sample_data" / "sample_flight.mcap")
    _cut(REPO / "sample_data" / "sample_flight.mcap", arch / "cut" / "static.MCAP", 60.0)
    (walk / "quick.toml").write_text(_quick_sample_pipeline())
    code, out, err = _cli("batch", "archive", "-p", "quick.toml", "-o", "out/archive", "-j",
                          "1")
    word, detail = _status("batch", code, out)
    assert word == "partial" and "1 ok, 1 partial; ran 2" in detail, out  # issue 39 item 4
    assert re.search(r"^ok +ran .*survey\.mcap", out, re.M), out
    changed = walk / "changed.toml"
    changed.write_text(_quick_sample_pipeline('\n[compensation]\nmode = "constant"\n'))
    code, out, err = _cli("batch", "archive", "-p", str(changed), "-o", "out/archive_new",
                          "-j", "1", "--baseline", "out/archive")
    word, detail = _status("batch", code, out)
    assert word == "changed" and detail.endswith("against the baseline: changed"), out
    return walk / "out" / "archive", walk / "out" / "archive_new"


def test_the_changed_flights_and_the_unchanged_ones(archives):
    old, new = archives
    diff = pd.read_parquet(new / "diff.parquet")
    changed = set(diff.flight[~diff.within])
    assert changed == {"survey"}, diff[~diff.within]
    moved = set(diff[(diff.flight == "survey") & ~diff.within]["item"])
    # the compensation mode moves B's compensated replays, not A: its solutions are the same
    assert moved == {"dv_after_mps", "dp_after_m"}, moved
    assert diff[diff.solution != ""].within.all()
    assert "changed" in (new / "diff.html").read_text()
    manifest = pospp.open_archive(new).manifest.set_index("run_dir")
    assert manifest.status.to_dict() == {"cut__static": "partial", "survey": "ok"}
    assert set(manifest.action) == {"ran"} and manifest.error.isna().all()
    code, out, err = _cli("diff", str(old), str(old))
    assert _status("diff", code, out)[0] == "unchanged" and code == 0
    assert "2 flight(s) compared: 2 within tolerance, 0 changed" in out
    code, out, err = _cli("diff", str(old), str(new))
    assert code == 3 and "  survey: " in out and "cut__static:" not in out


def test_the_api_worked_example_runs_as_written(archives, walk, tmp_path):
    """docs/api.md's worked example, every block in order, in the walk's folder."""
    text = (REPO / "docs" / "api.md").read_text()
    example = text[text.index("## Worked example"):]
    blocks = re.findall(r"```python\n(.*?)```", example, re.S)
    assert len(blocks) == 4
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, "docs/api.md", "exec"), namespace)  # noqa: S102
    assert (walk / "leg_errors.png").stat().st_size > 10_000


_KILLED_BATCH = """
import os, signal, sys
from pospp.batch import run_batch
from pospp.config import load_config
run_batch(sys.argv[2:], load_config(sys.argv[1]), "out/killed", workers=1,
          on_result=lambda outcome: os.kill(os.getpid(), signal.SIGKILL))
"""


def test_a_batch_killed_then_re_run_keeps_each_flights_result(sample, walk):
    """kill -9 of the batch process after its first flight; the unchanged re-run skips it
    (its result kept), resumes the other; a third run skips both, results kept."""
    arch = walk / "kill_archive"
    arch.mkdir()
    files = [_cut(REPO / "sample_data" / "sample_flight.mcap", arch / f"f{i}.mcap", 30.0 + i)
             for i in (1, 2)]
    proc = subprocess.run([sys.executable, "-c", _KILLED_BATCH, "pipelines/sample.toml",
                           *map(str, files)], cwd=walk, capture_output=True, text=True)
    assert proc.returncode == -9, proc.stderr
    first = pospp.open_archive("out/killed").manifest.set_index("run_dir")
    assert first.action.to_dict() == {"f1": "ran", "f2": "queued"}
    assert first.status["f1"] == "partial" and pd.isna(first.status["f2"])
    for actions in ({"f1": "skipped", "f2": "resumed"}, {"f1": "skipped", "f2": "skipped"}):
        code, out, err = _cli("batch", "kill_archive", "-p", "pipelines/sample.toml", "-o",
                              "out/killed", "-j", "1")
        assert _status("batch", code, out)[0] == "partial", err
        m = pospp.open_archive("out/killed").manifest.set_index("run_dir")
        assert m.action.to_dict() == actions
        assert m.status.to_dict() == {"f1": "partial", "f2": "partial"}


def _realdata_commands() -> list[list[str]]:
    text = (REPO / "docs" / "realdata.md").read_text()
    block = text[text.index("## Commands, dataset by dataset"):]
    block = re.search(r"```bash\n(.*?)```", block, re.S).group(1)
    return [shlex.split(line)[1:] for line in block.splitlines() if line.startswith("pospp ")]


@pytest.mark.realdata
def test_every_measured_log_with_its_documented_command(walk):
    if not (SHARED / "data").is_dir():
        pytest.skip(f"real datasets not found at {SHARED / 'data'} (outside data)")
    commands = _realdata_commands()
    assert {c[0] for c in commands} == {"convert", "run", "evaluate"} and len(commands) == 9
    for args in commands:
        code, out, err = _cli(*args)
        word, _ = _status(args[0], code, out)
        assert word != "failed", (args, err)
        if args[0] == "convert":
            assert any(line.startswith("  hint: ") for line in out.splitlines()) or \
                args[-1].endswith(".parquet"), out
    quad = json.loads((walk / "out" / "quad" / ".pospp-run.json").read_text())
    assert quad["status"] in ("ok", "degraded", "partial")  # the alignment succeeded
