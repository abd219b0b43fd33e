"""Forecasts across data gaps: where is a ship that has not been seen for a while?

Distributed maritime observation paper (``seeds/``, rough Russian OCR), eq. 1 and 3-7.

1. **Messages** (eq. 1): every observation of a vessel becomes the paper's message
   vector C_ij = [i, j, K, phi, lambda, h, k, v, P, t]: source i (``ais`` or
   ``system_track``), object j (the MMSI), class K (AIS class A/B, or ``radar``),
   position, course, speed, flags P (new / manoeuvre / lost) and time, with the
   position covariance of eq. 2 (sigma_x^2, sigma_y^2, K_xy) and course/speed sigmas.
   AIS reports carry the configured AIS sigmas; fused system tracks that the maritime
   batch identified (``system_tracks.mmsi``) carry their own.
2. **Gaps**: a vessel unobserved for longer than ``gap_threshold_s`` between two
   messages (or from its last message to the end of the data read) is in a gap.
3. **Filter**: a bootstrap particle filter (:mod:`pipeline.filters.particle`) is run
   over the vessel's last messages before the gap (the "lead-in": likelihood eq. 6,
   weights eq. 7) and then carried across the gap with the exogenous constraint only:
   u_k uniform over the admissible area (water minus islands, config polygons), zero
   outside, so particles that reach land get weight 0, are resampled away, and, when
   nothing admissible is left, more particles are drawn from the prior (the paper's
   remedy for degenerate weights; then a wider "manoeuvre" prior).
4. **Forecasts** at configured lead times after the gap start and at the gap's end
   (when the vessel reappears): the particle mean and covariance, the 90% region (a
   highest-density region of the particle cloud, Hyndman 1996), and the probability
   of each named zone = the share of particle mass in it (the paper: "the posterior
   probability of reaching a zone is estimated as the share of sample values in it").
   When simulated truth exists, the true position at the forecast time, its error and
   whether it fell in the 90% region; at the gap end without truth, the reappearing
   message is the reference.

Every function here is pure: tables, window and config in, tables out; randomness
only from the ``rng`` argument.
"""

from __future__ import annotations

import json
import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import polars as pl

from pipeline import frames, tables
from pipeline.config import Config, RegionConfig
from pipeline.gaps.config import GapsConfig
from pipeline.gaps.geometry import GapsGeometry, build_geometry
from pipeline.gaps.messages import detect_gaps, gap_messages, lead_in, plan_forecasts
from pipeline.gaps.propagate import Reference, lead_in_arrays, propagate_gaps, run_lead_in
from pipeline.geometry import assign_sectors
from pipeline.units import NS

OUTSIDE_ZONES = "(outside zones)"
"""Key of the probability mass outside every named zone in ``zone_probabilities_json``."""


# --- references: truth, or the reappearing message ---------------------------------


def truth_at(plan: pl.DataFrame, truth: pl.DataFrame | None) -> pl.DataFrame:
    """Truth of each plan row's vessel (by MMSI) at its forecast time, linearly
    interpolated between the neighbouring truth samples (at most 2 s away).
    Columns: plan_row, true_lat_deg, true_lon_deg (null when no truth)."""
    q = plan.select("plan_row", "mmsi", "forecast_time_ns").sort("forecast_time_ns")
    if truth is None or truth.height == 0:
        return q.select(
            "plan_row",
            pl.lit(None, pl.Float64).alias("true_lat_deg"),
            pl.lit(None, pl.Float64).alias("true_lon_deg"),
        )
    t = (
        truth.filter(pl.col("mmsi").is_not_null())
        .select("mmsi", pl.col("time_ns").alias("t"), "lat_deg", "lon_deg")
        .sort("t")
    )
    tol = 2 * NS
    b = q.join_asof(
        t,
        left_on="forecast_time_ns",
        right_on="t",
        by="mmsi",
        strategy="backward",
        tolerance=tol,
        check_sortedness=False,
    )
    a = q.join_asof(
        t,
        left_on="forecast_time_ns",
        right_on="t",
        by="mmsi",
        strategy="forward",
        tolerance=tol,
        check_sortedness=False,
    ).select(
        "plan_row",
        pl.col("t").alias("t1"),
        pl.col("lat_deg").alias("lat1"),
        pl.col("lon_deg").alias("lon1"),
    )
    m = b.join(a, on="plan_row")
    span = (pl.col("t1") - pl.col("t")).cast(pl.Float64)
    frac = pl.when(span > 0).then((pl.col("forecast_time_ns") - pl.col("t")) / span).otherwise(0.0)
    return m.select(
        "plan_row",
        pl.coalesce(
            pl.col("lat_deg") + frac * (pl.col("lat1") - pl.col("lat_deg")), pl.col("lat1")
        ).alias("true_lat_deg"),
        pl.coalesce(
            pl.col("lon_deg") + frac * (pl.col("lon1") - pl.col("lon_deg")), pl.col("lon1")
        ).alias("true_lon_deg"),
    )


