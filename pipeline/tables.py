"""Canonical Arrow schemas of the warehouse tables, read from ``schemas/tables.toml``
and ``schemas/tables.d/*.toml`` (one file per sensor family).

The TOML file is the one declaration; this module turns it into ``pyarrow`` schemas
and conforms tables to them (column order, types, the ``date`` partition column).
"""

from __future__ import annotations

import re
import threading
import tomllib
from dataclasses import dataclass
from functools import cache

import numpy as np
import numpy.ma  # pa.array(ndarray) imports it on first use (~25 ms): at import instead
import polars as pl
import pyarrow as pa
import pyarrow.compute as pc

from pipeline.resources import resource_path

_ARROW_TYPES: dict[str, pa.DataType] = {
    "int16": pa.int16(),
    "int32": pa.int32(),
    "int64": pa.int64(),
    "float64": pa.float64(),
    "string": pa.string(),
    "bool": pa.bool_(),
    "binary": pa.binary(),
    "date32": pa.date32(),
}


@dataclass(frozen=True)
class TableSpec:
    name: str
    kind: str  # raw | derived | ledger
    doc: str
    time_column: str
    sort_by: tuple[str, ...]
    schema: pa.Schema

    @property
    def partition_by(self) -> tuple[str, ...]:
        return ("date",) if "date" in self.schema.names else ()


SITE = "site"
"""The site column's name (declared once, ``schemas/tables.toml [site]``)."""


@dataclass(frozen=True)
class SiteColumn:
    """``tables.toml [site]``: the column every raw and derived table (and the ledgers in
    ``ledgers``) carries, and the site of rows whose file and command name none."""

    column: tuple[str, str, bool, str]
    default: str
    ledgers: frozenset[str]

    def carried_by(self, name: str, kind: str) -> bool:
        return kind in ("raw", "derived") or name in self.ledgers


@cache
def site_column() -> SiteColumn:
    doc = tomllib.loads((resource_path("schemas") / "tables.toml").read_text())["site"]
    return SiteColumn(tuple(doc["column"]), str(doc["default"]),  # type: ignore[arg-type]
                      frozenset(doc.get("ledgers", ())))


def default_site() -> str:
    """The site of rows whose MCAP file and command name none (``default``)."""
    return site_column().default


SITE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
"""A site name: 1-64 letters, digits, ``.``, ``_``, ``-``, starting with a letter or
digit (``--site`` and the ``site`` of an MCAP file's metadata alike)."""
SITE_NAME_RULE = "a site name is 1-64 letters, digits, '.', '_' or '-', starting with a " \
    "letter or digit"


def is_site_name(name: object) -> bool:
    """Whether ``name`` is a valid site name (:data:`SITE_NAME`)."""
    return isinstance(name, str) and SITE_NAME.fullmatch(name) is not None


def has_site(name: str) -> bool:
    """Whether table ``name`` carries the ``site`` column."""
    return SITE in spec(name).schema.names


@cache
def table_specs() -> dict[str, TableSpec]:
    root = resource_path("schemas")
    site = site_column()
    declared: dict[str, dict] = {}
    # tables.toml holds the spine's tables; each sensor family adds tables.d/<family>.toml
    for path in [root / "tables.toml", *sorted((root / "tables.d").glob("*.toml"))]:
        for name, t in tomllib.loads(path.read_text())["tables"].items():
            if name in declared:
                raise ValueError(f"table {name!r} declared twice (again in {path.name})")
            declared[name] = t
    specs = {}
    for name, t in declared.items():
        columns, sort_by = list(t["columns"]), list(t["sort_by"])
        if site.carried_by(name, t["kind"]):  # second column (Delta keeps its statistics)
            columns.insert(1, list(site.column))
            sort_by.append(SITE)
        fields = [
            pa.field(col, _ARROW_TYPES[typ], nullable=nullable, metadata={"doc": doc})
            for col, typ, nullable, doc in columns
        ]
        specs[name] = TableSpec(
            name=name,
            kind=t["kind"],
            doc=t["doc"],
            time_column=t["time_column"],
            sort_by=tuple(sort_by),
            schema=pa.schema(fields, metadata={"doc": t["doc"]}),
        )
    return specs


def spec(name: str) -> TableSpec:
    return table_specs()[name]


def schema(name: str) -> pa.Schema:
    return spec(name).schema


def empty(name: str) -> pa.Table:
    return schema(name).empty_table()


