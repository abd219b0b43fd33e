"""The `surveil` command: every command declared here, each a few lines over a job
function (``jobs/<job>.py``) that tests call directly.

The config file is loaded and validated once, before any command does its work (every
family's sections included), so a bad config is exit 2 at start, never a failed work unit.
``--config`` and ``--warehouse`` are accepted before or after the subcommand.

Shell completion (click): ``eval "$(_SURVEIL_COMPLETE=bash_source surveil)"`` (zsh:
``zsh_source``, fish: ``fish_source``); report names, sectors and table names complete.

Exit codes: 0 ok (everything read was used), 1 some units/files failed, some file was
partial or some row was rejected (re-runnable), 2 usage or config error (a damaged table:
one line naming it and `surveil doctor`), 3 committed but the views file could not be
rebuilt after (a full disk: the next command or `surveil doctor --repair` rebuilds it),
130 interrupted (SIGINT), 143 terminated (SIGTERM); `surveil doctor`: 0 healthy, 1
problems found.
"""

from __future__ import annotations

import contextlib
import functools
import json
import sys
from pathlib import Path
from typing import Any

import click

from jobs.common import (
    EXIT_INTERRUPTED,
    EXIT_USAGE,
    UsageError,
    checked_site,
    checked_warehouse,
    parse_duration,
    parse_origin,
    parse_time_ns,
    refuse_pre_sites,
    require_site,
    require_warehouse,
    setup_logging,
)
from pipeline.config import Config, ConfigError
from pipeline.families import load_config
from pipeline.signals import EXIT_TERMINATED, Terminated, install_handlers

LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL")
# the scenarios of pipeline.simulate.scenarios.SCENARIOS (a test checks), named here so
# that `surveil --help` does not import every simulator
SCENARIO_NAMES = ("channel", "channel-clean", "airfield", "gaps", "ownship", "region")
# the demo simulates one hour into one warehouse; the region scenario has its own config
DEMO_CHOICES = tuple(s for s in SCENARIO_NAMES if s != "region")


class _State:
    """What every command gets: the validated config and the warehouse path. Both are
    resolved on first use, so that ``--config`` / ``--warehouse`` given after the
    subcommand (parsed after the group's) still apply; every command uses them first."""

    def __init__(self, config_path: str | None, warehouse: str | None) -> None:
        self.config_path = config_path
        self.warehouse_option = warehouse
        self._cfg: Config | None = None
        self._warehouse: tuple[Any, Any] | None = None  # (what it was made of, the result)

    @property
    def cfg(self) -> Config:
        if self._cfg is None:
            self._cfg = load_config(self.config_path)
        return self._cfg

    def world(self, scenarios: list[str] | tuple[str, ...]) -> Config:
        """The config with the simulator's world of ``scenarios`` on top (the demo
        site's shipped ``config/scenarios/`` files): what the experiments read
        (:func:`pipeline.simulate.scenarios.with_scenario`)."""
        from pipeline.simulate.scenarios import with_scenario

        return with_scenario(self.cfg, scenarios)

    @property
    def warehouse(self) -> Path:
        """The warehouse a command writes (``ingest``, ``run``, ``demo`` create it): a
        local folder (absolute) or an object-store prefix (``s3://``, with the config's
        ``[warehouse] storage_options``); exit 2 when the scheme is unknown, when Delta
        cannot use the path, or when it was written before sites (no ``site`` column:
        rebuild it)."""
        given = (self.warehouse_option, id(self.cfg))
        if self._warehouse is not None and self._warehouse[0] == given:
            return self._warehouse[1]  # (checked once: on object storage each check is I/O)
        loc = checked_warehouse(self.warehouse_option or self.cfg.warehouse_path,
                                self.cfg.warehouse_storage_options)
        refuse_pre_sites(loc)
        where = loc.path if loc.is_local else loc
        self._warehouse = (given, where)
        return where  # type: ignore[return-value]

    @property
    def existing_warehouse(self) -> Path:
        """The warehouse a command reads: exit 2 naming it when it does not exist (a
        typo in ``--warehouse`` must not read as an empty warehouse, nor create one)."""
        where = self.warehouse
        require_warehouse(where)
        return where

    def site(self, name: str | None) -> str | None:
        """``--site`` of a command over an existing warehouse: exit 2 naming the
        warehouse's sites when it holds no such site."""
        return require_site(self.existing_warehouse, name)

    def sector(self, name: str | None) -> str | None:
        """``--sector``, checked against the config's sectors (maritime and airfield)."""
        if name is None:
            return None
        known = sector_names(self.cfg)
        if name not in known:
            raise UsageError(f"unknown sector {name!r}; the config's sectors are: "
                             f"{', '.join(known)}")
        return name


def _locked(st: _State, wait: bool = False) -> contextlib.AbstractContextManager:
    """The warehouse's writer lock for a command that commits (exit 2 naming the holder
    when another job has it)."""
    from pipeline.warehouse.lock import warehouse_lock

    return warehouse_lock(st.warehouse, command=" ".join(["surveil", *sys.argv[1:]]),
                          wait=wait)


