"""The `surveil` command: every command declared here, each a few lines over a job
function (``jobs/<job>.py``) that tests call directly.

The config file is loaded and validated once, before any command runs (every family's
sections included), so a bad config is exit 2 at start, never a failed work unit.

Exit codes: 0 ok, 1 some units/files failed (re-runnable), 2 usage or config error,
130 interrupted.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click

from jobs.common import (
    EXIT_INTERRUPTED,
    EXIT_USAGE,
    UsageError,
    parse_duration,
    parse_time_ns,
    setup_logging,
)
from pipeline.config import Config, ConfigError
from pipeline.families import load_config

LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL")


class _State:
    """What every command gets: the validated config and the warehouse path."""

    def __init__(self, cfg: Config, warehouse: str | None) -> None:
        self.cfg = cfg
        self.warehouse = Path(warehouse or cfg.warehouse_path).resolve()


def _window(from_: str | None, to: str | None, required: bool) -> tuple[int | None, int | None]:
    """--from/--to as int64 ns UTC, checked: both given when required, to after from."""
    if required and (from_ is None or to is None):
        raise UsageError("--from and --to are required")
    start = parse_time_ns(from_) if from_ else None
    end = parse_time_ns(to) if to else None
    if start is not None and end is not None and end <= start:
        raise UsageError("--to must be after --from")
    return start, end


def _duration_s(text: str) -> float:
    try:
        return parse_duration(text)
    except ValueError as exc:
        raise UsageError(str(exc)) from None


_FROM = click.option("--from", "from_", default=None,
                     help="window start, ISO 8601 (naive = UTC) or int ns")
_TO = click.option("--to", default=None, help="window end, exclusive")
_FROM_REQUIRED = click.option("--from", "from_", required=True,
                              help="window start, ISO 8601 (naive = UTC) or int ns")
_TO_REQUIRED = click.option("--to", required=True, help="window end, exclusive")
_EXECUTOR = click.option(
    "--executor", type=click.Choice(["serial", "process", "ray"]), default=None,
    help="How work units run (default from config: process pool).",
)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
              help="TOML config (default: the shipped config/surveil.toml).")
@click.option("--warehouse", type=click.Path(file_okay=False), default=None,
              help="Warehouse directory (default from config: ./warehouse).")
@click.option("--log-level", type=click.Choice(LOG_LEVELS, case_sensitive=False),
              default="WARNING", show_default=True)
@click.option("--log-json/--log-text", default=None,
              help="Log format (default: text on a terminal, JSON lines otherwise).")
@click.version_option(package_name="surveil-pipeline")
@click.pass_context
def cli(ctx: click.Context, config_path, warehouse, log_level, log_json) -> None:
    """surveil: MCAP surveillance archives -> Delta warehouse -> batch -> DuckDB reports."""
    setup_logging(log_level, log_json)
    ctx.obj = _State(load_config(config_path), warehouse)


# --- archive: simulate, import, ingest -------------------------------------------------


@cli.command()
@click.option("--scenario", type=click.Choice(["channel", "channel-clean", "airfield", "gaps",
                                              "ownship"]),
              default="channel", show_default=True)
@click.option("--duration", default="1h", show_default=True, help="e.g. 1h, 30m, 90s")
@click.option("--seed", type=int, default=7, show_default=True)
@click.option("--start", default=None,
              help="log start time, ISO 8601 (default 2026-01-15T00:00:00Z)")
@click.option("--out", type=click.Path(file_okay=False), required=True)
@click.pass_obj
def simulate(st: _State, scenario, duration, seed, start, out) -> None:
    """Write a simulated scenario as an MCAP archive (one file per hour)."""
    from jobs.simulate import run_simulate

    start_ns = parse_time_ns(start) if start else None
    for f in run_simulate(scenario, _duration_s(duration), seed, Path(out), st.cfg,
                          start_ns=start_ns):
        click.echo(str(f))


@cli.command("import")
@click.argument("paths", nargs=-1, type=click.Path(path_type=str))
@click.option("--out", "out_dir", required=True, type=click.Path(path_type=str),
              help="directory for the MCAP files (one per input, named <input name>.mcap)")
@click.option("--base-time", default="1970-01-01T00:00:00Z", show_default=True,
              help="for files without any date: base of synthetic log times (no time at "
              "all) or the day of time-of-day-only logs (ISO 8601 or ns)")
def import_command(paths, out_dir, base_time) -> None:
    """Wrap legacy captures (NMEA 0183 text, AIS CSV, raw ASTERIX, pcap) into MCAP with
    honest log times (channel metadata "log_time_source"), so `ingest` reads MCAP only."""
    from jobs.import_legacy import run_import

    summary = run_import(paths, out_dir, base_time_ns=parse_time_ns(base_time))
    click.echo(summary.render())
    sys.exit(summary.exit_code)


@cli.command()
@click.argument("paths", nargs=-1, required=True, type=click.Path())
@_FROM
@_TO
@click.option("--force", is_flag=True, help="re-ingest files the ledger says are unchanged")
@_EXECUTOR
@click.pass_obj
def ingest(st: _State, paths, from_, to, force, executor) -> None:
    """Decode MCAP files into the warehouse's raw tables."""
    from jobs.ingest import run_ingest

    start, end = _window(from_, to, required=False)
    summary = run_ingest([Path(p) for p in paths], st.cfg, st.warehouse,
                         start_ns=start, end_ns=end, force=force, executor=executor)
    click.echo(summary.render())
    sys.exit(summary.exit_code)


