"""What writes each warehouse table, and why a report came out empty.

A report with no rows says why: which of its source tables have no rows in the window
(and whether they have rows elsewhere, or in other sectors), and which command produces
them first. Raw tables come from ``surveil ingest`` of an archive (the simulator
scenario that writes them is named), derived tables from ``surveil batch`` (the family
that owns them) or a calibration command.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import duckdb

from pipeline import families
from pipeline.config import Config
from pipeline.reports import ALL_TIME, ReportSql, open_warehouse
from pipeline.tables import spec, table_specs

# raw tables -> the `surveil simulate` scenario that writes them (the demo hour has
# channel, airfield and ownship)
_SCENARIO_OF = {
    "radar_tracks": "channel", "ais_reports": "channel", "ais_static": "channel",
    "truth": "channel", "airfield_obs": "airfield", "airfield_truth": "airfield",
    "nav_gnss": "ownship", "nav_heading": "ownship", "nav_speed_log": "ownship",
    "nav_gyro_signals": "ownship", "ownship_truth": "ownship",
}
_CALIBRATIONS = {
    "radar_bias_by_site": "surveil calibrate-radars --from T --to T",
    "sensor_error_models": "surveil calibrate --from T --to T",
}


def producer(table: str) -> str:
    """The command that writes ``table``, as a user would type it."""
    if table in _CALIBRATIONS:
        return f"`{_CALIBRATIONS[table]}`"
    for fam in families.FAMILIES:  # (the stages import only when asked: PEP 562)
        if table in fam.outputs:
            return f"`surveil batch --from T --to T` ({fam.name} family)"
    kind = spec(table).kind if table in table_specs() else "raw"
    if kind in ("raw", "ledger"):
        scenario = _SCENARIO_OF.get(table)
        hint = f" (simulated: `surveil simulate --scenario {scenario}`)" if scenario else ""
        return f"`surveil ingest ARCHIVE`{hint}"
    return "`surveil batch --from T --to T`"


def _count(con: duckdb.DuckDBPyConnection, table: str, start_ns: int | None = None,
           end_ns: int | None = None, sector: str | None = None) -> int:
    t = spec(table)
    where, params = [], []
    if start_ns is not None and t.time_column:
        where.append(f'"{t.time_column}" >= ? AND "{t.time_column}" < ?')
        params += [int(start_ns), int(end_ns)]
    if sector is not None and "sector" in t.schema.names:
        where.append("sector = ?")
        params.append(sector)
    sql = f'SELECT count(*) FROM "{table}"' + (" WHERE " + " AND ".join(where) if where else "")
    return int(con.execute(sql, params).fetchall()[0][0])


def _empty_inputs(con: duckdb.DuckDBPyConnection, table: str, cfg: Config | None,
                  start_ns: int, end_ns: int) -> list[str]:
    """The inputs of the family that writes ``table`` that have no rows in the window."""
    if cfg is None:
        return []
    for fam in families.FAMILIES:
        if table in fam.outputs:
            try:
                inputs = [ti.table for ti in fam.inputs(cfg) if not ti.whole_table]
            except Exception:  # a family that cannot say without its config section
                return []
            return [t for t in inputs if t in table_specs()
                    and _count(con, t, start_ns, end_ns) == 0]
    return []


def why_empty(
    con: duckdb.DuckDBPyConnection,
    tables: Iterable[str],
    *,
    start_ns: int,
    end_ns: int,
    sector: str | None = None,
    cfg: Config | None = None,
) -> str:
    """One or two sentences: why queries over ``tables`` have nothing in the window
    (``con`` has the warehouse views; ``cfg`` lets a derived table name its empty inputs)."""
    reasons = []
    for table in tables:
        if table not in table_specs():
            continue
        in_window = _count(con, table, start_ns, end_ns)
        if in_window and sector is not None and "sector" in spec(table).schema.names:
            if _count(con, table, start_ns, end_ns, sector) == 0:
                reasons.append(f"{table} has {in_window} rows in the window, none in sector "
                               f"{sector!r}")
            continue
        if in_window:
            continue
        total = _count(con, table)
        missing = _empty_inputs(con, table, cfg, start_ns, end_ns)
        if missing:
            first = missing[0]
            reasons.append(f"{table} has no rows because its input {first} has none in the "
                           f"window: {producer(first)} first, then "
                           "`surveil batch --from T --to T`")
        elif total:
            reasons.append(f"{table} has no rows in the window ({total} rows at other times): "
                           f"run {producer(table)} for this window")
        else:
            reasons.append(f"{table} is empty: {producer(table)} writes it")
    if not reasons:
        return ("the source tables have rows in the window, but none the report keeps "
                "(e.g. no reference to score against)")
    return "; ".join(reasons)


def explain_empty_report(con: duckdb.DuckDBPyConnection, report: ReportSql, *, start_ns: int,
                         end_ns: int, sector: str | None = None, cfg: Config | None = None
                         ) -> str:
    """Why report ``report`` has no rows, from the tables its header names."""
    return why_empty(con, report.source_tables(), start_ns=start_ns, end_ns=end_ns,
                     sector=sector, cfg=cfg)


def explain_empty(warehouse: Path, report: ReportSql, *, start_ns: int | None,
                  end_ns: int | None, sector: str | None, cfg: Config | None = None) -> str:
    """Why ``report`` has no rows in the window: what its source tables hold and which
    command writes them."""
    con = open_warehouse(warehouse)
    try:
        return explain_empty_report(
            con, report, start_ns=ALL_TIME[0] if start_ns is None else start_ns,
            end_ns=ALL_TIME[1] if end_ns is None else end_ns, sector=sector, cfg=cfg)
    finally:
        con.close()
