"""Two-step time synchronisation of radar track reports (multi-radar paper, eq. 7-13).

Step 1 (eq. 7), inside each radar: a report swept at azimuth beta at ``time_ns`` is
extrapolated to the end of its scan, the moment the antenna reaches beta_Last:

.. math:: \\Delta t^{par} = \\frac{(\\beta_{Last} - \\beta) \\bmod 2\\pi}{2\\pi} T_{scan},
          \\qquad t^{TO} = t + \\Delta t^{par}

The paper writes ``|beta - beta_Last| / 2pi * T_scan``, i.e. beta_Last is the last
azimuth of the working zone and every beta <= beta_Last; the clockwise ``mod 2pi`` form
is the same number in that case and stays right for any beta_Last (e.g. a scan that
ends at north while targets lie at any azimuth).

Step 2 (eq. 8), across radars: at each synchronised epoch every radar contributes its
current picture, the reports of its latest scan whose end t_TO is <= epoch and
> epoch - T_scan - tolerance (at most one report per (site, local_track_id) per
epoch), extrapolated by ``Delta t^MR = epoch - t_TO``. (The paper extrapolates to the
latest scan end among the radars; we use a fixed epoch grid so that windows and
reprocessing runs see the same epochs.)

Extrapolation is linear, eq. 9 in our ENU convention (x east, course clockwise from
north): ``x* = x + V dt sin C``, ``y* = y + V dt cos C``.

Covariance inflation (eq. 12-13). Eq. 12 adds the three terms
``|sigma_v dt cos C| + |sigma_c V dt sin C| + |sigma_dt V cos C|`` linearly to sigma_x: a
worst-case bound. We add the same three terms as independent variances,

.. math:: P^* = P + J \\,\\mathrm{diag}(\\sigma_v^2, \\sigma_c^2, \\sigma_{\\Delta t}^2)\\, J^T,
          \\qquad J = \\partial(x^*, y^*) / \\partial(V, C, \\Delta t)

the variance form of eq. 12, because the fused sigmas must be calibrated (NEES of the
fused position averages ~2), which a linear worst-case sum would overstate. The course
and speed errors are those of one estimate used at both steps, so their contributions
add in amplitude across the steps (the paper's linear sum is exact there): the result
uses ``dt = dt_1 + dt_2`` for them, while the two timing errors sigma_dt are independent
and add as two variances. The position error of the report is taken as independent of
its course/speed errors (the tracker's cross-covariance is not in the log).
sigma_course_rad and sigma_speed_mps are carried unchanged: a constant-velocity
extrapolation does not change course or speed, hence not their errors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import polars as pl

from pipeline.frames import TWO_PI
from pipeline.maritime.config import SyncConfig
from pipeline.units import NS

#: slack on the "latest scan within one scan period" rule, s (antenna period jitter)
SCAN_TOLERANCE_S = 0.25

SYNCED_COLUMNS = (
    "time_ns",
    "site_id",
    "local_track_id",
    "report_time_ns",
    "x_enu_m",
    "y_enu_m",
    "P_xx",
    "P_yy",
    "P_xy",
    "course_rad",
    "speed_mps",
    "sigma_course_rad",
    "sigma_speed_mps",
)


def epoch_grid(start_ns: int, end_ns: int, period_s: float) -> np.ndarray:
    """Synchronised epochs in [start_ns, end_ns): multiples of ``period_s`` since the
    Unix epoch (so that any window cut yields the same grid), int64 ns."""
    period_ns = round(period_s * NS)
    if period_ns <= 0:
        raise ValueError("epoch period must be positive")
    first = -(-int(start_ns) // period_ns) * period_ns
    return np.arange(first, int(end_ns), period_ns, dtype=np.int64)


def scan_end_offset_s(
    azimuth_rad: np.ndarray, scan_end_azimuth_rad: np.ndarray, scan_period_s: np.ndarray
) -> np.ndarray:
    """Multi-radar paper eq. 7: time from the sweep of ``azimuth_rad`` to the scan end
    ``scan_end_azimuth_rad`` (beta_Last) for a clockwise antenna, s, in [0, T_scan)."""
    return np.mod(scan_end_azimuth_rad - azimuth_rad, TWO_PI) / TWO_PI * scan_period_s


def extrapolation_covariance(
    speed_mps: np.ndarray,
    course_rad: np.ndarray,
    dt_s: np.ndarray,
    sigma_speed_mps: np.ndarray,
    sigma_course_rad: np.ndarray,
    sigma_dt_s: float,
    n_timing_errors: int = 1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Covariance added by a linear extrapolation over ``dt_s`` (variance form of the
    multi-radar paper's eq. 12), returned as (dP_xx, dP_yy, dP_xy), m^2.

    .. math:: \\Delta P = (\\sigma_v^2 \\Delta t^2 + k\\,\\sigma_{\\Delta t}^2 V^2)\\, u u^T
              + \\sigma_c^2 V^2 \\Delta t^2\\, n n^T

    with u = (sin C, cos C) along track, n = (cos C, -sin C) across, and k =
    ``n_timing_errors`` independent interval errors of sigma ``sigma_dt_s``.
    """
    s, c = np.sin(course_rad), np.cos(course_rad)
    along = (sigma_speed_mps * dt_s) ** 2 + n_timing_errors * (sigma_dt_s * speed_mps) ** 2
    across = (sigma_course_rad * speed_mps * dt_s) ** 2
    return along * s * s + across * c * c, along * c * c + across * s * s, (along - across) * s * c


