"""Regenerate docs/cli.md and docs/pipelines.md from the CLI's help and the config dataclasses.

Run from the repository root: ``python docs/_make_cli_docs.py``. tests/unit/test_docs.py checks
that both files are in sync.
"""

from __future__ import annotations

import ast
import dataclasses
import enum
import inspect
import re
import typing
from pathlib import Path

from click.testing import CliRunner

from pospp import config as cfg
from pospp import config_schema as schema
from pospp.cli import main
from pospp.nav import tuning

DOCS = Path(__file__).resolve().parent
COMMANDS = ["run", "batch", "diff", "simulate", "evaluate", "diagnose", "observability",
            "convert", "export", "compare-sim", "report"]

CLI_HEAD = """# pospp command line

Every command is a thin shell over a function of the package (named in its help), so all of it
can be done from Python too. Units are in every option name.

## Errors and exit status

No command ends with a traceback: an error is one line `pospp: error: ...` on stderr naming the
file, key, topic or time and what is wrong (`pospp --debug COMMAND ...` shows the traceback
instead). The exit status is the same for every command (`pospp.cli.EXIT_CODES`, one place
maps a run's status to it):

- 0 ok: the run completed and every quality check passed; a batch where every flight did;
  `pospp diff`: everything within tolerance.
- 1 failed: the run failed (its folder holds the messages and a `failed` summary, or, when the
  failure was not about the input, such as a full disk, the previous run, and the error line
  says so), a batch had a failed flight, or any other error.
- 2 usage or configuration error: a bad option or choice (an unknown `--format`, `--preset`,
  `--imu-grade`), a pipeline file with a bad key or value, an input that is not a regular file
  (a named pipe, a device), a topic the log does not have, a reference that is not of this
  flight, an output folder or file pospp must not write into, a run folder another command is
  writing, a batch root another batch holds or whose manifest another tool wrote; `pospp`
  alone prints its help.
- 3 degraded: the run completed but a quality check failed (named in the console, summary and
  manifest); `pospp diff` and `pospp batch --baseline`: a change beyond tolerance.
- 4 partial: the run completed but a stage produced nothing (no calibration: the summary says
  why).

A batch exits with the code of its worst flight (failed, then degraded, then partial). Every
command ends with one status line on stdout, `pospp COMMAND: STATUS (detail)`, STATUS being
`ok`, `degraded`, `partial` or `failed` for a run or batch (`unchanged` or `changed` for
`pospp diff`); a command that stops on an error ends with its one error line on stderr
instead.

## Run folders: nothing of the user's is lost

- `pospp run -o OUT` uses OUT only when it is absent, empty, or an earlier pospp run (marker file
  `.pospp-run.json`: pospp version, input path and SHA-256, configuration hash, status, time).
  An earlier run is replaced only with `--force`; a folder holding any file pospp did not write
  is refused even with `--force` (the error names a few of them); a folder that contains the
  input is always refused.
- The run is written into `.OUT.pospp-staging-PID-HEX` beside OUT and swapped in whole when
  done, so OUT always holds one complete run, or one failed run (messages and a `failed`
  summary, no table of an earlier run), never a mix; a run killed at any moment leaves the
  previous run, and the next run into OUT removes the leftover staging folder. A run that
  fails for a reason that is not about its input (a full disk, a lost file) keeps the previous
  run: only a verdict on the input replaces it.
- Every command that writes a run folder (`run`, `report`, `evaluate`, `diagnose`, `export`,
  `compare-sim`) holds the folder's lock (`flock` on the folder) for its whole work: a second
  one is refused at once, naming the holder's pid. `run` checks OUT again at the swap: files
  put into it during the run stop the swap (named in the error; nothing is replaced).
- `pospp report`, `pospp evaluate` and `pospp diagnose` write into a run folder only (one with
  the marker), each file atomically. `pospp export -o FILE` and `pospp compare-sim -o FILE`
  never write the run's input log or any file of a run folder but their own default outputs,
  and replace an existing FILE only with `--force`.
- `pospp batch -o ROOT`: each flight's folder name comes from its path relative to the inputs'
  common folder (sub-folders joined by `__`, other characters than letters, digits, `-`, `_`
  and inner dots escaped as `%XX`, so no `..`, separator or undecodable byte; `*.mcap` in any
  case); a flight in the manifest keeps its folder, and a folder whose marker names another
  input is never given to a new one. `manifest.parquet` keeps every flight it has seen: its
  result (`ok`, `degraded`, `partial`, `failed`, the words of `pospp run`), what the last batch
  did (`ran`, `skipped`, `resumed`, or `queued` when a batch was stopped before reaching it)
  and a one-line error; it is written before the first flight and after each, so a batch
  killed at any moment leaves every flight's result. A flight is skipped only when its marker
  and summary match the input's SHA-256 and the configuration. The manifest is pospp's only
  when its file metadata says so: a root holding another tool's `manifest.parquet`, or a
  damaged one, is refused (move it aside: the manifest is then rebuilt from the run folders'
  markers); a folder name read from it is used only when it is one plain name (never an
  absolute or `..` path). `ROOT/.pospp-batch.lock` stops a second batch on the same root (the
  error names the pid); a worker process that dies (killed, out of memory) fails its flight
  alone, named, and the batch goes on; staging folders left by killed runs are removed when the
  next batch starts; local workers die with the batch process; an unreachable `--scheduler` is
  one line after `--scheduler-timeout-s`.
- `pospp diff A B` compares two run folders or two batch roots (docs/ci.md); `pospp batch
  --baseline OLD_ROOT` ends with the same comparison, written to `ROOT/diff.parquet` and
  `ROOT/diff.html`.

Typical session:

```bash
pospp simulate --preset flight --imu-grade flight --seed 1 -o out/flight.mcap
pospp run out/flight.mcap -p pipelines/flight.toml -o out/flight_run
pospp evaluate out/flight_run --truth out/flight.truth.parquet --skip-s 600
pospp diagnose out/flight_run
pospp observability -o out/observability
pospp batch archive/ -p pipelines/flight.toml -o out/archive -j 2
pospp batch archive/ -p pipelines/flight.toml -o out/archive_new --baseline out/archive
pospp diff out/archive out/archive_new -o out/diff
```

Pipeline files (`-p`) are described in [pipelines.md](pipelines.md); the tables a run writes in
[formats.md](formats.md). This page is generated by `python docs/_make_cli_docs.py`.
"""


