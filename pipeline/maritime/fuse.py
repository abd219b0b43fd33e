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

The sums of eq. 14 (information matrix and vector for the position, weight sums for
speed and course) are kept in one place, :class:`Information`, used by :func:`fuse`, by
the candidate system tracks of the track-to-track association and by its leave-one-out
distance (``pipeline.maritime.associate``): system track ids are decided on the same
fused state that is published.

Course is averaged as a weighted circular mean (weights 1/sigma_c^2), its sigma is
(sum w_c)^-1/2 (small-angle approximation, fine for sigma_c of a few degrees).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

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

#: the per-channel columns eq. 14 reads (order of :func:`channel_information`'s arguments)
CHANNEL_COLUMNS = (
    "x_enu_m",
    "y_enu_m",
    "P_xx",
    "P_yy",
    "P_xy",
    "speed_mps",
    "sigma_speed_mps",
    "course_rad",
    "sigma_course_rad",
)

#: a numpy array (one value per channel or per set of channels) or a polars expression
Terms = np.ndarray | pl.Expr


@dataclass(frozen=True)
class Information:
    """The sums of eq. 14 over a set of channels (multi-radar paper, eq. 14; position in
    matrix, i.e. information, form):

    .. math:: I = \\sum_i P_i^{-1}, \\quad \\mathbf i = \\sum_i P_i^{-1} \\mathbf p_i,
              \\quad \\sum_i w_{V,i}, \\ \\sum_i w_{V,i} V_i, \\quad
              \\sum_i w_{C,i}, \\ \\sum_i w_{C,i} (\\sin C_i, \\cos C_i)

    Fields: I_xx, I_yy, I_xy (m^-2), i_x, i_y (m^-1), w_v = sum 1/sigma_V^2 (s^2/m^2),
    wv = sum V/sigma_V^2 (s/m), w_c = sum 1/sigma_C^2 (rad^-2), wc_sin, wc_cos (rad^-2).

    This is the ONE implementation of eq. 14: :func:`fuse` aggregates it per (epoch,
    system track), the track-to-track association keeps its candidate system tracks as
    running sums of it and takes a row's own terms out of its group's sums for the
    leave-one-out distance (``pipeline.maritime.associate``). Every field is either a
    numpy array or a polars expression: the same arithmetic (and numpy ufuncs, which
    polars expressions implement) serves both, so the two paths cannot drift apart.
    Sets of channels add (``+``) and a channel's terms subtract (``-``).
    """

    I_xx: Terms
    I_yy: Terms
    I_xy: Terms
    i_x: Terms
    i_y: Terms
    w_v: Terms
    wv: Terms
    w_c: Terms
    wc_sin: Terms
    wc_cos: Terms

    def terms(self) -> tuple[Terms, ...]:
        """The fields in declaration order (e.g. the columns of a (n, 10) array)."""
        return tuple(getattr(self, f.name) for f in fields(self))

    def map(self, fn) -> Information:
        """``fn`` applied to every field (e.g. ``lambda e: e.sum().over(key)``)."""
        return Information(*(fn(t) for t in self.terms()))

    def __add__(self, other: Information) -> Information:
        return Information(*(a + b for a, b in zip(self.terms(), other.terms(), strict=True)))

    def __sub__(self, other: Information) -> Information:
        return Information(*(a - b for a, b in zip(self.terms(), other.terms(), strict=True)))

    def aliased(self, prefix: str) -> list[pl.Expr]:
        """Polars fields as expressions named ``prefix + field``."""
        return [t.alias(prefix + f.name) for f, t in zip(fields(self), self.terms(), strict=True)]

    @staticmethod
    def columns(prefix: str) -> Information:
        """The sums read back from columns written by :meth:`aliased`."""
        return Information(*(pl.col(prefix + f.name) for f in fields(Information)))

    def estimate(self) -> FusedEstimate:
        """The fused state of the set, eq. 14 in matrix form for the position
        (P_hat = I^-1, p_hat = P_hat i, closed-form 2x2 inverse), per parameter for
        speed and course (weighted circular mean), sigmas (sum w)^-1/2 (not eq. 15)."""
        det = self.I_xx * self.I_yy - self.I_xy * self.I_xy
        P_xx, P_yy, P_xy = self.I_yy / det, self.I_xx / det, -self.I_xy / det
        return FusedEstimate(
            x_m=P_xx * self.i_x + P_xy * self.i_y,
            y_m=P_xy * self.i_x + P_yy * self.i_y,
            P_xx=P_xx,
            P_yy=P_yy,
            P_xy=P_xy,
            speed_mps=self.wv / self.w_v,
            course_rad=np.arctan2(self.wc_sin, self.wc_cos) % TWO_PI,
            sigma_speed_mps=self.w_v**-0.5,
            sigma_course_rad=self.w_c**-0.5,
        )


