"""How often the second lane's guess of the lever-arm axes is A's: the axes a rough attitude
from the GNSS velocity track reveals (``qc.checks.lever_arm_observable_from_track``, made
before A) against the axes A's own attitude reveals (``flight_stages.lever_arm_seen``).

Run on demand (not collected by pytest)::

    python tests/benchmarks/bench_lever_guess.py [MCAP:PIPELINE ...]

Default: the sample, the four reference cases (../shared/reference_cases) and the measured
logs ArduPilot plane, ANSFL quadrotor and comma2k19 (../shared/data, converted to MCAP in a
temporary folder). A wrong guess costs a run on two threads its lever-arm and scale-factor
passes twice (``passes_ahead.passes_on_a`` makes them again), never its values. Results:
docs/benchmarks.md, "Speed, tenth round".
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the CLI (pospp.cli)

REPO = Path(__file__).resolve().parents[2]
SHARED = REPO.parent / "shared"
REFERENCE = ("flight_null_200hz", "flight_survey_errors", "flight_time_offset_200hz",
             "vehicle_errorfree")
MEASURED = ("ardupilot_plane_testlog2", "ansfl_quadrotor_straightline", "comma2k19_example1")


def _cases(tmp: Path) -> list[tuple[str, Path, Path]]:
    from pospp.convert import convert

    pipes = REPO / "pipelines"
    out = [("sample", REPO / "sample_data" / "sample_flight.mcap", pipes / "sample.toml")]
    for name in REFERENCE:
        path = SHARED / "reference_cases" / f"{name}.mcap"
        if path.is_file():
            pipe = pipes / ("vehicle.toml" if name.startswith("vehicle") else "flight.toml")
            out.append((name, path, pipe))
    for name in MEASURED:
        if (SHARED / "data" / name).is_dir():
            convert(SHARED / "data" / name, tmp / f"{name}.mcap")
            out.append((name, tmp / f"{name}.mcap", pipes / "realdata" / f"{name}.toml"))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="*", help="MCAP:PIPELINE (default: see the docstring)")
    args = ap.parse_args()

    from pospp import flight_stages
    from pospp.config import load_config
    from pospp.qc.checks import lever_arm_observable_from_track

    with tempfile.TemporaryDirectory() as tmp:
        cases = ([(Path(c.split(":")[0]).stem, Path(c.split(":")[0]), Path(c.split(":")[1]))
                  for c in args.cases] if args.cases else _cases(Path(tmp)))
        print("| log | guess (x, y, z) | A's axes | same |\n|---|---|---|---|")
        for name, path, pipe in cases:
            config = load_config(pipe)
            log = flight_stages.ingest(path, config)
            if len(log.vel) < 2:
                print(f"| {name} | no GNSS velocity: no guess | | |")
                continue
            guess = lever_arm_observable_from_track(
                (log.vel.time_ns - log.vel.time_ns[0]) * 1e-9, log.vel.v_n_mps).tolist()
            try:
                seen = flight_stages.lever_arm_seen(flight_stages.navigate(log, config)).tolist()
            except ValueError as exc:
                print(f"| {name} | {guess} | A failed: {str(exc)[:60]} | |")
                continue
            print(f"| {name} | {guess} | {seen} | {'yes' if guess == seen else 'no'} |")


if __name__ == "__main__":
    main()