def cli_markdown() -> str:
    r = CliRunner()
    parts = [CLI_HEAD]
    for args, title in [([], "pospp")] + [([c], f"pospp {c}") for c in COMMANDS]:
        text = r.invoke(main, [*args, "--help"], prog_name="pospp", terminal_width=100).output
        parts.append(f"## {title}\n\n```\n{text}```\n")
    return "\n".join(parts)


_ROLE = re.compile(r":(?:class|func|meth|data|mod|attr):`~?([^`]+)`")


def markdown_text(rst: str) -> str:
    """A docstring's reStructuredText inline markup as Markdown: ``x`` and :role:`x` -> `x`."""
    return _ROLE.sub(r"`\1`", rst).replace("``", "`")


def field_docs(cls: type) -> dict[str, str]:
    """The attribute docstrings of a config dataclass (the string under each field in
    pospp/config.py), joined on one line, Markdown."""
    tree = ast.parse(inspect.getsource(cls))
    body = tree.body[0].body  # type: ignore[attr-defined]
    out = {}
    for node, nxt in zip(body, body[1:], strict=False):
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and \
                isinstance(nxt, ast.Expr) and isinstance(nxt.value, ast.Constant) and \
                isinstance(nxt.value.value, str):
            out[node.target.id] = markdown_text(" ".join(nxt.value.value.split()))
    return out


