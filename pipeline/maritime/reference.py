"""Reconstructed reference trajectories of the vessels carrying AIS, and the reference the
maritime evaluation scores against: simulated truth when the log has it, else these.

On a real archive there is no truth. As OpenATS COMPASS's reconstructor and SASS-C do,
each target gets a reference trajectory smoothed over the whole interval from its
cooperative sensor, with its own uncertainty (``pipeline.filters.smoother``):

1. **Reports** (:func:`ais_measurements`): the AIS position reports of each MMSI the
   channel integrity kept (an AIS transponder in fault is no reference), in the regional
   frame, duplicates (the same MMSI at the same time, e.g. two receivers) dropped;
   velocity from SOG/COG where both are available, with per-axis variance
   max(σ_SOG², (SOG σ_COG)²); position variance from ``[ais] sigma_position_m`` to start.
2. **Segments**: a target's reports split where two of them are more than ``max_gap_s``
   apart: no reference is interpolated across a long silence.
3. **AIS position noise** of each segment from its reports alone, before any filter:
   the difference-based estimator of Gasser, Sroka & Jennen-Steinmetz (1986)
   (:func:`pipeline.filters.smoother.difference_variance`; median form, robust to turns
   and outliers), clipped to [0.5, 30] m; the config's ``[ais] sigma_position_m`` for a
   segment of fewer than 5 reports. The reference's covariance is then that of the data
   actually seen, on the simulator (3 m GNSS) and on a real receiver. (A first version
   ran the smoother twice, re-estimating R in between by one EM step; the difference
   estimate gives the same sigmas, ±0.1 m on the channel scenario, at half the cost.)
4. **Gating and manoeuvres** (:func:`pipeline.filters.smoother.imm_forward`): outliers
   marked, the segment split where the filter restarted after a jump; the manoeuvre
   probability of each report from the forward IMM, moved back over the
   ``MANOEUVRE_LOOKAHEAD`` reports before it (the forward filter notices a turn a few
   reports late; a backward IMM pass, :func:`pipeline.filters.smoother.
   manoeuvre_probability`, gives the same on the channel scenario at twice the cost).
   Then the RTS smoother of the model whose process noise follows that probability.
5. **Between reports** the exact smoother at the query time
   (:func:`pipeline.filters.smoother.interpolate`), up to ``extrapolate_s`` beyond a
   segment's ends; a reference whose own 95 % error exceeds ``max_p95_m`` is not used.

The knots (one row per AIS report, outliers included and marked) are the
``reference_tracks`` table. :class:`Reference` holds them (or the truth, through
:func:`truth_reference`) for the evaluation: positions, velocities and covariances at
any times, and the nearest reference to a point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import polars as pl

from pipeline.config import AisConfig, RegionConfig
from pipeline.filters import smoother as sm
from pipeline.frames import enu_to_geodetic, geodetic_to_enu
from pipeline.maritime.config import ReferenceConfig
from pipeline.spatial import expand_ranges, pairs_within
from pipeline.units import NS

TRUTH, RECONSTRUCTED = "truth", "reconstructed"
SIGMA_MIN_M, SIGMA_MAX_M = 0.5, 30.0
MANOEUVRE_LOOKAHEAD = 3
"""Reports ahead whose forward manoeuvre probability a report takes (the forward IMM
notices a turn a few reports after it began: :func:`pipeline.filters.smoother.lookahead_max`)."""
TRUTH_Q = 1e-6
"""Process noise of the truth "smoother" (m²/s³): its knots are exact, so between the
1-s samples this interpolates position and velocity (a cubic), with no error."""

REFERENCE_COLUMNS = (
    "time_ns", "reference_id", "segment", "ais_class", "x_enu_m", "y_enu_m", "lat_deg",
    "lon_deg", "vx_mps", "vy_mps", "sigma_x_m", "sigma_y_m", "sigma_vx_mps", "sigma_vy_mps",
    "p95_m", "manoeuvre_probability", "outlier", "residual_east_m", "residual_north_m",
    "loo_residual_m", "sigma_position_m",
)
_SCHEMA = {
    "time_ns": pl.Int64, "reference_id": pl.Int64, "segment": pl.Int32, "ais_class": pl.String,
    **{c: pl.Float64 for c in REFERENCE_COLUMNS[4:16]}, "outlier": pl.Boolean,
    **{c: pl.Float64 for c in REFERENCE_COLUMNS[17:]},
}


def empty_reference_tracks() -> pl.DataFrame:
    return pl.DataFrame(schema=_SCHEMA)


@dataclass(frozen=True, eq=False)
class Reference:
    """Reference trajectories: one packed row per (target, segment) of a smoother
    (``pipeline.filters.smoother``), times in s from ``t0_ns``.

    ``target``: the target id of each row (truth vessel id, or MMSI); ``mmsi`` (-1:
    none); ``ais_class`` ('A' | 'B' | '' none); ``kind``: truth | reconstructed."""

    kind: str
    t0_ns: int
    pk: sm.Packed
    fit: sm.Smoothed
    target: np.ndarray
    mmsi: np.ndarray
    ais_class: np.ndarray
    extrapolate_s: float
    max_p95_m: float

    @property
    def rows(self) -> int:
        return int(self.target.size)

    def span_ns(self) -> tuple[np.ndarray, np.ndarray]:
        """First and last knot of each row, ns."""
        n = self.pk.lengths
        t = self.fit.t
        first = t[:, 0] if t.size else np.empty(0)
        last = t[np.arange(n.size), np.maximum(n - 1, 0)] if t.size else np.empty(0)
        return (np.rint(first * NS).astype(np.int64) + self.t0_ns,
                np.rint(last * NS).astype(np.int64) + self.t0_ns)

    def at(self, row: np.ndarray, t_ns: np.ndarray) -> dict[str, np.ndarray]:
        """The reference of rows ``row`` at times ``t_ns`` (paired arrays): x, y, vx,
        vy (m, m/s), var_x, var_y (m²) and p95_m (its own 95 % horizontal error)."""
        row = np.asarray(row, np.int64)
        tq = (np.asarray(t_ns, np.int64) - self.t0_ns) / NS
        if row.size == 0:
            z = np.empty(0)
            return {k: z for k in ("x", "y", "vx", "vy", "var_x", "var_y", "p95_m")}
        col = _last_at_or_before(self.fit.t, self.pk.lengths, row, tq)
        p, v, a, _c = sm.interpolate(self.fit, row, col, tq)
        return {"x": p[:, 0], "y": p[:, 1], "vx": v[:, 0], "vy": v[:, 1],
                "var_x": a[:, 0], "var_y": a[:, 1], "p95_m": sm.radial_p95(a[:, 0], a[:, 1])}

    def knots(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The smoothed knots flat, row after row: time (ns), x, y (m), and each row's
        first knot and count."""
        f, n = self.fit, self.pk.lengths
        cells = n[:, None] > np.arange(f.t.shape[1])[None, :]
        t = np.rint(f.t[cells] * NS).astype(np.int64) + self.t0_ns
        return t, f.ps[..., 0][cells], f.ps[..., 1][cells], np.cumsum(n) - n, n

    @cached_property
    def _flat_knots(self) -> tuple[np.ndarray, ...]:
        """The knots' time (s), x, y, vx, vy flat, row after row, and each row's first
        (flat gathers, 1-D, rather than (row, col) fancy indexing of the padded grids)."""
        f, n = self.fit, self.pk.lengths
        cells = n[:, None] > np.arange(f.t.shape[1])[None, :]
        return (f.t[cells], f.ps[..., 0][cells], f.ps[..., 1][cells], f.vs[..., 0][cells],
                f.vs[..., 1][cells], np.cumsum(n) - n)

    def position(self, row: np.ndarray, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The reference position (x, y, m) of rows ``row`` at ``t_ns`` interpolated
        linearly between its smoothed knots (moved on with the knot velocity outside the
        span): the cheap form of :meth:`at` for what needs metres, not centimetres (the
        cells of a coverage map, a 500 m gate); no covariance."""
        row = np.asarray(row, np.int64)
        tq = (np.asarray(t_ns, np.int64) - self.t0_ns) / NS
        if row.size == 0:
            return np.empty(0), np.empty(0)
        n = self.pk.lengths
        col = _last_at_or_before(self.fit.t, n, row, tq)
        t_k, x_k, y_k, vx_k, vy_k, start = self._flat_knots
        k = start[row] + np.clip(col, 0, None)
        last = start[row] + n[row] - 1
        k1 = np.minimum(k + 1, last)
        inside = (col >= 0) & (k1 > k)
        t0 = t_k[k]
        w = np.where(inside, (tq - t0) / np.where(inside, t_k[k1] - t0, 1.0), 0.0)
        dt = np.where(inside, 0.0, tq - t0)
        x = np.where(inside, x_k[k] + w * (x_k[k1] - x_k[k]), x_k[k] + dt * vx_k[k])
        y = np.where(inside, y_k[k] + w * (y_k[k1] - y_k[k]), y_k[k] + dt * vy_k[k])
        return x, y

    def at_epochs(self, epochs_ns: np.ndarray) -> pl.DataFrame:
        """Every row at every epoch inside its span (± ``extrapolate_s``) whose own 95 %
        error is within ``max_p95_m``: time_ns, row, target, mmsi, x, y, vx, vy, var_x,
        var_y, p95_m (sorted by time, row)."""
        epochs = np.unique(np.asarray(epochs_ns, np.int64))
        first, last = self.span_ns()
        ext = round(self.extrapolate_s * NS)
        lo = np.searchsorted(epochs, first - ext, "left")
        hi = np.searchsorted(epochs, last + ext, "right")
        row, idx = expand_ranges(lo, hi)
        order = np.lexsort((row, idx))
        row, t = row[order], epochs[idx[order]]
        r = self.at(row, t)
        keep = r["p95_m"] <= self.max_p95_m
        return pl.DataFrame({
            "time_ns": t[keep], "row": row[keep], "target": self.target[row[keep]],
            "mmsi": self.mmsi[row[keep]], **{k: v[keep] for k, v in r.items()},
        }, schema_overrides={"time_ns": pl.Int64, "row": pl.Int64, "target": pl.Int64,
                             "mmsi": pl.Int64})


def _last_at_or_before(t: np.ndarray, lengths: np.ndarray, row: np.ndarray, tq: np.ndarray
                       ) -> np.ndarray:
    """Column of the last knot of ``row`` at or before ``tq`` (-1: before the first): one
    searchsorted on (row, time) keys over the flattened rows."""
    n, L = t.shape
    if n == 0:
        return np.full(row.size, -1)
    base = min(float(np.nanmin(t)), float(np.min(tq, initial=np.inf))) - 1.0
    span = max(float(np.nanmax(t)), float(np.max(tq, initial=-np.inf))) - base + 1.0
    cells = lengths[:, None] > np.arange(L)[None, :]
    key = (np.arange(n)[:, None] * span + (t - base))[cells]  # row-major: sorted per row
    start = np.cumsum(lengths) - lengths
    q = row * span + (tq - base)
    pos = np.searchsorted(key, q, "right") - 1
    return np.clip(pos - start[row], -1, lengths[row] - 1)


# --- AIS reports -> reference -------------------------------------------------------------


def ais_measurements(ais: pl.DataFrame, region: RegionConfig, ais_cfg: AisConfig,
                     rcfg: ReferenceConfig) -> pl.DataFrame:
    """One row per (MMSI, time) in time order per MMSI: time_ns, mmsi, ais_class, x, y,
    vx, vy (nan: no SOG/COG), r_pos_m2, r_vel_m2ps2 (module docstring, step 1)."""
    if ais.height == 0:
        return pl.DataFrame(schema={"time_ns": pl.Int64, "mmsi": pl.Int64,
                                    "ais_class": pl.String, "x": pl.Float64, "y": pl.Float64,
                                    "vx": pl.Float64, "vy": pl.Float64,
                                    "r_pos_m2": pl.Float64, "r_vel_m2ps2": pl.Float64})
    a = (ais.select("time_ns", "mmsi", "ais_class", "lat_deg", "lon_deg", "sog_mps", "cog_rad")
         .sort("mmsi", "time_ns").unique(["mmsi", "time_ns"], keep="first", maintain_order=True))
    x, y = geodetic_to_enu(a["lat_deg"].to_numpy(), a["lon_deg"].to_numpy(),
                           region.origin_lat_deg, region.origin_lon_deg)
    sog = a["sog_mps"].fill_null(np.nan).to_numpy()
    cog = a["cog_rad"].fill_null(np.nan).to_numpy()
    vx, vy = sog * np.sin(cog), sog * np.cos(cog)
    sig_c = math.radians(rcfg.sigma_cog_deg)
    rv = np.maximum(ais_cfg.sigma_sog_mps**2, (np.nan_to_num(sog) * sig_c) ** 2)
    return a.select("time_ns", "mmsi", "ais_class").with_columns(
        pl.Series("x", x), pl.Series("y", y), pl.Series("vx", vx), pl.Series("vy", vy),
        pl.lit(ais_cfg.sigma_position_m**2).alias("r_pos_m2"), pl.Series("r_vel_m2ps2", rv))


def _segments(key: np.ndarray, t_ns: np.ndarray, max_gap_s: float,
              extra_breaks: np.ndarray | None = None) -> np.ndarray:
    """Segment code of rows sorted by (key, time): a new one at each key change, gap >
    max_gap_s or extra break."""
    if key.size == 0:
        return np.zeros(0, np.int64)
    brk = np.r_[True, (key[1:] != key[:-1]) | (np.diff(t_ns) > max_gap_s * NS)]
    if extra_breaks is not None:
        brk |= extra_breaks
    return np.cumsum(brk) - 1


def _arrays(pk: sm.Packed, m: pl.DataFrame, t0_ns: int, r_pos: np.ndarray | None = None
            ) -> tuple[np.ndarray, ...]:
    t = pk.grid((m["time_ns"].to_numpy() - t0_ns) / NS)
    z = pk.grid(m.select("x", "y").to_numpy())
    zv = pk.grid(m.select("vx", "vy").to_numpy())
    r = pk.grid(m["r_pos_m2"].to_numpy() if r_pos is None else r_pos, fill=1.0)
    rv = pk.grid(m["r_vel_m2ps2"].to_numpy(), fill=1.0)
    return t, z, r, zv, rv


def reconstruct(ais: pl.DataFrame, region: RegionConfig, ais_cfg: AisConfig,
                rcfg: ReferenceConfig) -> tuple[Reference, pl.DataFrame]:
    """The reference of every MMSI in ``ais`` (module docstring) and its knots
    (``reference_tracks`` rows, REFERENCE_COLUMNS)."""
    model = sm.MotionModel(rcfg.q_low_m2ps3, rcfg.q_high_m2ps3, rcfg.sojourn_low_s,
                           rcfg.sojourn_high_s, rcfg.gate_probability, rcfg.max_rejections)
    m = ais_measurements(ais, region, ais_cfg, rcfg)
    t0_ns = int(m["time_ns"].min()) if m.height else 0
    mmsi = m["mmsi"].to_numpy()
    t_ns = m["time_ns"].to_numpy()
    seg = _segments(mmsi, t_ns, rcfg.max_gap_s)
    pk = sm.pack(seg)
    t, z, _r, zv, rv = _arrays(pk, m, t0_ns)
    # each segment's AIS position variance from its reports alone (smoother docstring)
    r_seg = sm.difference_variance(pk, t, z)
    r_seg = np.clip(np.where(np.isfinite(r_seg), r_seg, ais_cfg.sigma_position_m**2),
                    SIGMA_MIN_M**2, SIGMA_MAX_M**2)
    cells0 = pk.lengths[:, None] > np.arange(t.shape[1])[None, :]
    imm = sm.imm_forward(pk, t, z, np.where(cells0, r_seg[:, None], 1.0), zv, rv, model)
    accepted = pk.flat(imm.accepted) if m.height else np.zeros(0, bool)
    restart = pk.flat(imm.restart) if m.height else np.zeros(0, bool)
    vel_ok = pk.flat(imm.velocity_used) if m.height else np.zeros(0, bool)
    mu_fwd = pk.flat(sm.lookahead_max(imm.mu_high, MANOEUVRE_LOOKAHEAD)) if m.height \
        else np.zeros(0)
    r_of = np.empty(m.height)
    rows0, _ = pk.cells()
    r_of[pk.order] = r_seg[rows0]
    # segments of the accepted reports, split at the restarts
    kept = m.with_columns(pl.Series("_seg0", seg), pl.Series("_restart", restart),
                          pl.Series("_mu", mu_fwd), pl.Series("r_pos_m2", r_of),
                          pl.when(pl.Series(vel_ok)).then(pl.col("vx")).otherwise(np.nan),
                          pl.when(pl.Series(vel_ok)).then(pl.col("vy")).otherwise(np.nan)
                          ).filter(pl.Series(accepted))
    seg2 = _segments(kept["_seg0"].to_numpy(), kept["time_ns"].to_numpy(), np.inf,
                     kept["_restart"].to_numpy())
    pk2 = sm.pack(seg2)
    t, z, r, zv, rv = _arrays(pk2, kept, t0_ns)
    mu = pk2.grid(kept["_mu"].to_numpy())
    mu_int = np.fmax(mu, np.c_[mu[:, :1], mu[:, :-1]])  # interval (j-1, j]: max of its ends
    q = model.q_low + np.nan_to_num(mu_int) * (model.q_high - model.q_low)
    if q.shape[1] > 1:
        q[:, 0] = q[:, 1]
    fit = sm.rts_smooth(pk2, t, z, r, zv, rv, q)
    r_seg = r[:, 0] if r.size else np.zeros(0)
    ref = Reference(
        RECONSTRUCTED, t0_ns, pk2, fit, target=_row_values(pk2, kept["mmsi"].to_numpy()),
        mmsi=_row_values(pk2, kept["mmsi"].to_numpy()),
        ais_class=_row_values(pk2, kept["ais_class"].to_numpy().astype(object)),
        extrapolate_s=rcfg.extrapolate_s, max_p95_m=rcfg.max_p95_m)
    knots = _knots(ref, kept, mu, r_seg, region).vstack(_outliers(ref, m, accepted, region))
    return ref, knots.sort("time_ns", "reference_id", "segment").select(REFERENCE_COLUMNS)


def _row_values(pk: sm.Packed, values: np.ndarray) -> np.ndarray:
    """The value of each packed row (its first entry)."""
    return values[pk.order[pk.start]] if pk.lengths.size else values[:0]


def _knots(ref: Reference, kept: pl.DataFrame, mu: np.ndarray, r_seg: np.ndarray,
           region: RegionConfig) -> pl.DataFrame:
    pk, f = ref.pk, ref.fit
    if kept.height == 0:
        return empty_reference_tracks()
    rows, _ = pk.cells()
    seg_of = np.empty(kept.height, np.int64)
    seg_of[pk.order] = rows
    ps, vs = pk.flat(f.ps), pk.flat(f.vs)
    a, c = pk.flat(f.as_), pk.flat(f.cs)
    z = kept.select("x", "y").to_numpy()
    res = z - ps
    # leave-one-out residual: e / (1 - h), h = P_s / R the hat value of the report
    h = np.clip(a / r_seg[seg_of][:, None], 0.0, 0.999)
    loo = np.hypot(*(res / (1.0 - h)).T)
    lat, lon = enu_to_geodetic(ps[:, 0], ps[:, 1], region.origin_lat_deg,
                               region.origin_lon_deg)
    sig_p = np.sqrt(r_seg)[seg_of]
    return pl.DataFrame({
        "time_ns": kept["time_ns"], "reference_id": kept["mmsi"],
        "segment": seg_of.astype(np.int32), "ais_class": kept["ais_class"],
        "x_enu_m": ps[:, 0], "y_enu_m": ps[:, 1], "lat_deg": np.atleast_1d(lat),
        "lon_deg": np.atleast_1d(lon), "vx_mps": vs[:, 0], "vy_mps": vs[:, 1],
        "sigma_x_m": np.sqrt(a[:, 0]), "sigma_y_m": np.sqrt(a[:, 1]),
        "sigma_vx_mps": np.sqrt(c[:, 0]), "sigma_vy_mps": np.sqrt(c[:, 1]),
        "p95_m": sm.radial_p95(a[:, 0], a[:, 1]), "manoeuvre_probability": pk.flat(mu),
        "outlier": np.zeros(kept.height, bool), "residual_east_m": res[:, 0],
        "residual_north_m": res[:, 1], "loo_residual_m": loo, "sigma_position_m": sig_p,
    }, schema=_SCHEMA)


def _outliers(ref: Reference, m: pl.DataFrame, accepted: np.ndarray, region: RegionConfig
              ) -> pl.DataFrame:
    """The gated-out reports as knots marked ``outlier``: the reference at their time
    (when there is one) and their residual from it."""
    out = m.filter(~pl.Series(accepted))
    if out.height == 0:
        return empty_reference_tracks()
    row = ref_rows_of(ref, out["mmsi"].to_numpy(), out["time_ns"].to_numpy())
    have = row >= 0
    r = ref.at(np.maximum(row, 0), out["time_ns"].to_numpy())
    nan = np.full(out.height, np.nan)
    pick = {k: np.where(have, v, np.nan) for k, v in r.items()}
    res_e = out["x"].to_numpy() - pick["x"]
    res_n = out["y"].to_numpy() - pick["y"]
    lat, lon = enu_to_geodetic(out["x"].to_numpy(), out["y"].to_numpy(),
                               region.origin_lat_deg, region.origin_lon_deg)
    return pl.DataFrame({
        "time_ns": out["time_ns"], "reference_id": out["mmsi"],
        "segment": np.where(have, row, -1).astype(np.int32), "ais_class": out["ais_class"],
        "x_enu_m": out["x"], "y_enu_m": out["y"], "lat_deg": np.atleast_1d(lat),
        "lon_deg": np.atleast_1d(lon), "vx_mps": out["vx"], "vy_mps": out["vy"],
        "sigma_x_m": np.sqrt(pick["var_x"]), "sigma_y_m": np.sqrt(pick["var_y"]),
        "sigma_vx_mps": nan, "sigma_vy_mps": nan, "p95_m": pick["p95_m"],
        "manoeuvre_probability": nan, "outlier": np.ones(out.height, bool),
        "residual_east_m": res_e, "residual_north_m": res_n,
        "loo_residual_m": np.hypot(res_e, res_n), "sigma_position_m": nan,
    }, schema=_SCHEMA).with_columns(pl.col(pl.Float64).fill_nan(None))


def ref_rows_of(ref: Reference, target: np.ndarray, t_ns: np.ndarray) -> np.ndarray:
    """The row of ``ref`` of each (target, time) whose span (± extrapolate_s) holds the
    time (-1: none; the first such row)."""
    first, last = ref.span_ns()
    ext = round(ref.extrapolate_s * NS)
    out = np.full(np.size(target), -1, np.int64)
    if ref.rows == 0 or np.size(target) == 0:
        return out
    order = np.lexsort((first, ref.target))
    tg, f, la = ref.target[order], first[order] - ext, last[order] + ext
    lo = np.searchsorted(tg, target, "left")
    hi = np.searchsorted(tg, target, "right")
    row, idx = expand_ranges(lo, hi)
    inside = (t_ns[row] >= f[idx]) & (t_ns[row] <= la[idx])
    row, idx = row[inside], idx[inside]
    # the first matching row wins (``row`` is sorted: expand_ranges repeats in order)
    first_of = np.flatnonzero(np.r_[True, row[1:] != row[:-1]]) if row.size else row
    out[row[first_of]] = order[idx[first_of]]
    return out


# --- truth as a reference ---------------------------------------------------------------------


def truth_reference(truth: pl.DataFrame, region: RegionConfig, *, extrapolate_s: float = 10.0
                    ) -> Reference:
    """The simulated truth as a :class:`Reference` (exact knots at its samples, velocity
    from speed and course; no error), for the evaluation steps that work on references."""
    tr = (truth.select("time_ns", pl.col("vessel_id").cast(pl.Int64), "mmsi", "lat_deg",
                       "lon_deg", "speed_mps", "course_rad")
          .sort("vessel_id", "time_ns").unique(["vessel_id", "time_ns"], keep="last",
                                              maintain_order=True))
    x, y = geodetic_to_enu(tr["lat_deg"].to_numpy(), tr["lon_deg"].to_numpy(),
                           region.origin_lat_deg, region.origin_lon_deg)
    spd, crs = tr["speed_mps"].to_numpy(), tr["course_rad"].to_numpy()
    vessel = tr["vessel_id"].to_numpy()
    t_ns = tr["time_ns"].to_numpy()
    t0_ns = int(t_ns.min()) if t_ns.size else 0
    pk = sm.pack(_segments(vessel, t_ns, np.inf))
    t = pk.grid((t_ns - t0_ns) / NS)
    n, L = pk.shape
    cells = pk.lengths[:, None] > np.arange(L)[None, :]
    p = pk.grid(np.column_stack([x, y]))
    v = pk.grid(np.column_stack([spd * np.sin(crs), spd * np.cos(crs)]))
    zero = np.where(cells[..., None], 0.0, np.nan) * np.ones(2)
    q = np.where(cells, TRUTH_Q, np.nan)
    fit = sm.Smoothed(t, p, v, zero, zero, zero, p, v, zero, zero, zero, q,
                      np.full((n, L), np.nan))
    mmsi = tr["mmsi"].fill_null(-1).to_numpy()
    return Reference(TRUTH, t0_ns, pk, fit, target=_row_values(pk, vessel),
                     mmsi=_row_values(pk, mmsi),
                     ais_class=np.full(n, "", dtype=object), extrapolate_s=extrapolate_s,
                     max_p95_m=np.inf)


# --- points -> references ----------------------------------------------------------------


def match_points(t_ns: np.ndarray, x: np.ndarray, y: np.ndarray, key: np.ndarray,
                 var_x: np.ndarray, var_y: np.ndarray, cov_xy: np.ndarray,
                 at: pl.DataFrame, *, max_distance_m: float, gate_d2: float,
                 min_share: float) -> np.ndarray:
    """Row of ``at`` (:meth:`Reference.at_epochs`) that is the reference of each point
    (-1: none): a track (``key``, e.g. the system track id) takes a target for its points
    when it lies within the gate (squared Mahalanobis distance < ``gate_d2`` with the
    point's and the reference's covariance) at least ``min_share`` of the epochs both
    exist; each point then takes the nearest of its track's targets within
    ``max_distance_m``. A track of a ship without AIS passing one with AIS is close to
    it for a few epochs only, and is not scored against it."""
    out = np.full(t_ns.size, -1, np.int64)
    at_t = at["time_ns"].to_numpy()
    if t_ns.size == 0 or at_t.size == 0:
        return out
    epochs = np.unique(np.concatenate([t_ns, at_t]))
    ga, gb = np.searchsorted(epochs, t_ns), np.searchsorted(epochs, at_t)
    rx, ry = at["x"].to_numpy(), at["y"].to_numpy()
    reach = max_distance_m * (1 + 1e-9) + 1e-6
    i, j, d2e = pairs_within(ga, x, y, reach, gb, rx, ry, cell_m=reach)
    if i.size == 0:
        return out
    dx, dy = x[i] - rx[j], y[i] - ry[j]
    sxx = var_x[i] + at["var_x"].to_numpy()[j]
    syy = var_y[i] + at["var_y"].to_numpy()[j]
    sxy = cov_xy[i]
    det = sxx * syy - sxy * sxy
    d2 = (syy * dx * dx - 2.0 * sxy * dx * dy + sxx * dy * dy) / det
    target = at["target"].to_numpy()
    arow = at["row"].to_numpy()
    # share of co-present epochs within the gate, per (track, target)
    pair = pl.DataFrame({"key": key[i], "target": target[j], "in": d2 < gate_d2})
    hits = pair.group_by("key", "target").agg(pl.col("in").sum().alias("n_in"))
    # co-present epochs: the track's epochs inside the target's rows' epoch sets
    both = _copresent(t_ns, key, at_t, target, arow, hits)
    ok = both.filter(pl.col("n_in") >= min_share * pl.col("n_both"))
    good = pl.DataFrame({"key": key[i], "target": target[j], "_k": np.arange(i.size)}).join(
        ok.select("key", "target"), on=["key", "target"], how="semi")["_k"].to_numpy()
    if good.size == 0:
        return out
    i, j, d = i[good], j[good], d2e[good]
    order = np.lexsort((target[j], d, i))
    first = order[np.r_[True, i[order][1:] != i[order][:-1]]]
    out[i[first]] = j[first]
    return out


def _copresent(t_ns: np.ndarray, key: np.ndarray, at_t: np.ndarray, target: np.ndarray,
               arow: np.ndarray, hits: pl.DataFrame) -> pl.DataFrame:
    """``hits`` with n_both: the epochs at which the track (key) and the target both have a
    point (the target's usable epochs are the rows of ``at`` with that target)."""
    pts = pl.DataFrame({"key": key, "time_ns": t_ns}).unique()
    refs = pl.DataFrame({"target": target, "time_ns": at_t}).unique()
    cand = hits.select("key", "target")
    both = (pts.join(cand, on="key").join(refs, on=["target", "time_ns"], how="inner")
            .group_by("key", "target").agg(pl.len().alias("n_both")))
    return hits.join(both, on=["key", "target"], how="left").with_columns(
        pl.col("n_both").fill_null(0))


def match_by_members(f_row_of_r: np.ndarray, owner: np.ndarray, n_fused: int,
                     f_t: np.ndarray, f_x: np.ndarray, f_y: np.ndarray, at: pl.DataFrame
                     ) -> np.ndarray:
    """Row of ``at`` that is the reference of each fused point (-1: none), from the
    owners of its radar members: ``owner`` is the row of ``at`` matched to each radar
    point by :func:`match_points` keyed by its radar's local track (a radar tracker's
    track follows one ship: the same rule, at the level where it holds), ``f_row_of_r``
    the fused row of each radar point. A fused point takes the target most of its
    members belong to (ties: the one nearest to it); a point none of whose members has
    an owner is not scored, so a system track that strays onto a ship without AIS is
    not scored against the ship it left."""
    out = np.full(n_fused, -1, np.int64)
    ok = (owner >= 0) & (f_row_of_r >= 0)
    if not ok.any():
        return out
    target = at["target"].to_numpy()
    at_t = at["time_ns"].to_numpy()
    fr, tg = f_row_of_r[ok], target[owner[ok]]
    votes = (pl.DataFrame({"f": fr, "target": tg}).group_by("f", "target")
             .agg(pl.len().alias("n")))
    # the target's row of ``at`` at the fused point's epoch
    key_at = pl.DataFrame({"time_ns": at_t, "target": target, "j": np.arange(at_t.size)}) \
        .unique(["time_ns", "target"], keep="first")
    v = votes.with_columns(pl.Series("time_ns", f_t[votes["f"].to_numpy()])).join(
        key_at, on=["time_ns", "target"], how="inner")
    if v.height == 0:
        return out
    j = v["j"].to_numpy()
    fi = v["f"].to_numpy()
    d = np.hypot(f_x[fi] - at["x"].to_numpy()[j], f_y[fi] - at["y"].to_numpy()[j])
    order = np.lexsort((d, -v["n"].to_numpy(), fi))
    first = order[np.r_[True, fi[order][1:] != fi[order][:-1]]]
    out[fi[first]] = j[first]
    return out