def sector_names(cfg: Config) -> list[str]:
    """Every sector a --sector may name: maritime sectors, then airfield sectors."""
    names = [s.name for s in cfg.sectors]
    airfield = (cfg.families or {}).get("airfield")
    names += [s.name for s in getattr(airfield, "sectors", ()) or () if s.name not in names]
    return names


def _set_config(ctx: click.Context, _param: click.Parameter, value: str | None) -> None:
    if value is not None:
        ctx.ensure_object(_State).config_path = value
        ctx.find_object(_State)._cfg = None


def _set_warehouse(ctx: click.Context, _param: click.Parameter, value: str | None) -> None:
    if value is not None:
        ctx.find_object(_State).warehouse_option = value


def _global_options(cmd: click.Command, validate: bool = True) -> click.Command:
    """``--config`` / ``--warehouse`` after the subcommand, too; the config is loaded
    and validated once every option is parsed, before the command's body runs."""
    body = cmd.callback

    def validated(*args: Any, **kwargs: Any) -> Any:
        click.get_current_context().find_object(_State).cfg  # noqa: B018 (exit 2 when bad)
        return body(*args, **kwargs)

    if validate and body is not None:
        cmd.callback = functools.update_wrapper(validated, body)
    cmd.params += [
        click.Option(["--config"], type=click.Path(dir_okay=False), expose_value=False,
                     callback=_set_config, is_eager=True,
                     help="TOML config (also accepted before the subcommand)."),
        click.Option(["--warehouse"], type=click.Path(file_okay=False), expose_value=False,
                     callback=_set_warehouse,
                     help="Warehouse: a directory or s3://BUCKET/PREFIX (also accepted "
                          "before the subcommand)."),
    ]
    return cmd


def _complete_reports(ctx: click.Context, _param: click.Parameter, incomplete: str) -> list:
    from pipeline.reports import list_reports, reports_config

    try:
        dirs = reports_config(load_config(ctx.find_root().params.get("config_path"))).dirs
    except ConfigError:
        dirs = ()
    return [n for n in list_reports(dirs) if n.startswith(incomplete)]


def _complete_sectors(ctx: click.Context, _param: click.Parameter, incomplete: str) -> list:
    try:
        cfg = load_config(ctx.find_root().params.get("config_path"))
    except ConfigError:
        return []
    return [n for n in sector_names(cfg) if n.startswith(incomplete)]


def _complete_tables(_ctx: click.Context, _param: click.Parameter, incomplete: str) -> list:
    from pipeline.tables import table_specs

    return [n for n in table_specs() if n.startswith(incomplete)]


def _window(from_: str | None, to: str | None, required: bool) -> tuple[int | None, int | None]:
    """--from/--to as int64 ns UTC, checked: both given when required, to after from."""
    if required and (from_ is None or to is None):
        raise UsageError("--from and --to are required")
    start = parse_time_ns(from_) if from_ else None
    end = parse_time_ns(to) if to else None
    if start is not None and end is not None and end <= start:
        raise UsageError("--to must be after --from")
    return start, end


def _bounded(st: _State, start: int | None, end: int | None, site: str | None = None
             ) -> tuple[int, int]:
    """A batch/reprocess window clipped to the data the ledger knows (of ``site``), or
    exit 2 when it is too long or too big for the memory budget (:mod:`pipeline.batch.window`)."""
    from pipeline.batch.window import bounded_window

    w = bounded_window(st.cfg, st.warehouse, start, end, site)  # type: ignore[arg-type]
    if w.note:
        click.echo(w.note, err=True)
    return w.start_ns, w.end_ns


def _duration_s(text: str) -> float:
    try:
        return parse_duration(text)
    except ValueError as exc:
        raise UsageError(str(exc)) from None


_FROM_HELP = ("window start (inclusive): ISO 8601 such as 2026-01-15T00:00:00Z (no zone "
              "= UTC), or integer ns since 1970 UTC")
_TO_HELP = "window end (exclusive), same forms as --from"
_FROM = click.option("--from", "from_", default=None, metavar="TIME", help=_FROM_HELP)
_TO = click.option("--to", default=None, metavar="TIME", help=_TO_HELP)
_FROM_REQUIRED = click.option("--from", "from_", required=True, metavar="TIME", help=_FROM_HELP)
_TO_REQUIRED = click.option("--to", required=True, metavar="TIME", help=_TO_HELP)
_SECTOR = click.option("--sector", default=None, shell_complete=_complete_sectors,
                       help="one sector of the config (default: every sector); an unknown "
                            "name lists them")
def _parse_site(_ctx: click.Context, _param: click.Parameter, value: str | None
                ) -> str | None:
    try:
        return None if value is None else checked_site(value)
    except UsageError as exc:
        raise click.BadParameter(str(exc)) from None


def _site_option(help_text: str) -> Any:
    return click.option("--site", default=None, metavar="NAME", callback=_parse_site,
                        help=help_text)


_SITE_READ = _site_option("that site's rows only (default: every site, each reported "
                          "apart in a `site` column)")
_SITE_BATCH = _site_option("that site only: its rows are read and replaced, other sites' "
                           "are untouched (default: every site with data in the window, "
                           "each batched alone)")
