"""Track-to-track association across radars, per synchronised epoch, with stable ids.

Gates (multi-radar paper, "determination of common tracks"): two synchronised tracks
may belong to one ship only when ALL differences are inside gates set from the
expected accuracies:

- position and velocity: squared Mahalanobis distance d^2 = D^T (P_a + P_b)^-1 D below
  chi2.ppf(gate_probability, 4), D the difference of the state vectors (east, north,
  v_east, v_north) (m, m/s) and P their covariances, block-diagonal (the trackers'
  position-velocity cross-covariance is not in the log), so d^2 is the position term
  plus the velocity term; with ``velocity_cost = false`` the position term alone
  below chi2.ppf(gate_probability, 2);
- course: |wrap(C_a - C_b)| <= max_course_difference_rad, skipped when both speeds are
  below course_gate_min_speed_mps (the course of a stopped ship is noise);
- speed: |V_a - V_b| <= max_speed_difference_mps.

The velocity v = V (sin C, cos C) has covariance J diag(sigma_V^2, sigma_C^2) J^T:
sigma_V along the course and V sigma_C across it (:func:`velocity_covariance`; as
``pipeline.maritime.hypothesis.velocity_covariance``). Below course_gate_min_speed_mps
the course is noise (the course gate's rule), so the across-course sigma is raised to at
least sigma_V.

Among competing pairings the least summed Mahalanobis distance wins (two-radar
identification paper, eq. 7-16: hypotheses H1..H4 of case A, and cases B/C when one
radar sees fewer targets; its state vector, eq. 2, has the velocity components, which
its simulation left out and its conclusion proposes to use). For two radars the paper's
per-hypothesis sum Sum_i (X_i - X_p)^T P_i^-1 (X_i - X_p), with X_p the fused state,
equals the pairwise D^T (P_1 + P_2)^-1 D, so minimising it over all hypotheses is the
assignment problem ``scipy.optimize.linear_sum_assignment`` on [d^2 | diag(gate)]:
leaving a track unpaired costs the gate, which yields cases B and C (and any m x n)
naturally.

N radars: sites are taken in a fixed order; site k's tracks are assigned to the
candidate system tracks built from sites < k (their eq. 14 fused position/course/speed
and the sigmas of speed and course, position in matrix form: the same ``Information``
sums that pipeline.maritime.fuse publishes), unassigned ones start new candidates.

Continuity over epochs: (site_id, local_track_id) -> system_track_id. A local track keeps
its system track as long as the gates still pass (its pairing gets a bonus that no
sum of gated distances can outweigh); a candidate takes the id most of its members
had (a pairing that persisted keeps its id; ties: closer to that track's last fused
state); a candidate made only of new local tracks joins a system track seen within
track_timeout_s that it gates with (extrapolated to the epoch; position d^2, 2 dof, and
the course/speed gates: the velocity of a track last seen up to track_timeout_s ago is
a stale estimate, with no manoeuvre model to widen it), else it gets a new id
a new id. A mapping not refreshed for track_timeout_s is forgotten.

A new id says when the system track was born: ``birth_ms * 1_000_000 + rank`` (the
epoch of its first row in ms since the Unix epoch, and its rank among the tracks born
in that ms; :func:`birth_ids`). Unlike a counter from the start of the rows given, the
id does not depend on where a window or a work unit starts: two cuts of one day that
associate an epoch alike number its new tracks alike (the batch's units overlap and
stitch on that, ``pipeline.maritime.stitch``).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from itertools import pairwise

import numpy as np
import polars as pl
from scipy.optimize import linear_sum_assignment

from pipeline.filters.quantiles import chi2_ppf
from pipeline.frames import wrap_angle
from pipeline.maritime.config import AssociationConfig
from pipeline.maritime.fuse import (
    CHANNEL_COLUMNS,
    Information,
    channel_information,
    channel_information_of_columns,
    group_sums,
)
from pipeline.maritime.sync import extrapolate_position, extrapolation_covariance
from pipeline.units import NS

try:  # the epoch loop in C (optional: built when a C compiler is present)
    from pipeline.maritime import _associate
except ImportError:  # pragma: no cover - same ids, ~30-100x slower
    _associate = None

#: continuity bonus, in units of the gate: keeps gated persisting pairs whatever the sums
_BONUS_GATES = 1000.0


@dataclass(frozen=True)
class Kinematics:
    """Positions, covariances and velocities of n tracks (all arrays (n,)): x_m, y_m
    (regional ENU), P_xx, P_yy, P_xy (m^2), speed_mps, course_rad, and the sigmas of
    speed and course (m/s, rad; None: the velocity is not used in d^2)."""

    x_m: np.ndarray
    y_m: np.ndarray
    P_xx: np.ndarray
    P_yy: np.ndarray
    P_xy: np.ndarray
    speed_mps: np.ndarray
    course_rad: np.ndarray
    sigma_speed_mps: np.ndarray | None = None
    sigma_course_rad: np.ndarray | None = None

    def take(self, idx: np.ndarray) -> Kinematics:
        return Kinematics(*(None if (v := getattr(self, f.name)) is None else np.asarray(v)[idx]
                            for f in fields(self)))

    def has_velocity(self) -> bool:
        return self.sigma_speed_mps is not None and self.sigma_course_rad is not None


def gate_threshold(gate_probability: float, dof: int = 2) -> float:
    """chi2.ppf(gate_probability, dof): the gate on d^2 (2 dof: position; 4: position
    and velocity)."""
    return float(chi2_ppf(gate_probability, dof))


def association_gate(cfg: AssociationConfig) -> float:
    """The gate of the track-to-track cost: 4 dof with ``velocity_cost``, else 2."""
    return gate_threshold(cfg.gate_probability, 4 if cfg.velocity_cost else 2)


def velocity_covariance(
    k: Kinematics, min_course_speed_mps: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(V_xx, V_yy, V_xy), (m/s)^2, of v = V (sin C, cos C): sigma_V^2 along the course,
    (V sigma_C)^2 across it (J diag(sigma_V^2, sigma_C^2) J^T), the across term raised to
    at least sigma_V^2 below ``min_course_speed_mps`` (a stopped ship's course is noise)."""
    s, c = np.sin(k.course_rad), np.cos(k.course_rad)
    along = np.asarray(k.sigma_speed_mps, float) ** 2
    across = (k.speed_mps * k.sigma_course_rad) ** 2
    across = np.where(k.speed_mps < min_course_speed_mps, np.maximum(across, along), across)
    return along * s * s + across * c * c, along * c * c + across * s * s, (along - across) * s * c