def references(plan: pl.DataFrame, obs: pl.DataFrame, truth: pl.DataFrame | None) -> pl.DataFrame:
    """Reference position of each plan row: truth when the log has it, else (at the gap
    end) the reappearing message. Columns: plan_row, reference, true_lat/lon_deg."""
    tr = truth_at(plan, truth)
    seen = obs.select(
        "mmsi",
        pl.col("time_ns").alias("forecast_time_ns"),
        pl.col("lat_deg").alias("obs_lat"),
        pl.col("lon_deg").alias("obs_lon"),
    ).unique(["mmsi", "forecast_time_ns"], keep="first")
    ends = (
        plan.filter(pl.col("forecast_kind") == "gap_end")
        .join(seen, on=["mmsi", "forecast_time_ns"], how="inner")
        .select("plan_row", "obs_lat", "obs_lon")
    )
    return (
        plan.select("plan_row")
        .join(tr, on="plan_row", how="left")
        .join(ends, on="plan_row", how="left")
        .select(
            "plan_row",
            pl.when(pl.col("true_lat_deg").is_not_null())
            .then(pl.lit("truth"))
            .when(pl.col("obs_lat").is_not_null())
            .then(pl.lit("observation"))
            .otherwise(pl.lit(None, pl.String))
            .alias("reference"),
            pl.coalesce("true_lat_deg", "obs_lat").alias("true_lat_deg"),
            pl.coalesce("true_lon_deg", "obs_lon").alias("true_lon_deg"),
        )
        .sort("plan_row")
    )


# --- the stage -----------------------------------------------------------------------


def empty_forecasts() -> pl.DataFrame:
    """No forecasts: an empty frame with the ``gap_forecasts`` columns."""
    return pl.from_arrow(tables.empty("gap_forecasts"))


def forecast_gaps(
    ais_reports: pl.DataFrame,
    system_tracks: pl.DataFrame | None,
    truth: pl.DataFrame | None,
    *,
    cfg: Config,
    gaps_cfg: GapsConfig,
    start_ns: int,
    end_ns: int,
    data_end_ns: int,
    rng: np.random.Generator,
    threads: int = 1,
) -> pl.DataFrame:
    """``gap_forecasts`` rows with forecast time in [start_ns, end_ns).

    Inputs: AIS position reports and fused system tracks (only those with an MMSI are
    used) from ``gaps_cfg.lookback_s`` before the window to ``data_end_ns`` (how far the
    caller read: a silence running to there is an open gap), and truth over the window
    (or None). Pure: the same inputs and rng state give the same rows, whatever
    ``threads`` (how many batches of gaps run at once).
    """
    g = gaps_cfg
    last_seen = _last_message_ns(ais_reports, system_tracks)
    if last_seen is None:
        return empty_forecasts()
    data_end = min(int(data_end_ns), last_seen)
    obs = gap_messages(ais_reports, system_tracks, ais=cfg.ais, gaps=g, region=cfg.region,
                       data_end_ns=data_end)
    gaps = detect_gaps(obs, threshold_s=g.gap_threshold_s, data_end_ns=data_end)
    geometry = build_geometry(g, cfg.region)
    gaps = in_water(gaps, obs, geometry, g.water_margin_m)
    plan = plan_forecasts(gaps, g, start_ns=start_ns, end_ns=end_ns).with_row_index("plan_row")
    if plan.height == 0:
        return empty_forecasts()
    refs = references(plan, obs, truth)
    rx, ry = frames.geodetic_to_enu(
        refs["true_lat_deg"].fill_null(np.nan).to_numpy(),
        refs["true_lon_deg"].fill_null(np.nan).to_numpy(),
        cfg.region.origin_lat_deg,
        cfg.region.origin_lon_deg,
    )
    ref = Reference(np.atleast_1d(rx), np.atleast_1d(ry))
    leads = lead_in(obs, gaps, g)
    gap_ids = np.unique(plan["gap_id"].to_numpy())
    batches = [gap_ids[i : i + g.batch_gaps] for i in range(0, gap_ids.size, g.batch_gaps)]
    # one random stream per batch (spawned in batch order): the rows do not depend on
    # how many threads run the batches, nor in which order they finish
    streams = rng.spawn(len(batches))

    def run(batch: np.ndarray, stream: np.random.Generator) -> dict[str, np.ndarray]:
        return _run_batch(batch, plan, leads, g, geometry, cfg.region, ref, stream)

    if threads > 1 and len(batches) > 1:
        # the particle arithmetic (numpy's loops, the C transition) runs without the GIL:
        # 2 threads take a dense hour's unit from ~22-30 to ~15-18 s on 2 cores
        # (docs/scale.md, perf24)
        with ThreadPoolExecutor(min(threads, len(batches)), "gaps-batch") as pool:
            records = list(pool.map(run, batches, streams))
    else:
        records = [run(b, s) for b, s in zip(batches, streams, strict=True)]
    stats = {k: np.concatenate([r[k] for r in records]) for k in records[0]}
    return _assemble(plan, gaps, leads, refs, ref, stats, g, geometry, cfg)


