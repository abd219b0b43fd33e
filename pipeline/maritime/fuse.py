"""Inverse-variance fusion of associated radar tracks (multi-radar paper, eq. 14-15).

Per synchronised epoch and system track, each parameter lambda (east, north, speed,
course) is the weighted mean of the radars' synchronised estimates, eq. 14:

.. math:: \\hat\\lambda = \\frac{\\sum_i w_i \\lambda_i}{\\sum_i w_i},
          \\qquad w_i = 1 / \\sigma_{\\lambda,i}^2

with each channel's CURRENT variance (after the sync inflation of eq. 12), not an a
priori "best radar". The fused sigma is the exact one for independent channels,

.. math:: \\hat\\sigma_\\lambda = \\left(\\sum_i w_i\\right)^{-1/2}

and NOT the paper's eq. 15 (kept as :func:`paper_eq15_sigma` for comparison): eq. 15
equals it when all channels have the same sigma and is smaller (over-optimistic)
otherwise.

The position (east, north) is fused as ONE parameter vector with matrix weights
W_i = P_i^-1, the matrix form of eq. 14 (information form):

.. math:: \\hat P = \\left(\\sum_i P_i^{-1}\\right)^{-1}, \\qquad
          \\hat{\\mathbf p} = \\hat P \\sum_i P_i^{-1} \\mathbf p_i

(it reduces to eq. 14 per axis when every P_i is diagonal). Averaging east and north
separately with 1/P_xx and 1/P_yy ignores the orientation of each radar's error
ellipse (long across the line of sight): where two radars see a ship from different
aspects, that per-axis mean was measured to have a LARGER cross-track error than the
better radar alone (channel scenario, leg L1 near R1: 18.3 m vs 15.2 m RMS, see
docs/maritime.md). With matrix weights n^T P̂ n <= n^T P_i n for every direction n and
every channel i, so the fused sigma of any projection (cross-track deviation included)
never exceeds the best channel's.

Course is averaged as a weighted circular mean (weights 1/sigma_c^2), its sigma is
(sum w_c)^-1/2 (small-angle approximation, fine for sigma_c of a few degrees).
"""

from __future__ import annotations

import numpy as np
import polars as pl

from pipeline.frames import TWO_PI

FUSED_COLUMNS = (
    "time_ns",
    "system_track_id",
    "x_enu_m",
    "y_enu_m",
    "sigma_x_m",
    "sigma_y_m",
    "cov_xy_m2",
    "course_rad",
    "speed_mps",
    "sigma_course_rad",
    "sigma_speed_mps",
    "n_sources",
    "sources",
)