def grades_markdown() -> list[str]:
    """What each ``[imu] grade`` holds: the filter tuning (pospp.nav.tuning.PRESETS) and the
    keys whose default follows the grade (pospp.config.GRADE_DEFAULTS)."""
    tun = [f.name for f in dataclasses.fields(tuning.ImuTuning) if f.name != "name"]
    dflt = [f.name for f in dataclasses.fields(cfg.GradeDefaults)]
    grades = [g.value for g in cfg.Grade]
    lines = ["## What each `[imu] grade` holds", "",
             "The grade picks algorithm A's IMU noise model (the `[imu]` keys of the same names",
             "override one value each; `pospp.nav.tuning.PRESETS`) and the defaults of a few",
             "keys of other sections (`pospp.config.GRADE_DEFAULTS`; an explicit value wins).",
             "Units are in the names: deg/h, deg/sqrt(h) (`dpsh`), ug, m/s/sqrt(h) (`mpsph`),",
             "ppm, s, m, m/s.", "",
             "| key | " + " | ".join(f"`{g}`" for g in grades) + " |",
             "|---|" + "---|" * len(grades)]
    for k in tun:
        vals = [getattr(tuning.tuning_preset(g), k) for g in grades]
        lines.append(f"| `[imu] {k}` | " + " | ".join(f"{v:g}" for v in vals) + " |")
    section = {"pos_sigma_floor_m": "gnss", "vel_sigma_floor_mps": "gnss",
               "leg_min_duration_s": "legs", "leg_duration_tolerance_s": "legs",
               "leg_settle_s": "legs"}
    for k in dflt:
        key = k.removeprefix("leg_") if section.get(k) == "legs" else k
        vals = [getattr(cfg.GRADE_DEFAULTS[g], k) for g in cfg.Grade]
        lines.append(f"| `[{section.get(k, '?')}] {key}` | " + " | ".join(f"{v:g}" for v in vals)
                     + " |")
    return [*lines, ""]


def _type_name(tp: object) -> str:
    name = str(tp).replace("typing.", "").replace("<class '", "").replace("'>", "")
    return name.replace(" | ", " or ")


def pipelines_markdown() -> str:
    lines = [
        "# Pipeline files",
        "",
        "A pipeline file (`pipelines/*.toml`, `pospp run -p`) sets every stage's parameters. Each",
        "section maps to one frozen dataclass of `pospp.config`; every key carries its unit. An",
        "omitted key takes its default (an empty file is valid); an unknown section or key, a",
        "value of the wrong type, outside its choices or outside its limits is an error naming",
        "the file and the key. Every number must be finite, every string at most",
        f"{schema.MAX_STRING_LEN} characters, the file at most {schema.MAX_CONFIG_BYTES} bytes of",
        "UTF-8; the limits of each key are written next to its field in `pospp/config.py`",
        "(`Limits`) and listed below; a list's limits apply to each element.",
        "Shipped: `flight.toml` and `vehicle.toml` (the simulator's paper presets),",
        "`sample.toml` (the bundled sample flight); `realdata/*.toml`, the measured logs",
        "(docs/realdata.md). This page is generated by `python docs/_make_cli_docs.py` from",
        "`pospp/config.py`.",
        "",
        "**Frames.** Vectors are in the body frame b, FRD (x forward, y right, z down), unless",
        "the key says otherwise: `[gnss] lever_arm_m` is the antenna's position from the IMU",
        "in body FRD, `[sensor] lever_arm_m` the imaging sensor's. The IMU's logged axes",
        "(`[input] sensor_frame`, FLU for ROS logs: y and z opposite) are rotated into b at",
        "ingestion, so no other key is in them.",
        "",
    ]
    hints = typing.get_type_hints(cfg.PipelineConfig)
    for f in dataclasses.fields(cfg.PipelineConfig):
        if f.name == "name":
            lines += ["`name` (str, default `\"default\"`): the configuration's name.", ""]
            continue
        cls = hints[f.name]
        lines += [f"## [{f.name}]", "", markdown_text(inspect.cleandoc(cls.__doc__ or "")), "",
                  "| key | type | default | choices | limits | meaning |",
                  "|---|---|---|---|---|---|"]
        sub = typing.get_type_hints(cls)
        meaning = field_docs(cls)
        for g in dataclasses.fields(cls):
            tp = sub[g.name]
            is_enum = isinstance(tp, type) and issubclass(tp, enum.Enum)
            ch = ", ".join(f"`{m.value}`" for m in tp) if is_enum else ""
            lim = schema.limits_of(cls, g.name).describe()
            default = g.default.value if isinstance(g.default, enum.Enum) else g.default
            lines.append(f"| `{g.name}` | {'str' if is_enum else _type_name(tp)} | "
                         f"`{default!r}` | {ch} | {lim} | {meaning.get(g.name, '')} |")
        lines.append("")
    return "\n".join(lines + grades_markdown())


if __name__ == "__main__":
    (DOCS / "cli.md").write_text(cli_markdown())
    (DOCS / "pipelines.md").write_text(pipelines_markdown())
