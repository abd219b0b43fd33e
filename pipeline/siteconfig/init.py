"""``surveil config init [SOURCES...] --out FILE``: a commented site config from what the
recordings hold (:mod:`pipeline.siteconfig`).

SOURCES are a warehouse (a folder with ``tables/``) or recordings: MCAP files and
anything ``surveil import`` reads (NMEA text, AIS CSV, ASTERIX, pcap, ROS 1 bags), files
or folders. Recordings are read exactly as ``surveil ingest`` would read them: legacy
files are imported into a temporary folder, everything is ingested into a temporary
warehouse, and both are removed afterwards (nothing is written beside the sources; the
real ingest comes after, with the new config). Without SOURCES the ``--warehouse`` is
read. The config written is loaded back before the command ends (exit 2 if it would not
load, which is a bug).
"""

from __future__ import annotations

import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.config import Config
from pipeline.convert.legacy import detect_format
from pipeline.errors import UsageError
from pipeline.families import load_config
from pipeline.render import printable
from pipeline.siteconfig.propose import propose
from pipeline.siteconfig.render import render, summary_lines
from pipeline.siteconfig.survey import sites_of, survey_warehouse

MCAP_MAGIC = b"\x89MCAP"


@dataclass
class InitResult:
    out: Path
    lines: list[str] = field(default_factory=list)

    def render(self) -> str:
        lines = [f"config init: wrote {self.out}", *("  " + x for x in self.lines),
                 f"next: surveil config check {self.out}; then surveil --config "
                 f"{self.out} ingest ... (docs/site.md)"]
        return "\n".join(map(printable, lines))  # names from the archive, escaped


def _is_warehouse(p: Path) -> bool:
    return p.is_dir() and (p / "tables").is_dir()


def _is_mcap(p: Path) -> bool:
    try:
        with open(p, "rb") as f:
            return f.read(5) == MCAP_MAGIC
    except OSError:
        return False


def split_sources(sources: list[Path]) -> tuple[list[Path], list[Path]]:
    """(MCAP files, files for ``surveil import``) under ``sources``; UsageError for a
    missing path or a file neither is."""
    mcap, legacy = [], []
    for src in sources:
        if not src.exists():
            raise UsageError(f"source does not exist: {src}")
        files = sorted(q for q in src.rglob("*") if q.is_file() and not q.name.startswith(".")
                       ) if src.is_dir() else [src]
        for f in files:
            if _is_mcap(f):
                mcap.append(f)
            elif detect_format(f) != "unknown":
                legacy.append(f)
            elif not src.is_dir():
                raise UsageError(f"not a recording surveil reads (MCAP, NMEA text, AIS CSV, "
                                 f"ASTERIX, pcap, ROS 1 bag): {f}")
    if not mcap and not legacy:
        raise UsageError("no recordings under " + ", ".join(map(str, sources)))
    return mcap, legacy


def run_config_init(cfg: Config, sources: list[Path], out: Path, *, warehouse: Path | None,
                    name: str | None = None, site: str | None = None,
                    origin: tuple[float, float] | None = None,
                    coastline: Path | None = None, force: bool = False,
                    base_time_ns: int = 0) -> InitResult:
    """Survey the sources, write the config to ``out`` (refused when it exists, unless
    ``force``), load it back; ``cfg``: the config the recordings are decoded with (its
    ``[validation]``, ``[import.csv]``, ``[asterix]``); ``base_time_ns``: as ``surveil
    import --base-time`` (the day of time-of-day-only recordings)."""
    if out.exists() and not force:
        raise UsageError(f"{out} exists: choose another --out, or --force to replace it")
    if coastline is not None and not coastline.is_file():
        raise UsageError(f"--coastline {coastline}: no such file")
    houses = [s for s in sources if _is_warehouse(s)]
    if houses and len(houses) != len(sources):
        raise UsageError("give either one warehouse or recordings, not both")
    if len(houses) > 1:
        raise UsageError("give one warehouse at a time")
    tmp = None
    try:
        if houses or not sources:
            wh = houses[0] if houses else warehouse
            if wh is None or not _is_warehouse(wh):
                raise UsageError(f"no warehouse at {wh}: give recordings or a warehouse")
            described = [f"warehouse {wh.resolve()}"]
            known = sites_of(wh)
            if site is None and len(known) > 1:
                raise UsageError(f"warehouse {wh} holds {len(known)} sites ({', '.join(known)}):"
                                 " choose one with --site")
            if site is not None and site not in known:
                raise UsageError(f"no site {site!r} in warehouse {wh} (sites: "
                                 f"{', '.join(known) or 'none'})")
        else:
            tmp = Path(tempfile.mkdtemp(prefix="surveil-config-init-"))
            wh = tmp / "warehouse"
            _ingest(cfg, sources, tmp, wh, base_time_ns)
            described = [str(s.resolve()) for s in sources]
        survey = survey_warehouse(wh, site)
        if survey.start_ns is None:
            held = _held(wh, site)
            raise UsageError("the recordings hold no AIS, radar, airfield or own-ship row, "
                             "nothing a site config declares"
                             + (f" (they hold: {held})" if held else "")
                             + "; `surveil ingest` them to see what they hold")
        named = [s for s in sites_of(wh) if s != "default"]
        title = name or site or (named[0] if len(named) == 1 else None) or (
            sources[0].resolve().stem if sources else "site")
        prop = propose(survey, wh, name=title, origin=origin, coastline=coastline)
        text = render(prop, sources=described)
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text, encoding="utf-8")
    load_config(out)  # what every command will do with it: a ConfigError is exit 2
    return InitResult(out, summary_lines(prop))


def _held(warehouse: Path, site: str | None) -> str:
    """``asterix_service 2, rejects 1`` from the ledger's rows per table (what ingest kept)."""
    import json

    import polars as pl

    from pipeline.warehouse.delta import read_table

    led = pl.from_arrow(read_table(warehouse, "ingest_ledger", columns=["site", "rows_json",
                                                                       "not_stored_json"]))
    if site is not None:
        led = led.filter(pl.col("site") == site)
    rows: dict[str, int] = {}
    for col in ("rows_json", "not_stored_json"):
        for text in led[col].drop_nulls().to_list():
            for k, n in json.loads(text or "{}").items():
                rows[k] = rows.get(k, 0) + int(n)
    return ", ".join(f"{k} {n:,}" for k, n in sorted(rows.items()) if n)


def _ingest(cfg: Config, sources: list[Path], tmp: Path, wh: Path, base_time_ns: int
            ) -> None:
    from pipeline.convert.importer import run_import
    from pipeline.ingest.driver import run_ingest

    mcap, legacy = split_sources(sources)
    if legacy:
        summary = run_import(legacy, tmp / "imported", cfg=cfg, base_time_ns=base_time_ns)
        mcap += [Path(f.output) for f in summary.imported]
    if not mcap:
        raise UsageError("none of the recordings could be read (surveil import lists why)")
    run_ingest(mcap, cfg, wh, executor="serial")