_SITE_CAL = _site_option("that site only (default: every site with data in the window, "
                          "each fitted against its own rows and stored with its site)")
_IGNORE_PLACE = click.option(
    "--ignore-place", is_flag=True,
    help="batch even when most of a site's positions lie outside the config's region "
         "(default: exit 2 naming the distance; write a config for the place instead)")
_WAIT = click.option("--wait", is_flag=True,
                     help="wait for another job holding the warehouse (default: exit 2 "
                          "naming it)")
_FORMAT = click.option("--format", "fmt", type=click.Choice(["table", "csv", "json"]),
                       default="table", show_default=True)
_EXECUTOR = click.option(
    "--executor", type=click.Choice(["serial", "process", "ray"]), default=None,
    help="How work units run (default from config: process pool).",
)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
              help="TOML config (default: the shipped config/surveil.toml).")
@click.option("--warehouse", type=click.Path(file_okay=False), default=None,
              help="Warehouse: a directory or s3://BUCKET/PREFIX (default from config: "
                   "./warehouse; docs/scale.md for object storage).")
@click.option("--log-level", type=click.Choice(LOG_LEVELS, case_sensitive=False),
              default="WARNING", show_default=True)
@click.option("--log-json/--log-text", default=None,
              help="Log format (default: text on a terminal, JSON lines otherwise).")
@click.version_option(package_name="surveil-pipeline")
@click.pass_context
def cli(ctx: click.Context, config_path, warehouse, log_level, log_json) -> None:
    """surveil: MCAP surveillance archives -> Delta warehouse -> batch -> DuckDB reports."""
    setup_logging(log_level, log_json)
    ctx.obj = _State(config_path, warehouse)


# --- archive: simulate, import, ingest -------------------------------------------------


@cli.command()
@click.option("--scenario", type=click.Choice(SCENARIO_NAMES),
              default="channel", show_default=True)
@click.option("--duration", default=None,
              help="e.g. 1h, 30m, 90s (default 1h; region: 24h)")
@click.option("--seed", type=int, default=7, show_default=True)
@click.option("--start", default=None,
              help="log start time, ISO 8601 (default 2026-01-15T00:00:00Z)")
@click.option("--ships", type=int, default=None,
              help="region: mean number of ships in the scene (default 1000)")
@click.option("--radars", type=int, default=None,
              help="region: number of radar sites along the coast (default 6)")
@click.option("--out", type=click.Path(file_okay=False), required=True)
@click.option("--scenario-config", type=click.Path(dir_okay=False), default=None,
              help="the scenario's world on top of the site config: fault schedules, "
                   "injected biases, the own ship's voyage (default: for the demo site, "
                   "the shipped config/scenarios/<scenario>.toml; for yours, none)")
@click.pass_obj
def simulate(st: _State, scenario, duration, seed, start, ships, radars, out,
             scenario_config) -> None:
    """Write a simulated scenario as an MCAP archive (one file per hour). The region
    scenario also writes its config, region.toml, beside the files."""
    from jobs.simulate import run_simulate

    start_ns = parse_time_ns(start) if start else None
    for f in run_simulate(scenario, _duration_s(duration) if duration else None, seed,
                          Path(out), st.cfg, start_ns=start_ns, ships=ships, radars=radars,
                          scenario_config=scenario_config):
        click.echo(str(f))


@cli.command("import")
@click.argument("paths", nargs=-1, type=click.Path(path_type=str))
@click.option("--out", "out_dir", required=True, type=click.Path(path_type=str),
              help="directory for the MCAP files (one per input, named <input name>.mcap)")
@click.option("--base-time", default=None,
              help="for files without any date: the day of time-of-day-only logs and ASTERIX "
              "recordings, or the start of synthetic log times (no time at all); ISO 8601 or "
              "ns. Default: the date in the file name, else 1970-01-01 (and a warning)")
@_site_option("the site (deployment) the captures come from, written into each MCAP "
              "file's metadata (`surveil.import` record, key `site`) for ingest to stamp "
              "on every row (default: none named: ingest's --site or 'default')")
@click.pass_obj
def import_command(st: _State, paths, out_dir, base_time, site) -> None:
    """Wrap legacy captures (NMEA 0183 text, AIS CSV, raw ASTERIX, pcap) into MCAP with
    honest log times (channel metadata "log_time_source"), so `ingest` reads MCAP only."""
    from pipeline.convert.importer import run_import

    summary = run_import(paths, out_dir, cfg=st.cfg, site=site,
                         base_time_ns=None if base_time is None else parse_time_ns(base_time))
    click.echo(summary.render())
    sys.exit(summary.exit_code)


@cli.command()
@click.argument("paths", nargs=-1, required=True, type=click.Path())
@_FROM
@_TO
@click.option("--force", is_flag=True, help="re-ingest files the ledger says are unchanged")
@_site_option("the site of files whose MCAP metadata names none (default 'default'); a "
              "file naming another site is exit 2")
