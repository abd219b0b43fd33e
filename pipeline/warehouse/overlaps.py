"""Two sources in one warehouse: files that carry the same topic over overlapping times.

Two archives of different sites (or one archive ingested twice under two paths) mix
silently in every table keyed by topic, track number or ship id: a fused picture of two
estuaries, truth ids that collide. Ingest looks each new file's channels up in
``mcap_index`` (per file and topic: the span of the chunks holding it) and records every
other file with the same topic over an overlapping span in ``source_overlaps``; the
ingest summary warns.

Only files of the same site overlap: two sites' archives over the same hours are the
normal case (each site's rows are batched and reported apart, ids unique per site); two
sources of one site over the same topic and times are the mixing this guards against.
Channels whose times are synthetic (files without any time: 1970-01-01 plus 1 ms per
line; undated times of day) overlap nothing: their times say nothing about when.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterable
from pathlib import Path

import polars as pl

from pipeline.tables import conform, empty
from pipeline.time_sources import channel_synthetic
from pipeline.warehouse.delta import read_table, replace_rows, sql_literal


def find_overlaps(warehouse: Path, files: Iterable[str]) -> pl.DataFrame:
    """``source_overlaps`` rows of ``files`` against every other file of ``mcap_index``."""
    wanted = sorted(set(files))
    cols = ["source_file", "site", "topic", "start_time_ns", "end_time_ns", "metadata_json"]
    index = pl.from_arrow(read_table(warehouse, "mcap_index", columns=cols)).drop_nulls(
        ["source_file", "site", "topic", "start_time_ns", "end_time_ns"])
    index = index.filter(~index["metadata_json"].map_elements(
        _synthetic, return_dtype=pl.Boolean, skip_nulls=False)).drop("metadata_json")
    mine = index.filter(pl.col("source_file").is_in(wanted))
    if mine.height == 0:
        return pl.from_arrow(empty("source_overlaps"))
    pairs = mine.join(index, on=["site", "topic"], suffix="_other").filter(
        (pl.col("source_file") != pl.col("source_file_other"))
        & (pl.col("start_time_ns") < pl.col("end_time_ns_other"))
        & (pl.col("start_time_ns_other") < pl.col("end_time_ns")))
    return pairs.select(
        "source_file", "site", "topic", pl.col("source_file_other").alias("other_file"),
        pl.max_horizontal("start_time_ns", "start_time_ns_other").alias("overlap_start_ns"),
        pl.min_horizontal("end_time_ns", "end_time_ns_other").alias("overlap_end_ns"),
        pl.lit(time.time_ns(), pl.Int64).alias("detected_at_ns"),
    ).sort("source_file", "topic", "other_file")


def _synthetic(metadata_json: str | None) -> bool:
    """A channel whose times are synthetic (:func:`pipeline.time_sources.
    channel_synthetic`) overlaps nothing: two files without times both start at 1970. Per
    channel in Python: one JSON object per file and topic."""
    try:
        meta = json.loads(metadata_json or "{}")
    except ValueError:
        return False
    return channel_synthetic(meta if isinstance(meta, dict) else {})


def record_overlaps(warehouse: Path, files: Iterable[str]) -> pl.DataFrame:
    """Find the overlaps of ``files`` and replace their rows in ``source_overlaps`` (one
    commit; none when there is nothing to write or remove). Returns them."""
    wanted = sorted(set(files))
    found = find_overlaps(warehouse, wanted)
    had = read_table(warehouse, "source_overlaps", columns=["source_file"])
    stale = set(had["source_file"].to_pylist()) & set(wanted)
    if found.height or stale:
        in_list = ", ".join(sql_literal(f) for f in wanted)
        replace_rows(warehouse, "source_overlaps", conform("source_overlaps", found),
                     predicate_sql=f"source_file IN ({in_list})")
    return found


def synthetic_time_channels(warehouse: Path, files: Iterable[str]) -> list[tuple[str, str, str]]:
    """``(file, topic, log_time_source)`` of the channels of ``files`` whose times are
    synthetic (:func:`pipeline.time_sources.channel_synthetic`), for the ingest
    warning."""
    wanted = set(files)
    cols = ["source_file", "topic", "metadata_json"]
    index = pl.from_arrow(read_table(warehouse, "mcap_index", columns=cols))
    out = []
    for f, topic, meta_json in index.filter(pl.col("source_file").is_in(sorted(wanted))).sort(
            "source_file", "topic").iter_rows():
        if _synthetic(meta_json):
            meta = json.loads(meta_json or "{}")
            out.append((f, topic, str(meta.get("log_time_source") or "?")))
    return out

