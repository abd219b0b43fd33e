"""``surveil import PATH... --out DIR``: wrap legacy captures (NMEA 0183 text logs, AIS CSV
tables, raw ASTERIX, pcap) into MCAP. Registered in jobs/cli.py under
``# (family commands)``."""

from __future__ import annotations

import sys

import click


@click.command("import")
@click.argument("paths", nargs=-1, type=click.Path(path_type=str))
@click.option(
    "--out",
    "out_dir",
    required=True,
    type=click.Path(path_type=str),
    help="directory for the MCAP files (one per input, named <input name>.mcap)",
)
@click.option(
    "--base-time",
    default="1970-01-01T00:00:00Z",
    show_default=True,
    help="for files without any date: base of synthetic log times (no time at "
    "all) or the day of time-of-day-only logs (ISO 8601 or ns)",
)
def import_command(paths, out_dir, base_time) -> None:
    """Wrap legacy captures into MCAP with honest log times (see the channel metadata
    "log_time_source"), so that `surveil ingest` reads MCAP only."""
    from jobs.common import parse_time_ns
    from jobs.import_legacy import run_import

    summary = run_import(paths, out_dir, base_time_ns=parse_time_ns(base_time))
    click.echo(summary.render())
    sys.exit(summary.exit_code)