@_EXECUTOR
@_WAIT
@click.pass_obj
def ingest(st: _State, paths, from_, to, force, site, executor, wait) -> None:
    """Decode MCAP files into the warehouse's raw tables."""
    from jobs.progress import terminal_progress
    from pipeline.ingest.driver import expand_paths, run_ingest

    start, end = _window(from_, to, required=False)
    progress = terminal_progress()
    with _locked(st, wait), progress or contextlib.nullcontext():
        if progress is not None:
            progress.ingest_total(expand_paths(list(paths), st.warehouse))
        summary = run_ingest(list(paths), st.cfg, st.warehouse,
                             start_ns=start, end_ns=end, force=force, executor=executor,
                             on_result=progress.ingest_result if progress else None,
                             site=site)
    click.echo(summary.render())
    sys.exit(summary.exit_code)


# --- batch, reprocess, demo --------------------------------------------------------------


@cli.command()
@_FROM_REQUIRED
@_TO_REQUIRED
@_SITE_BATCH
@_EXECUTOR
@_IGNORE_PLACE
@_WAIT
@click.pass_obj
def batch(st: _State, from_, to, site, executor, ignore_place, wait) -> None:
    """Run every sensor family's batch over one window; commit it atomically."""
    from jobs.batch import run_batch
    from jobs.progress import terminal_progress

    window = _window(from_, to, required=True)
    warehouse = st.existing_warehouse
    site = st.site(site)
    start, end = _bounded(st, *window, site)
    progress = terminal_progress()
    with _locked(st, wait), progress or contextlib.nullcontext():
        summary = run_batch(st.cfg, warehouse, start_ns=start, end_ns=end,
                            executor_kind=executor, progress=progress, site=site,
                            ignore_place=ignore_place)
    click.echo(summary.render())
    sys.exit(summary.exit_code)


@cli.command()
@_FROM_REQUIRED
@_TO_REQUIRED
@_SITE_BATCH
@_EXECUTOR
@_IGNORE_PLACE
@_WAIT
@click.pass_obj
def reprocess(st: _State, from_, to, site, executor, ignore_place, wait) -> None:
    """Re-ingest the archived files overlapping a window and re-run its batch."""
    from jobs.progress import terminal_progress
    from jobs.reprocess import run_reprocess

    window = _window(from_, to, required=True)
    warehouse = st.existing_warehouse
    site = st.site(site)
    start, end = _bounded(st, *window, site)
    progress = terminal_progress()
    with _locked(st, wait), progress or contextlib.nullcontext():
        summary = run_reprocess(st.cfg, warehouse, start_ns=start, end_ns=end,
                                executor_kind=executor, progress=progress, site=site,
                                ignore_place=ignore_place)
    click.echo(summary.render())
    sys.exit(summary.exit_code)


@cli.command("run")
@click.argument("folders", nargs=-1, type=click.Path())
@_site_option("the site of files whose metadata names none (raw recordings are imported "
              "with it), and the only site batched (default: such files are 'default'; "
              "every site is batched)")
@_EXECUTOR
@_IGNORE_PLACE
@_WAIT
@click.pass_obj
def run_command(st: _State, folders, site, executor, ignore_place, wait) -> None:
    """The nightly job: scan the archive folders (FOLDERS, default [archive] folders)
    for MCAP files and raw recordings `surveil import` reads (imported into the
    warehouse's imported/ folder), ingest the new and changed ones (files still being
    written wait for [archive] settle_s), batch the windows they touch, any a failed run
    left and any batched with another config, record the run in the `runs` table.
    Nothing new: does nothing, says so. Exit codes as ingest's; 2 when a site's
    positions lie outside the config's region."""
    from jobs.progress import terminal_progress
    from pipeline.batch.nightly import run_nightly

    progress = terminal_progress()
    with _locked(st, wait), progress or contextlib.nullcontext():
        summary = run_nightly(st.cfg, st.warehouse, folders=list(folders),
                              executor_kind=executor, progress=progress, site=site,
                              ignore_place=ignore_place,
                              command=" ".join(["surveil", *sys.argv[1:]]))
    click.echo(summary.render())
    sys.exit(summary.exit_code)


@cli.command()
@click.option("--seed", type=int, default=7, show_default=True)
@click.option("--duration", default="1h", show_default=True)
@click.option("--scenarios", default="channel,airfield,ownship", show_default=True,
              help="comma-separated scenarios to simulate (channel, airfield, gaps, ownship)")
@_EXECUTOR
@click.pass_obj
def demo(st: _State, seed, duration, scenarios, executor) -> None:
    """Simulate one hour, ingest, batch, and print the accuracy and identification reports
    (then `surveil audit` draws the hour: the command is printed at the end)."""
    from jobs.demo import run_demo

    chosen = [s.strip() for s in scenarios.split(",") if s.strip()]
    unknown = [s for s in chosen if s not in DEMO_CHOICES]
    if unknown or not chosen:
        raise UsageError(f"--scenarios: unknown {', '.join(unknown) or '(none given)'}; "
                         f"choose from {', '.join(DEMO_CHOICES)}")
    duration_s = _duration_s(duration)
    with _locked(st):
        result = run_demo(st.cfg, st.warehouse, seed=seed, duration_s=duration_s,
                          echo=click.echo, executor_kind=executor, scenarios=chosen)
    sys.exit(result.exit_code)