# --- batch, reprocess, demo --------------------------------------------------------------


@cli.command()
@_FROM_REQUIRED
@_TO_REQUIRED
@_EXECUTOR
@click.pass_obj
def batch(st: _State, from_, to, executor) -> None:
    """Run every sensor family's batch over one window; commit it atomically."""
    from jobs.batch import run_batch

    start, end = _window(from_, to, required=True)
    summary = run_batch(st.cfg, st.warehouse, start_ns=start, end_ns=end, executor_kind=executor)
    click.echo(summary.render())
    sys.exit(summary.exit_code)


@cli.command()
@_FROM_REQUIRED
@_TO_REQUIRED
@_EXECUTOR
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
@_EXECUTOR
@click.pass_obj
def demo(st: _State, seed, duration, executor) -> None:
    """Simulate one hour, ingest, batch, and print the accuracy and identification reports."""
    from jobs.demo import run_demo

    result = run_demo(st.cfg, st.warehouse, seed=seed, duration_s=_duration_s(duration),
                      echo=click.echo, executor_kind=executor)
    sys.exit(result.exit_code)


# --- reports -------------------------------------------------------------------------------


@cli.command()
@click.argument("name", required=False)
@_FROM
@_TO
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


# --- calibration ----------------------------------------------------------------------------


@cli.command()
@_FROM_REQUIRED
@_TO_REQUIRED
@click.option("--max-order", type=click.IntRange(1, 8), default=4, show_default=True,
              help="highest AR order compared by BIC")
@click.option("--min-speed", type=float, default=0.0, show_default=True,
              help="use only reports of reference targets at least this fast, m/s")
@click.pass_obj
def calibrate(st: _State, from_, to, max_order, min_speed) -> None:
    """Fit each airfield sensor's coloured-error AR model against the reference channel
    (airfield paper eq. 2, 7, 8; order by BIC) into sensor_error_models."""
    from jobs.calibrate import run_calibrate

    start, end = _window(from_, to, required=True)
    summary = run_calibrate(st.cfg, st.warehouse, start_ns=start, end_ns=end,
                            max_order=max_order, min_speed_mps=min_speed)
    click.echo(summary.render())


@cli.command("calibrate-radars")
@_FROM_REQUIRED
@_TO_REQUIRED
@click.option("--format", "fmt", type=click.Choice(["text", "json"]), default="text",
              show_default=True)
@click.pass_obj
def calibrate_radars(st: _State, from_, to, fmt) -> None:
    """Estimate each radar's range, azimuth and time bias from AIS ships in a window,
    with 95 % intervals; write radar_bias_by_site and print the config lines."""
    from jobs.calibrate import render, run_calibration

    start, end = _window(from_, to, required=True)
    est = run_calibration(st.cfg, st.warehouse, start_ns=start, end_ns=end)
    click.echo(est.write_json() if fmt == "json" else render(est))


# --- experiments (the papers' simulation experiments, seeded) -------------------------------


@cli.group()
def experiment() -> None:
    """Reproduce the source papers' simulation experiments with the production code."""


_TEXT_OR_JSON = click.option("--format", "fmt", type=click.Choice(["text", "json"]),
                             default="text", show_default=True)


def _emit(result: dict, fmt: str) -> None:
    from pipeline.maritime.experiment import render

    click.echo(json.dumps(result, indent=2) if fmt == "json" else render(result))


@experiment.command()
@click.option("--sigma", type=float, required=True, help="radar position sigma, m (x and y)")
@click.option("--dx", type=float, default=0.0, show_default=True, help="separation east, m")
@click.option("--dy", type=float, default=0.0, show_default=True, help="separation north, m")
@click.option("--trials", type=int, default=10_000, show_default=True)
@click.option("--seed", type=int, default=1, show_default=True)
@_TEXT_OR_JSON
@click.pass_obj
def identification(st: _State, sigma, dx, dy, trials, seed, fmt) -> None:
    """Two stationary targets, two radars: probability of correct identification
    (two-radar identification paper), with its 95 % Monte Carlo interval."""
    from pipeline.maritime.experiment import identification_experiment

    _emit(identification_experiment(st.cfg, sigma_m=sigma, dx_m=dx, dy_m=dy, trials=trials,
                                    seed=seed), fmt)