def with_date(table: pa.Table, time_column: str) -> pa.Table:
    """Add/replace the ``date`` partition column: UTC day of an int64-ns column.

    Exact integer floor division (a float64 cast rejects ns times above 2**53 and would
    round times within ~256 ns of midnight into the wrong day). Without nulls, one numpy
    floor division (two new arrays, where Arrow's kernels make six: fresh memory costs
    ~1 ms per MiB here)."""
    ns_per_day = 86_400 * 10**9
    t = table[time_column]
    if t.null_count == 0 and pa.types.is_integer(t.type):
        days = np.floor_divide(t.to_numpy(), ns_per_day).astype(np.int32)
        date = pa.array(days).view(pa.date32())
    else:
        t = pc.cast(t, pa.int64())
        q = pc.divide(t, ns_per_day)  # integer division truncates toward zero
        floor_fix = pc.and_(pc.less(t, 0), pc.not_equal(pc.multiply(q, ns_per_day), t))
        days = pc.subtract(q, pc.cast(floor_fix, pa.int64()))
        date = pc.cast(pc.cast(days, pa.int32()), pa.date32())
    if "date" in table.column_names:
        return table.set_column(table.column_names.index("date"), "date", date)
    return table.append_column("date", date)


class ConstantStrings:
    """String arrays of one repeated value, kept for reuse: :meth:`get` answers a slice
    of one array per value (provenance columns repeat one source file and one topic over
    every decoded group; building them anew per group touches ~8 MB of fresh pages per
    100,000 rows). Holds the ``limit`` values used last; its owner (an ingest's context)
    drops it when done. Thread-safe: decoders of several files may run in threads."""

    def __init__(self, limit: int = 16):
        self._limit = limit
        self._held: dict[str, pa.Array] = {}
        self._lock = threading.Lock()

    def get(self, value: str, n: int) -> pa.Array:
        """``value`` ``n`` times, a slice of the array kept for ``value``."""
        with self._lock:
            held = self._held.pop(value, None)
            if held is None or len(held) < n:
                size = n if held is None else max(n, 2 * len(held))
                held = _repeated(value, size)
            self._held[value] = held  # most recent last
            while len(self._held) > self._limit:
                self._held.pop(next(iter(self._held)))
        return held.slice(0, n)


def constant_strings(value: str, n: int, held: ConstantStrings | None = None) -> pa.Array:
    """``value`` ``n`` times, as a string array: from ``held`` (reused) or built now."""
    return held.get(value, n) if held is not None else _repeated(value, n)


def _repeated(value: str, n: int) -> pa.Array:
    """``value`` ``n`` times, built from its Arrow buffers (``pa.repeat`` copies value by
    value: 11 ms for 100,000 paths of 39 bytes, against ~1 ms plus the fresh pages)."""
    raw = value.encode()
    if len(raw) * n >= 2**31:  # beyond int32 offsets: as before (Arrow's error)
        return pa.repeat(pa.scalar(value, pa.string()), n)
    offsets = (np.arange(n + 1, dtype=np.int64) * len(raw)).astype(np.int32)
    buffers = [None, pa.py_buffer(offsets), pa.py_buffer(raw * n)]
    return pa.Array.from_buffers(pa.string(), n, buffers, null_count=0)


def shape(name: str, data: pa.Table | pl.DataFrame, *, site: str | None = None) -> pa.Table:
    """Cast ``data`` to table ``name``'s schema: select and order columns, add ``date``.
    Missing nullable columns are filled with nulls; a missing non-nullable column
    raises ``KeyError``. Row order is kept (see :func:`conform` to sort).

    ``site``: the value of every row's ``site`` column (replacing any). Without it, a
    missing ``site`` is the default site (``tables.toml [site] default``), as for a file
    naming none: decoders and stages are site-agnostic, and the jobs stamp the file's or
    the batch's site where they stage the rows (``TableStager(site=...)``)."""
    s = spec(name)
    table = data.to_arrow() if isinstance(data, pl.DataFrame) else data
    if "date" in s.schema.names:
        table = with_date(table, s.time_column)
    have = dict(zip(table.column_names, table.columns, strict=True))
    if SITE in s.schema.names and (site is not None or SITE not in have):
        have[SITE] = _repeated(site if site is not None else default_site(), table.num_rows)
    cols = []
    for f in s.schema:
        col = have.get(f.name)
        if col is not None:  # cast only what differs (a no-op cast costs ~20 us of Python)
            cols.append(col if col.type == f.type else col.cast(f.type))
        elif f.nullable:
            cols.append(pa.nulls(table.num_rows, f.type))
        else:
            raise KeyError(f"table {name}: missing required column {f.name!r}")
    return pa.Table.from_arrays(cols, schema=s.schema)


def conform(name: str, data: pa.Table | pl.DataFrame, *, site: str | None = None
            ) -> pa.Table:
    """:func:`shape`, then sort by the table's sort key."""
    out = shape(name, data, site=site)
    sort_by = spec(name).sort_by
    if out.num_rows and sort_by:
        out = out.sort_by([(c, "ascending") for c in sort_by])
    return out


