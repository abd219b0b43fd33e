"""Probability of detection of each radar from its update intervals, per target and per
range/azimuth cell: the rows of the ``radar_detection`` table (issue 37).

As OpenATS COMPASS defines it (its "Detection" requirement; research notes §4.3):
PD = 1 − missed update intervals ÷ expected update intervals, counted on each
referenced target while it lies within the radar's range:

- a radar's **updates** of a target are its track reports (sweep times) of the local
  tracks that belong to the target: a local track belongs to the target its
  synchronised points were scored against most often (``track_errors`` radar rows, i.e.
  the reference of the system track it was fused into), and a report counts when it
  lies within ``max_distance_m`` of the target's reference at its time (a tracker that
  swapped targets does not update the first one);
- the target's **in-range runs**: the stretches of consecutive smoothed knots of its
  reference within the site's ``max_range_m`` (to one knot interval at their edges:
  seconds, where a ship needs minutes to cross a range ring);
- in a run, a gap of Δ between consecutive updates holds round(Δ / T) − 1 missed scans
  (the "miss tolerance" of half a period: a late sweep is not a miss), the run's start
  and end floor(Δ / T) each; a run without any update misses all of its scans. Two
  updates less than T / 2 apart are one scan.
- every update and every missed scan is placed in the cell (range bin, azimuth bin of
  the radar, sector) of the reference at its time: updates at their sweep time, missed
  scans evenly inside their gap. (Positions here are the reference's knots interpolated
  linearly, :meth:`~pipeline.maritime.reference.Reference.position`: metres are enough
  for kilometre cells and a 500 m gate, at a fraction of the exact smoother's cost.)
  Summing the cells per radar gives PD per sector (``detection_by_sector``), per cell
  the coverage map (``radar_coverage``).

Counting on update intervals rather than on a fixed scan grid keeps a real radar's
slowly drifting rotation period from turning one late sweep into a miss and an extra
update. The same code runs against simulated truth (every vessel) and against the
reconstructed reference (the vessels carrying AIS), so the two can be compared.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import polars as pl

from pipeline.config import RadarSite, RegionConfig, Sector
from pipeline.frames import geodetic_to_enu
from pipeline.geometry import assign_sectors
from pipeline.maritime.reference import Reference, ref_rows_of
from pipeline.spatial import expand_ranges
from pipeline.units import NS

DETECTION_COLUMNS = (
    "time_ns", "end_time_ns", "site_id", "sector", "range_bin_m", "azimuth_bin_deg",
    "reference", "reference_id", "target_class", "expected_scans", "detected_scans",
)
_SCHEMA = {
    "time_ns": pl.Int64, "end_time_ns": pl.Int64, "site_id": pl.String, "sector": pl.String,
    "range_bin_m": pl.Float64, "azimuth_bin_deg": pl.Float64, "reference": pl.String,
    "reference_id": pl.Int64, "target_class": pl.String, "expected_scans": pl.Int64,
    "detected_scans": pl.Int64,
}


def empty_detection() -> pl.DataFrame:
    return pl.DataFrame(schema=_SCHEMA)


def local_track_targets(associations: pl.DataFrame, errors: pl.DataFrame) -> pl.DataFrame:
    """(site_id, local_track_id) -> reference_id: the target its synchronised points were
    scored against most often (ties: the smaller id)."""
    radar = errors.filter(pl.col("source") != "fused").select(
        "time_ns", "system_track_id", pl.col("source").alias("site_id"), "reference_id")
    if radar.height == 0 or associations.height == 0:
        return pl.DataFrame(schema={"site_id": pl.String, "local_track_id": pl.Int64,
                                    "reference_id": pl.Int64})
    j = associations.select("time_ns", "system_track_id", "site_id", "local_track_id").join(
        radar, on=["time_ns", "system_track_id", "site_id"], how="inner")
    return (j.group_by("site_id", "local_track_id", "reference_id").agg(pl.len().alias("n"))
            .sort("site_id", "local_track_id", "n", "reference_id",
                  descending=[False, False, True, False])
            .unique(["site_id", "local_track_id"], keep="first", maintain_order=True)
            .select("site_id", "local_track_id", "reference_id"))


def radar_detection(
    aligned: pl.DataFrame,
    associations: pl.DataFrame,
    errors: pl.DataFrame,
    reference: Reference,
    *,
    sites: Sequence[RadarSite],
    sectors: Sequence[Sector],
    region: RegionConfig,
    classes: pl.DataFrame | None,
    start_ns: int,
    end_ns: int,
    max_distance_m: float,
    range_bin_m: float,
    azimuth_bin_deg: float,
) -> pl.DataFrame:
    """The ``radar_detection`` rows of [start_ns, end_ns) (module docstring).

    ``aligned``: the radar reports in the regional frame (time_ns = sweep time, site_id,
    local_track_id, x_enu_m, y_enu_m); ``associations`` and ``errors``: the unit's
    synchronised points and their scores; ``classes``: (reference_id, target_class) or
    None."""
    if reference.rows == 0 or not sites:
        return empty_detection()
    owner = local_track_targets(associations, errors)
    rep = aligned.select("time_ns", "site_id", "local_track_id", "x_enu_m", "y_enu_m").join(
        owner, on=["site_id", "local_track_id"], how="inner")
    site_ids = [s.site_id for s in sites]
    e, n = geodetic_to_enu(np.array([s.lat_deg for s in sites]),
                           np.array([s.lon_deg for s in sites]),
                           region.origin_lat_deg, region.origin_lon_deg)
    sx, sy = np.atleast_1d(e), np.atleast_1d(n)
    period = np.array([s.scan_period_s for s in sites])
    max_range = np.array([s.max_range_m for s in sites])
    # candidate (site, reference row) pairs: some knot within reach of the site
    pair_site, pair_row = _pairs_in_range(reference, sx, sy, max_range)
    if pair_site.size == 0:
        return empty_detection()
    T_ns = np.rint(period[pair_site] * NS).astype(np.int64)
    # each pair's knots in range of its site or not; runs of in-range knots
    kt, kx, ky, kstart, klen = reference.knots()
    pid, j = expand_ranges(np.zeros(pair_site.size, np.int64), klen[pair_row])
    idx = kstart[pair_row[pid]] + j
    g_t = kt[idx]
    g_in = np.hypot(kx[idx] - sx[pair_site[pid]], ky[idx] - sy[pair_site[pid]]) \
        <= max_range[pair_site[pid]]
    brk = np.r_[True, (pid[1:] != pid[:-1]) | (g_in[1:] != g_in[:-1])]
    run_all = np.cumsum(brk) - 1
    first_of = np.flatnonzero(brk)
    last_of = np.r_[first_of[1:] - 1, run_all.size - 1]
    run_in = g_in[first_of]
    run_pair = pid[first_of]
    run_start, run_end = g_t[first_of], g_t[last_of]
    in_run = np.flatnonzero(run_in)
    # updates: the reports of the pair's site and target inside one of its in-range runs
    u_pair, u_t, u_x, u_y = _updates(rep, reference, site_ids, pair_site, pair_row, sx, sy,
                                     max_distance_m)
    t_all_ = np.r_[g_t, u_t]
    t_base = int(t_all_.min())
    span = int(t_all_.max() - t_base) + 1
    if span >= 1 << 44:
        raise ValueError("radar_detection: a unit spans more than 4.8 h")
    run_key = run_pair * (1 << 44) + (run_start - t_base)
    c = np.searchsorted(run_key, u_pair * (1 << 44) + (u_t - t_base), "right") - 1
    c = np.maximum(c, 0)
    ok = (run_pair[c] == u_pair) & run_in[c] & (u_t <= run_end[c] + T_ns[u_pair] // 2)
    u_run, u_t, u_x, u_y = c[ok], u_t[ok], u_x[ok], u_y[ok]
    order = np.lexsort((u_t, u_run))
    u_run, u_t, u_x, u_y = u_run[order], u_t[order], u_x[order], u_y[order]
    # one update per scan: drop an update within T/2 of the previous one of its run
    T_run = T_ns[run_pair]
    run_end = run_end + T_run  # a run covers its last knot's scan
    dup = np.r_[False, (u_run[1:] == u_run[:-1])
                & (np.diff(u_t) < T_run[u_run[1:]] // 2)][:u_run.size]
    u_run, u_t, u_x, u_y = u_run[~dup], u_t[~dup], u_x[~dup], u_y[~dup]
    # missed scans: interior gaps, heads, tails, runs without updates
    miss_run, miss_t = _misses(u_run, u_t, in_run, run_start, run_end, T_run)
    # everything in cells: updates where the reference was at their sweep, missed scans
    # where it was then (one more interpolation, for the misses only)
    mx, my = reference.position(pair_row[run_pair[miss_run]], miss_t)
    t_all = np.r_[u_t, miss_t]
    r_all = np.r_[u_run, miss_run]
    px, py = np.r_[u_x, mx], np.r_[u_y, my]
    det = np.r_[np.ones(u_t.size, bool), np.zeros(miss_t.size, bool)]
    inside = (t_all >= start_ns) & (t_all < end_ns)
    t_all, r_all, det, px, py = t_all[inside], r_all[inside], det[inside], px[inside], \
        py[inside]
    if t_all.size == 0:
        return empty_detection()
    p_all = run_pair[r_all]
    s_all, row_all = pair_site[p_all], pair_row[p_all]
    dx, dy = px - sx[s_all], py - sy[s_all]
    rng = np.hypot(dx, dy)
    az = np.degrees(np.arctan2(dx, dy)) % 360.0
    cells = pl.DataFrame({
        "site": s_all, "x_enu_m": px, "y_enu_m": py,
        "range_bin_m": np.floor(rng / range_bin_m) * range_bin_m,
        "azimuth_bin_deg": np.floor(az / azimuth_bin_deg) * azimuth_bin_deg,
        "reference_id": reference.target[row_all], "detected": det,
    }, schema_overrides={"reference_id": pl.Int64})
    cells = assign_sectors(cells, sectors, region)
    out = cells.group_by("site", "sector", "range_bin_m", "azimuth_bin_deg",
                         "reference_id").agg(
        pl.len().cast(pl.Int64).alias("expected_scans"),
        pl.col("detected").sum().cast(pl.Int64).alias("detected_scans"))
    out = out.with_columns(pl.col("site").replace_strict(
        list(range(len(site_ids))), site_ids, return_dtype=pl.String).alias("site_id"))
    if classes is not None and classes.height:
        out = out.join(classes.select("reference_id", "target_class").unique("reference_id"),
                       on="reference_id", how="left")
    else:
        out = out.with_columns(pl.lit(None, pl.String).alias("target_class"))
    return out.with_columns(
        pl.lit(int(start_ns), pl.Int64).alias("time_ns"),
        pl.lit(int(end_ns), pl.Int64).alias("end_time_ns"),
        pl.lit(reference.kind).alias("reference"),
    ).select(DETECTION_COLUMNS).cast(_SCHEMA).sort(
        "time_ns", "site_id", "sector", "range_bin_m", "azimuth_bin_deg", "reference_id",
        nulls_last=True)


def _pairs_in_range(reference: Reference, sx: np.ndarray, sy: np.ndarray,
                    max_range: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(site, row) pairs with some knot of the row within 1.1 x the site's range."""
    pk, fit = reference.pk, reference.fit
    r_idx, c_idx = pk.cells()
    x, y = fit.ps[r_idx, c_idx, 0], fit.ps[r_idx, c_idx, 1]
    d = np.hypot(x[:, None] - sx[None, :], y[:, None] - sy[None, :])  # (knots, sites)
    near = d <= 1.1 * max_range[None, :]
    hit = np.zeros((reference.rows, sx.size), bool)
    kk, ss = np.nonzero(near)
    hit[r_idx[kk], ss] = True
    row, site = np.nonzero(hit)
    order = np.lexsort((row, site))
    return site[order], row[order]