# --- reports -------------------------------------------------------------------------------


@cli.command()
@click.argument("name", required=False, shell_complete=_complete_reports)
@_FROM
@_TO
@_SECTOR
@_FORMAT
@click.option("--param", "params", multiple=True, metavar="NAME=VALUE",
              help="a parameter the report's header declares (repeatable)")
@click.option("--list", "list_", is_flag=True, help="list the available reports")
@_SITE_READ
@click.pass_obj
def report(st: _State, name, from_, to, sector, fmt, params, list_, site) -> None:
    """Run a report (sql/ or a [reports] dirs folder) over the warehouse."""
    import duckdb

    from pipeline.catalog import explain_empty
    from pipeline.render import format_report
    from pipeline.reports import (
        REPORT_MEMORY,
        ReportError,
        UnknownReportError,
        list_reports,
        load_report,
        named_report_batches,
        reports_config,
        write_csv,
    )

    dirs = reports_config(st.cfg).dirs
    if list_ or not name:
        _list_reports(dirs)
        return
    start, end = _window(from_, to, required=False)
    sector = st.sector(sector)
    site = st.site(site)
    try:  # CSV is written as DuckDB streams it; a table or JSON is formatted whole
        with named_report_batches(st.existing_warehouse, name, start_ns=start, end_ns=end,
                                  sector=sector, cfg=st.cfg, params=_params(params),
                                  site=site) as reader:
            if fmt == "csv":
                sys.stdout.flush()
                rows = write_csv(reader, sys.stdout.buffer)
            else:
                table = reader.read_all()
                rows = table.num_rows
    except UnknownReportError as exc:
        raise UsageError(f"no report {name!r}; available: {', '.join(list_reports(dirs))}"
                         ) from exc
    except ReportError as exc:
        raise UsageError(str(exc)) from exc
    except duckdb.OutOfMemoryException as exc:
        click.echo(f"error: report {name} needs more memory than DuckDB may use "
                   f"({REPORT_MEMORY}; spilling to disk did not suffice): narrow "
                   "--from/--to or raise SURVEIL_REPORT_MEMORY (e.g. 8GB). "
                   f"{str(exc).splitlines()[0]}", err=True)
        sys.exit(1)
    except duckdb.Error as exc:  # e.g. a parameter the report's SQL cannot use
        raise UsageError(f"report {name}: {str(exc).strip().splitlines()[0]}") from None
    if rows == 0:
        why = explain_empty(st.existing_warehouse, load_report(name, dirs), start_ns=start,
                            end_ns=end, sector=sector, cfg=st.cfg, site=site)
        click.echo(f"{name}: no rows. {why}", err=True)
    if fmt != "csv":
        click.echo(format_report(table, fmt, title=name), nl=fmt != "table")
    from pipeline.batch.provenance import report_provenance

    for line in report_provenance(st.existing_warehouse, st.cfg,  # on stderr: the configs
                                  load_report(name, dirs).source_tables(), start, end, site):
        click.echo(line, err=True)


def _list_reports(dirs: tuple[Path, ...]) -> None:
    from pipeline.reports import report_listing

    for line in report_listing(dirs):
        click.echo(line)


def _params(items: tuple[str, ...]) -> dict[str, str]:
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise UsageError(f"--param {item!r}: use NAME=VALUE")
        out[key.lstrip("$")] = value
    return out


@cli.command()
@_FROM_REQUIRED
@_TO_REQUIRED
@_SECTOR
@click.option("--out", "out_dir", type=click.Path(file_okay=False), required=True,
              help="folder for audit_<from>_<to>[_<sector>].html (and .pdf)")
@click.option("--pdf", is_flag=True, help="also print the page to PDF with headless Chromium")
@_SITE_READ
@click.pass_obj
def audit(st: _State, from_, to, sector, out_dir, pdf, site) -> None:
    """One self-contained HTML page (opens without a network): requirement verdicts,
    accuracy, identification, SIAP, cross-track, bias, faults, heading, gaps and a map."""
    from jobs.audit import run_audit

    start, end = _window(from_, to, required=True)
    site = st.site(site)
    result = run_audit(st.cfg, st.existing_warehouse, Path(out_dir), start_ns=start, end_ns=end,
                       sector=st.sector(sector), pdf=pdf, site=site)
    click.echo(result.render())
    sys.exit(EXIT_USAGE if pdf and result.pdf is None else 0)


@cli.command()
@_FROM_REQUIRED
@_TO_REQUIRED
@click.option("--out", "out_path", type=click.Path(dir_okay=False), required=True,
              help="the MCAP file to write")
@_SITE_READ
@click.pass_obj
def export(st: _State, from_, to, out_path, site) -> None:
    """Fused, per-radar, AIS and airfield tracks and the config's geometry as an MCAP file
    in Foxglove's schemas (protobuf): open it in Foxglove's Map and 3D panels."""
    from jobs.export import run_export

    start, end = _window(from_, to, required=True)
    site = st.site(site)
    summary = run_export(st.cfg, st.existing_warehouse, Path(out_path), start_ns=start,
                         end_ns=end, site=site)
    click.echo(summary.render())