def _d2(dx, dy, sxx, syy, sxy) -> np.ndarray:
    """(dx, dy) S^-1 (dx, dy)^T with S = [[sxx, sxy], [sxy, syy]] (closed-form inverse)."""
    return (syy * dx * dx - 2.0 * sxy * dx * dy + sxx * dy * dy) / (sxx * syy - sxy * sxy)


def gated_d2(a: Kinematics, b: Kinematics, cfg: AssociationConfig, gate: float) -> np.ndarray:
    """(n_a, n_b) squared Mahalanobis distances D^T (P_a + P_b)^-1 D, +inf where the
    d^2, course or speed gate fails (broadcast, closed-form 2x2 inverses). D is the
    position difference, plus the velocity difference when ``cfg.velocity_cost`` and
    both sides carry speed and course sigmas (then ``gate`` should be the 4-dof one,
    :func:`association_gate`)."""
    dx = a.x_m[:, None] - b.x_m[None, :]
    dy = a.y_m[:, None] - b.y_m[None, :]
    sxx = a.P_xx[:, None] + b.P_xx[None, :]
    syy = a.P_yy[:, None] + b.P_yy[None, :]
    sxy = a.P_xy[:, None] + b.P_xy[None, :]
    d2 = _d2(dx, dy, sxx, syy, sxy)
    if cfg.velocity_cost and a.has_velocity() and b.has_velocity():
        ua = a.speed_mps * np.sin(a.course_rad), a.speed_mps * np.cos(a.course_rad)
        ub = b.speed_mps * np.sin(b.course_rad), b.speed_mps * np.cos(b.course_rad)
        Va = velocity_covariance(a, cfg.course_gate_min_speed_mps)
        Vb = velocity_covariance(b, cfg.course_gate_min_speed_mps)
        d2 = d2 + _d2(ua[0][:, None] - ub[0][None, :], ua[1][:, None] - ub[1][None, :],
                      *(Va[i][:, None] + Vb[i][None, :] for i in range(3)))
    va, vb = a.speed_mps[:, None], b.speed_mps[None, :]
    slow = (va < cfg.course_gate_min_speed_mps) & (vb < cfg.course_gate_min_speed_mps)
    dc = np.abs(wrap_angle(a.course_rad[:, None] - b.course_rad[None, :]))
    ok = (
        (d2 < gate)
        & (np.abs(va - vb) <= cfg.max_speed_difference_mps)
        & (slow | (dc <= cfg.max_course_difference_rad))
    )
    return np.where(ok, d2, np.inf)