def fuse(associated: pl.DataFrame) -> pl.DataFrame:
    """Fuse the radars' synchronised tracks of each (epoch, system track), eq. 14
    (position in matrix form, see the module docstring).

    Consumes the rows of ``associate_tracks``, sorted by (time_ns, system_track_id,
    site_id): each group's sums are one ``numpy.add.reduceat`` over its consecutive rows
    (the same terms, added in the same order, as :func:`fuse_reference`'s polars
    aggregation); produces the same rows as it.
    """
    n = associated.height
    if n == 0:
        return fuse_reference(associated)
    t = associated["time_ns"].to_numpy()
    sid = associated["system_track_id"].to_numpy()
    if not ((t[1:] > t[:-1]) | ((t[1:] == t[:-1]) & (sid[1:] >= sid[:-1]))).all():
        return fuse_reference(associated)
    c = {k: associated[k].to_numpy().astype(float) for k in (
        "P_xx", "P_yy", "P_xy", "x_enu_m", "y_enu_m", "sigma_speed_mps", "sigma_course_rad",
        "speed_mps", "course_rad")}
    det = c["P_xx"] * c["P_yy"] - c["P_xy"] ** 2
    ixx, iyy, ixy = c["P_yy"] / det, c["P_xx"] / det, -c["P_xy"] / det
    x, y = c["x_enu_m"], c["y_enu_m"]
    wv, wc = c["sigma_speed_mps"] ** -2, c["sigma_course_rad"] ** -2
    terms = np.column_stack([
        ixx, iyy, ixy, ixx * x + ixy * y, ixy * x + iyy * y, wv, wc, wv * c["speed_mps"],
        wc * np.sin(c["course_rad"]), wc * np.cos(c["course_rad"]),
    ])
    new = np.r_[True, (t[1:] != t[:-1]) | (sid[1:] != sid[:-1])]
    starts = np.flatnonzero(new)
    sixx, siyy, sixy, six, siy, swv, swc, sv, ss, sc = group_sums(terms, starts).T
    d = sixx * siyy - sixy**2
    pxx, pyy, pxy = siyy / d, sixx / d, -sixy / d
    # polars' arctan2 and pow, as the reference (numpy's differ in the last bit at times)
    polar = pl.DataFrame({"s": ss, "c": sc, "wc": swc, "wv": swv}).select(
        (pl.arctan2(pl.col("s"), pl.col("c")) % TWO_PI).alias("course"),
        pl.col("wc").pow(-0.5).alias("sc"),
        pl.col("wv").pow(-0.5).alias("sv"),
    )
    return pl.DataFrame({
        "time_ns": t[starts],
        "system_track_id": sid[starts],
        "x_enu_m": pxx * six + pxy * siy,
        "y_enu_m": pxy * six + pyy * siy,
        "sigma_x_m": np.sqrt(pxx),
        "sigma_y_m": np.sqrt(pyy),
        "cov_xy_m2": pxy,
        "course_rad": polar["course"],
        "speed_mps": sv / swv,
        "sigma_course_rad": polar["sc"],
        "sigma_speed_mps": polar["sv"],
        "n_sources": np.diff(np.r_[starts, n]).astype(np.int16),
        "sources": _sources(associated["site_id"], new, starts),
    }, schema_overrides={"time_ns": pl.Int64, "system_track_id": pl.Int64})