@cli.command(context_settings={"ignore_unknown_options": True})  # QUERY may start "--"
@click.argument("query", required=False)
@_FORMAT
@click.option("--allow-write-files", "write_dir", type=click.Path(file_okay=False),
              help="a folder the SQL may write (COPY ... TO exports) and read; without "
                   "it the SQL reaches no file: the warehouse is read through its views")
@click.pass_obj
def sql(st: _State, query, fmt, write_dir) -> None:
    """Run SQL over the warehouse views (the tables reports use; `surveil schema` lists
    them), read-only: no file, extension or database is reachable but the views (and
    the --allow-write-files folder). Without QUERY: the statements piped on stdin, or
    on a terminal an interactive prompt (end a statement with ';', quit with .quit or
    Ctrl-D)."""
    from pipeline.render import format_report
    from pipeline.reports import open_warehouse, run_sql, sql_write_dir

    con = open_warehouse(st.existing_warehouse, refuse_damaged=False,  # the others read
                         write_dir=sql_write_dir(st.existing_warehouse, write_dir))
    try:
        if query is None and not sys.stdin.isatty():  # piped: every statement up to a
            lines = sys.stdin.read().splitlines()     # .quit, the last ';' optional
            query = "\n".join(lines[:next((i for i, ln in enumerate(lines)
                                           if ln.strip() in _QUIT), len(lines))])
        if query is not None and query.strip():
            table = run_sql(con, query)
            if table is not None:
                click.echo(format_report(table, fmt), nl=fmt != "table")
            return
        _prompt(con, fmt)
    finally:
        con.close()


_QUIT = (".quit", ".exit", "\\q")


def _prompt(con: Any, fmt: str) -> None:
    import contextlib

    from pipeline.render import format_report
    from pipeline.reports import run_sql

    with contextlib.suppress(ImportError):
        import readline  # noqa: F401  (line editing and history for input())
    click.echo("surveil sql: the warehouse tables are views (`surveil schema`); end a "
               "statement with ';', .quit to leave", err=True)
    buf: list[str] = []
    while True:
        try:
            line = input("surveil> " if not buf else "    ...> ")
        except EOFError:
            click.echo("", err=True)
            return
        if not buf and line.strip() in _QUIT:
            return
        buf.append(line)
        if not line.rstrip().endswith(";"):
            continue
        text, buf = "\n".join(buf), []
        try:
            table = run_sql(con, text)
        except UsageError as exc:
            click.echo(f"error: {exc}", err=True)
            continue
        if table is not None:
            click.echo(format_report(table, fmt), nl=fmt != "table")


@cli.command()
@click.argument("table", required=False, shell_complete=_complete_tables)
@_FORMAT
def schema(table, fmt) -> None:
    """Every warehouse table (kind, meaning), or one TABLE's columns with their types,
    units and meanings, from schemas/tables.toml."""
    from pipeline.render import format_report, schema_table
    from pipeline.tables import table_specs

    if table is not None and table not in table_specs():
        raise UsageError(f"no table {table!r}; tables: {', '.join(table_specs())}")
    click.echo(format_report(schema_table(table), fmt, title=table or "warehouse tables"),
               nl=fmt != "table")


@cli.command()
@click.option("--repair", is_flag=True,
              help="repair what it can (under the writer lock): broken log entries moved "
                   "aside (backed up in _doctor/), references to missing files removed and "
                   "their units batched again, views rebuilt, dead jobs' leftovers removed")
@_EXECUTOR
@click.pass_obj
def doctor(st: _State, repair, executor) -> None:
    """Check every warehouse table (log readable, every data file present with its
    recorded size, schema as schemas/ declares), the views file and dead jobs' leftovers;
    print a table of findings. Exit 0 healthy, 1 problems found (after --repair: some
    remain or a command is left to run), 2 usage error."""
    from pipeline.batch.doctor import run_doctor

    result = run_doctor(st.cfg, st.existing_warehouse, repair=repair, executor_kind=executor,
                        command=" ".join(["surveil", *sys.argv[1:]]))
    click.echo(result.render())
    sys.exit(result.exit_code)


# --- calibration ----------------------------------------------------------------------------


@cli.command()
@_FROM_REQUIRED
@_TO_REQUIRED
@click.option("--max-order", type=click.IntRange(1, 8), default=4, show_default=True,
              help="highest AR order compared by BIC")
@click.option("--min-speed", type=float, default=0.0, show_default=True,
              help="use only reports of reference targets at least this fast, m/s")
@_SITE_CAL
@click.pass_obj
def calibrate(st: _State, from_, to, max_order, min_speed, site) -> None:
    """Fit each airfield sensor's coloured-error AR model against the reference channel
    (airfield paper eq. 2, 7, 8; order by BIC) into sensor_error_models."""
    from pipeline.batch.calibrate import run_calibrate

    start, end = _window(from_, to, required=True)
    warehouse = st.existing_warehouse
    site = st.site(site)
    with _locked(st):
        summary = run_calibrate(st.cfg, warehouse, start_ns=start, end_ns=end,
                                max_order=max_order, min_speed_mps=min_speed, site=site)
    click.echo(summary.render())
    sys.exit(summary.exit_code)