def assign(cost: np.ndarray, miss_cost: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Least-sum assignment of rows to columns where leaving a row unassigned costs
    ``miss_cost`` (augmented matrix [cost | diag(miss)]); +inf entries are forbidden.
    Returns matched (row indices, column indices).

    Gated matrices are sparse: a row whose only admissible column admits only that row
    is matched directly; ``linear_sum_assignment`` runs on the rest only.
    """
    n, m = cost.shape
    if n == 0 or m == 0:
        return np.empty(0, int), np.empty(0, int)
    miss = np.broadcast_to(np.asarray(miss_cost, float), (n,))
    ok = np.isfinite(cost) & (cost < miss[:, None])
    row_n, col_n = ok.sum(axis=1), ok.sum(axis=0)
    col_of = np.argmax(ok, axis=1)
    lone = (row_n == 1) & (col_n[col_of] == 1)
    r1, c1 = np.flatnonzero(lone), col_of[lone]
    rest_r = np.flatnonzero((row_n > 0) & ~lone)
    rest_c = np.flatnonzero(ok[rest_r].any(axis=0)) if rest_r.size else np.empty(0, int)
    if rest_r.size == 0:
        return r1, c1
    sub = np.where(ok[np.ix_(rest_r, rest_c)], cost[np.ix_(rest_r, rest_c)], np.inf)
    k, mc = rest_r.size, rest_c.size
    aug = np.full((k, mc + k), np.inf)
    aug[:, :mc] = sub
    aug[np.arange(k), mc + np.arange(k)] = miss[rest_r]
    rows, cols = linear_sum_assignment(aug)
    keep = cols < mc
    r = np.concatenate([r1, rest_r[rows[keep]]])
    c = np.concatenate([c1, rest_c[cols[keep]]])
    order = np.argsort(r)
    return r[order], c[order]


_STATE_FORM = 1
"""How ``_associate.c`` turns the sums into a state: 1 = information form
(:meth:`pipeline.maritime.fuse.Information.estimate`)."""


def _channel_terms(rows: Kinematics, sv: np.ndarray, sc: np.ndarray) -> np.ndarray:
    """Each channel's own eq. 14 terms (:func:`pipeline.maritime.fuse.channel_information`),
    (n, 10) in the order of :class:`~pipeline.maritime.fuse.Information`'s fields: what a
    candidate's sums accumulate."""
    own = channel_information(rows.x_m, rows.y_m, rows.P_xx, rows.P_yy, rows.P_xy,
                              rows.speed_mps, sv, rows.course_rad, sc)
    return np.column_stack(own.terms())


def assign_grouped(
    rows: np.ndarray,
    cols: np.ndarray,
    cost: np.ndarray,
    miss: np.ndarray,
    group_of_row: np.ndarray,
    n_cols: int,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`assign` of many independent matrices at once, given as entries.

    Rows and columns are global indices; each row belongs to one group
    (``group_of_row``) and pairs only with columns of its group; entries not given are
    +inf; ``miss``: each row's miss cost. The result is what :func:`assign` returns for
    each group's matrix (rows and columns in ascending order), concatenated and sorted
    by row: lone matches directly, then, per group that has any left, the same
    ``linear_sum_assignment`` on the same augmented matrix. The loop runs over those
    groups only (a handful where the gates overlap), never over rows.
    """
    rows = np.asarray(rows, np.int64)
    cols = np.asarray(cols, np.int64)
    cost = np.asarray(cost, float)
    ok = np.isfinite(cost) & (cost < miss[rows])
    rows, cols, cost = rows[ok], cols[ok], cost[ok]
    if rows.size == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    order = np.lexsort((cols, rows))
    rows, cols, cost = rows[order], cols[order], cost[order]
    n_rows = group_of_row.size
    row_n = np.bincount(rows, minlength=n_rows)
    col_n = np.bincount(cols, minlength=n_cols)
    first = np.flatnonzero(np.r_[True, rows[1:] != rows[:-1]])
    col_of = np.full(n_rows, -1, np.int64)
    col_of[rows[first]] = cols[first]
    has = row_n > 0
    lone = has & (row_n == 1) & (col_n[np.maximum(col_of, 0)] == 1)
    r_out, c_out = [np.flatnonzero(lone)], [col_of[lone]]
    rest = has & ~lone
    sel = rest[rows]
    e_rows, e_cols, e_cost = rows[sel], cols[sel], cost[sel]
    if e_rows.size:
        g = group_of_row[e_rows]
        by_group = np.argsort(g, kind="stable")
        g, e_rows, e_cols = g[by_group], e_rows[by_group], e_cols[by_group]
        e_cost = e_cost[by_group]
        bounds = np.flatnonzero(np.r_[True, g[1:] != g[:-1], True])
        for a, b in pairwise(bounds):
            rr, cc, vv = e_rows[a:b], e_cols[a:b], e_cost[a:b]
            rest_r = np.unique(rr)
            rest_c = np.unique(cc)
            k, mc = rest_r.size, rest_c.size
            aug = np.full((k, mc + k), np.inf)
            aug[np.searchsorted(rest_r, rr), np.searchsorted(rest_c, cc)] = vv
            aug[np.arange(k), mc + np.arange(k)] = miss[rest_r]
            lr, lc = linear_sum_assignment(aug)
            keep = lc < mc
            r_out.append(rest_r[lr[keep]])
            c_out.append(rest_c[lc[keep]])
    r = np.concatenate(r_out)
    c = np.concatenate(c_out)
    order = np.argsort(r, kind="stable")
    return r[order], c[order]


class _Candidates:
    """Candidate system tracks of one epoch as running sums of eq. 14 in information
    form (multi-radar paper, eq. 14; :class:`pipeline.maritime.fuse.Information`, one
    row of ``sums`` per candidate), so a candidate's state is exactly what
    :func:`pipeline.maritime.fuse.fuse` publishes for the same members."""

    def __init__(self, capacity: int, n_sites: int) -> None:
        self.n = 0
        self.sums = np.zeros((capacity, len(fields(Information))))
        self.prev_ids = np.full((capacity, n_sites), -1, dtype=np.int64)

    def add(
        self,
        clusters: np.ndarray,
        rows: Kinematics,
        sv: np.ndarray,
        sc: np.ndarray,
        prev: np.ndarray,
        site: int,
    ) -> None:
        np.add.at(self.sums, clusters, _channel_terms(rows, sv, sc))
        self.prev_ids[clusters, site] = prev

    def new(self, k: int) -> np.ndarray:
        idx = np.arange(self.n, self.n + k)
        self.n += k
        return idx

    def state(self) -> tuple[Kinematics, np.ndarray, np.ndarray]:
        """Fused kinematics of the candidates (eq. 14, :meth:`Information.estimate`:
        position, speed, course and their sigmas), with (sigma_speed, sigma_course)."""
        f = Information(*self.sums[: self.n].T).estimate()
        kin = Kinematics(f.x_m, f.y_m, f.P_xx, f.P_yy, f.P_xy, f.speed_mps, f.course_rad,
                         f.sigma_speed_mps, f.sigma_course_rad)
        return kin, f.sigma_speed_mps, f.sigma_course_rad


@dataclass
class _Memory:
    """State carried across epochs: per local-track key and per system track."""

    key_sys: np.ndarray  # (n_keys,) system index (allocation order), -1 none
    key_seen: np.ndarray  # (n_keys,) last epoch ns
    sys_seen: np.ndarray  # (n_sys,) last epoch ns
    sys_state: np.ndarray  # (n_sys, 9): x, y, Pxx, Pyy, Pxy, V, C, sigma_V, sigma_C
    n_sys: int = 0

    def grow(self, k: int) -> np.ndarray:
        if self.n_sys + k > self.sys_seen.size:
            cap = max(2 * self.sys_seen.size, self.n_sys + k)
            self.sys_seen = np.resize(self.sys_seen, cap)
            self.sys_state = np.resize(self.sys_state, (cap, 9))
        idx = np.arange(self.n_sys, self.n_sys + k)
        self.n_sys += k
        return idx


BIRTH_RANK_LIMIT = 1_000_000
"""Tracks born in one millisecond at most (``birth_ids``): ids stay below 2^63 until
the year 2262 like the int64 ns timestamps themselves."""


def birth_ids(sys_idx: np.ndarray, time_ns: np.ndarray) -> np.ndarray:
    """System track id of each row from its system index (allocated in epoch order,
    from 0): ``birth_ms * BIRTH_RANK_LIMIT + rank``, birth_ms the first epoch of the
    index in ms, rank its order among the indices born in that ms."""
    if sys_idx.size == 0:
        return sys_idx.astype(np.int64)
    first = np.full(int(sys_idx.max()) + 1, np.iinfo(np.int64).max, np.int64)
    np.minimum.at(first, sys_idx, time_ns)
    birth_ms = first // 1_000_000  # nondecreasing: indices are allocated epoch by epoch
    rank = np.arange(first.size) - np.searchsorted(birth_ms, birth_ms, side="left")
    if rank.max() >= BIRTH_RANK_LIMIT:
        raise ValueError(f"more than {BIRTH_RANK_LIMIT} system tracks born in one ms")
    return (birth_ms * BIRTH_RANK_LIMIT + rank)[sys_idx]


def associate_tracks(synced: pl.DataFrame, *, cfg: AssociationConfig) -> pl.DataFrame:
    """Assign every synchronised radar track to a system track, epoch by epoch.

    Consumes (from ``synchronise``): time_ns, site_id, local_track_id, x_enu_m, y_enu_m,
    P_xx, P_yy, P_xy (m^2), course_rad, speed_mps, sigma_course_rad, sigma_speed_mps
    (other columns pass through).

    Produces the same rows plus system_track_id (int64, stable over time, new ids from
    the birth epoch: :func:`birth_ids`) and mahalanobis_d2 (distance to the eq. 14 fused position of
    the OTHER members of its system track at that epoch; null when alone), sorted by
    (time_ns, system_track_id, site_id).
    """
    df, site_idx, n_keys, n_sites = prepare_rows(synced)
    sys_idx = _assign_ids(df, site_idx, n_keys, n_sites, cfg)
    ids = birth_ids(sys_idx, df["time_ns"].to_numpy())
    order = np.lexsort((site_idx, ids, df["time_ns"].to_numpy()))
    out = df.drop("_key")[order].with_columns(pl.Series("system_track_id", ids[order],
                                                        dtype=pl.Int64))
    d2, alone = leave_one_out_d2(out)
    return out.with_columns(
        pl.when(pl.Series(alone)).then(None).otherwise(pl.Series(d2)).alias("mahalanobis_d2")
    )


def associate_tracks_reference(synced: pl.DataFrame, *, cfg: AssociationConfig
                               ) -> pl.DataFrame:
    """:func:`associate_tracks` with the numpy epoch loop and the polars leave-one-out
    distance (the reference the fast path is tested against)."""
    df, site_idx, n_keys, n_sites = prepare_rows(synced)
    sys_idx = _assign_ids_reference(df, site_idx, n_keys, n_sites, cfg)
    out = df.drop("_key").with_columns(
        pl.Series("system_track_id", birth_ids(sys_idx, df["time_ns"].to_numpy()),
                  dtype=pl.Int64)
    )
    return _with_leave_one_out_d2(out).sort("time_ns", "system_track_id", "site_id")


def prepare_rows(synced: pl.DataFrame) -> tuple[pl.DataFrame, np.ndarray, int, int]:
    """The epoch loop's input: rows sorted by (time_ns, site_id, local_track_id) with a
    ``_key`` column (index of the (site, local track) pair), each row's site index (sites
    in sorted order), the number of keys and of sites. Rows that come sorted (as
    ``synchronise`` returns them) are not sorted again."""
    sites = sorted(synced["site_id"].unique().to_list())
    code = synced["site_id"].replace_strict(sites, list(range(len(sites))),
                                            return_dtype=pl.Int64).to_numpy()
    t = synced["time_ns"].to_numpy()
    track = synced["local_track_id"].to_numpy()
    if not _lex_sorted(t, code, track):
        order = np.lexsort((track, code, t))
        synced, t, code, track = synced[order], t[order], code[order], track[order]
    if track.size:
        lo, span = int(track.min()), int(track.max()) - int(track.min()) + 1
        if span * max(len(sites), 1) < 2**62:
            _, key = np.unique(code * span + (track - lo), return_inverse=True)
        else:  # pragma: no cover - absurd track ids
            _, key = np.unique(np.column_stack([code, track]), axis=0, return_inverse=True)
        n_keys = int(key.max()) + 1
    else:
        key, n_keys = np.zeros(0, np.int64), 0
    df = synced.with_columns(pl.Series("_key", key.astype(np.int64).ravel(), dtype=pl.UInt32))
    return df, code, n_keys, len(sites)


def _lex_sorted(*keys: np.ndarray) -> bool:
    """True when the rows are sorted by the keys (first key first)."""
    n = keys[0].size
    if n < 2:
        return True
    tied = np.ones(n - 1, bool)  # pairs not yet decided by an earlier key
    for k in keys:
        a, b = k[:-1], k[1:]
        if np.any(tied & (b < a)):
            return False
        tied &= b == a
    return True


def leave_one_out_d2(df: pl.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """(d2, alone): mahalanobis_d2 of each row to the eq. 14 fusion (matrix form,
    :class:`~pipeline.maritime.fuse.Information`) of the OTHER members of its (time_ns,
    system_track_id) group (the group's sums minus the row's own terms), and whether the
    row is alone in its group (no distance). Rows sorted by (time_ns, system_track_id,
    site_id); compensated group sums (:func:`~pipeline.maritime.fuse.group_sums`: the
    sums of :func:`_with_leave_one_out_d2`'s window expressions, bit for bit)."""
    n = df.height
    if n == 0:
        return np.empty(0), np.empty(0, bool)
    c = {k: df[k].to_numpy().astype(float) for k in CHANNEL_COLUMNS}
    t, sid = df["time_ns"].to_numpy(), df["system_track_id"].to_numpy()
    new = np.r_[True, (t[1:] != t[:-1]) | (sid[1:] != sid[:-1])]
    starts = np.flatnonzero(new)
    group = np.cumsum(new) - 1
    own = np.column_stack(channel_information(*c.values()).terms())
    with np.errstate(divide="ignore", invalid="ignore"):  # rows alone: no others
        o = Information(*(group_sums(own, starts)[group] - own).T).estimate()
        d2 = _d2(c["x_enu_m"] - o.x_m, c["y_enu_m"] - o.y_m, c["P_xx"] + o.P_xx,
                 c["P_yy"] + o.P_yy, c["P_xy"] + o.P_xy)
    alone = np.diff(np.r_[starts, n])[group] == 1
    return d2, alone


def _assign_ids(
    df: pl.DataFrame, site_idx: np.ndarray, n_keys: int, n_sites: int, cfg: AssociationConfig
) -> np.ndarray:
    """System index of every row: the compiled epoch loop (``_associate.c``: the same
    gates, costs and assignments as :func:`_assign_ids_reference`, with spatial gating
    and without a numpy call per site step), or the reference without a C compiler."""
    if _associate is None:
        return _assign_ids_reference(df, site_idx, n_keys, n_sites, cfg)
    return _assign_ids_native(df, site_idx, n_keys, n_sites, cfg)


def _lsa_columns(cost: bytes, k: int, m: int) -> bytes:
    """The kernel's callback: scipy's assignment of a (k, m) cost matrix (k <= m), as
    int64 column per row."""
    _, cols = linear_sum_assignment(np.frombuffer(cost, np.float64).reshape(k, m))
    return np.ascontiguousarray(cols, np.int64).tobytes()


def _assign_ids_native(
    df: pl.DataFrame, site_idx: np.ndarray, n_keys: int, n_sites: int, cfg: AssociationConfig
) -> np.ndarray:
    cols = [
        np.ascontiguousarray(df[c].to_numpy(), np.float64)
        for c in ("x_enu_m", "y_enu_m", "P_xx", "P_yy", "P_xy", "speed_mps", "course_rad",
                  "sigma_speed_mps", "sigma_course_rad")
    ]
    kin = Kinematics(*cols)
    terms = np.ascontiguousarray(_channel_terms(kin, kin.sigma_speed_mps, kin.sigma_course_rad))
    out = np.empty(df.height, np.int64)
    _associate.assign_ids(
        np.ascontiguousarray(df["time_ns"].to_numpy(), np.int64),
        np.ascontiguousarray(site_idx, np.int64),
        np.ascontiguousarray(df["_key"].to_numpy(), np.int64),
        *cols,
        terms,
        out,
        int(n_keys),
        int(n_sites),
        association_gate(cfg),
        gate_threshold(cfg.gate_probability, 2),
        float(cfg.max_course_difference_rad),
        float(cfg.max_speed_difference_mps),
        float(cfg.course_gate_min_speed_mps),
        float(_BONUS_GATES),
        round(cfg.track_timeout_s * NS),
        _STATE_FORM,
        int(cfg.velocity_cost),
        _lsa_columns,
    )
    return out


def _assign_ids_reference(
    df: pl.DataFrame, site_idx: np.ndarray, n_keys: int, n_sites: int, cfg: AssociationConfig
) -> np.ndarray:
    """The epoch loop in numpy (the reference the compiled loop is tested against).
    Everything inside an epoch is array work (broadcast gates, one
    linear_sum_assignment per site and one for the ids); epochs must be processed in
    order because each epoch's ids depend on the previous ones, hence the loop."""
    t = df["time_ns"].to_numpy()
    kin = Kinematics(
        *(
            df[c].to_numpy().astype(float)
            for c in ("x_enu_m", "y_enu_m", "P_xx", "P_yy", "P_xy", "speed_mps", "course_rad",
                      "sigma_speed_mps", "sigma_course_rad")
        )
    )
    sv, sc = kin.sigma_speed_mps, kin.sigma_course_rad
    key = df["_key"].to_numpy().astype(np.int64)
    mem = _Memory(
        key_sys=np.full(n_keys, -1, np.int64),
        key_seen=np.full(n_keys, np.iinfo(np.int64).min // 2, np.int64),
        sys_seen=np.zeros(max(16, n_keys), np.int64),
        sys_state=np.zeros((max(16, n_keys), 9)),
    )
    gate = association_gate(cfg)  # the cost of the per-epoch assignment
    gate_position = gate_threshold(cfg.gate_probability, 2)  # ids against past tracks
    timeout_ns = round(cfg.track_timeout_s * NS)
    out = np.empty(t.size, np.int64)
    bounds = np.flatnonzero(np.r_[True, t[1:] != t[:-1], True]) if t.size else np.zeros(1, int)
    for a, b in pairwise(bounds):
        rows = np.arange(a, b)
        prev = np.where(mem.key_seen[key[rows]] >= t[a] - timeout_ns, mem.key_sys[key[rows]], -1)
        cand, member = _cluster_epoch(
            kin.take(rows), sv[rows], sc[rows], prev, site_idx[rows], n_sites, cfg, gate
        )
        ids = _resolve_ids(cand, mem, int(t[a]), cfg, gate_position)
        out[rows] = ids[member]
        mem.key_sys[key[rows]] = out[rows]
        mem.key_seen[key[rows]] = t[a]
        fused, fsv, fsc = cand.state()
        mem.sys_seen[ids] = t[a]
        mem.sys_state[ids] = np.column_stack(
            [
                fused.x_m,
                fused.y_m,
                fused.P_xx,
                fused.P_yy,
                fused.P_xy,
                fused.speed_mps,
                fused.course_rad,
                fsv,
                fsc,
            ]
        )
    return out


def _cluster_epoch(
    rows: Kinematics,
    sv: np.ndarray,
    sc: np.ndarray,
    prev: np.ndarray,
    site: np.ndarray,
    n_sites: int,
    cfg: AssociationConfig,
    gate: float,
) -> tuple[_Candidates, np.ndarray]:
    """Sequential N-radar clustering of one epoch's rows (sorted by site). Returns the
    candidates and each row's candidate index. ``gate``: :func:`association_gate`."""
    if not rows.has_velocity():
        rows = replace(rows, sigma_speed_mps=sv, sigma_course_rad=sc)
    cand = _Candidates(site.size, n_sites)
    member = np.full(site.size, -1)
    for s in np.unique(site):
        r = np.flatnonzero(site == s)
        if cand.n:
            fused, _, _ = cand.state()
            cost = gated_d2(rows.take(r), fused, cfg, gate)
            persists = (prev[r, None, None] == cand.prev_ids[None, : cand.n, :]).any(-1)
            persists &= (prev[r] >= 0)[:, None]
            cost = np.where(persists & np.isfinite(cost), cost - _BONUS_GATES * gate, cost)
            ri, ci = assign(cost, gate)
            member[r[ri]] = ci
        fresh = r[member[r] < 0]
        member[fresh] = cand.new(fresh.size)
        cand.add(member[r], rows.take(r), sv[r], sc[r], prev[r], int(s))
    return cand, member


def _resolve_ids(
    cand: _Candidates, mem: _Memory, t_ns: int, cfg: AssociationConfig, gate: float
) -> np.ndarray:
    """System index (allocation order) of each candidate, one assignment problem:
    columns are the system tracks seen within track_timeout_s. A candidate may take
    an id its members had (cost -10 per member vote; ties between ids go to the older
    id (+ rank/n_live < 1), ties between candidates for one id to the one closer to
    that track's last state (+ 0.01 min(d^2/gate, 1))), or, when none of its members
    had an id, an id it gates with (cost d^2/gate - 1, in [-1, 0)). The rest get new
    ids. d^2 is the position's (``gate``: 2 dof): :func:`_predict` carries no velocity
    sigmas, the last fused velocity being a stale estimate."""
    live = np.flatnonzero(mem.sys_seen[: mem.n_sys] >= t_ns - round(cfg.track_timeout_s * NS))
    votes = (cand.prev_ids[: cand.n, :, None] == live[None, None, :]).sum(axis=1)
    fused, _, _ = cand.state()
    d2 = gated_d2(fused, _predict(mem, live, t_ns), cfg, gate)
    voted = votes > 0
    orphan = ~(cand.prev_ids[: cand.n] >= 0).any(axis=1)
    cost = np.full(votes.shape, np.inf)
    age_rank = np.broadcast_to(np.arange(live.size) / max(live.size, 1), votes.shape)
    cost[voted] = -10.0 * votes[voted] + age_rank[voted] + 0.01 * np.minimum(d2[voted] / gate, 1.0)
    reuse = orphan[:, None] & np.isfinite(d2)
    cost[reuse] = d2[reuse] / gate - 1.0
    ids = np.full(cand.n, -1, np.int64)
    ci, li = assign(cost, 0.0)
    ids[ci] = live[li]
    new = np.flatnonzero(ids < 0)
    ids[new] = mem.grow(new.size)
    return ids


def _predict(mem: _Memory, sys: np.ndarray, t_ns: int) -> Kinematics:
    """Last fused state of system tracks ``sys`` extrapolated to ``t_ns`` (eq. 9, with
    the eq. 12 variance inflation for speed and course errors)."""
    s = mem.sys_state[sys].T
    dt = (t_ns - mem.sys_seen[sys]) / NS
    x, y = extrapolate_position(s[0], s[1], s[5], s[6], dt)
    dxx, dyy, dxy = extrapolation_covariance(s[5], s[6], dt, s[7], s[8], 0.0)
    return Kinematics(x, y, s[2] + dxx, s[3] + dyy, s[4] + dxy, s[5], s[6])


def _with_leave_one_out_d2(df: pl.DataFrame) -> pl.DataFrame:
    """mahalanobis_d2 of each row to the eq. 14 fusion (matrix form, the same
    :class:`pipeline.maritime.fuse.Information` as :func:`pipeline.maritime.fuse.fuse`)
    of the OTHER members of its system track at that epoch: the group's sums minus the
    row's own terms, then d^2 = D^T (P + P_others)^-1 D; null when alone."""
    g = ["time_ns", "system_track_id"]
    own = channel_information_of_columns()
    others = own.map(lambda t: t.sum().over(g)) - own
    o_cols = others.aliased("_o_")
    tmp = df.with_columns(*o_cols, pl.len().over(g).alias("_n"))
    o = Information.columns("_o_").estimate()
    dx, dy = pl.col("x_enu_m") - o.x_m, pl.col("y_enu_m") - o.y_m
    sxx, syy = pl.col("P_xx") + o.P_xx, pl.col("P_yy") + o.P_yy
    sxy = pl.col("P_xy") + o.P_xy
    d2 = (syy * dx * dx - 2.0 * sxy * dx * dy + sxx * dy * dy) / (sxx * syy - sxy * sxy)
    return tmp.with_columns(
        pl.when(pl.col("_n") > 1).then(d2).otherwise(None).alias("mahalanobis_d2")
    ).drop(*(e.meta.output_name() for e in o_cols), "_n")


def split_parents(associations: pl.DataFrame, track_timeout_s: float) -> pl.DataFrame:
    """The system track each system track split from: for a track whose first epoch
    holds local tracks that, at their previous report (at most ``track_timeout_s``
    before), belonged to one other system track, (system_track_id, parent_track_id,
    split_ns = the child's first epoch). A track born of new local tracks only, or of
    local tracks from several system tracks, has no row.

    Consumes associations: time_ns, site_id, local_track_id, system_track_id (every
    associated row, fused or not: a row left out of the fusion still says which system
    track its radar track was on)."""
    key = ["site_id", "local_track_id"]
    rows = associations.select("time_ns", *key, "system_track_id")
    if not rows["time_ns"].is_sorted():
        rows = rows.sort("time_ns", maintain_order=True)
    first = rows.filter(pl.col("time_ns") == pl.col("time_ns").min().over("system_track_id"))
    # each first row's local track at its report before (an as-of join: ~9x a sort of
    # every row by local track)
    moved = first.join_asof(
        rows.select(pl.col("time_ns").alias("previous_ns"), *key,
                    pl.col("system_track_id").alias("parent_track_id")),
        left_on="time_ns", right_on="previous_ns", by=key, strategy="backward",
        allow_exact_matches=False, check_sortedness=False,
    ).filter(pl.col("parent_track_id").is_not_null()
             & (pl.col("parent_track_id") != pl.col("system_track_id"))
             & (pl.col("time_ns") - pl.col("previous_ns") <= round(track_timeout_s * NS)))
    return (moved.group_by("system_track_id", pl.col("time_ns").alias("split_ns"))
            .agg(pl.col("parent_track_id").unique())
            .filter(pl.col("parent_track_id").list.len() == 1)
            .select("system_track_id", pl.col("parent_track_id").list.first(), "split_ns")
            .sort("system_track_id"))