def _updates(rep: pl.DataFrame, reference: Reference, site_ids: list[str],
             pair_site: np.ndarray, pair_row: np.ndarray, sx: np.ndarray, sy: np.ndarray,
             max_distance_m: float) -> tuple[np.ndarray, ...]:
    """(pair index, sweep time, reference x, y there) of each report that updates its local
    track's target."""
    if rep.height == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0), np.empty(0)
    t = rep["time_ns"].to_numpy()
    target = rep["reference_id"].to_numpy()
    row = ref_rows_of(reference, target, t)
    site = rep["site_id"].replace_strict(site_ids, list(range(len(site_ids))), default=-1,
                                         return_dtype=pl.Int64).to_numpy()
    ok = (row >= 0) & (site >= 0)
    t, row, site = t[ok], row[ok], site[ok]
    x, y = rep["x_enu_m"].to_numpy()[ok], rep["y_enu_m"].to_numpy()[ok]
    px, py = reference.position(row, t)
    near = np.hypot(x - px, y - py) <= max_distance_m
    t, row, site, px, py = t[near], row[near], site[near], px[near], py[near]
    # pair index of (site, row): pairs are sorted by (site, row)
    key = pair_site * (reference.rows + 1) + pair_row
    q = site * (reference.rows + 1) + row
    pos_i = np.searchsorted(key, q)
    found = (pos_i < key.size) & (key[np.minimum(pos_i, key.size - 1)] == q)
    return pos_i[found], t[found], px[found], py[found]