# Units are in the column names (STYLE: `range_m`, `sog_mps`, `time_ns`); the suffix says it.
_UNIT_SUFFIXES: dict[str, str] = {
    "ns": "ns (UTC, since 1970)",
    "s": "s",
    "m": "m",
    "m2": "m^2",
    "mps": "m/s",
    "mps2": "m/s^2",
    "rad": "rad",
    "radps": "rad/s",
    "deg": "deg",
    "bytes": "bytes",
    "per_h": "1/h",
}


def column_unit(name: str) -> str:
    """The unit a column's name carries (``range_m`` -> ``m``), '' when none."""
    if name.endswith("_per_h"):
        return _UNIT_SUFFIXES["per_h"]
    head, _, suffix = name.rpartition("_")
    return _UNIT_SUFFIXES.get(suffix, "") if head else ""


def column_doc(field: pa.Field) -> str:
    """The meaning of a column as declared in schemas/ (``doc``)."""
    return (field.metadata or {}).get(b"doc", b"").decode()


def column_comment(field: pa.Field) -> str:
    """``[unit] meaning``: the text of ``surveil schema`` and of the DuckDB column comments."""
    unit = column_unit(field.name)
    doc = column_doc(field)
    return f"[{unit}] {doc}" if unit else doc


# -- valid ranges of raw rows (tables.toml [valid]) --------------------------------------


@dataclass(frozen=True)
class Validity:
    """``ranges``: ``table.column``, column name or unit suffix (``_ns``) -> closed
    ``(lo, hi)``;
    ``string_max_bytes``: longest string kept, except in ``long_strings``."""

    ranges: dict[str, tuple[float, float]]
    string_max_bytes: int
    long_strings: frozenset[str]

    def range_of(self, column: str, table: str = "") -> tuple[float, float] | None:
        """By ``table.column``, else ``column``, else the unit suffix (``_ns``)."""
        if f"{table}.{column}" in self.ranges:
            return self.ranges[f"{table}.{column}"]
        if column in self.ranges:
            return self.ranges[column]
        suffix = "_" + column.rsplit("_", 1)[-1] if "_" in column else None
        return self.ranges.get(suffix) if suffix else None


@cache
def validity() -> Validity:
    v = tomllib.loads((resource_path("schemas") / "tables.toml").read_text()).get("valid", {})
    return Validity(
        ranges={k: (lo, hi) for k, (lo, hi) in v.get("ranges", {}).items()},
        string_max_bytes=int(v.get("string_max_bytes", 4096)),
        long_strings=frozenset(v.get("long_strings", ())),
    )


def invalid_rows(name: str, table: pa.Table) -> tuple[np.ndarray, list[str]] | None:
    """Rows of ``table`` (a raw table) that break ``tables.toml [valid]``: ``None`` when
    every row is valid, else ``(row indices, reason per row)`` naming the first column
    broken. Vectorised per column; Python only for the reasons of the bad rows."""
    v = validity()
    why: dict[int, str] = {}
    for f in table.schema:
        col = table[f.name]
        if pa.types.is_string(f.type) or pa.types.is_large_string(f.type):
            if f.name in v.long_strings:
                continue
            too_long = pc.fill_null(pc.greater(pc.binary_length(col), v.string_max_bytes), False)
            if not pc.any(too_long).as_py():
                continue
            bad = np.flatnonzero(too_long.to_numpy(zero_copy_only=False))
            lengths = pc.binary_length(col).to_numpy(zero_copy_only=False)
            for i in bad.tolist():
                why.setdefault(i, f"{f.name} is {int(lengths[i])} bytes long "
                                  f"(at most {v.string_max_bytes})")  # fmt: skip
            continue
        rng = v.range_of(f.name, name)
        if rng is None or not (pa.types.is_integer(f.type) or pa.types.is_floating(f.type)):
            continue
        lo, hi = rng
        lo_s = pa.scalar(lo, f.type) if pa.types.is_floating(f.type) else pa.scalar(int(lo))
        hi_s = pa.scalar(hi, f.type) if pa.types.is_floating(f.type) else pa.scalar(int(hi))
        out = pc.fill_null(pc.or_(pc.less(col, lo_s), pc.greater(col, hi_s)), False)
        if not pc.any(out).as_py():
            continue
        bad = np.flatnonzero(out.to_numpy(zero_copy_only=False))
        values = col.take(pa.array(bad)).to_pylist()
        for i, val in zip(bad.tolist(), values, strict=True):
            why.setdefault(i, f"{f.name} = {val!r} outside [{lo!r}, {hi!r}]")
    if not why:
        return None
    idx = np.array(sorted(why), dtype=np.int64)
    return idx, [why[i] for i in idx.tolist()]
