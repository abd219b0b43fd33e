"""The `surveil` command: click over the jobs' Python API.

Exit codes: 0 ok, 1 some units/files failed (re-runnable), 2 usage or config error,
130 interrupted.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import click

from jobs.common import (
    EXIT_INTERRUPTED,
    EXIT_USAGE,
    UsageError,
    parse_time_ns,
    setup_logging,
)
from pipeline.config import Config, ConfigError
from pipeline.families import load_config

log = logging.getLogger("surveil")


class _State:
    def __init__(self, config_path: str | None, warehouse: str | None) -> None:
        self.config_path = config_path
        self.warehouse_opt = warehouse
        self._cfg: Config | None = None

    @property
    def cfg(self) -> Config:
        if self._cfg is None:
            self._cfg = load_config(self.config_path)
        return self._cfg

    @property
    def warehouse(self) -> Path:
        return Path(self.warehouse_opt or self.cfg.warehouse_path).resolve()


def _window(from_: str | None, to: str | None, required: bool) -> tuple[int | None, int | None]:
    if required and (from_ is None or to is None):
        raise UsageError("--from and --to are required")
    start = parse_time_ns(from_) if from_ else None
    end = parse_time_ns(to) if to else None
    if start is not None and end is not None and end <= start:
        raise UsageError("--to must be after --from")
    return start, end


_executor_opt = click.option(
    "--executor", type=click.Choice(["serial", "process", "ray"]), default=None,
    help="How work units run (default from config: process pool).",
)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
              help="TOML config (default: the shipped config/surveil.toml).")
@click.option("--warehouse", type=click.Path(file_okay=False), default=None,
              help="Warehouse directory (default from config: ./warehouse).")
@click.option("--log-level", default="WARNING", show_default=True)
@click.option("--log-json/--log-text", default=None,
              help="Log format (default: text on a terminal, JSON lines otherwise).")
@click.version_option(package_name="surveil-pipeline")
@click.pass_context
def cli(ctx: click.Context, config_path, warehouse, log_level, log_json) -> None:
    """surveil: MCAP surveillance archives -> Delta warehouse -> batch -> DuckDB reports."""
    setup_logging(log_level, log_json)
    ctx.obj = _State(config_path, warehouse)


@cli.command()
@click.option("--scenario", default="channel", show_default=True)
@click.option("--duration", default="1h", show_default=True, help="e.g. 1h, 30m, 90s")
@click.option("--seed", type=int, default=7, show_default=True)
@click.option("--start", default=None,
              help="log start time, ISO 8601 (default 2026-01-15T00:00:00Z)")
@click.option("--out", type=click.Path(file_okay=False), required=True)
@click.pass_obj
def simulate(st: _State, scenario, duration, seed, start, out) -> None:
    """Write a simulated scenario as an MCAP archive (one file per hour)."""
    from jobs.simulate import parse_duration, run_simulate

    try:
        duration_s = parse_duration(duration)
    except ValueError as exc:
        raise UsageError(str(exc)) from exc
    start_ns = parse_time_ns(start) if start else None
    files = run_simulate(scenario, duration_s, seed, Path(out), st.cfg, start_ns=start_ns)
    for f in files:
        click.echo(str(f))


@cli.command()
@click.argument("paths", nargs=-1, required=True, type=click.Path())
@click.option("--from", "from_", default=None, help="only messages at/after this time")
@click.option("--to", default=None, help="only messages before this time")
@click.option("--force", is_flag=True, help="re-ingest files the ledger says are unchanged")
@_executor_opt
@click.pass_obj
def ingest(st: _State, paths, from_, to, force, executor) -> None:
    """Decode MCAP files into the warehouse's raw tables."""
    from jobs.ingest import run_ingest

    start, end = _window(from_, to, required=False)
    summary = run_ingest([Path(p) for p in paths], st.cfg, st.warehouse,
                         start_ns=start, end_ns=end, force=force, executor=executor)
    click.echo(summary.render())
    sys.exit(summary.exit_code)