@cli.command("calibrate-radars")
@_FROM_REQUIRED
@_TO_REQUIRED
@click.option("--format", "fmt", type=click.Choice(["text", "json"]), default="text",
              show_default=True)
@_SITE_CAL
@click.pass_obj
def calibrate_radars(st: _State, from_, to, fmt, site) -> None:
    """Estimate each radar's range, azimuth and time bias from AIS ships in a window,
    with 95 % intervals; write radar_bias_by_site and print the config lines."""
    from pipeline.batch.calibrate import run_calibration
    from pipeline.errors import views_stale_note

    start, end = _window(from_, to, required=True)
    warehouse = st.existing_warehouse
    site = st.site(site)
    with _locked(st):
        cal = run_calibration(st.cfg, warehouse, start_ns=start, end_ns=end, site=site)
    click.echo(cal.estimates.write_json() if fmt == "json" else cal.render())
    if fmt == "json" and cal.views_error:
        click.echo(views_stale_note("calibration", cal.views_error), err=True)
    sys.exit(cal.exit_code)


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
@_FORMAT
@click.option("--out", "out_path", type=click.Path(dir_okay=False), default=None,
              help="also write every run's fault rows to this Parquet file")
@click.pass_obj
def channel_faults(st: _State, runs, first_seed, executor, fmt, out_path) -> None:
    """Seeded Monte Carlo of channel integrity (issue 22): every radar and AIS fault kind
    in a compressed channel scene, a GNSS outage and jump on the own ship; per kind the
    share detected within 3 scans / reports / fixes, the delay, fused accuracy with
    exclusion on and off, the false-identification share (time of ships without AIS
    carrying an MMSI) and the correct share of ships with AIS; the fault-free
    false-alarm share against q."""
    from pipeline.experiments.channel_montecarlo import run_montecarlo, summarise
    from pipeline.render import format_report

    res = run_montecarlo(st.world(["channel", "ownship"]),
                         seeds=range(first_seed, first_seed + runs),
                         executor=executor or st.cfg.execution.executor)
    if out_path:
        res["faults"].write_parquet(out_path)
    click.echo(format_report(summarise(res).to_arrow(), fmt, title="channel faults Monte Carlo"))


@experiment.command()
@click.option("--runs", type=click.IntRange(1, 1000), default=50, show_default=True,
              help="simulated runs (seeds first-seed .. first-seed + runs - 1)")
@click.option("--first-seed", type=int, default=1, show_default=True)
@click.option("--duration", default="30m", show_default=True,
              help="length of each run (the paper's scenario: the turn is in minutes 15-19)")
@click.option("--per-seed", is_flag=True, help="one row per seed instead of the summary")
@_EXECUTOR
@_FORMAT
@click.pass_obj
def ownship(st: _State, runs, first_seed, duration, per_seed, executor, fmt) -> None:
    """Own-ship heading over seeds (gyro/GNSS/log paper): integrated heading RMS and max
    after convergence per seed against truth, the gyro alone, the gate's rejections."""
    from pipeline.experiments.ownship_montecarlo import run_montecarlo, summarise
    from pipeline.render import format_report

    table = run_montecarlo(st.world(["ownship"]), seeds=range(first_seed, first_seed + runs),
                           duration_s=_duration_s(duration),
                           executor=executor or st.cfg.execution.executor)
    out = table if per_seed else summarise(table)
    click.echo(format_report(out.to_arrow(), fmt, title="ownship Monte Carlo"))


@experiment.command()
@click.option("--runs", type=click.IntRange(1, 1000), default=10, show_default=True,
              help="seeded runs (seeds first-seed .. first-seed + runs - 1)")
@click.option("--first-seed", type=int, default=1, show_default=True)
@click.option("--duration", default="1h", show_default=True,
              help="length of each scene (maritime and airfield)")
@click.option("--clean", is_flag=True, help="without the config's fault schedules")
@click.option("--per-seed", is_flag=True, help="every figure of every seed instead of the summary")
@_EXECUTOR
@click.option("--format", "fmt", type=click.Choice(["table", "csv", "json"]), default="table",
              show_default=True)
@click.pass_obj
def reference(st: _State, runs, first_seed, duration, clean, per_seed, executor, fmt) -> None:
    """Is the reconstructed reference honest (issue 37)? The channel and airfield scenes
    through the batch stages with the truth and with the truth withheld: every accuracy
    figure (RMS, p95 per sector / area and source) and PD per radar / channel of the
    reports, truth-based beside reference-based (tolerance 10 % and 0.01)."""
    from pipeline.experiments.reference_montecarlo import run_montecarlo, summarise
    from pipeline.render import format_report

    figures = run_montecarlo(st.cfg, seeds=range(first_seed, first_seed + runs),
                             duration_s=_duration_s(duration), clean=clean,
                             executor=executor or st.cfg.execution.executor)
    out = figures if per_seed else summarise(figures)
    click.echo(format_report(out.to_arrow(), fmt, title="reference Monte Carlo"))


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
@_FORMAT
@click.option("--out", "out_path", type=click.Path(dir_okay=False), default=None,
              help="also write every forecast (both variants) to this Parquet file")
