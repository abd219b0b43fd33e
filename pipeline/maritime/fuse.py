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
