"""Which families a site's batch runs over a window, and one line for each it skips.

Every family and every sensor is optional (issue 35): a site may be AIS only, radar +
AIS, own ship only, airfield only, or any mix. A family runs in a window when the config
lets it (:meth:`pipeline.families.Declared.unconfigured`: the airfield family needs an
``[airfield]`` section) and one of its raw inputs holds rows there; otherwise its units
are not planned and the batch summary says why, in one line:

- ``airfield: skipped: no [airfield] section in the config; airfield_obs holds 6,666
  reports in the window from 0/7 (smr), 0/107 (mlat): declare them (surveil config
  init, docs/site.md)``
- ``nav: skipped: no own-ship data in the window (nav_gnss, nav_heading, ...: 0 rows)``
- ``maritime: no radar site declared: AIS transponders get the kinematic self-test alone,
  no fused picture``

A skipped family's tables are still committed for the window (empty): rows an earlier
batch wrote there under another config do not survive it.

The rows per table come from the ingest ledger (``rows_json`` of the site's files whose
span overlaps the window: an upper bound, read without touching the tables); a window
the ledger knows no file of (a warehouse filled by windowed ingests, which write no
ledger rows) skips nothing on that ground.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import polars as pl

from pipeline import tables
from pipeline.config import Config
from pipeline.families import declared
from pipeline.family import Family
from pipeline.warehouse.delta import read_table

UNCONFIGURED_INPUTS = {"airfield": ("airfield_obs",)}
"""The raw inputs of a family that declares none without its section (its ``inputs``
are empty then): what the skipped line counts."""
FUSED_KINDS = ("smr", "mlat", "vasn")  # pipeline.airfield.config.SENSOR_KINDS
REFERENCES = frozenset({"truth", "ownship_truth", "airfield_truth", "fault_truth"})
"""Reference tables (simulated truth): a family does not run on them alone."""


@dataclass(frozen=True)
class Scope:
    """The families to run and a note per family skipped (or run with a caveat)."""

    run: tuple[str, ...]
    notes: tuple[str, ...] = field(default=())


def ledger_rows(warehouse: Path, start_ns: int, end_ns: int, site: str | None
                ) -> dict[str, int] | None:
    """Rows per raw table of the files (ok or partial) of ``site`` whose span overlaps
    ``[start_ns, end_ns)``, from the ledger; None when the ledger knows no such file."""
    ledger = pl.from_arrow(read_table(warehouse, "ingest_ledger", columns=[
        "site", "status", "start_time_ns", "end_time_ns", "rows_json"]))
    hit = ledger.filter(pl.col("status").is_in(["ok", "partial"])
                        & (pl.col("start_time_ns") < end_ns)
                        & (pl.col("end_time_ns") >= start_ns))
    if site is not None:
        hit = hit.filter(pl.col("site") == site)
    if hit.height == 0:
        return None
    out: dict[str, int] = {}
    for text in hit["rows_json"].to_list():
        for name, n in json.loads(text or "{}").items():
            out[name] = out.get(name, 0) + int(n)
    return out


def batch_scope(warehouse: Path, cfg: Config, fams: tuple[Family, ...], start_ns: int,
                end_ns: int, site: str | None) -> Scope:
    """The families of ``fams`` that run over the window for ``site``, and the notes
    (module docstring)."""
    decl = declared(cfg)
    rows = ledger_rows(warehouse, start_ns, end_ns, site)
    owners = {name: f.name for f in fams for name in f.outputs}
    run: list[str] = []
    notes: list[str] = []
    for fam in fams:  # in wave order: a family reading another's output sees it decided
        raw = [i.table for i in fam.inputs(cfg) if not i.whole_table and i.table not in owners
               and i.table not in REFERENCES and tables.spec(i.table).kind == "raw"]
        why = decl.unconfigured(fam.name)
        if why is not None:
            raw = raw or list(UNCONFIGURED_INPUTS.get(fam.name, ()))
            notes.append(f"{fam.name}: skipped: {why}"
                         + _undeclared_data(warehouse, fam, cfg, raw, rows, start_ns, end_ns,
                                            site))
            continue
        upstream = [owners[i.table] for i in fam.inputs(cfg) if i.table in owners
                    and owners[i.table] != fam.name]
        if rows is not None and not any(rows.get(t, 0) for t in raw) and not any(
                u in run for u in upstream):
            listed = ", ".join(raw)
            notes.append(f"{fam.name}: skipped: no rows of {listed} in the window"
                         + (f" (nor of {', '.join(upstream)}'s outputs)" if upstream else ""))
            continue
        run.append(fam.name)
        if fam.name == "maritime" and not decl.radars:
            n_radar = (rows or {}).get("radar_tracks", 0)
            notes.append("maritime: no radar site declared: AIS transponders get the "
                         "kinematic self-test alone, no fused picture"
                         + (f"; radar_tracks holds up to {n_radar:,} reports in the window:"
                            " declare their sites in [[radar_sites]] (`surveil config init`)"
                            if n_radar else ""))
    return Scope(tuple(run), tuple(notes))


def _undeclared_data(warehouse: Path, fam: Family, cfg: Config, raw: list[str],
                     rows: dict[str, int] | None, start_ns: int, end_ns: int,
                     site: str | None) -> str:
    """``; airfield_obs holds N reports ... from 0/7 (smr): declare them ...`` when the
    unconfigured family's inputs hold rows in the window."""
    held = [(t, (rows or {}).get(t, 0)) for t in raw if (rows or {}).get(t, 0)]
    if not held:
        return ""
    text = "; " + ", ".join(f"{t} holds up to {n:,} rows in the window" for t, n in held)
    if fam.name == "airfield":
        sources = airfield_sources(warehouse, start_ns, end_ns, site)
        if sources:
            text += " from " + ", ".join(sources)
        if sources and not any(f"({k}," in s for s in sources for k in FUSED_KINDS):
            return text + " (kinds the airfield family does not fuse: the rows stay in " \
                          "airfield_obs for SQL)"
    return text + ": declare them (`surveil config init`, docs/site.md)"


def airfield_sources(warehouse: Path, start_ns: int, end_ns: int, site: str | None,
                     limit: int = 6) -> list[str]:
    """``"0/7 (smr, CAT010, 6,666 reports)"`` per data source of ``airfield_obs`` in the
    window, most reports first."""
    obs = pl.from_arrow(read_table(warehouse, "airfield_obs", start_ns=start_ns, end_ns=end_ns,
                                   columns=["sensor_id", "sensor_kind", "asterix_category"],
                                   site=site, sort=False))
    if obs.height == 0:
        return []
    by = (obs.group_by("sensor_id", "sensor_kind", "asterix_category").len()
          .sort(["len", "sensor_id"], descending=[True, False]))
    out = []
    for sid, kind, cat, n in by.head(limit).iter_rows():
        what = f"{kind}, CAT{int(cat):03d}" if cat is not None else kind
        out.append(f"{sid} ({what}, {n:,} reports)")
    if by.height > limit:
        out.append(f"{by.height - limit} more")
    return out