@experiment.command()
@click.option("--sigma", type=float, required=True, help="radar position sigma, m (x and y)")
@click.option("--dx", type=float, default=0.0, show_default=True, help="separation east, m")
@click.option("--dy", type=float, default=0.0, show_default=True, help="separation north, m")
@click.option("--speed", type=float, default=5.0, show_default=True, help="target speed, m/s")
@click.option("--course-difference", type=float, default=20.0, show_default=True,
              help="angle between the two targets' courses, deg")
@click.option("--trials", type=int, default=10_000, show_default=True)
@click.option("--seed", type=int, default=1, show_default=True)
@_TEXT_OR_JSON
@click.pass_obj
def velocity(st: _State, sigma, dx, dy, speed, course_difference, trials, seed, fmt) -> None:
    """Moving targets: probability of correct identification with and without the
    reported velocities."""
    from pipeline.maritime.experiment import velocity_experiment

    _emit(velocity_experiment(st.cfg, sigma_m=sigma, dx_m=dx, dy_m=dy, speed_mps=speed,
                              course_difference_deg=course_difference, trials=trials,
                              seed=seed), fmt)


@experiment.command("channel-faults")
@click.option("--runs", type=click.IntRange(1, 1000), default=20, show_default=True,
              help="seeded runs (seeds first-seed .. first-seed + runs - 1)")
@click.option("--first-seed", type=int, default=1000, show_default=True)
@_EXECUTOR
@click.option("--format", "fmt", type=click.Choice(["table", "csv", "json"]), default="table",
              show_default=True)
@click.option("--out", "out_path", type=click.Path(dir_okay=False), default=None,
              help="also write every run's fault rows to this Parquet file")
@click.pass_obj
def channel_faults(st: _State, runs, first_seed, executor, fmt, out_path) -> None:
    """Seeded Monte Carlo of channel integrity (issue 22): every radar and AIS fault kind
    in a compressed channel scene, a GNSS outage and jump on the own ship; per kind the
    share detected within 3 scans / reports / fixes, the delay, fused accuracy with
    exclusion on and off; the fault-free false-alarm share against q."""
    from jobs.report import format_report
    from pipeline.experiments.channel_montecarlo import run_montecarlo, summarise

    res = run_montecarlo(st.cfg, seeds=range(first_seed, first_seed + runs),
                         executor=executor or st.cfg.execution.executor)
    if out_path:
        res["faults"].write_parquet(out_path)
    click.echo(format_report(summarise(res).to_arrow(), fmt, title="channel faults Monte Carlo"))


@cli.command("gaps-montecarlo")
@click.option("--runs", type=click.IntRange(1, 1000), default=20, show_default=True,
              help="simulated runs (seeds first-seed .. first-seed + runs - 1)")
@click.option("--first-seed", type=int, default=1, show_default=True)
@click.option("--duration", default="3h", show_default=True,
              help="length of each simulated run (1h, 90m, 3h, seconds)")
@click.option("--particles", type=click.IntRange(100, 100_000), default=None,
              help="particles per gap (default: [gaps] particles)")
@click.option("--by-lead", is_flag=True, help="one row per lead-time band and variant")
@_EXECUTOR
@click.option("--format", "fmt", type=click.Choice(["table", "csv", "json"]), default="table",
              show_default=True)
@click.option("--out", "out_path", type=click.Path(dir_okay=False), default=None,
              help="also write every forecast (both variants) to this Parquet file")
@click.pass_obj
def gaps_montecarlo(st: _State, runs, first_seed, duration, particles, by_lead, executor, fmt,
                    out_path) -> None:
    """Seeded Monte Carlo of the data-gap forecasts on the `gaps` scenario, with and
    without the admissible-area constraint: share of true positions inside the 90%
    region, forecast errors, probability of the zone the ship actually reached."""
    from jobs.report import format_report
    from pipeline.experiments.gaps_montecarlo import run_montecarlo, summarise

    forecasts = run_montecarlo(
        st.cfg, seeds=range(first_seed, first_seed + runs), duration_s=_duration_s(duration),
        particles=particles, executor=executor or st.cfg.execution.executor,
    )
    if out_path:
        forecasts.write_parquet(out_path)
    table = summarise(forecasts, by_lead=by_lead)
    click.echo(format_report(table.to_arrow(), fmt, title="gaps Monte Carlo"))


def main() -> None:
    """Console entry point: map errors to exit codes instead of tracebacks."""
    try:
        cli.main(standalone_mode=False)
    except (click.exceptions.Abort, KeyboardInterrupt):
        click.echo("interrupted", err=True)
        sys.exit(EXIT_INTERRUPTED)
    except click.ClickException as exc:
        exc.show()
        sys.exit(EXIT_USAGE)
    except (UsageError, ConfigError) as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(EXIT_USAGE)


if __name__ == "__main__":
    main()
