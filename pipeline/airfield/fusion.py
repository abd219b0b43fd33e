"""The airfield fusion stage: reports of every channel -> fused target tracks and the
channel-health decisions (airfield paper eq. 16–23). Pure: tables + window + config in,
tables out.

Per epoch k (Δt = ``filter.epoch_s``; a report belongs to the epoch nearest its time):

1. targets born at k get the prior of :func:`pipeline.filters.airfield_kf.prior` and are
   updated with every channel reporting them (no check: the prior is diffuse);
2. the others are predicted (eq. 17) in the mode their VASN data allow (known VASN
   input / stationary because the VASN is silent / constant velocity);
3. channel outage: a channel that reported ≥ ``outage_min_tracks`` targets at k−1 and
   reports fewer than ``outage_min_share`` of them at k is in outage until that share
   is back; every target it left gets an ``outage`` check with η = 1;
4. every report of a target older than ``warmup_s`` is checked on the prior: ξ (eq. 21)
   against (d1, d2) (eq. 22) gives η (eq. 23); the exclusion rule of
   :mod:`pipeline.filters.integrity` excludes and readmits the channel for that target;
5. the channels in use update the target one after another (equivalent to the joint
   update of eq. 19: their white noises are independent).

The loop runs over epochs; targets are vectorised inside it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import polars as pl

from pipeline.airfield.associate import associate
from pipeline.airfield.config import AirfieldConfig, IntegrityConfig
from pipeline.airfield.frames import assign_areas
from pipeline.filters import airfield_kf as kf
from pipeline.filters.ar_errors import VarModel
from pipeline.filters.integrity import chi2_thresholds, eta, nis, step_exclusion
from pipeline.frames import enu_to_geodetic
from pipeline.units import NS

CHECK_NONE, CHECK_NIS, CHECK_BIRTH, CHECK_OUTAGE = 0, 1, 2, 3
CHECK_NAMES = np.array(["", "nis", "birth", "outage"], dtype=object)
SIGMA_P0_M = 100.0
SIGMA_V0_VASN_MPS = 0.5
SIGMA_V0_MPS = 5.0


@dataclass(frozen=True, eq=False)
class ChannelModels:
    """Error models the filter uses: AR position model per sensor id, the VASN's AR(1)
    velocity model, and where each came from (``config`` or a fit window)."""

    position: Mapping[str, VarModel]
    velocity: VarModel | None
    source: Mapping[str, str]


def config_models(cfg: AirfieldConfig) -> ChannelModels:
    """The nominal models of the config (the simulator's)."""
    vasn = [s for s in cfg.sensors if s.kind == "vasn"]
    return ChannelModels(
        position={s.sensor_id: s.position_model for s in cfg.sensors},
        velocity=vasn[0].velocity_model if vasn else None,
        source={s.sensor_id: s.error_model for s in cfg.sensors},
    )


@dataclass(frozen=True, eq=False)
class Grids:
    """Reports on the (epoch, target) grid, one array per channel."""

    e0: int
    track_ids: np.ndarray
    has: np.ndarray  # (C, K, N) bool
    z: np.ndarray  # (C, K, N, 2)
    R: np.ndarray  # (C, K, N, 2, 2)
    W: np.ndarray  # (K, N, 2) VASN velocity (nan when none)
    first: np.ndarray  # (N,) first epoch index
    last: np.ndarray  # (N,) last epoch index


def build_grids(obs: pl.DataFrame, sensor_ids: tuple[str, ...], vasn_id: str | None) -> Grids:
    """Scatter labelled reports (epoch, track_id, sensor_id, xc/yc, r_*, vxc/vyc) onto
    the grid; a second report of one channel for one target at one epoch is dropped."""
    obs = obs.unique(subset=["epoch", "track_id", "sensor_id"], keep="first", maintain_order=True)
    track_ids, tj = np.unique(obs["track_id"].to_numpy().astype(str), return_inverse=True)
    ep = obs["epoch"].to_numpy()
    e0 = int(ep.min())
    k = ep - e0
    K, N, C = int(k.max()) + 1, track_ids.size, len(sensor_ids)
    has = np.zeros((C, K, N), bool)
    z = np.zeros((C, K, N, 2))
    R = np.zeros((C, K, N, 2, 2))
    R[..., 0, 0] = R[..., 1, 1] = 1.0
    W = np.full((K, N, 2), np.nan)
    sid = obs["sensor_id"].to_numpy()
    xy = obs.select("xc_m", "yc_m").to_numpy()
    rr = (
        obs.select("r_xx_m2", "r_xy_m2", pl.col("r_xy_m2").alias("r_yx_m2"), "r_yy_m2")
        .to_numpy()
        .reshape(-1, 2, 2)
    )
    for c, s in enumerate(sensor_ids):  # three channels
        m = sid == s
        has[c, k[m], tj[m]] = True
        z[c, k[m], tj[m]] = xy[m]
        R[c, k[m], tj[m]] = rr[m]
        if s == vasn_id:
            W[k[m], tj[m]] = obs.filter(pl.Series(m)).select("vxc_mps", "vyc_mps").to_numpy()
    any_ = has.any(axis=0)
    first = np.argmax(any_, axis=0)
    last = K - 1 - np.argmax(any_[::-1], axis=0)
    return Grids(e0, track_ids, has, z, R, W, first, last)


@dataclass
class _Out:
    """Per-epoch outputs of the loop, (K, N, ...) arrays."""

    x: np.ndarray
    P: np.ndarray
    mode: np.ndarray
    used: np.ndarray  # (C, K, N)
    check: np.ndarray  # (C, K, N) CHECK_*
    xi: np.ndarray  # (C, K, N)
    eta: np.ndarray  # (C, K, N) int8, -1 = no decision
    excluded: np.ndarray  # (C, K, N)
    innov: np.ndarray  # (C, K, N) |r|, m
    # recorded for the smoother (``record``): the full state after the updates (K, N, d),
    # its prediction from k-1 (K, N, d; nan at a birth), and the full posterior
    # covariance of the targets alive at each epoch ({k: (targets, (n, d, d) float32)})
    x_full: np.ndarray | None = None
    x_prior: np.ndarray | None = None
    P_full: dict[int, tuple[np.ndarray, np.ndarray]] | None = None


def run_filter(g: Grids, model: kf.FilterModel, cfg: AirfieldConfig, vasn_c: int | None,
               *, record: bool = False) -> _Out:
    """The epoch loop (module doc, steps 1–5); ``record``: keep what the fixed-interval
    smoother of the reference needs (:mod:`pipeline.airfield.reference`)."""
    C, K, N = g.has.shape
    icfg, fcfg = cfg.integrity, cfg.filter
    d1, d2 = chi2_thresholds(icfg.q, 2)
    warm = round(icfg.warmup_s / fcfg.epoch_s)
    t_stat = fcfg.vasn_stationary_after_s / fcfg.epoch_s
    d = model.layout.dim
    out = _Out(
        np.full((K, N, d), np.nan),
        np.full((K, N, 2, 2), np.nan),
        np.full((K, N), -1, np.int8),
        np.zeros((C, K, N), bool),
        np.zeros((C, K, N), np.int8),
        np.full((C, K, N), np.nan),
        np.full((C, K, N), -1, np.int8),
        np.zeros((C, K, N), bool),
        np.full((C, K, N), np.nan),
    )
    if record:
        out.x_full = np.full((K, N, d), np.nan)
        out.x_prior = np.full((K, N, d), np.nan)
        out.P_full = {}
    x = np.zeros((N, d))
    P = np.repeat(np.eye(d)[None], N, axis=0)
    excluded = np.zeros((C, N), bool)
    run = np.zeros((C, N), np.int64)
    outage = np.zeros(C, bool)
    frozen = np.zeros((C, N), bool)
    last_vasn = np.full(N, -(10**9))
    for k in range(K):
        alive = (g.first <= k) & (k <= g.last)
        born = g.first == k
        prev = alive & ~born
        ip = np.flatnonzero(prev)
        if ip.size:
            mode, Wk, Wk1 = _modes(g, k, excluded, outage, last_vasn, vasn_c, t_stat)
            x[ip], P[ip] = kf.predict(model, x[ip], P[ip], mode[ip], Wk[ip], Wk1[ip])
            out.mode[k, ip] = mode[ip]
            if record:
                out.x_prior[k, ip] = x[ip]
        if np.any(born):
            drop = birth_outliers(g, k, born, model, d2)
            if not icfg.exclusion:
                drop[:] = False
            x, P = _birth(g, k, born, model, x, P, vasn_c, drop)
            excluded[:, born] = drop
            run[:, born] = 0
            out.check[:, k, born] = np.where(g.has[:, k, born], CHECK_BIRTH, CHECK_NONE)
            out.eta[:, k, born] = np.where(drop, 1, -1)
            out.used[:, k, born] = g.has[:, k, born] & ~drop
        for c in range(C):
            outage[c], frozen[c] = _outage(g, c, k, prev, alive, outage[c], frozen[c], icfg)
            lost = outage[c] & frozen[c] & alive & ~g.has[c, k]
            out.check[c, k, lost] = CHECK_OUTAGE
            out.eta[c, k, lost] = 1
            if icfg.exclusion:
                excluded[c, lost] = True
                run[c, lost] = 0
        use = np.zeros((C, N), bool)
        for c in range(C):
            rep = prev & g.has[c, k]
            if not np.any(rep):
                continue
            ir = np.flatnonzero(rep)
            r, S, _ = kf.innovation(model, x[ir], P[ir], c, g.z[c, k, ir], g.R[c, k, ir])
            xi = np.full(N, np.nan)
            xi[ir] = nis(r, S)
            decided = rep & (k - g.first >= warm)
            flag = np.zeros(N, bool)
            flag[ir] = eta(xi[ir], d1, d2).astype(bool)
            if icfg.exclusion:
                excluded[c], run[c] = step_exclusion(
                    excluded[c], run[c], flag, xi < d2, decided, icfg.readmit_run
                )
            use[c] = rep & ~excluded[c]
            out.check[c, k, rep] = CHECK_NIS
            out.xi[c, k] = xi
            out.innov[c, k, ir] = np.hypot(r[:, 0], r[:, 1])
            out.eta[c, k, decided] = flag[decided]
        for c in range(C):
            iu = np.flatnonzero(use[c])
            if iu.size:
                x[iu], P[iu] = kf.update(model, x[iu], P[iu], c, g.z[c, k, iu], g.R[c, k, iu])
            out.used[c, k] |= use[c]
        out.excluded[:, k] = excluded & alive[None, :]
        if vasn_c is not None:
            last_vasn = np.where(g.has[vasn_c, k] & alive, k, last_vasn)
        out.x[k, alive] = x[alive]
        out.P[k, alive] = P[alive][:, 0:2, 0:2]
        if record:
            ia = np.flatnonzero(alive)
            out.x_full[k, ia] = x[ia]
            out.P_full[k] = (ia, P[ia].astype(np.float32))
    return out


def _modes(
    g: Grids,
    k: int,
    excluded: np.ndarray,
    outage: np.ndarray,
    last_vasn: np.ndarray,
    vasn_c: int | None,
    t_stat: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Transition mode k−1 → k per target and the VASN velocities W(k−1), W(k)."""
    N = g.first.size
    if vasn_c is None:
        return np.full(N, kf.MODE_CV), np.zeros((N, 2)), np.zeros((N, 2))
    ok = ~excluded[vasn_c]
    a0 = ok & g.has[vasn_c, k - 1] & np.isfinite(g.W[k - 1, :, 0])
    a1 = ok & g.has[vasn_c, k] & np.isfinite(g.W[k, :, 0])
    W0 = np.where(a0[:, None], g.W[k - 1], 0.0)
    W1 = np.where(a1[:, None], g.W[k], 0.0)
    Wk = np.where(a0[:, None], W0, W1)
    Wk1 = np.where(a1[:, None], W1, W0)
    # silent for long enough: engines off, stationary (the VASN's blind case). Not during
    # a VASN outage: silence then says nothing (holding parked targets stationary through
    # an outage was tried: a vehicle that drives off during it is lost, see docs)
    silent = (k - last_vasn) > t_stat
    mode = np.where(
        a0 | a1,
        kf.MODE_VASN,
        np.where(silent & ~outage[vasn_c] & ok, kf.MODE_STATIONARY, kf.MODE_CV),
    )
    return mode, Wk, Wk1


def birth_outliers(g: Grids, k: int, born: np.ndarray, model: kf.FilterModel, d2: float
                   ) -> np.ndarray:
    """(C, nb) bool: channels inconsistent with every other channel reporting a new
    target while those others agree with each other (at least two of them).

    Pairwise test with the channels' stationary error covariances (the birth prior):
    ξ_ij = (z_i − z_j)ᵀ (Σ_i + Σ_j + R_i + R_j)⁻¹ (z_i − z_j) against d2. With a diffuse
    position prior a new target's first reports cannot be checked one by one (eq. 21
    needs a prior), so a channel that is already faulty when a target appears would be
    absorbed into its error state; this catches it when a majority disagrees."""
    has = g.has[:, k, born]
    C, nb = has.shape
    z = g.z[:, k, born]
    R = g.R[:, k, born]
    ok = np.ones((C, C, nb), bool)
    for i in range(C):
        Si = model.P0_err[model.layout.err0(i), model.layout.err0(i)]
        for j in range(i + 1, C):  # three channel pairs
            Sj = model.P0_err[model.layout.err0(j), model.layout.err0(j)]
            xi = nis(z[i] - z[j], Si + Sj + R[i] + R[j])
            ok[i, j] = ok[j, i] = ~(has[i] & has[j]) | (xi < d2)
    out = np.zeros((C, nb), bool)
    for i in range(C):
        others = [j for j in range(C) if j != i]
        n_other = has[others].sum(axis=0)
        against = np.all([~ok[i, j] | ~has[j] for j in others], axis=0)
        agree = np.all([ok[a, b] for a in others for b in others if a < b], axis=0)
        out[i] = has[i] & (n_other >= 2) & against & agree
    return out


def _birth(g: Grids, k: int, born: np.ndarray, model: kf.FilterModel, x: np.ndarray,
           P: np.ndarray, vasn_c: int | None, drop: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """Prior for the targets born at k, then an update with every channel at k except
    the ``drop`` ones ((C, nb) from :func:`birth_outliers`)."""
    has = g.has[:, k, born] & ~drop                 # (C, nb)
    zsum = np.einsum("cn,cnk->nk", has, g.z[:, k, born])
    p0 = zsum / np.maximum(has.sum(axis=0), 1)[:, None]
    if vasn_c is not None:
        wv = has[vasn_c] & np.isfinite(g.W[k, born, 0])
        v0 = np.where(wv[:, None], np.nan_to_num(g.W[k, born]), 0.0)
    else:
        wv = np.zeros(p0.shape[0], bool)
        v0 = np.zeros_like(p0)
    xb, Pb = kf.prior(model, p0, v0, SIGMA_P0_M, np.where(wv, SIGMA_V0_VASN_MPS, SIGMA_V0_MPS))
    for c in range(has.shape[0]):
        m = has[c]
        if np.any(m):
            xb[m], Pb[m] = kf.update(model, xb[m], Pb[m], c, g.z[c, k, born][m],
                                     g.R[c, k, born][m])
    x = x.copy()
    P = P.copy()
    x[born], P[born] = xb, Pb
    return x, P


def _outage(
    g: Grids,
    c: int,
    k: int,
    prev: np.ndarray,
    alive: np.ndarray,
    in_outage: bool,
    frozen: np.ndarray,
    icfg: IntegrityConfig,
) -> tuple[bool, np.ndarray]:
    """Channel-level outage state of channel c at epoch k (module doc, step 3)."""
    seen = g.has[c, k]
    if not in_outage:
        if k == 0:
            return False, frozen
        expected = prev & g.has[c, k - 1]
        n = int(expected.sum())
        if n >= icfg.outage_min_tracks and (expected & seen).sum() < icfg.outage_min_share * n:
            return True, expected.copy()
        return False, np.zeros_like(frozen)
    still = frozen & alive
    n = int(still.sum())
    if n == 0 or (still & seen).sum() >= icfg.outage_min_share * n:
        return False, np.zeros_like(frozen)
    return True, frozen


def fuse_airfield(
    obs: pl.DataFrame,
    cfg: AirfieldConfig,
    models: ChannelModels,
    *,
    start_ns: int,
    end_ns: int,
) -> tuple[pl.DataFrame, pl.DataFrame]:
    """Fused tracks and channel-health rows in [start_ns, end_ns) from reports in the
    common frame (:func:`pipeline.airfield.frames.to_common_frame`), which may start
    earlier (the filter's lead-in). Returns (airfield_tracks rows, channel_health rows)
    without the truth-scored columns (see :mod:`pipeline.airfield.score`)."""
    tracks, health, _ = fuse_airfield_run(obs, cfg, models, start_ns=start_ns, end_ns=end_ns)
    return tracks, health


@dataclass(frozen=True, eq=False)
class FilterRun:
    """What the smoother needs of one run of the filter: the grid, the recorded loop
    outputs, the model and the epoch step (ns)."""

    grids: Grids
    out: _Out
    model: kf.FilterModel
    step_ns: int


def fuse_airfield_run(
    obs: pl.DataFrame,
    cfg: AirfieldConfig,
    models: ChannelModels,
    *,
    start_ns: int,
    end_ns: int,
    record: bool = False,
) -> tuple[pl.DataFrame, pl.DataFrame, FilterRun | None]:
    """:func:`fuse_airfield`, and with ``record`` the :class:`FilterRun` the reference's
    smoother runs backwards over (None without reports)."""
    fcfg = cfg.filter
    step_ns = round(fcfg.epoch_s * NS)
    obs = obs.filter(pl.col("time_ns") < end_ns).with_columns(
        ((pl.col("time_ns") + step_ns // 2) // step_ns).alias("epoch")
    )
    if obs.height == 0:
        return pl.DataFrame(), pl.DataFrame(), None
    timeout = round(fcfg.track_timeout_s / fcfg.epoch_s)
    labelled, targets = associate(
        obs,
        gate_m=fcfg.association_gate_m,
        min_votes=fcfg.min_association_votes,
        timeout_epochs=timeout,
    )
    sensor_ids = tuple(s.sensor_id for s in cfg.sensors)
    vasn = [s.sensor_id for s in cfg.sensors if s.kind == "vasn"]
    vasn_id = vasn[0] if vasn and models.velocity is not None else None
    vel = (
        models.velocity
        if models.velocity is not None
        else VarModel(np.zeros((1, 2, 2)), 0.01 * np.eye(2))
    )
    model = kf.build_model(
        sensor_ids,
        models.position,
        vel,
        dt_s=fcfg.epoch_s,
        sigma_input_m=fcfg.sigma_input_m,
        sigma_stationary_m=fcfg.sigma_stationary_m,
        sigma_accel_mps2=fcfg.sigma_accel_mps2,
    )
    g = build_grids(labelled, sensor_ids, vasn_id)
    vasn_c = sensor_ids.index(vasn_id) if vasn_id else None
    out = run_filter(g, model, cfg, vasn_c, record=record)
    tracks = _track_rows(g, out, targets, cfg, step_ns)
    health = _health_rows(g, out, cfg, sensor_ids, step_ns, tracks)
    keep = (pl.col("time_ns") >= start_ns) & (pl.col("time_ns") < end_ns)
    run = FilterRun(g, out, model, step_ns) if record else None
    return tracks.filter(keep), health.filter(keep), run


def _track_rows(
    g: Grids, out: _Out, targets: pl.DataFrame, cfg: AirfieldConfig, step_ns: int
) -> pl.DataFrame:
    kk, nn = np.nonzero(~np.isnan(out.x[:, :, 0]))
    x = out.x[kk, nn]
    P = out.P[kk, nn]
    used = out.used[:, kk, nn]  # (C, M)
    C = used.shape[0]
    names = [s.sensor_id for s in cfg.sensors]
    # channel sets as bit codes, named through a 2^C table (no per-row Python)
    table = np.array([",".join(n for c, n in enumerate(names) if code >> c & 1)
                      for code in range(1 << C)], dtype=object)
    codes = (used.astype(np.int64) << np.arange(C)[:, None]).sum(axis=0)
    channels = table[codes]
    lat, lon = enu_to_geodetic(x[:, 0], x[:, 1], cfg.reference_lat_deg, cfg.reference_lon_deg)
    sector, area = assign_areas(x[:, 0], x[:, 1], cfg)
    mode = out.mode[kk, nn]
    df = pl.DataFrame(
        {
            "time_ns": (g.e0 + kk).astype(np.int64) * step_ns,
            "track_id": g.track_ids[nn],
            "x_m": x[:, 0],
            "y_m": x[:, 1],
            "vx_mps": x[:, 2],
            "vy_mps": x[:, 3],
            "lat_deg": np.atleast_1d(lat),
            "lon_deg": np.atleast_1d(lon),
            "sigma_x_m": np.sqrt(P[:, 0, 0]),
            "sigma_y_m": np.sqrt(P[:, 1, 1]),
            "cov_xy_m2": P[:, 0, 1],
            "motion_mode": np.where(mode < 0, "birth", np.array(kf.MODES, dtype=object)[mode]),
            "n_channels": used.sum(axis=0).astype(np.int16),
            "channels": channels,
            "sector": sector,
            "area": area,
        },
        schema_overrides={
            "sector": pl.String,
            "area": pl.String,
            "channels": pl.String,
            "motion_mode": pl.String,
        },
    )
    return df.join(targets, on="track_id", how="left")


def _health_rows(
    g: Grids,
    out: _Out,
    cfg: AirfieldConfig,
    sensor_ids: tuple[str, ...],
    step_ns: int,
    tracks: pl.DataFrame,
) -> pl.DataFrame:
    d1, d2 = chi2_thresholds(cfg.integrity.q, 2)
    cc, kk, nn = np.nonzero(out.check != CHECK_NONE)
    kinds = {s.sensor_id: s.kind for s in cfg.sensors}
    z = g.z[cc, kk, nn]
    has = g.has[cc, kk, nn]
    e = out.eta[cc, kk, nn]
    df = pl.DataFrame(
        {
            "time_ns": (g.e0 + kk).astype(np.int64) * step_ns,
            "track_id": g.track_ids[nn],
            "channel": np.array(sensor_ids, dtype=object)[cc],
            "check": CHECK_NAMES[out.check[cc, kk, nn]],
            "nis": out.xi[cc, kk, nn],
            "eta": np.where(e < 0, np.nan, e),
            "excluded": out.excluded[cc, kk, nn],
            "used": out.used[cc, kk, nn],
            "innovation_m": out.innov[cc, kk, nn],
            "report_x_m": np.where(has, z[:, 0], np.nan),
            "report_y_m": np.where(has, z[:, 1], np.nan),
        },
        schema_overrides={"channel": pl.String, "check": pl.String},
    ).with_columns(
        pl.col("nis").fill_nan(None),
        pl.col("innovation_m").fill_nan(None),
        pl.col("eta").fill_nan(None).cast(pl.Int16),
        pl.col("report_x_m").fill_nan(None),
        pl.col("report_y_m").fill_nan(None),
        pl.col("channel").replace_strict(kinds).alias("sensor_kind"),
        pl.lit(d1).alias("d1"),
        pl.lit(d2).alias("d2"),
        pl.lit(2, pl.Int16).alias("dof"),
    )
    return df.join(
        tracks.select("time_ns", "track_id", "sector", "area"),
        on=["time_ns", "track_id"],
        how="left",
    )