def group_sums(values: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Sums of consecutive row groups (starting at ``starts``) of ``values`` (n, k), with
    compensated (Kahan) summation in row order: the sums polars' group and window
    aggregations compute, bit for bit. Vectorised over the groups; the loop runs over the
    position in the group (a handful: one row per radar site)."""
    n = values.shape[0]
    size = np.diff(np.r_[starts, n])
    # one or two terms: the compensated sum is the plain one (the first step adds to 0)
    s = np.add.reduceat(values, starts, axis=0) if n else np.zeros((0, values.shape[1]))
    big = np.flatnonzero(size > 2)
    if big.size == 0:
        return s
    st, sz = starts[big], size[big]
    acc = np.zeros((big.size, values.shape[1]))
    c = np.zeros_like(acc)
    for k in range(int(sz.max())):
        g = np.flatnonzero(sz > k)
        y = values[st[g] + k] - c[g]
        t = acc[g] + y
        c[g] = (t - acc[g]) - y
        acc[g] = t
    s[big] = acc
    return s


def _sources(site: pl.Series, new: np.ndarray, starts: np.ndarray) -> pl.Series:
    """Comma-joined sorted distinct site ids of each group: a bit mask of the group's
    sites, each distinct mask written once."""
    names = sorted(site.unique().to_list())
    if len(names) > 62:  # pragma: no cover - more sites than bits: the slow way
        groups = np.cumsum(new) - 1
        return (pl.DataFrame({"g": groups, "s": site})
                .group_by("g", maintain_order=True)
                .agg(pl.col("s").unique().sort().str.join(","))["s"])
    code = site.replace_strict(names, list(range(len(names))), return_dtype=pl.Int64).to_numpy()
    mask = np.bitwise_or.reduceat(np.left_shift(np.int64(1), code), starts)
    masks, inverse = np.unique(mask, return_inverse=True)
    text = [",".join(n for b, n in enumerate(names) if m >> b & 1) for m in masks.tolist()]
    return pl.Series("sources", text, dtype=pl.String).gather(inverse.ravel())


def fuse_reference(associated: pl.DataFrame) -> pl.DataFrame:
    """:func:`fuse` as one polars ``group_by`` (the reference the numpy path is tested
    against; also used for unsorted input).

    Consumes (from ``associate_tracks``): time_ns, system_track_id, site_id, x_enu_m,
    y_enu_m, P_xx, P_yy, P_xy (m^2), course_rad, speed_mps, sigma_course_rad,
    sigma_speed_mps.

    Produces one row per (time_ns, system_track_id): x_enu_m, y_enu_m (m), sigma_x_m,
    sigma_y_m (m), cov_xy_m2 (m^2), course_rad (rad in [0, 2pi)), speed_mps,
    sigma_course_rad, sigma_speed_mps, n_sources (int16), sources (comma-joined sorted
    site ids); sorted by (time_ns, system_track_id).
    """
    # information matrix I_i = P_i^-1 of each channel (closed-form 2x2 inverse)
    det = pl.col("P_xx") * pl.col("P_yy") - pl.col("P_xy") ** 2
    ixx, iyy, ixy = pl.col("P_yy") / det, pl.col("P_xx") / det, -pl.col("P_xy") / det
    x, y = pl.col("x_enu_m"), pl.col("y_enu_m")
    wv, wc = pl.col("sigma_speed_mps").pow(-2), pl.col("sigma_course_rad").pow(-2)
    sums = associated.group_by("time_ns", "system_track_id").agg(
        ixx.sum().alias("sixx"),
        iyy.sum().alias("siyy"),
        ixy.sum().alias("sixy"),
        (ixx * x + ixy * y).sum().alias("six"),
        (ixy * x + iyy * y).sum().alias("siy"),
        wv.sum().alias("swv"),
        wc.sum().alias("swc"),
        (wv * pl.col("speed_mps")).sum().alias("sv"),
        (wc * pl.col("course_rad").sin()).sum().alias("ss"),
        (wc * pl.col("course_rad").cos()).sum().alias("sc"),
        pl.len().cast(pl.Int16).alias("n_sources"),
        pl.col("site_id").unique().sort().str.join(",").alias("sources"),
    )
    # P_hat = (sum I_i)^-1, p_hat = P_hat sum I_i p_i
    d = pl.col("sixx") * pl.col("siyy") - pl.col("sixy") ** 2
    pxx, pyy, pxy = pl.col("siyy") / d, pl.col("sixx") / d, -pl.col("sixy") / d
    return sums.select(
        "time_ns",
        "system_track_id",
        (pxx * pl.col("six") + pxy * pl.col("siy")).alias("x_enu_m"),
        (pxy * pl.col("six") + pyy * pl.col("siy")).alias("y_enu_m"),
        pxx.sqrt().alias("sigma_x_m"),
        pyy.sqrt().alias("sigma_y_m"),
        pxy.alias("cov_xy_m2"),
        (pl.arctan2(pl.col("ss"), pl.col("sc")) % TWO_PI).alias("course_rad"),
        (pl.col("sv") / pl.col("swv")).alias("speed_mps"),
        pl.col("swc").pow(-0.5).alias("sigma_course_rad"),
        pl.col("swv").pow(-0.5).alias("sigma_speed_mps"),
        "n_sources",
        "sources",
    ).sort("time_ns", "system_track_id")


def fused_sigma(sigmas: np.ndarray) -> float:
    """Sigma of the inverse-variance weighted mean of independent channels,
    (sum_i 1/sigma_i^2)^-1/2, in the unit of ``sigmas``."""
    return float(np.sum(np.asarray(sigmas, float) ** -2) ** -0.5)


def paper_eq15_sigma(sigmas: np.ndarray) -> float:
    """Multi-radar paper eq. 15, for comparison only:

    .. math:: \\hat\\sigma = \\frac{\\sum_i \\sqrt{w_i}}{\\sqrt{N} \\sum_i w_i},
              \\qquad w_i = 1/\\sigma_i^2

    It equals (sum w_i)^-1/2 when all sigma_i are equal and UNDERESTIMATES the sigma of
    the eq. 14 mean when the channels differ (by Cauchy-Schwarz, sum sqrt(w_i) <=
    sqrt(N sum w_i)); e.g. sigmas 10 m and 40 m give 8.3 m instead of 9.7 m.
    """
    w = np.asarray(sigmas, float) ** -2
    return float(np.sum(np.sqrt(w)) / (np.sqrt(w.size) * np.sum(w)))