def in_water(gaps: pl.DataFrame, obs: pl.DataFrame, geometry: GapsGeometry,
             margin_m: float) -> pl.DataFrame:
    """The gaps of vessels inside the configured water: the last message before the gap
    lies in the admissible area, or at most ``margin_m`` outside it (a port at the
    water's edge). A vessel elsewhere (another sea: AIS of a place the config does not
    describe, a receiver hearing ships far inland) has no admissible start for its
    particles: its forecasts would all be ``infeasible`` (18,543 of a real AIS day's
    with the demo config, 204 of its 219 s of batch). Every gap without a constraint."""
    if geometry.water is None or gaps.height == 0:
        return gaps
    last = obs.select("mmsi", pl.col("time_ns").alias("gap_start_ns"), "x_enu_m",
                      "y_enu_m").unique(["mmsi", "gap_start_ns"], keep="first",
                                        maintain_order=True)
    at = gaps.join(last, on=["mmsi", "gap_start_ns"], how="left", maintain_order="left")
    keep = geometry.near(at["x_enu_m"].fill_null(np.nan).to_numpy(),
                         at["y_enu_m"].fill_null(np.nan).to_numpy(), margin_m)
    return gaps.filter(pl.Series(keep))


def _last_message_ns(ais_reports: pl.DataFrame, system_tracks: pl.DataFrame | None) -> int | None:
    """Time of the last AIS report or identified system track; None when there is none."""
    times = [ais_reports["time_ns"].max()]
    if system_tracks is not None:
        identified = pl.col("time_ns").filter(pl.col("mmsi").is_not_null())
        times.append(system_tracks.select(identified.max()).item())
    times = [t for t in times if t is not None]
    return int(max(times)) if times else None


def _run_batch(
    gap_ids: np.ndarray,
    plan: pl.DataFrame,
    leads: pl.DataFrame,
    g: GapsConfig,
    geometry: GapsGeometry,
    region: RegionConfig,
    ref: Reference,
    rng: np.random.Generator,
) -> dict[str, np.ndarray]:
    """Lead-in filter and gap propagation for one batch of gaps (vectorised over them)."""
    li = lead_in_arrays(leads, gap_ids, g.max_lead_in_obs)
    x, logw = run_lead_in(li, g, geometry, rng)
    mine = plan.filter(pl.col("gap_id").is_in(gap_ids.tolist())).with_columns(
        (pl.col("lead_ns") / NS).round(3).alias("lead_s")
    )
    schedule = [
        (
            float(lead),
            np.searchsorted(gap_ids, part["gap_id"].to_numpy()),
            part["plan_row"].to_numpy(),
        )
        for (lead,), part in mine.group_by(["lead_s"], maintain_order=True)
    ]
    schedule.sort(key=lambda s: s[0])
    return propagate_gaps(x, logw, schedule, g, geometry, region, ref, rng)