@cli.command()
@click.option("--from", "from_", required=True)
@click.option("--to", required=True)
@_executor_opt
@click.pass_obj
def batch(st: _State, from_, to, executor) -> None:
    """Run every sensor family's batch over one window; commit it atomically."""
    from jobs.batch import run_batch

    start, end = _window(from_, to, required=True)
    summary = run_batch(st.cfg, st.warehouse, start_ns=start, end_ns=end, executor_kind=executor)
    click.echo(summary.render())
    sys.exit(summary.exit_code)


@cli.command()
@click.argument("name", required=False)
@click.option("--from", "from_", default=None)
@click.option("--to", default=None)
@click.option("--sector", default=None, help="one sector name (default: every sector)")
@click.option("--format", "fmt", type=click.Choice(["table", "csv", "json"]), default="table",
              show_default=True)
@click.option("--list", "list_", is_flag=True, help="list the available reports")
@click.pass_obj
def report(st: _State, name, from_, to, sector, fmt, list_) -> None:
    """Run a report from sql/ over the warehouse."""
    from jobs.report import format_report, run_named_report
    from pipeline.reports import UnknownReportError, list_reports, load_report

    if list_ or not name:
        for n in list_reports():
            click.echo(f"{n:<28} {load_report(n).description[:100]}")
        return
    start, end = _window(from_, to, required=False)
    try:
        table = run_named_report(st.warehouse, name, start_ns=start, end_ns=end, sector=sector)
    except UnknownReportError as exc:
        raise UsageError(f"no report {name!r}; available: {', '.join(list_reports())}") from exc
    click.echo(format_report(table, fmt, title=name), nl=fmt != "table")


@cli.command()
@click.option("--from", "from_", required=True)
@click.option("--to", required=True)
@_executor_opt
@click.pass_obj
def reprocess(st: _State, from_, to, executor) -> None:
    """Re-ingest the archived files overlapping a window and re-run its batch."""
    from jobs.reprocess import run_reprocess

    start, end = _window(from_, to, required=True)
    summary = run_reprocess(st.cfg, st.warehouse, start_ns=start, end_ns=end,
                            executor_kind=executor)
    click.echo(summary.render())
    sys.exit(summary.exit_code)


@cli.command()
@click.option("--seed", type=int, default=7, show_default=True)
@click.option("--duration", default="1h", show_default=True)
@_executor_opt
@click.pass_obj
def demo(st: _State, seed, duration, executor) -> None:
    """Simulate one hour, ingest, batch, and print the accuracy and identification reports."""
    from jobs.demo import run_demo
    from jobs.simulate import parse_duration

    result = run_demo(st.cfg, st.warehouse, seed=seed, duration_s=parse_duration(duration),
                      echo=click.echo, executor_kind=executor)
    sys.exit(result.exit_code)


# Sensor-family commands: each family module defines its click commands; add them here,
# one line per command, e.g. cli.add_command(import_command).
# (family commands)
from jobs.cli_gaps import gaps_montecarlo  # noqa: E402

cli.add_command(gaps_montecarlo)
from jobs.cli_airfield import calibrate as _airfield_calibrate  # noqa: E402

cli.add_command(_airfield_calibrate)
from jobs.cli_ingest import import_command  # noqa: E402

cli.add_command(import_command)
from jobs.cli_maritime import calibrate_radars as _maritime_calibrate  # noqa: E402
from jobs.cli_maritime import experiment as _maritime_experiment  # noqa: E402

cli.add_command(_maritime_experiment)
cli.add_command(_maritime_calibrate)


def main() -> None:
    """Console entry point: map errors to exit codes instead of tracebacks."""
    try:
        cli.main(standalone_mode=False)
    except click.exceptions.Abort:
        click.echo("interrupted", err=True)
        sys.exit(EXIT_INTERRUPTED)
    except KeyboardInterrupt:
        click.echo("interrupted", err=True)
        sys.exit(EXIT_INTERRUPTED)
    except click.ClickException as exc:
        exc.show()
        sys.exit(EXIT_USAGE)
    except (UsageError, ConfigError) as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(EXIT_USAGE)
    except SystemExit:
        raise


if __name__ == "__main__":
    main()
