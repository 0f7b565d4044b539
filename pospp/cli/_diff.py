"""``pospp diff A B``: what changed between two runs or two batch roots (pospp.api.diff)."""

from __future__ import annotations

import click

from pospp.cli._status import EXIT_CODES, status_line


@click.command()
@click.argument("a", type=click.Path(exists=True, file_okay=False))
@click.argument("b", type=click.Path(exists=True, file_okay=False))
@click.option("--tolerances", "tolerance_file", type=click.Path(exists=True, dir_okay=False),
              default=None,
              help="TOML with a [tolerance] table (position_m, velocity_mps, attitude_arcsec, "
                   "bias_sigma_fraction, horizon_error_mps, horizon_error_m); defaults: 1 cm, "
                   "1 mm/s, 1 arcsec, a tenth of A's bias sigma, 1 mm/s, 1 cm.")
@click.option("-o", "--out", "out_dir", default=None, type=click.Path(file_okay=False),
              help="Folder for diff.parquet (every row) and diff.html (what changed); "
                   "default: the console only.")
def diff(a: str, b: str, tolerance_file: str | None, out_dir: str | None) -> None:
    """What changed from run (or batch root) A to B: headline and trajectory differences.

    Calls pospp.api.diff.diff_paths: per flight (folders of the same name under two roots),
    the status, legs, calibrated biases and sigmas, B's errors at the horizon, and each
    trajectory solution's position, velocity and attitude differences (max and RMS) against
    the tolerances. Exit status 0 when everything is within tolerance, 3 when not, 1 on error.
    """
    from pospp.api.diff import diff_paths, load_tolerances, write_diff
    from pospp.api.diff_text import diff_lines, diff_status

    tol = load_tolerances(tolerance_file) if tolerance_file else None
    result = diff_paths(a, b, tol)
    for line in diff_lines(result):
        click.echo(line)
    written = write_diff(result, out_dir) if out_dir else ()
    for path in written:
        click.echo(f"  {path}")
    status_line("diff", diff_status(result))
    raise SystemExit(EXIT_CODES["ok"] if result.within else EXIT_CODES["changed"])
