"""The sites a warehouse holds (ingest ledger, batch units) and a ``--site`` checked
against them. Light to import: every command's option parsing uses it."""

from __future__ import annotations

import logging
from pathlib import Path

from pipeline.errors import UsageError


def sites_in(warehouse: Path, start_ns: int, end_ns: int) -> list[str]:
    """The sites the ingest ledger knows files of (ok or partial) overlapping
    ``[start_ns, end_ns)``, sorted."""
    import polars as pl

    from pipeline.warehouse.delta import read_table

    ledger = pl.from_arrow(read_table(warehouse, "ingest_ledger", columns=[
        "site", "status", "start_time_ns", "end_time_ns"]))
    hit = ledger.filter(pl.col("status").is_in(["ok", "partial"])
                        & (pl.col("start_time_ns") < end_ns)
                        & (pl.col("end_time_ns") >= start_ns))
    return sorted(hit["site"].unique().to_list())


def warehouse_sites(warehouse: Path) -> list[str]:
    """The sites a warehouse holds: of its ingest ledger's files and its committed batch
    units, sorted."""
    import polars as pl

    from pipeline.warehouse.delta import read_table

    found: set[str] = set()
    for table in ("ingest_ledger", "batch_units"):
        found |= set(pl.from_arrow(read_table(warehouse, table, columns=["site"]))["site"]
                     .to_list())
    return sorted(found)


def require_site(warehouse: Path, site: str | None) -> str | None:
    """``site`` when the warehouse holds it (or None); :class:`UsageError` (exit 2)
    naming the warehouse's sites otherwise: a typo in ``--site`` must not read as a site
    without data (was: ``report --site nosuch`` exit 0 blaming the gyro signals, ``batch
    --site nosuch`` committed empty units)."""
    if site is None:
        return None
    known = warehouse_sites(warehouse)
    if site not in known:
        raise UsageError(f"no site {site!r} in warehouse {warehouse} (its sites: "
                         f"{', '.join(known) or 'none: ingest recordings first'})")
    return site


def one_site(warehouse: Path, site: str | None, start_ns: int, end_ns: int) -> str | None:
    """``site`` as given (None: every site). A command drawing one picture (audit,
    export) over several sites without ``--site`` warns: their rows are drawn together
    (each report row keeps its ``site``), fine for sites of different families (the demo's
    channel, airfield and own ship), confusing for two VTS sites."""
    if site is None:
        found = sites_in(warehouse, start_ns, end_ns)
        if len(found) > 1:
            logging.getLogger(__name__).warning(
                "the window holds data of %d sites (%s), drawn together; --site NAME for one",
                len(found), ", ".join(found))
    return site