@dataclass(frozen=True)
class FusedEstimate:
    """Eq. 14 estimate of sets of channels (arrays or polars expressions): x_m, y_m
    (regional ENU, m), P_xx, P_yy, P_xy (m^2), speed_mps, course_rad (rad in [0, 2pi)),
    sigma_speed_mps, sigma_course_rad."""

    x_m: Terms
    y_m: Terms
    P_xx: Terms
    P_yy: Terms
    P_xy: Terms
    speed_mps: Terms
    course_rad: Terms
    sigma_speed_mps: Terms
    sigma_course_rad: Terms


def channel_information(
    x_m: Terms,
    y_m: Terms,
    P_xx: Terms,
    P_yy: Terms,
    P_xy: Terms,
    speed_mps: Terms,
    sigma_speed_mps: Terms,
    course_rad: Terms,
    sigma_course_rad: Terms,
) -> Information:
    """Each channel's own terms of eq. 14: I_i = P_i^-1 (closed-form 2x2 inverse),
    I_i p_i, w_V = 1/sigma_V^2, w_V V, w_C = 1/sigma_C^2, w_C (sin C, cos C). Arguments
    are arrays (n,) or polars expressions, units as in :data:`CHANNEL_COLUMNS`."""
    det = P_xx * P_yy - P_xy * P_xy
    ixx, iyy, ixy = P_yy / det, P_xx / det, -P_xy / det
    wv, wc = sigma_speed_mps**-2, sigma_course_rad**-2
    return Information(
        I_xx=ixx,
        I_yy=iyy,
        I_xy=ixy,
        i_x=ixx * x_m + ixy * y_m,
        i_y=ixy * x_m + iyy * y_m,
        w_v=wv,
        wv=wv * speed_mps,
        w_c=wc,
        wc_sin=wc * np.sin(course_rad),
        wc_cos=wc * np.cos(course_rad),
    )


def channel_information_of_columns() -> Information:
    """:func:`channel_information` of the frame's :data:`CHANNEL_COLUMNS` (expressions)."""
    return channel_information(*(pl.col(c) for c in CHANNEL_COLUMNS))


def fuse(associated: pl.DataFrame) -> pl.DataFrame:
    """Fuse the radars' synchronised tracks of each (epoch, system track), eq. 14
    (position in matrix form, see the module docstring): the sums of
    :class:`Information` per group, then :meth:`Information.estimate`.

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
    own = channel_information(*(associated[k].to_numpy().astype(float) for k in CHANNEL_COLUMNS))
    new = np.r_[True, (t[1:] != t[:-1]) | (sid[1:] != sid[:-1])]
    starts = np.flatnonzero(new)
    sums = Information(*group_sums(np.column_stack(own.terms()), starts).T)
    f = sums.estimate()
    # polars' pow, as the reference's ``w ** -0.5`` on expressions (numpy's differs in the
    # last bit at times); np.arctan2 on an expression is numpy's, as here
    polar = pl.DataFrame({"wc": sums.w_c, "wv": sums.w_v}).select(
        pl.col("wc").pow(-0.5).alias("sc"),
        pl.col("wv").pow(-0.5).alias("sv"),
    )
    return pl.DataFrame({
        "time_ns": t[starts],
        "system_track_id": sid[starts],
        "x_enu_m": f.x_m,
        "y_enu_m": f.y_m,
        "sigma_x_m": np.sqrt(f.P_xx),
        "sigma_y_m": np.sqrt(f.P_yy),
        "cov_xy_m2": f.P_xy,
        "course_rad": f.course_rad,
        "speed_mps": f.speed_mps,
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
    sums = associated.group_by("time_ns", "system_track_id").agg(
        *channel_information_of_columns().map(lambda t: t.sum()).aliased("_s_"),
        pl.len().cast(pl.Int16).alias("n_sources"),
        pl.col("site_id").unique().sort().str.join(",").alias("sources"),
    )
    f = Information.columns("_s_").estimate()
    return sums.select(
        "time_ns",
        "system_track_id",
        f.x_m.alias("x_enu_m"),
        f.y_m.alias("y_enu_m"),
        np.sqrt(f.P_xx).alias("sigma_x_m"),
        np.sqrt(f.P_yy).alias("sigma_y_m"),
        f.P_xy.alias("cov_xy_m2"),
        f.course_rad.alias("course_rad"),
        f.speed_mps.alias("speed_mps"),
        f.sigma_course_rad.alias("sigma_course_rad"),
        f.sigma_speed_mps.alias("sigma_speed_mps"),
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