def _assemble(
    plan: pl.DataFrame,
    gaps: pl.DataFrame,
    leads: pl.DataFrame,
    refs: pl.DataFrame,
    ref: Reference,
    stats: dict[str, np.ndarray],
    g: GapsConfig,
    geometry: GapsGeometry,
    cfg: Config,
) -> pl.DataFrame:
    order = np.argsort(stats["plan_row"])
    st = {k: v[order] for k, v in stats.items()}
    zone_names = [name for name, _ in geometry.zones] + [OUTSIDE_ZONES]
    zp = st.pop("zone_p")
    if not geometry.zones:
        zone_names = [OUTSIDE_ZONES]
    best = np.argmax(zp, axis=1)
    true_zone = geometry.zone_index(ref.x, ref.y)[st["plan_row"]]
    has_ref = np.isfinite(ref.x[st["plan_row"]])
    err = np.hypot(st["x_enu_m"] - ref.x[st["plan_row"]], st["y_enu_m"] - ref.y[st["plan_row"]])
    n_lead = leads.group_by("gap_id").len("lead_in_messages")
    status = _constraint_status(st, g, geometry)
    st.pop("constraint_infeasible")
    frame = pl.DataFrame(
        {
            **{k: v for k, v in st.items() if k != "true_in_region90"},
            "zone_probabilities_json": [
                json.dumps({n: round(float(p), 4) for n, p in zip(zone_names, row, strict=True)})
                for row in zp
            ],  # one JSON document per output row
            "most_likely_zone": pl.Series(
                np.array(zone_names, dtype=object)[best].tolist(), dtype=pl.String
            ),
            "most_likely_zone_probability": zp[np.arange(zp.shape[0]), best],
            "constraint_status": pl.Series(status.tolist(), dtype=pl.String),
            "true_in_region": pl.Series(
                np.where(has_ref, st["true_in_region90"], None).tolist(), dtype=pl.Boolean
            ),
            "true_zone": pl.Series(
                np.where(
                    has_ref,
                    np.array(zone_names, dtype=object)[np.minimum(true_zone, len(zone_names) - 1)],
                    None,
                ).tolist(),
                dtype=pl.String,
            ),
            "true_zone_probability": np.where(
                has_ref, zp[np.arange(zp.shape[0]), np.minimum(true_zone, zp.shape[1] - 1)], np.nan
            ),
            "error_m": np.where(has_ref, err, np.nan),
            "expected_error_m": np.where(has_ref, st["expected_error_m"], np.nan),
        },
        strict=False,
    )
    out = (
        plan.join(frame, left_on="plan_row", right_on="plan_row", how="inner")
        .join(gaps.with_row_index("gap_id"), on=["gap_id", "mmsi", "gap_start_ns"], how="left")
        .join(n_lead, on="gap_id", how="left")
        .join(refs, on="plan_row", how="left")
        .with_columns(
            (pl.col("lead_ns") / NS).alias("lead_s"),
            pl.lit(g.particles).alias("n_particles"),
            pl.lit(g.region_probability).alias("region_probability"),
            (pl.col("region_area_m2") / math.pi).sqrt().alias("region_radius_m"),
            (pl.col("constraint_mass_removed") > 0).alias("constraint_active"),
            pl.col("error_m").fill_nan(None),
            pl.col("true_zone_probability").fill_nan(None),
            pl.col("expected_error_m").fill_nan(None),
        )
    )
    tx, ty = frames.geodetic_to_enu(
        out["true_lat_deg"].fill_null(np.nan).to_numpy(),
        out["true_lon_deg"].fill_null(np.nan).to_numpy(),
        cfg.region.origin_lat_deg,
        cfg.region.origin_lon_deg,
    )
    out = out.with_columns(
        pl.Series("true_x_enu_m", np.atleast_1d(tx)).fill_nan(None),
        pl.Series("true_y_enu_m", np.atleast_1d(ty)).fill_nan(None),
    )
    return assign_sectors(out, cfg.sectors, cfg.region)


def _constraint_status(
    st: dict[str, np.ndarray], g: GapsConfig, geometry: GapsGeometry
) -> np.ndarray:
    """off | inactive | active | replenished | infeasible, per row (most severe wins)."""
    if not g.constrain or geometry.water is None:
        return np.full(st["plan_row"].size, "off", dtype=object)
    return np.select(
        [
            st["constraint_infeasible"],
            st["prior_draw_rounds"] > 0,
            st["constraint_mass_removed"] > 0,
        ],
        ["infeasible", "replenished", "active"],
        default="inactive",
    ).astype(object)