def _misses(u_run: np.ndarray, u_t: np.ndarray, runs: np.ndarray, run_start: np.ndarray,
            run_end: np.ndarray, T_run: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(run, time) of every missed scan (module docstring)."""
    parts_r, parts_t = [], []
    if u_t.size:
        same = u_run[1:] == u_run[:-1]
        gap = np.diff(u_t)
        i = np.flatnonzero(same)
        T = T_run[u_run[i]]
        n = np.maximum(np.rint(gap[i] / T).astype(np.int64) - 1, 0)
        rr, jj = expand_ranges(np.zeros(i.size, np.int64), n)
        parts_r.append(u_run[i][rr])
        parts_t.append(u_t[i][rr] + (jj + 1) * gap[i][rr] // (n[rr] + 1))
        # heads and tails
        firsts = np.flatnonzero(np.r_[True, ~same])
        lasts = np.flatnonzero(np.r_[~same, True])
        for idx, sign, edge in ((firsts, -1, run_start), (lasts, 1, run_end)):
            r = u_run[idx]
            span = np.abs(u_t[idx] - np.where(sign < 0, edge[r], edge[r] - 1))
            n = span // T_run[r]
            rr, jj = expand_ranges(np.zeros(idx.size, np.int64), n)
            parts_r.append(r[rr])
            parts_t.append(u_t[idx][rr] + sign * (jj + 1) * T_run[r][rr])
    # runs without any update: every scan missed, at the middle of each slot
    empty = np.setdiff1d(runs, np.unique(u_run))
    n = (run_end[empty] - run_start[empty]) // T_run[empty]
    rr, jj = expand_ranges(np.zeros(empty.size, np.int64), n)
    parts_r.append(empty[rr])
    parts_t.append(run_start[empty][rr] + jj * T_run[empty][rr] + T_run[empty][rr] // 2)
    if not parts_r:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    return np.concatenate(parts_r), np.concatenate(parts_t)