def extrapolate_position(
    x_m: np.ndarray,
    y_m: np.ndarray,
    speed_mps: np.ndarray,
    course_rad: np.ndarray,
    dt_s: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Multi-radar paper eq. 9 (x east): x* = x + V dt sin C, y* = y + V dt cos C, m."""
    return x_m + speed_mps * dt_s * np.sin(course_rad), y_m + speed_mps * dt_s * np.cos(course_rad)


def synchronise(aligned: pl.DataFrame, *, epochs_ns: np.ndarray, sync: SyncConfig) -> pl.DataFrame:
    """Two-step synchronisation of aligned radar reports to ``epochs_ns``.

    Consumes (from ``align_reports``): time_ns, site_id, local_track_id, azimuth_rad,
    scan_end_azimuth_rad, scan_period_s, x_enu_m, y_enu_m, P_xx, P_yy, P_xy,
    course_rad, speed_mps, sigma_course_rad, sigma_speed_mps.

    Produces one row per (epoch, site, local track) in the radar's current picture:
    time_ns (epoch), site_id, local_track_id, report_time_ns, x_enu_m, y_enu_m (m),
    P_xx, P_yy, P_xy (m^2, inflated at both steps), course_rad, speed_mps,
    sigma_course_rad, sigma_speed_mps; sorted by (time_ns, site_id, local_track_id).
    """
    epochs = np.unique(np.asarray(epochs_ns, dtype=np.int64))
    scans = _step1(aligned)
    row, epoch = _serve(scans, epochs)
    return _step2_columns(aligned, scans, row, epoch, sync.sigma_dt_s)


@dataclass(frozen=True)
class _Scans:
    """Step 1 as arrays: ``rows`` (indices into the aligned reports, the kept report of
    each (site, track, scan), ordered by (scan end, site, local track)) and per kept
    row its dt_1 (s), t_TO (ns), scan end (ns), scan period (s, the scan's largest) and
    the end of the same site's next scan (ns; int64 max when none)."""

    rows: np.ndarray
    dt1_s: np.ndarray
    t_to_ns: np.ndarray
    scan_end_ns: np.ndarray
    scan_T_s: np.ndarray  # noqa: N815 - T as in the paper
    next_end_ns: np.ndarray


def _step1(aligned: pl.DataFrame) -> _Scans:
    """Step 1 (eq. 7), with numpy on the key columns only: scan-end time t_TO of each
    report, grouped into scans per site (a run of a site's t_TO values closer than half a
    scan period; its end is the latest t_TO in it); a track reported twice in one scan
    keeps its latest report. Same rows, order and values as :func:`_step1_scans`."""
    T = aligned["scan_period_s"].to_numpy().astype(float)
    dt1 = scan_end_offset_s(
        aligned["azimuth_rad"].to_numpy(), aligned["scan_end_azimuth_rad"].to_numpy(), T
    )
    t = aligned["time_ns"].to_numpy()
    t_to = t + np.round(dt1 * NS).astype(np.int64)
    sites = aligned["site_id"]
    names = sorted(sites.unique().to_list())
    site = sites.replace_strict(names, list(range(len(names))), return_dtype=pl.Int64).to_numpy()
    track = aligned["local_track_id"].to_numpy()
    o = _by_site_and_time(site, t_to)
    so, to, To = site[o], t_to[o], T[o]
    first = np.r_[True, so[1:] != so[:-1]] if o.size else np.zeros(0, bool)
    gap = np.r_[0, np.diff(to)].astype(float)
    new = first | (gap > To * (0.5 * NS))
    scan = np.cumsum(new) - 1  # scan index of each sorted row
    starts = np.flatnonzero(new)
    end = np.maximum.reduceat(to, starts) if o.size else np.zeros(0, np.int64)
    big_T = np.maximum.reduceat(To, starts) if o.size else np.zeros(0)
    scan_site = so[starts]
    nxt = np.full(starts.size, np.iinfo(np.int64).max)
    same = scan_site[1:] == scan_site[:-1]
    nxt[:-1][same] = end[1:][same]
    # the latest report of each (site, track, scan): order by (scan, track, time)
    sc_row = np.empty(o.size, np.int64)
    sc_row[o] = scan
    scan_track = _combined(sc_row, track)
    if scan_track is None:
        k = np.lexsort((t, track, sc_row))
        last = np.r_[(sc_row[k][1:] != sc_row[k][:-1]) | (track[k][1:] != track[k][:-1]), True] \
            if k.size else np.zeros(0, bool)
    else:
        k = np.lexsort((t, scan_track))
        last = np.r_[scan_track[k][1:] != scan_track[k][:-1], True] if k.size \
            else np.zeros(0, bool)
    keep = k[last]
    ks = sc_row[keep]
    # (end, site, track) order: the scans by (end, site), then their tracks (one each)
    scan_rank = np.empty(starts.size, np.int64)
    scan_rank[np.lexsort((scan_site, end))] = np.arange(starts.size)
    by_scan = _combined(scan_rank[ks], track[keep])
    final = keep[np.lexsort((track[keep], site[keep], end[ks])) if by_scan is None
                 else np.argsort(by_scan)]
    fs = sc_row[final]
    return _Scans(final, dt1[final], t_to[final], end[fs], big_T[fs], nxt[fs])


def _combined(major: np.ndarray, minor: np.ndarray) -> np.ndarray | None:
    """One int64 key ordered as (major, minor) (non-negative ``major``), None when it
    would not fit in 63 bits."""
    if minor.size == 0:
        return np.zeros(0, np.int64)
    lo, span = int(minor.min()), int(minor.max()) - int(minor.min()) + 1
    if span.bit_length() + int(major.max()).bit_length() > 62:
        return None
    return major * span + (minor - lo)


def _by_site_and_time(site: np.ndarray, t_ns: np.ndarray) -> np.ndarray:
    """An order of the rows by (site, time), ties in any order (the scans do not depend on
    it): one argsort of a combined key when it fits in 63 bits, else a lexsort."""
    if t_ns.size == 0:
        return np.zeros(0, np.int64)
    t0, span = int(t_ns.min()), int(t_ns.max()) - int(t_ns.min()) + 1
    if span.bit_length() + int(site.max()).bit_length() > 62:
        return np.lexsort((t_ns, site))
    return np.argsort(site * span + (t_ns - t0))


def _serve(scans: _Scans, epochs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Step 2 selection (eq. 8): epochs each report serves, as (row index into the scans,
    epoch) pairs. A report of a scan ending at s serves the epochs e with s <= e <
    min(next scan end, s + T_scan + tolerance)."""
    end = scans.scan_end_ns
    limit = end + np.round((scans.scan_T_s + SCAN_TOLERANCE_S) * NS).astype(np.int64)
    lo = np.searchsorted(epochs, end, side="left")
    hi = np.searchsorted(epochs, np.minimum(limit, scans.next_end_ns), side="left")
    row, idx = expand_ranges(lo, hi)
    return row, epochs[idx]


def _step2_columns(aligned: pl.DataFrame, scans: _Scans, row: np.ndarray, epoch: np.ndarray,
                   sigma_dt_s: float) -> pl.DataFrame:
    """:func:`_step2` on arrays: extrapolate each picked report by dt_1 + dt_2, inflate its
    covariance, and gather only the output columns, in (epoch, site, track) order."""
    src = scans.rows[row]
    dt = scans.dt1_s[row] + (epoch - scans.t_to_ns[row]) / NS

    def col(name: str) -> np.ndarray:
        return aligned[name].to_numpy()[src]

    V, C = col("speed_mps"), col("course_rad")
    x, y = extrapolate_position(col("x_enu_m"), col("y_enu_m"), V, C, dt)
    sv, sc = col("sigma_speed_mps"), col("sigma_course_rad")
    dxx, dyy, dxy = extrapolation_covariance(V, C, dt, sv, sc, sigma_dt_s, n_timing_errors=2)
    site = aligned["site_id"].gather(src)
    track = col("local_track_id")
    names = sorted(site.unique().to_list())
    code = site.replace_strict(names, list(range(len(names))), return_dtype=pl.Int64).to_numpy()
    o = np.lexsort((track, code, epoch))
    return pl.DataFrame(
        {
            "time_ns": epoch[o],
            "site_id": site.gather(o),
            "local_track_id": track[o],
            "report_time_ns": col("time_ns")[o],
            "x_enu_m": x[o],
            "y_enu_m": y[o],
            "P_xx": (col("P_xx") + dxx)[o],
            "P_yy": (col("P_yy") + dyy)[o],
            "P_xy": (col("P_xy") + dxy)[o],
            "course_rad": C[o],
            "speed_mps": V[o],
            "sigma_course_rad": sc[o],
            "sigma_speed_mps": sv[o],
        },
        schema_overrides={"time_ns": pl.Int64, "report_time_ns": pl.Int64},
    ).select(SYNCED_COLUMNS)


def _step1_scans(aligned: pl.DataFrame) -> pl.DataFrame:
    """Step 1 (eq. 7) in polars (the reference of :func:`_step1`): scan-end time t_TO of
    each report, grouped into scans per site; a track reported twice in one scan keeps
    its latest report."""
    dt1 = scan_end_offset_s(
        aligned["azimuth_rad"].to_numpy(),
        aligned["scan_end_azimuth_rad"].to_numpy(),
        aligned["scan_period_s"].to_numpy(),
    )
    df = aligned.with_columns(
        pl.Series("dt1_s", dt1, dtype=pl.Float64),
        (pl.col("time_ns") + pl.Series(np.round(dt1 * NS).astype(np.int64))).alias("t_to_ns"),
    ).sort("site_id", "t_to_ns", "local_track_id")
    gap = pl.col("t_to_ns").diff().over("site_id")
    df = df.with_columns(
        (gap.is_null() | (gap > pl.col("scan_period_s") * (0.5 * NS))).cum_sum().alias("scan_id")
    ).with_columns(
        pl.col("t_to_ns").max().over("scan_id").alias("scan_end_ns"),
        pl.col("scan_period_s").max().over("scan_id").alias("scan_T_s"),
    )
    next_end = (
        df.group_by("scan_id")
        .agg(pl.col("site_id").first(), pl.col("scan_end_ns").first())
        .sort("scan_id")
        .select("scan_id", pl.col("scan_end_ns").shift(-1).over("site_id").alias("next_end_ns"))
    )
    return (
        df.join(next_end, on="scan_id", how="left")
        .sort("time_ns")
        .unique(["site_id", "local_track_id", "scan_id"], keep="last", maintain_order=True)
        .sort("scan_end_ns", "site_id", "local_track_id")
    )


def synchronise_reference(aligned: pl.DataFrame, *, epochs_ns: np.ndarray, sync: SyncConfig
                          ) -> pl.DataFrame:
    """:func:`synchronise` through polars frames (the reference it is tested against)."""
    epochs = np.unique(np.asarray(epochs_ns, dtype=np.int64))
    scans = _step1_scans(aligned)
    row, epoch = _serve_epochs(scans, epochs)
    return _step2(scans[row], epoch, sync.sigma_dt_s)


def _serve_epochs(scans: pl.DataFrame, epochs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Step 2 selection (eq. 8) on the polars scans (reference path)."""
    end = scans["scan_end_ns"].to_numpy()
    limit = end + np.round((scans["scan_T_s"].to_numpy() + SCAN_TOLERANCE_S) * NS).astype(np.int64)
    nxt = scans["next_end_ns"].fill_null(np.iinfo(np.int64).max).to_numpy()
    lo = np.searchsorted(epochs, end, side="left")
    hi = np.searchsorted(epochs, np.minimum(limit, nxt), side="left")
    row, idx = expand_ranges(lo, hi)
    return row, epochs[idx]


def expand_ranges(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For rows with index ranges [lo_i, hi_i): (row i repeated, each index in its range),
    vectorised with repeat + cumsum (no loop). Empty ranges give no pairs."""
    counts = np.maximum(np.asarray(hi) - np.asarray(lo), 0)
    row = np.repeat(np.arange(counts.size), counts)
    first = np.cumsum(counts) - counts
    return row, np.asarray(lo)[row] + (np.arange(row.size) - first[row])


def _step2(pick: pl.DataFrame, epoch: np.ndarray, sigma_dt_s: float) -> pl.DataFrame:
    """Extrapolate each picked report by dt_1 + dt_2 and inflate its covariance."""
    dt = pick["dt1_s"].to_numpy() + (epoch - pick["t_to_ns"].to_numpy()) / NS
    V, C = pick["speed_mps"].to_numpy(), pick["course_rad"].to_numpy()
    x, y = extrapolate_position(pick["x_enu_m"].to_numpy(), pick["y_enu_m"].to_numpy(), V, C, dt)
    dxx, dyy, dxy = extrapolation_covariance(
        V,
        C,
        dt,
        pick["sigma_speed_mps"].to_numpy(),
        pick["sigma_course_rad"].to_numpy(),
        sigma_dt_s,
        n_timing_errors=2,
    )
    return (
        pick.with_columns(
            pl.Series("time_ns", epoch, dtype=pl.Int64),
            pl.col("time_ns").alias("report_time_ns"),
            pl.Series("x_enu_m", x),
            pl.Series("y_enu_m", y),
            pl.col("P_xx") + pl.Series(dxx),
            pl.col("P_yy") + pl.Series(dyy),
            pl.col("P_xy") + pl.Series(dxy),
        )
        .select(SYNCED_COLUMNS)
        .sort("time_ns", "site_id", "local_track_id")
    )