@click.pass_obj
def gaps_montecarlo(st: _State, runs, first_seed, duration, particles, by_lead, executor, fmt,
                    out_path) -> None:
    """Seeded Monte Carlo of the data-gap forecasts on the `gaps` scenario, with and
    without the admissible-area constraint: share of true positions inside the 90%
    region, forecast errors, probability of the zone the ship actually reached."""
    from pipeline.experiments.gaps_montecarlo import run_montecarlo, summarise
    from pipeline.render import format_report

    forecasts = run_montecarlo(
        st.cfg, seeds=range(first_seed, first_seed + runs), duration_s=_duration_s(duration),
        particles=particles, executor=executor or st.cfg.execution.executor,
    )
    if out_path:
        forecasts.write_parquet(out_path)
    table = summarise(forecasts, by_lead=by_lead)
    click.echo(format_report(table.to_arrow(), fmt, title="gaps Monte Carlo"))


# --- configuration ------------------------------------------------------------------------


@cli.group("config")
def config_group() -> None:
    """The configuration file."""


@config_group.command("check")
@click.argument("file", required=False, type=click.Path(dir_okay=False))
@click.pass_obj
def config_check(st: _State, file: str | None) -> None:
    """Validate FILE (default: the --config file) as every command does and print it
    resolved: every section, values in file units, defaults marked. Exit 0, or 2
    listing every problem."""
    from jobs.config_check import resolved_config

    click.echo(resolved_config(file or st.config_path), nl=False)


def _origin(_ctx: click.Context, _param: click.Parameter, value: str | None
            ) -> tuple[float, float] | None:
    try:
        return None if value is None else parse_origin(value)
    except UsageError as exc:
        raise click.BadParameter(str(exc)) from None


@config_group.command("init")
@click.argument("sources", nargs=-1, type=click.Path(path_type=Path))
@click.option("--out", "out_path", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="the site config to write (refused when it exists, unless --force)")
@click.option("--name", default=None, help="the region's name (default: --site, else the "
              "recordings' site, else the first source's name)")
@_site_option("a warehouse's site to describe (needed when it holds several)")
@click.option("--origin", default=None, callback=_origin, metavar="LAT,LON",
              help="the site's reference point, deg (default: the median of the recordings' "
                   "positions; needed when they carry none, e.g. an SMR + MLAT capture)")
@click.option("--coastline", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="water or land polygons (GeoJSON or WKT) for the gap forecasts' "
                   "admissible area (which of the two is read from the vessels' positions)")
@click.option("--force", is_flag=True, help="replace --out when it exists")
@click.option("--base-time", default="1970-01-01T00:00:00Z", show_default=True,
              help="as `surveil import --base-time`: the day of recordings whose times are "
                   "a time of day only (ISO 8601 or ns)")
@click.pass_obj
def config_init(st: _State, sources, out_path, name, site, origin, coastline, force,
                base_time) -> None:
    """Write a commented site config for what SOURCES hold: a warehouse, or recordings
    (MCAP and anything `surveil import` reads, files or folders; read through a
    temporary import + ingest, removed afterwards). Region and origin from the data's
    positions, the AIS sources, radar sites and airfield sensors present (positions from
    the data, or estimated against another sensor, marked PROPOSED), own ships, proposed
    sectors over the traffic, the requirement presets commented out (docs/site.md)."""
    from pipeline.siteconfig.init import run_config_init

    wh = Path(st.warehouse_option) if st.warehouse_option else None
    result = run_config_init(st.cfg, list(sources), out_path, warehouse=wh, name=name,
                             site=site, origin=origin, coastline=coastline, force=force,
                             base_time_ns=parse_time_ns(base_time))
    click.echo(result.render())


for _cmd in [*cli.commands.values(), *experiment.commands.values()]:
    if not isinstance(_cmd, click.Group):
        _global_options(_cmd)
_global_options(config_check, validate=False)  # it validates FILE (or --config) itself
_global_options(config_init)


def main() -> None:
    """Console entry point: map errors to exit codes instead of tracebacks. SIGINT
    (Ctrl-C) exits 130, SIGTERM 143: the job unwinds (pool workers stopped, staging
    removed, nothing half committed: ``pipeline.signals``)."""
    install_handlers()
    try:
        cli.main(standalone_mode=False)
    except (click.exceptions.Abort, KeyboardInterrupt):
        click.echo("interrupted (SIGINT): nothing incomplete was committed", err=True)
        sys.exit(EXIT_INTERRUPTED)
    except Terminated:
        click.echo("terminated (SIGTERM): nothing incomplete was committed", err=True)
        sys.exit(EXIT_TERMINATED)
    except click.ClickException as exc:
        exc.show()
        sys.exit(EXIT_USAGE)
    except (UsageError, ConfigError) as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(EXIT_USAGE)


if __name__ == "__main__":
    main()
