"""Channel integrity of the coastal picture: every radar per sector and every AIS
transponder tested the airfield way (airfield paper eq. 21-23), excluded from fusion and
identification while in fault (issue 22).

The airfield paper's test (its eq. 21-23, :mod:`pipeline.filters.integrity`) takes the
quadratic form of a channel's innovation against the estimate of the state,

.. math:: \\xi = r^T (H P H^T + R)^{-1} r, \\qquad
          \\eta = 0 \\text{ if } \\xi \\in (d_1, d_2), \\; 1 \\text{ otherwise}

with d1, d2 the equal-tail chi-square quantiles for a false-alarm probability q. Here the
estimate a channel is tested against is the picture WITHOUT that channel:

- **radar** (site c, sector g, epoch k): for every system track with a report of c, the
  leave-one-out reference is the information-form fusion (multi-radar paper eq. 14, matrix
  form) of the track's other radars that are not excluded and of the AIS report of the
  transponder that track carries (extrapolated to the epoch, sigma
  ``ais_sigma_position_m``): r_i = p_i - p_ref, S_i = P_i + P_ref, xi_i ~ chi2(2). With two
  radars and no AIS, xi_1 = xi_2: the disagreement cannot be attributed and the track is
  not tested (with three or more radars, two others are a majority and it is).
  The channel's tracks in the sector give two statistics (the chi-square quantiles at
  q/2 each, so one decision has false-alarm probability ~q):

  * the NIS sum, sum_i xi_i ~ chi2(2n), two equal tails at q/4 (any excess error:
    degraded noise, a fault of any shape);
  * a registration test: r_i = H_i theta + noise with theta = (range bias b_r, azimuth
    bias b_az, time offset dt) and H_i = [u_r, rho u_az, -v] (u_r, u_az: the radial and
    clockwise unit vectors from the site, rho the range, v the track velocity; the model
    of ``pipeline.maritime.bias``). theta_hat = A^-1 b with A = sum H^T S^-1 H,
    b = sum H^T S^-1 r, and T = b^T A^-1 b ~ chi2(3) (n >= 2), upper tail q/2. theta_hat
    is the evidence a fault episode reports (estimated range, azimuth and time bias).
    The sums A and b are kept with a fourth parameter, the range gain (H's column
    rho u_r), for the online registration (:mod:`pipeline.maritime.registration`); the
    test takes their first three rows and columns.

  A single bad AIS (an AIS fault) makes one track disagree with every radar: tracks with
  xi_i above chi2_2(1 - outlier_q) are outliers, and outliers fewer than half of the
  channel's tracks in the sector are left out of its test (under H0 they occur with
  probability outlier_q = 1e-4 per track, so the null distributions hold).
- **radar coverage** (outage): ships that other channels see in the site's range in the
  sector (other radars' tracks, AIS transponders whose radar track vanished) but that the
  site does not detect (no report, or a coasted one: course and speed bit-equal to its
  previous report, the tracker's prediction) -- a share above ``coverage_miss_share`` of
  at least ``coverage_min_targets`` is an outage (eta = 1). **Missing scans**: a site whose
  last published scan ended more than ``scan_gap_factor`` scan periods before the epoch is
  down in every sector.
- **AIS** (transponder m, each report): against the radar-only fused track the
  transponder belongs to (its reference track, established by the first report that
  falls in the gate of a track and kept while the transponder is excluded), extrapolated
  to the report time; S = sigma_AIS^2 I + P_fused; xi ~ chi2(2), thresholds of eq. 22 at
  q. A transponder whose reports match no track in the coverage of a radar in service
  (a spoofed track) is tested against the nearest track. The first ``ais_warmup_reports``
  of a transponder without a reference track are not decided (a new ship's radar track
  needs three scans). A report is not decided on a track reported by a radar excluded for
  more than 2 ``readmit_run`` epochs in a row (a lasting fault, not a false alarm): the
  fault corrupts the picture, the association's pairings too, and the disagreements it
  causes are the radar's; when that radar is readmitted, the transponders of the sector
  in its range take their reference tracks anew.
  The reference track is kept while the transponder fails (a swapped MMSI keeps failing
  against the ship it belonged to); a failing transponder takes another track only when
  its reports fall in that track's gate ``readmit_run`` times in a row, the track is free
  or held only by failing transponders, and its own stream did not jump (a report more
  than ``ais_jump_m`` from the previous one dead-reckoned): that is the radar association
  having exchanged two ships' track ids, not an MMSI moving to another ship.
- **silent radars are no witnesses**: a radar takes part in the AIS checks of a sector
  (``covered`` above: a reference track looked for, a transponder without one tested as a
  spoofer) only while it publishes scans (its last scan ended at most
  ``scan_gap_factor`` scan periods ago) and has detected at least
  ``coverage_min_targets`` ships (distinct tracks, each in ``readmit_run`` epochs) in that
  sector within ``witness_s`` (:func:`_seeing`; a track glimpsed at a sector's edge is no
  sight of it). A radar declared in the config without data, or a sector it does not see,
  is out of service there: before, every AIS report in its range was tested against a
  radar track that does not exist (``ais_unmatched``, nis = inf; 18,161 of 18,623 reports
  of a real AIS day with two declared, silent radars). AIS-only data gets the kinematic
  self-test alone.

Per epoch the radars are tested first (with the AIS exclusions of the previous epoch),
their exclusions updated, then the AIS reports against the radar picture of the radars
in service: a radar fault is attributed to the radar, not to every transponder it sees.
Exclusion and readmission follow the airfield rule
(:func:`pipeline.filters.integrity.step_exclusion`): excluded on a failure of an upper
threshold (eta = 1 from the lower tail of the NIS sum, a channel agreeing better than
its sigmas, is recorded but excludes nothing: it harms no fusion), readmitted after
``readmit_run`` passing checks in a row. One deviation for radars: an upper-tail failure
excludes once ``radar_confirm`` (2) epochs in a row failed. A radar false alarm would
otherwise take a good radar out of every sector for ``readmit_run`` epochs (~2 % of a
fault-free hour at radar_q = 0.001), leaving a sector to a radar 4x worse; confirmation
costs one epoch of exclusion delay on a real fault (the flag itself is not delayed).
With ``exclusion = false`` every check is recorded and nothing is excluded.

The loop runs over epochs; inside it every track, radar row and AIS report of the epoch
is one array operation.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import polars as pl

from pipeline import frames
from pipeline import time_sources as ts
from pipeline.config import Config
from pipeline.filters.integrity import chi2_thresholds, eta, step_exclusion
from pipeline.filters.quantiles import chi2_ppf
from pipeline.geometry import assign_sectors
from pipeline.maritime.associate import gate_threshold
from pipeline.maritime.config import ChannelIntegrityConfig, MaritimeConfig
from pipeline.maritime.fuse import channel_information
from pipeline.maritime.identity import ais_at_epochs
from pipeline.maritime.sync import extrapolation_covariance
from pipeline.spatial import MAX_CELLS, pairs_within
from pipeline.units import NS

#: wide prior on (range bias m, azimuth bias rad, time offset s, range gain): conditions A
#: when the tracks' geometry leaves a parameter unobservable (e.g. every ship stationary,
#: or every ship at one range: bias and gain)
THETA_PRIOR = np.array([1.0e3, 0.2, 100.0, 0.05])
TESTED = 3
"""The integrity's registration test takes the first three parameters (range bias,
azimuth bias, time offset: airfield paper eq. 21-23 on the model of
:mod:`pipeline.maritime.bias`); the online registration
(:mod:`pipeline.maritime.registration`) estimates the range gain too."""
DIM = THETA_PRIOR.size

HEALTH_COLUMNS = (
    "time_ns", "channel", "sensor_kind", "sector", "check", "targets", "nis", "dof", "d1",
    "d2", "q", "bias_stat", "bias_d2", "eta", "excluded", "range_bias_m", "azimuth_bias_rad",
    "time_offset_s", "offset_east_m", "offset_north_m", "innovation_m", "expected", "missed",
    "outliers", "scan_gap_s", "kinematic_nis", "mmsi", "system_track_id",
)  # fmt: skip


@dataclass(frozen=True, eq=False)
class IntegrityResult:
    """What :func:`check_channels` returns.

    - ``health``: rows of ``maritime_channel_health`` (one per radar, sector and epoch
      decided; one per AIS report decided), see ``schemas/tables.d/maritime_integrity.toml``;
    - ``associations``: the ``associated`` rows sorted by (time_ns, system_track_id,
      site_id) with ``used`` (bool): fused (its radar was in service in its sector after
      that epoch's check);
    - ``ais_excluded``: (mmsi, time_ns) of the AIS reports sent while their transponder was
      excluded (left out of identification);
    - ``evidence``: the registration test's sums per epoch and radar group, the
      evidence :mod:`pipeline.maritime.registration` estimates and corrects from.
    """

    health: pl.DataFrame
    associations: pl.DataFrame
    ais_excluded: pl.DataFrame
    evidence: RegistrationEvidence


@dataclass(frozen=True, eq=False)
class RegistrationEvidence:
    """Per epoch k and radar group (site * (G + 1) + sector; G: outside every sector) the
    sums of the leave-one-out residuals of the group's tracks tested (outliers of a
    minority left out): ``A`` = sum H^T S^-1 H (K, n_groups, 4, 4, no prior), ``b`` =
    sum H^T S^-1 r (K, n_groups, 4), ``nis`` = sum r^T S^-1 r, ``n`` tracks, ``trace`` =
    sum tr(S^-1 P) (P: the radar's own covariance: how much of S is the radar's),
    ``n_ais`` of the tracks tested against their AIS report (the rest: against two or
    more other radars);
    ``blocked``: the group's scan check failed there (no scan published: an outage no
    correction readmits); ``excluded`` after the epoch's check. Per row
    of ``associations``: its epoch ``row_k``, group ``row_group``, ``H`` (n, 2, 4),
    d(position)/d(range bias, azimuth bias, time offset, range gain), its leave-one-out residual
    ``row_r`` (n, 2) and its covariance ``row_innov_cov`` (n, 3) (NaN: no other radar,
    no AIS report on the track), ``row_tested`` (in the test: its AIS report or two
    other radars), its own covariance ``row_cov`` (n, 3), its speed, course and their
    sigmas ``row_velocity`` (n, 4: m/s, rad) and the SOG and COG of the AIS report its
    track was tested against ``row_ais_velocity`` (n, 2; NaN: none, or not given).
    ``G``, ``C``: sectors, sites.
    ``pair_info`` (K, 4C, 4C: A of the pairs), ``pair_b`` (K, 4C), ``pair_nis`` (K,),
    ``pair_n`` (K, C): the radar-radar evidence of tracks without a transponder seen by
    two sites (:func:`_pair_evidence`), in every site's registration at once."""

    epochs: np.ndarray
    A: np.ndarray
    b: np.ndarray
    nis: np.ndarray
    n: np.ndarray
    trace: np.ndarray
    n_ais: np.ndarray
    blocked: np.ndarray
    excluded: np.ndarray
    row_k: np.ndarray
    row_group: np.ndarray
    H: np.ndarray
    row_r: np.ndarray
    row_innov_cov: np.ndarray
    row_tested: np.ndarray
    row_cov: np.ndarray
    row_velocity: np.ndarray
    row_ais_velocity: np.ndarray
    G: int
    C: int
    pair_info: np.ndarray
    pair_b: np.ndarray
    pair_nis: np.ndarray
    pair_n: np.ndarray


# --- the inputs as arrays (computed once, before the epoch loop) -----------------------


@dataclass(frozen=True, eq=False)
class _Radar:
    """The associated radar rows, sorted by (epoch, system track, site), and the tracks of
    every epoch ("slots": one per (epoch, system track), in the same order)."""

    bounds: np.ndarray  # (K + 1,) rows of each epoch
    slot: np.ndarray  # (n,) slot of each row's track, relative to its epoch's first slot
    group: np.ndarray  # (n,) site * (G + 1) + sector index (G: outside every sector)
    site: np.ndarray  # (n,)
    xy: np.ndarray  # (n, 2) synchronised position, regional ENU, m
    P: np.ndarray  # (n, 3) its covariance xx, yy, xy, m^2
    info: np.ndarray  # (n, 5) information terms (eq. 14, matrix form)
    H: np.ndarray  # (n, 2, 4) d(position)/d(range bias, azimuth bias, time offset, gain)
    v: np.ndarray  # (n, 2) velocity east, north, m/s
    sv: np.ndarray  # (n,) sigma speed, m/s
    sc: np.ndarray  # (n,) sigma course, rad
    slot_bounds: np.ndarray  # (K + 1,) slots of each epoch
    track: np.ndarray  # (N,) system_track_id of each slot (sorted within an epoch)
    slot_sector: np.ndarray  # (N,) sector of the slot's first row
    p_all: np.ndarray  # (N, 2) estimate from every radar row
    P_all: np.ndarray  # (N, 3)
    near: np.ndarray  # (N, C) within each site's range
    detected: np.ndarray  # (N, C) the site reported it at the epoch, not coasted
    detected_row: np.ndarray  # (n,) the row is not a coasted report


@dataclass(frozen=True, eq=False)
class _Ais:
    """AIS references at epochs and AIS reports to decide, as arrays."""

    ref_bounds: np.ndarray  # (K + 1,) rows of the reference picture of each epoch
    ref_m: np.ndarray  # transponder index
    ref_xy: np.ndarray  # (r, 2) extrapolated to the epoch
    ref_info: np.ndarray  # (r, 5)
    ref_velocity: np.ndarray  # (r, 2) SOG m/s, COG rad of the report (NaN: not given)
    ref_sector: np.ndarray
    ref_near: np.ndarray  # (r, C)
    rep_bounds: np.ndarray  # (K + 1,) reports decided at each epoch (the next epoch)
    rep_m: np.ndarray
    rep_t: np.ndarray  # report time, ns
    rep_dt: np.ndarray  # report time - epoch, s (<= 0)
    rep_xy: np.ndarray
    rep_sector: np.ndarray
    rep_near: np.ndarray  # (n, C) within each site's range
    rep_lead: np.ndarray  # before the window: reference tracks only, no decision
    rep_groups: np.ndarray  # (n, C) radar group (site, sector of the report) per site
    rep_round: np.ndarray  # rank of the report among its transponder's at its epoch
    rep_jump: np.ndarray  # farther than ais_jump_m from its previous report dead-reckoned
    rep_self: np.ndarray  # NIS against the previous report moved on (NaN: none)
    var: np.ndarray  # (3,) AIS position covariance xx, yy, xy, m^2
    rep_cand: np.ndarray  # (n, NEAREST) slots nearest to the report (every radar row), -1
    rep_cand_d2: np.ndarray  # (n, NEAREST) their squared Mahalanobis distances
    mmsi: np.ndarray  # transponder index -> MMSI
    mmsi_near: np.ndarray  # (M, C) transponder ever reported within the site's range


NEAREST = 4  # candidate tracks kept per AIS report
_MAX_SCALE = 8  # grids for the AIS candidates: cells of 4^0 .. 4^8 x the median reach / 4
COVERAGE_MARGIN = 0.97  # share of a radar's max range where it is expected to see a ship
_UNIT = np.array([1.0, 1.0, 0.0])  # a covariance (xx, yy, xy) that is never singular


def _info(P: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(n, 5) position terms I_xx, I_yy, I_xy, i_x, i_y of eq. 14 (matrix form) for
    positions with covariance P (n, 3): :func:`pipeline.maritime.fuse.channel_information`,
    the one implementation of eq. 14 (speed and course are not tested here)."""
    one = np.ones(x.shape)
    info = channel_information(x, y, P[:, 0], P[:, 1], P[:, 2], one, one, one, one)
    return np.column_stack(info.terms()[:5])


def _estimate(info: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions (n, 2) and covariances (n, 3) from summed information terms (eq. 14:
    P = I^-1, p = P i); NaN where there is no information."""
    with np.errstate(divide="ignore", invalid="ignore"):
        det = info[:, 0] * info[:, 1] - info[:, 2] ** 2
        P = np.column_stack([info[:, 1], info[:, 0], -info[:, 2]]) / det[:, None]
        p = np.column_stack([P[:, 0] * info[:, 3] + P[:, 2] * info[:, 4],
                             P[:, 2] * info[:, 3] + P[:, 1] * info[:, 4]])
    return p, P


def _d2(r: np.ndarray, S: np.ndarray) -> np.ndarray:
    """r^T S^-1 r for r (n, 2), S (n, 3) (closed-form 2x2, eq. 21)."""
    det = S[:, 0] * S[:, 1] - S[:, 2] ** 2
    return (S[:, 1] * r[:, 0] ** 2 - 2 * S[:, 2] * r[:, 0] * r[:, 1]
            + S[:, 0] * r[:, 1] ** 2) / det


def _sums(index: np.ndarray, values: np.ndarray, size: int) -> np.ndarray:
    """Per-index sums of the columns of ``values`` (n, m) -> (size, m), one bincount."""
    m = values.shape[1]
    flat = (index[:, None] * m + np.arange(m)).ravel()
    w = values.ravel().astype(float, copy=False)
    return np.bincount(flat, weights=w, minlength=size * m).reshape(size, m)


def coasted_reports(aligned: pl.DataFrame) -> pl.DataFrame:
    """(site_id, local_track_id, time_ns, coasted) of the aligned reports: a report whose
    course and speed equal its track's previous report's to the bit is the tracker's
    prediction (no plot: coasting). One row per (site_id, local_track_id, time_ns), the
    last of duplicates; equality as polars compares (NaN equals NaN, a null nothing).

    The rows are put in (site, track, time) order by one stable ``np.lexsort`` of integer
    keys (the site as a category code): a third of a polars sort on the string key."""
    site = aligned["site_id"].cast(pl.Categorical).to_physical().fill_null(-1).to_numpy()
    track = aligned["local_track_id"].fill_null(np.iinfo(np.int64).min).to_numpy()
    t = aligned["time_ns"].to_numpy()
    order = np.lexsort((t, track, site))
    site, track, t = site[order], track[order], t[order]
    same = np.zeros(order.size, bool)
    same[1:] = (site[1:] == site[:-1]) & (track[1:] == track[:-1])
    coasted = same & _repeats(aligned["course_rad"], order) & _repeats(
        aligned["speed_mps"], order)
    last = np.ones(order.size, bool)  # the last row of each (site, track, time)
    last[:-1] = ~(same[1:] & (t[1:] == t[:-1]))
    keep = order[last]
    return aligned.select("site_id", "local_track_id", "time_ns")[keep].with_columns(
        pl.Series("coasted", coasted[last]))


def coasted_reports_polars(aligned: pl.DataFrame) -> pl.DataFrame:
    """:func:`coasted_reports` as one polars sort, shift and unique: the reference its
    fast path is tested against (rows in another order)."""
    key = ["site_id", "local_track_id"]
    return (
        aligned.select(*key, "time_ns", "course_rad", "speed_mps")
        .sort(*key, "time_ns", maintain_order=True)
        .with_columns(  # sorted by track: the previous row, when of the same track
            ((pl.col("course_rad") == pl.col("course_rad").shift(1))
             & (pl.col("speed_mps") == pl.col("speed_mps").shift(1))
             & _same_as_previous(key))
            .fill_null(False).alias("coasted")
        )
        .select(*key, "time_ns", "coasted")
        .unique([*key, "time_ns"], keep="last", maintain_order=True)
    )


def _repeats(column: pl.Series, order: np.ndarray) -> np.ndarray:
    """Row i (in ``order``) equals row i - 1 as polars' ``==`` says: NaN equals NaN, -0.0
    equals 0.0, a null equals nothing (False on the first row)."""
    x = column.to_numpy()[order].astype(np.float64, copy=False)
    valid = ~column.is_null().to_numpy()[order]
    out = np.zeros(order.size, bool)
    out[1:] = (((x[1:] == x[:-1]) | (np.isnan(x[1:]) & np.isnan(x[:-1])))
               & valid[1:] & valid[:-1])
    return out


@dataclass(frozen=True, eq=False)
class _Geometry:
    site_xy: np.ndarray  # (C, 2) site positions in the regional frame, m
    site_range: np.ndarray  # (C,) max range, m
    G: int  # sectors (index G: outside every sector)

    def near(self, xy: np.ndarray) -> np.ndarray:
        """(n, C): positions well inside each site's range (``COVERAGE_MARGIN`` of it: a
        ship at the edge may be out of range for the radar and in for the estimate)."""
        d = xy[:, None, :] - self.site_xy[None, :, :]
        return np.hypot(d[..., 0], d[..., 1]) <= COVERAGE_MARGIN * self.site_range[None, :]


def site_positions_enu(cfg: Config) -> np.ndarray:
    """(C, 2) each radar site's position in the regional frame, m (``cfg.radar_sites``
    order)."""
    sx, sy = frames.geodetic_to_enu(
        np.array([s.lat_deg for s in cfg.radar_sites]),
        np.array([s.lon_deg for s in cfg.radar_sites]),
        cfg.region.origin_lat_deg, cfg.region.origin_lon_deg)
    return np.column_stack([np.atleast_1d(sx), np.atleast_1d(sy)])


def registration_jacobian(xy: np.ndarray, site_xy: np.ndarray, vx: np.ndarray, vy: np.ndarray
                          ) -> np.ndarray:
    """(n, 2, 4) H = d(position)/d(range bias, azimuth bias, time offset, range gain) of
    reports at ``xy`` (n, 2) seen from ``site_xy`` (n, 2) moving at (``vx``, ``vy``) m/s:
    [u_r, rho u_az, -v, rho u_r] (measured range = (1 + gain) true range + bias)."""
    d = xy - site_xy
    rho = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1.0)
    H = np.empty((xy.shape[0], 2, DIM))
    H[:, 0, 0], H[:, 1, 0] = d[:, 0] / rho, d[:, 1] / rho  # range bias: line of sight
    H[:, 0, 1], H[:, 1, 1] = d[:, 1], -d[:, 0]  # azimuth bias (clockwise): rho u_az
    H[:, 0, 2], H[:, 1, 2] = -vx, -vy  # time offset: the report is dt late
    H[:, 0, 3], H[:, 1, 3] = d[:, 0], d[:, 1]  # range gain: rho u_r
    return H


def _radar_arrays(
    assoc: pl.DataFrame, coasted: pl.DataFrame, epochs: np.ndarray, cfg: Config,
    geo: _Geometry, sector_index: dict[str | None, int],
) -> _Radar:
    G, C = geo.G, geo.site_xy.shape[0]
    sites = [s.site_id for s in cfg.radar_sites]
    df = assoc.join(
        coasted.rename({"time_ns": "report_time_ns"}),
        on=["site_id", "local_track_id", "report_time_ns"], how="left", maintain_order="left",
    ).with_columns(
        pl.col("site_id").replace_strict(sites, list(range(C)), return_dtype=pl.Int64)
        .alias("_site"),
    )
    site = df["_site"].to_numpy().astype(np.int64)  # (int even when empty: no radar)
    sector = _sector_codes(df["sector"], sector_index)
    xy = df.select("x_enu_m", "y_enu_m").to_numpy()
    P = df.select("P_xx", "P_yy", "P_xy").to_numpy()
    vx, vy = frames.velocity_enu(df["speed_mps"].to_numpy(), df["course_rad"].to_numpy())
    H = registration_jacobian(xy, geo.site_xy[site], vx, vy)
    t = df["time_ns"].to_numpy()
    bounds = np.searchsorted(t, np.append(epochs, np.iinfo(np.int64).max))
    slot = _track_slots(t, df["system_track_id"].to_numpy())
    # slots: one per (epoch, track), in row order
    k_row = np.repeat(np.arange(epochs.size), np.diff(bounds))
    n_slots = np.zeros(epochs.size, np.int64)
    np.maximum.at(n_slots, k_row, slot + 1)
    slot_bounds = np.r_[0, np.cumsum(n_slots)]
    gslot = slot_bounds[k_row] + slot
    N = int(slot_bounds[-1])
    info = _info(P, xy[:, 0], xy[:, 1])
    p_all, P_all = _estimate(_sums(gslot, info, N))
    first = np.unique(gslot, return_index=True)[1]
    detected = np.zeros((N, C), bool)
    seen = ~df["coasted"].fill_null(False).to_numpy()
    detected[gslot[seen], site[seen]] = True
    track = np.zeros(N, np.int64)
    track[gslot] = df["system_track_id"].to_numpy()
    return _Radar(
        bounds=bounds, slot=slot, group=(site * (G + 1) + sector).astype(np.int64), site=site,
        xy=xy, P=P,
        info=info, H=H, v=np.column_stack([vx, vy]), sv=df["sigma_speed_mps"].to_numpy(),
        sc=df["sigma_course_rad"].to_numpy(), slot_bounds=slot_bounds, track=track,
        slot_sector=sector[first], p_all=p_all, P_all=P_all, near=geo.near(p_all),
        detected=detected, detected_row=seen,
    )


def _track_slots(time_ns: np.ndarray, track: np.ndarray) -> np.ndarray:
    """Each row's track slot in its epoch (0, 1, ... in track id order) of rows sorted by
    (time_ns, track): the dense rank of the track within the epoch."""
    if time_ns.size == 0:
        return np.zeros(0, np.int64)
    new_epoch = np.r_[True, time_ns[1:] != time_ns[:-1]]
    new_slot = new_epoch | np.r_[True, track[1:] != track[:-1]]
    n = np.cumsum(new_slot) - 1
    return n - np.maximum.accumulate(np.where(new_epoch, n, 0))


def _ais_arrays(
    ais_reports: pl.DataFrame, epochs: np.ndarray, start_ns: int, cfg: Config,
    ic: ChannelIntegrityConfig, epoch_ns: int, sector_index: dict[str | None, int],
    geo: _Geometry, rad: _Radar,
) -> _Ais:
    acfg = replace(cfg.ais, sigma_position_m=ic.ais_sigma_position_m,
                   max_report_age_s=ic.ais_max_age_s)
    reports = ais_reports.filter(pl.col("lat_deg").is_not_null() & pl.col("lon_deg").is_not_null())
    ref = ais_at_epochs(reports, epochs, cfg=acfg, region=cfg.region)
    mmsi = np.unique(reports["mmsi"].to_numpy())

    def sectors_of(df: pl.DataFrame) -> np.ndarray:
        return _sector_codes(assign_sectors(df, cfg.sectors, cfg.region)["sector"],
                             sector_index)

    x, y = frames.geodetic_to_enu(reports["lat_deg"].to_numpy(), reports["lon_deg"].to_numpy(),
                                  cfg.region.origin_lat_deg, cfg.region.origin_lon_deg)
    rep = self_test(
        _with_timing(reports).select(*SELF_TEST_COLUMNS)
        .with_columns(pl.Series("x_enu_m", np.atleast_1d(x)),
                      pl.Series("y_enu_m", np.atleast_1d(y))), ic)
    k = np.searchsorted(epochs, rep["time_ns"].to_numpy(), side="left")  # next epoch
    keep = k < epochs.size
    rep = rep.filter(pl.Series(keep)).with_columns(pl.Series("k", k[keep])).sort(
        "k", "time_ns", "mmsi")
    kk = rep["k"].to_numpy()
    rt = rep["time_ns"].to_numpy()
    rxy = rep.select("x_enu_m", "y_enu_m").to_numpy()
    cand, cand_d2 = nearest_slots(rxy, kk, rad, ic.ais_sigma_position_m**2,
                                  gate_threshold(cfg.ais.gate_probability))
    rsector = sectors_of(rep)
    C = geo.site_xy.shape[0]
    var = ic.ais_sigma_position_m**2
    ref_xy = ref.select("x_enu_m", "y_enu_m").to_numpy()
    ref_cov = ref.select("P_xx", "P_yy", "P_xy").to_numpy()
    ref_velocity = ref.select("mmsi", "ais_time_ns").join(
        reports.select("mmsi", pl.col("time_ns").alias("ais_time_ns"), "sog_mps", "cog_rad")
        .unique(["mmsi", "ais_time_ns"], keep="last"),
        on=["mmsi", "ais_time_ns"], how="left", maintain_order="left",
    ).select(pl.col("sog_mps", "cog_rad").cast(pl.Float64).fill_null(np.nan)).to_numpy()
    return _Ais(
        ref_bounds=np.searchsorted(ref["time_ns"].to_numpy(),
                                   np.append(epochs, np.iinfo(np.int64).max)),
        ref_m=np.searchsorted(mmsi, ref["mmsi"].to_numpy()),
        ref_xy=ref_xy,
        ref_info=_info(ref_cov, ref_xy[:, 0], ref_xy[:, 1]),
        ref_velocity=ref_velocity,
        ref_sector=sectors_of(ref),
        ref_near=geo.near(ref_xy),
        rep_bounds=np.searchsorted(kk, np.arange(epochs.size + 1)),
        rep_m=np.searchsorted(mmsi, rep["mmsi"].to_numpy()),
        rep_t=rt,
        rep_dt=(rt - epochs[kk]) / NS,
        rep_xy=rxy,
        rep_sector=rsector,
        rep_near=geo.near(rxy),
        rep_groups=np.arange(C)[None, :] * (geo.G + 1) + rsector[:, None],
        rep_round=_rank_within(kk, rep["mmsi"].to_numpy()),
        rep_jump=rep["jump"].to_numpy(),
        rep_self=rep["self_xi"].fill_null(np.nan).to_numpy(),
        mmsi_near=_sums(np.searchsorted(mmsi, rep["mmsi"].to_numpy()), geo.near(rxy),
                        mmsi.size) > 0,
        var=np.array([var, var, 0.0]),
        rep_lead=(rt < start_ns) | (rt <= epochs[kk] - epoch_ns),
        rep_cand=cand,
        rep_cand_d2=cand_d2,
        mmsi=mmsi,
    )


def _rank_within(k: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Rank of each row among the earlier rows with its (k, m): ``int_range(len).over(k,
    m)`` with one stable lexsort."""
    order = np.lexsort((m, k))  # stable: rows of a (k, m) keep their order
    ks, ms = k[order], m[order]
    start = np.ones(order.size, bool)
    start[1:] = (ks[1:] != ks[:-1]) | (ms[1:] != ms[:-1])
    first = np.maximum.accumulate(np.where(start, np.arange(order.size), 0))
    rank = np.empty(order.size, np.int64)
    rank[order] = np.arange(order.size) - first
    return rank


def _sector_codes(sector: pl.Series, sector_index: dict[str | None, int]) -> np.ndarray:
    """``sector_index`` of each sector name (None: outside every sector); an unknown name
    raises."""
    names = [n for n in sector_index if n is not None]
    return (sector.replace_strict(names, [sector_index[n] for n in names],
                                  return_dtype=pl.Int64)
            .fill_null(sector_index[None]).to_numpy().astype(np.int64))  # (int when empty)


def _same_as_previous(key: list[str]) -> pl.Expr:
    """True where the row's ``key`` equals the previous row's (False on the first row): on
    rows sorted by ``key``, ``pl.col(c).shift(1)`` masked by it is ``shift(1).over(key)``
    without the window's group-by."""
    same = pl.int_range(pl.len()) > 0  # (a null key is a group of its own, as in over)
    for c in key:
        same = same & pl.col(c).eq_missing(pl.col(c).shift(1))
    return same


#: ITU-R M.1371-5 Annex 8, message 27 (long-range broadcast): position in 1/10 min
#: (185 m), SOG in knots, no time stamp (a latency flag: "> 5 s" by default). Its
#: position is no fix of a known time to 3 m: not tested against the transponder's own
#: kinematics, nor the previous report of one that is.
LONG_RANGE_MSG_TYPE = 27
_WHOLE_SECOND_SOURCES = (ts.TAG_BLOCK, ts.NAIS_EPOCH)  # reception times in whole seconds
_WGS84_A_M = 6378137.0
_WGS84_E2 = 6.69437999014e-3


def _with_timing(reports: pl.DataFrame) -> pl.DataFrame:
    """``reports`` with ``msg_type``, ``utc_second`` and ``time_source`` (null where a
    frame built without them, as the tests' synthetic AIS, lacks them)."""
    cols = {"msg_type": pl.Int16, "utc_second": pl.Int16, "time_source": pl.String}
    return reports.with_columns(pl.lit(None, dtype).alias(c) for c, dtype in cols.items()
                                if c not in reports.columns)


SELF_TEST_COLUMNS = ("time_ns", "mmsi", "lat_deg", "lon_deg", "sog_mps", "cog_rad", "msg_type",
                     "utc_second", "time_source")


def self_test(reports: pl.DataFrame, ic: ChannelIntegrityConfig) -> pl.DataFrame:
    """Every AIS report against its transponder's previous one (the kinematic
    self-test, :func:`fix_time` and :func:`_kinematics`): ``reports`` with
    :data:`SELF_TEST_COLUMNS` (``msg_type``, ``utc_second``, ``time_source`` may be
    absent; other columns are kept), one row per (mmsi, time_ns) sorted by them, with
    ``fix_ns``, ``time_var_s2``, ``self_xi`` (null: not decided) and ``jump``."""
    return (_with_timing(reports).unique(["mmsi", "time_ns"], keep="last")
            .sort("mmsi", "time_ns")
            .with_columns(*fix_time(ic))
            .with_columns(*_kinematics(ic)))


def fix_time(ic: ChannelIntegrityConfig) -> tuple[pl.Expr, pl.Expr]:
    """``(fix_ns, time_var_s2)``: when each report's position was fixed, and the
    variance of that time (s^2), from its time stamp and its ``time_source``
    (:mod:`pipeline.time_sources`).

    - **Time stamp** (``utc_second`` s in 0-59; ITU-R M.1371-5 Annex 8, messages 1-3,
      18, 19: "UTC second when the report was generated by the EPFS"; 60-63: not
      available, manual input, dead reckoning, inoperative): the fix lies in that second
      of the minute before the reception time t, and not after t. With
      lag = ((t - s + L) mod 60 s) - L (``L`` = :data:`pipeline.time_sources.
      REPORT_LATENCY_MAX_S`: a fix up to 2 s after its reception is the two clocks
      disagreeing) it is the middle of [t - lag, t - lag + w], uniform there,

      .. math:: t_{fix} = t - lag + w/2, \\qquad \\sigma_t^2 = w^2 / 12, \\qquad
                w = \\min(lag, 1\\,\\mathrm{s})

      for a reception time to the millisecond (``nais:t``, ``pghp``, ``csv:*``, ``pcap``,
      ``mcap_log_time``, ...) received after its second began, else w = 1 s (a time in
      whole seconds, an interpolated or refined one: ``tag_block:c``, ``nais:epoch``,
      ``interpolated:*``). Whatever the reception time's source: a report received
      0.5-45 s after its fix (a transponder repeating a stale position, a network
      feed's latency) is tested at its fix.
    - **No time stamp**, a reception time the recording carries: that time, the
      position's age at reception unknown (``ais_sigma_report_age_s``: the EPFS updates
      once a second or slower, the report waits for its slot), plus (1 s)^2 / 12 for
      times in whole seconds.
    - **No time stamp and an interpolated time** (``interpolated:*``, placed by line
      number between lines with a time): null, not decided (the line's bracket is not
      known to the report; a line 10 s after the last base station report may be 10 s
      from its time)."""
    t = pl.col("time_ns")
    s = pl.col("utc_second").cast(pl.Int64)
    late_ns = round(ts.REPORT_LATENCY_MAX_S * NS)
    stamped = s.is_between(0, 59).fill_null(False)
    lag_ns = (t - s * NS + late_ns) % ts.MINUTE_NS - late_ns
    src = pl.col("time_source").fill_null("")
    whole = pl.any_horizontal(src == lab for lab in _WHOLE_SECOND_SOURCES)
    interpolated = src.str.starts_with(ts.INTERPOLATED)
    w_s = (pl.when(whole | interpolated | (lag_ns < 0)).then(1.0)
           .otherwise((lag_ns / NS).clip(0.0, 1.0)))  # fmt: skip
    received = ic.ais_sigma_report_age_s**2 + pl.when(whole).then(1.0 / 12.0).otherwise(0.0)
    var = pl.when(stamped).then(w_s**2 / 12.0).when(interpolated).then(None).otherwise(received)
    fix = t - lag_ns + (w_s * (NS / 2)).round().cast(pl.Int64)
    return (pl.when(stamped).then(fix).otherwise(t).alias("fix_ns"),
            var.alias("time_var_s2"))


def _step_enu(lat_deg: pl.Expr, dlat_deg: pl.Expr, dlon_deg: pl.Expr) -> tuple[pl.Expr, pl.Expr]:
    """(east_m, north_m) of a small step (dlat, dlon) at latitude ``lat_deg`` on the
    WGS-84 ellipsoid: the prime-vertical radius N cos(lat) dlon and the meridional radius
    M dlat, at the report itself, so the step's north is the north of the COG (a tangent
    plane far from its origin turns it: a feed spanning a hemisphere)."""
    phi = lat_deg.radians()
    w = 1.0 - _WGS84_E2 * phi.sin() ** 2
    n_radius = _WGS84_A_M / w.sqrt()
    m_radius = _WGS84_A_M * (1.0 - _WGS84_E2) / w.pow(1.5)
    dlon = (dlon_deg + 180.0) % 360.0 - 180.0
    return n_radius * phi.cos() * dlon.radians(), m_radius * dlat_deg.radians()


def _kinematics(ic: ChannelIntegrityConfig) -> tuple[pl.Expr, pl.Expr]:
    """On rows sorted by (mmsi, time_ns) with :func:`fix_time`'s columns, the transponder
    against itself: each report against its previous one (a message 27 skipped, see
    :data:`LONG_RANGE_MSG_TYPE`) moved on by the two reports' SOG and COG along the chord
    of the arc they describe (mean course C, length mean SOG V x dt x sinc(half the
    course change): exact for a steady turn), dt between the two fixes, the step on the
    ellipsoid at the report (:func:`_step_enu`). The residual e = (step - chord) in the
    along-track (C) and cross-track axes, each with its own variance: the airfield
    paper's eq. 21, xi = r^T S^-1 r, with S diagonal in the track's axes (2 dof), and
    the upper threshold of its eq. 22,

    .. math:: \\xi_{self} = \\frac{e_a^2}{2\\sigma_p^2 + \\tfrac12(\\sigma_V\\Delta t)^2
              + \\bar V^2(\\sigma_{t,k}^2 + \\sigma_{t,k-1}^2) + \\tfrac{1}{12} q_a\\Delta t^3}
              + \\frac{e_c^2}{2\\sigma_p^2 + \\tfrac12(\\bar V\\Delta t\\sigma_C)^2
              + \\tfrac{1}{12} q_a\\Delta t^3}

    - 2 sigma_p^2: the two positions' GNSS errors (``ais_sigma_position_m``);
    - the mean of two SOGs errs by sigma_V / sqrt 2 along the track, of two COGs by
      sigma_C / sqrt 2 across it (``ais_sigma_sog_mps``, ``ais_sigma_cog_deg``);
    - a time error moves a position along its velocity: sigma_t per report from
      :func:`fix_time` (its time stamp, or its reception time's source);
    - the ship's velocity is not steady between reports: a white-noise acceleration of
      spectral density q_a (``ais_manoeuvre_psd_m2_s3``) given the two reported
      velocities (a Brownian bridge) moves it by q_a dt^3 / 12 per axis.

    Upper tail at ``ais_q`` (``ais_q``/2 when the radar test decides the report too,
    :class:`_Tables`); null when the previous report is more than ``ais_max_gap_s``
    away, a SOG/COG or the time variance is missing. A stuck position (SOG says it
    moves, it does not) fails it; ``jump``: the report farther than ``ais_jump_m`` from
    there (an MMSI now sent by another ship, a position fault) as opposed to the radar
    tracks changing."""
    fix = pl.col("msg_type").fill_null(0) != LONG_RANGE_MSG_TYPE

    def prev(c: str) -> pl.Expr:  # the previous report of the transponder that is a fix
        return pl.when(fix).then(pl.col(c)).shift(1).forward_fill()

    same = fix & (prev("mmsi") == pl.col("mmsi")).fill_null(False)
    p = {c: pl.when(same).then(prev(c)) for c in
         ("fix_ns", "lat_deg", "lon_deg", "sog_mps", "cog_rad", "time_var_s2")}
    dt = (pl.col("fix_ns") - p["fix_ns"]) / NS
    half = ((pl.col("cog_rad") - p["cog_rad"] + np.pi) % (2 * np.pi) - np.pi) / 2.0
    course = p["cog_rad"] + half
    speed = (pl.col("sog_mps") + p["sog_mps"]) / 2.0
    sinc = pl.when(half.abs() > 1e-9).then(half.sin() / half).otherwise(1.0)
    chord = speed * dt * sinc
    east, north = _step_enu(pl.col("lat_deg"), pl.col("lat_deg") - p["lat_deg"],
                            pl.col("lon_deg") - p["lon_deg"])
    ex, ey = east - chord * course.sin(), north - chord * course.cos()
    along, across = ex * course.sin() + ey * course.cos(), ex * course.cos() - ey * course.sin()
    common = 2.0 * ic.ais_sigma_position_m**2 + ic.ais_manoeuvre_psd_m2_s3 * dt.abs() ** 3 / 12
    var_along = (common + 0.5 * (ic.ais_sigma_sog_mps * dt) ** 2
                 + speed**2 * (pl.col("time_var_s2") + p["time_var_s2"]))
    var_across = common + 0.5 * (speed * dt * ic.ais_sigma_cog_rad) ** 2
    xi = pl.when(dt.abs() <= ic.ais_max_gap_s).then(along**2 / var_along
                                                    + across**2 / var_across)
    jump = ((ex * ex + ey * ey).sqrt() > ic.ais_jump_m).fill_null(False)
    return xi.alias("self_xi"), jump.alias("jump")


def nearest_slots(xy: np.ndarray, k: np.ndarray, rad: _Radar, var: float, gate: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The NEAREST tracks (slots, every radar row's estimate) of each point at its epoch
    k among those in the gate, by squared Mahalanobis distance d2 = r^T S^-1 r with
    S = P + var I (eq. 21); -1 / inf when fewer than NEAREST are in the gate.

    The slots are found with a grid join (:func:`pipeline.spatial.pairs_within`): a slot
    can hold d2 < gate only within |r| < sqrt(gate * lambda_max(S)), lambda_max the larger
    eigenvalue of the 2x2 S, so each slot reaches that far and no farther. The decisions
    use only candidates with d2 < gate (``_ais_epoch``), so this gives the same decisions
    as :func:`nearest_slots_dense` (every slot of the epoch, quadratic in the targets)
    and the same (slot, d2) for every gated candidate, in the same order (d2, then slot).
    """
    n = xy.shape[0]
    cand = np.full((n, NEAREST), -1, np.int64)
    cd2 = np.full((n, NEAREST), np.inf)
    N = rad.p_all.shape[0]
    if n == 0 or N == 0:
        return cand, cd2
    S_all = rad.P_all + np.array([var, var, 0.0])
    half_trace = 0.5 * (S_all[:, 0] + S_all[:, 1])
    lam_max = half_trace + np.hypot(0.5 * (S_all[:, 0] - S_all[:, 1]), S_all[:, 2])
    # a margin for rounding: pairs beyond the exact gate are dropped below
    reach = np.sqrt(gate * lam_max) * (1.0 + 1e-6) + 1e-6
    slot_epoch = np.repeat(np.arange(rad.slot_bounds.size - 1), np.diff(rad.slot_bounds))
    finite = np.isfinite(reach)
    base_m = float(np.clip(np.median(reach[finite]), 10.0, 1e5)) if finite.any() else 1e3
    # slots by reach, each scale on its own grid (cell = reach / MAX_CELLS): a coasting
    # track's wide gate is paired with the points of a few of its cells, not every point
    # of the epoch (the pairs of one grid for all held ~1 GB at 3,000 ships)
    scale = np.zeros(N, np.int64)
    scale[finite] = np.ceil(np.log(np.maximum(reach[finite] / (MAX_CELLS * base_m), 1.0))
                            / np.log(4.0))
    scale = np.minimum(scale, _MAX_SCALE)
    parts = []
    for sc in np.unique(scale):
        sel = np.flatnonzero(scale == sc)
        i, j, _ = pairs_within(slot_epoch[sel], rad.p_all[sel, 0], rad.p_all[sel, 1],
                               reach[sel], k, xy[:, 0], xy[:, 1], base_m * 4.0 ** int(sc))
        parts.append((sel[i], j))
    slot = np.concatenate([p[0] for p in parts])
    row = np.concatenate([p[1] for p in parts])
    d2 = _d2(xy[row] - rad.p_all[slot], S_all[slot])
    keep = d2 < gate
    row, slot, d2 = row[keep], slot[keep], d2[keep]
    order = np.lexsort((slot, d2, row))
    row, slot, d2 = row[order], slot[order], d2[order]
    counts = np.bincount(row, minlength=n)
    rank = np.arange(row.size) - np.repeat(np.cumsum(counts) - counts, counts)
    top = rank < NEAREST
    cand[row[top], rank[top]] = slot[top]
    cd2[row[top], rank[top]] = d2[top]
    return cand, cd2


def nearest_slots_dense(xy: np.ndarray, k: np.ndarray, rad: _Radar, var: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The NEAREST tracks (slots, every radar row's estimate) of each point at its epoch
    k, by squared Mahalanobis distance (covariance + var I); -1 / inf when fewer. Every
    slot of the epoch against every point: the reference for :func:`nearest_slots`."""
    n = xy.shape[0]
    cand = np.full((n, NEAREST), -1, np.int64)
    cd2 = np.full((n, NEAREST), np.inf)
    lo, hi = rad.slot_bounds[k], rad.slot_bounds[k + 1]
    counts = hi - lo
    row = np.repeat(np.arange(n), counts)
    slot = lo[row] + (np.arange(row.size) - np.repeat(np.cumsum(counts) - counts, counts))
    S = rad.P_all[slot] + np.array([var, var, 0.0])
    d2 = _d2(xy[row] - rad.p_all[slot], S)
    order = np.lexsort((d2, row))
    row, slot, d2 = row[order], slot[order], d2[order]
    rank = np.arange(row.size) - np.repeat(np.cumsum(counts) - counts, counts)
    top = rank < NEAREST
    cand[row[top], rank[top]] = slot[top]
    cd2[row[top], rank[top]] = d2[top]
    return cand, cd2


def _seeing(rad: _Radar, epochs: np.ndarray, n_groups: int, window_ns: int, min_tracks: int,
            min_epochs: int) -> np.ndarray:
    """(K, n_groups): the radar group (site, sector) sees ships at epoch k: at least
    ``min_tracks`` distinct tracks (system track ids) each detected in ``min_epochs``
    epochs (coasted reports are no detection; a track glimpsed at a sector's edge for an
    epoch or two is no sight of the sector) of a run whose detections are less than
    ``window_ns`` apart, the last of them in ``(t_k - window_ns, t_k]``. Each (group,
    track)'s detections are merged into such runs, each counted from its
    ``min_epochs``-th detection to its last + the window, and the runs open at each epoch
    are summed by one cumulative sum per group: no loop over epochs."""
    k_row = np.repeat(np.arange(epochs.size), np.diff(rad.bounds))
    det = rad.detected_row
    if not det.any():
        return np.zeros((epochs.size, n_groups), bool)
    slot = rad.slot_bounds[k_row] + rad.slot
    # the distinct (group, track, epoch) in that order, as one int64 key (a unique and a
    # sort of the three columns cost 5x; numpy's unique of such keys 15x)
    track = pl.Series(rad.track[slot[det]]).rank("dense").to_numpy().astype(np.int64) - 1
    T, K = int(track.max()) + 1, epochs.size
    key = pl.Series((rad.group[det] * T + track) * K + k_row[det]).unique().sort().to_numpy()
    g, track, t = key // (T * K), key // K % T, epochs[key % K]
    # a new span where the (group, track) changes or the detection is a window or more
    # after the previous one
    start = np.ones(t.size, bool)
    start[1:] = (g[1:] != g[:-1]) | (track[1:] != track[:-1]) | (t[1:] - t[:-1] >= window_ns)
    first = np.flatnonzero(start)
    last = np.r_[first[1:], t.size] - 1
    long = last - first + 1 >= min_epochs
    first, last = first[long], last[long]
    lo = np.searchsorted(epochs, t[first + min_epochs - 1], side="left")
    hi = np.searchsorted(epochs, t[last] + window_ns, side="left")  # open: t_k < last + w
    count = np.zeros((epochs.size + 1, n_groups), np.int64)
    np.add.at(count, (lo, g[first]), 1)
    np.add.at(count, (hi, g[first]), -1)
    return np.cumsum(count, axis=0)[:-1] >= min_tracks


def _scan_gaps(aligned: pl.DataFrame, epochs: np.ndarray, cfg: Config
               ) -> tuple[np.ndarray, np.ndarray]:
    """(K, C) time since each site's last published scan at each epoch, s (NaN before the
    site's first report in the inputs: the recording may start there, no decision), and
    (K, C) whether the site's tracker has had 4 scan periods since its first report to
    initiate the tracks of the ships in range (before that, no coverage decision)."""
    out = np.full((epochs.size, len(cfg.radar_sites)), np.nan)
    ready = np.zeros(out.shape, bool)
    ends = aligned.group_by("site_id").agg(pl.col("log_time_ns").unique().sort())
    by_site = dict(zip(ends["site_id"].to_list(), ends["log_time_ns"].to_list(), strict=True))
    for c, s in enumerate(cfg.radar_sites):  # a handful of sites
        t = np.asarray(by_site.get(s.site_id, []), np.int64)
        if t.size == 0:
            continue
        i = np.searchsorted(t, epochs, side="right") - 1
        out[:, c] = np.where(i >= 0, (epochs - t[np.maximum(i, 0)]) / NS, np.nan)
        ready[:, c] = epochs - t[0] >= round(4 * s.scan_period_s * NS)
    return out, ready


class _Tables:
    """Chi-square thresholds of the tests, looked up by degrees of freedom."""

    def __init__(self, ic: ChannelIntegrityConfig, n_max: int) -> None:
        n = np.arange(1, n_max + 1)
        q = ic.radar_q
        self.nis_d1 = np.r_[np.nan, chi2_ppf(q / 4.0, 2 * n)]  # sum test, q/2 in all
        self.nis_d2 = np.r_[np.nan, chi2_ppf(1.0 - q / 4.0, 2 * n)]
        self.bias_d2 = float(chi2_ppf(1.0 - q / 2.0, 3))
        self.ais_d1, self.ais_d2 = chi2_thresholds(ic.ais_q / 2.0, 2)  # q/2 each: radar
        self.self_d2 = float(chi2_ppf(1.0 - ic.ais_q / 2.0, 2))  # and kinematics
        self.self_alone_d2 = float(chi2_ppf(1.0 - ic.ais_q, 2))  # kinematics alone
        self.outlier = float(chi2_ppf(1.0 - ic.outlier_q, 2))


# --- the epoch loop ----------------------------------------------------------------------


@dataclass(eq=False)
class _State:
    """What the loop carries from epoch to epoch: exclusion state of every radar group
    (site, sector) and transponder, the transponders' reference tracks (system track id,
    -1 none), when each was last present, reports seen per transponder, and a candidate
    track a failing transponder keeps falling on (``alt``, ``alt_n`` times in a row)."""

    rad_excl: np.ndarray
    rad_run: np.ndarray
    ais_excl: np.ndarray
    ais_run: np.ndarray
    ais_ref: np.ndarray
    ais_ref_seen: np.ndarray
    ais_nrep: np.ndarray
    ais_alt: np.ndarray
    ais_alt_n: np.ndarray
    ais_jumped: np.ndarray
    ais_sector: np.ndarray  # sector of the transponder's last report
    rad_age: np.ndarray  # epochs each radar group has been excluded in a row
    rad_fail: np.ndarray  # epochs each radar group has failed in a row (upper tail)


@dataclass(eq=False)
class _RadarOut:
    """Per (epoch, group) results, (K, n_groups) arrays; ``checked`` marks decisions."""

    checked: np.ndarray
    eta: np.ndarray
    excluded: np.ndarray
    check: np.ndarray  # 0 nis, 1 bias, 2 coverage, 3 scan, 4 site
    n: np.ndarray
    nis: np.ndarray
    T: np.ndarray
    theta: np.ndarray  # (K, n_groups, 3)
    expected: np.ndarray
    missed: np.ndarray
    outliers: np.ndarray
    A: np.ndarray  # (K, n_groups, 16) sum H^T S^-1 H
    b: np.ndarray  # (K, n_groups, 4) sum H^T S^-1 r
    trace: np.ndarray  # (K, n_groups) sum tr(S^-1 P)
    n_ais: np.ndarray  # (K, n_groups) tracks tested against their AIS report


@dataclass(eq=False)
class _AisOut:
    """Per AIS report results (``decided`` marks decisions)."""

    decided: np.ndarray
    kind: np.ndarray  # 0 ais, 1 ais_unmatched, 2 ais_kinematics
    self_xi: np.ndarray
    xi: np.ndarray
    eta: np.ndarray
    excluded: np.ndarray
    r: np.ndarray  # (n, 2)
    track: np.ndarray


def check_channels(
    associated: pl.DataFrame,
    aligned: pl.DataFrame,
    ais_reports: pl.DataFrame,
    *,
    epochs_ns: np.ndarray,
    start_ns: int,
    cfg: Config,
    mc: MaritimeConfig,
) -> IntegrityResult:
    """Test every radar (per sector) and every AIS transponder at each epoch (module
    docstring) and decide which radar rows are fused and which AIS reports identify.

    Consumes ``associated`` (from ``associate_tracks`` with ``sector``: time_ns,
    system_track_id, site_id, local_track_id, report_time_ns, x_enu_m, y_enu_m, P_xx,
    P_yy, P_xy, course_rad, speed_mps, sigma_course_rad, sigma_speed_mps), ``aligned``
    (the radar reports: site_id, local_track_id, time_ns, course_rad, speed_mps,
    log_time_ns) and ``ais_reports`` (time_ns, mmsi, lat_deg, lon_deg, sog_mps, cog_rad;
    from before the window too: those only establish reference tracks). ``epochs_ns``:
    the synchronised epochs; ``start_ns``: the window start (decisions from there on).
    """
    ic = mc.integrity
    epochs = np.unique(np.asarray(epochs_ns, np.int64))
    assoc = associated.sort("time_ns", "system_track_id", "site_id", maintain_order=True)
    G, C = len(cfg.sectors), len(cfg.radar_sites)
    sector_names = [s.name for s in cfg.sectors]
    sector_index: dict[str | None, int] = {n: i for i, n in enumerate(sector_names)}
    sector_index[None] = G
    geo = _Geometry(site_positions_enu(cfg), np.array([s.max_range_m for s in cfg.radar_sites]),
                    G)
    epoch_ns = round(mc.sync.epoch_period_s * NS)
    rad = _radar_arrays(assoc, coasted_reports(aligned), epochs, cfg, geo, sector_index)
    ais = _ais_arrays(ais_reports, epochs, start_ns, cfg, ic, epoch_ns, sector_index, geo, rad)
    scan_gap, tracking = _scan_gaps(aligned, epochs, cfg)
    scan_down = scan_gap > ic.scan_gap_factor * np.array([s.scan_period_s
                                                          for s in cfg.radar_sites])
    K, n_groups = epochs.size, C * (G + 1)
    site_sectors = np.zeros(n_groups, bool)
    site_sectors[np.unique(rad.group)] = True
    thr = _Tables(ic, max(int(np.max(np.diff(rad.bounds), initial=1)), 1))
    gate = gate_threshold(cfg.ais.gate_probability)
    timeout_ns = round(mc.association.track_timeout_s * NS)
    # a radar group excluded longer than this is in a lasting fault, not a false alarm
    # (one of those lasts readmit_run epochs): tracks it reports are not used to decide
    # AIS, and its transponders take their tracks anew when it is readmitted
    lasting = 2 * ic.readmit_run
    M = ais.mmsi.size
    st = _State(np.zeros(n_groups, bool), np.zeros(n_groups, np.int64), np.zeros(M, bool),
                np.zeros(M, np.int64), np.full(M, -1, np.int64), np.zeros(M, np.int64),
                np.zeros(M, np.int64), np.full(M, -1, np.int64), np.zeros(M, np.int64),
                np.zeros(M, bool), np.full(M, G, np.int64), np.zeros(n_groups, np.int64),
                np.zeros(n_groups, np.int64))
    # radar groups that see ships now (witnesses for or against a transponder there), of
    # sites publishing scans (NaN gap: none yet in the inputs, a radar without data)
    seeing = _seeing(rad, epochs, n_groups, round(ic.witness_s * NS), ic.coverage_min_targets,
                     ic.readmit_run)
    seeing &= np.repeat(np.isfinite(scan_gap) & ~scan_down, G + 1, axis=1)
    ro = _RadarOut(*(np.zeros((K, n_groups), t) for t in (bool, bool, bool, np.int8,
                                                            np.int64, float, float)),
                   np.full((K, n_groups, 3), np.nan),
                   *(np.zeros((K, n_groups), np.int64) for _ in range(3)),
                   np.zeros((K, n_groups, DIM * DIM)), np.zeros((K, n_groups, DIM)),
                   np.zeros((K, n_groups)), np.zeros((K, n_groups)))
    n_rep = ais.rep_m.size
    ao = _AisOut(np.zeros(n_rep, bool), np.zeros(n_rep, np.int8), np.full(n_rep, np.nan),
                 np.full(n_rep, np.nan),
                 np.zeros(n_rep, bool), np.zeros(n_rep, bool), np.full((n_rep, 2), np.nan),
                 np.full(n_rep, -1, np.int64))
    used = np.ones(assoc.height, bool)
    row_r = np.full((assoc.height, 2), np.nan)
    row_innov_cov = np.full((assoc.height, 3), np.nan)
    row_tested = np.zeros(assoc.height, bool)
    row_ais = np.zeros(assoc.height, bool)  # the row's track carries a transponder in service
    row_ais_velocity = np.full((assoc.height, 2), np.nan)  # that transponder's SOG, COG
    # an epoch without radar rows, AIS references or reports, with no radar group out of
    # service and no scan down, decides nothing and changes no state: skipped (an hour of
    # sparse AIS without radar: its ~1,100 epochs cost 0.4 CPU-s, now the few with reports)
    quiet = ((np.diff(rad.bounds) == 0) & (np.diff(rad.slot_bounds) == 0)
             & (np.diff(ais.ref_bounds) == 0) & (np.diff(ais.rep_bounds) == 0)
             & ~scan_down.any(axis=1))

    for k in range(K):
        if quiet[k] and not st.rad_excl.any():
            continue
        t_k = int(epochs[k])
        a, b = int(rad.bounds[k]), int(rad.bounds[k + 1])
        s0, s1 = int(rad.slot_bounds[k]), int(rad.slot_bounds[k + 1])
        T = s1 - s0
        ra, rb = int(ais.ref_bounds[k]), int(ais.ref_bounds[k + 1])
        tracks = rad.track[s0:s1]
        inv = rad.slot[a:b]
        g = rad.group[a:b]
        in_use = ~st.rad_excl[g]
        # -- the AIS reference of each track: the one transponder in service on it
        m_ref = ais.ref_m[ra:rb]
        pos, hit = _lookup(tracks, st.ais_ref[m_ref])
        hit &= ~st.ais_excl[m_ref]
        n_ais = np.bincount(pos[hit], minlength=T)
        one = hit & (n_ais[pos] == 1) if T else hit
        ais_info = _sums(pos[one], ais.ref_info[ra:rb][one], T)
        has_ais = n_ais == 1
        if one.any():
            slot_ref = np.full(T, -1)
            slot_ref[pos[one]] = ra + np.flatnonzero(one)
            ref_row = slot_ref[inv]
            row_ais_velocity[a:b][ref_row >= 0] = ais.ref_velocity[ref_row[ref_row >= 0]]
        # -- radar checks against the picture without the channel (eq. 14 leave-one-out)
        info = rad.info[a:b]
        own = info * in_use[:, None]
        tot = _sums(inv, own, T)
        n_other = np.bincount(inv, weights=in_use, minlength=T)[inv] - in_use
        checkable = has_ais[inv] | (n_other >= 2)
        p_ref, P_ref = _estimate(tot[inv] - own + ais_info[inv])
        r = rad.xy[a:b] - p_ref
        S = rad.P[a:b] + P_ref
        xi = np.where(checkable, _d2(np.where(checkable[:, None], r, 0.0),
                                     np.where(checkable[:, None], S, _UNIT)), np.nan)
        checkable &= ~_ais_odd(xi, tot, own, info, rad.xy[a:b], rad.P[a:b], n_other, has_ais,
                               inv, T, thr)
        grp = _radar_groups(xi, r, S, rad.P[a:b], checkable, has_ais[inv], rad.H[a:b], g,
                            n_groups, thr)
        row_r[a:b], row_innov_cov[a:b], row_tested[a:b] = r, S, checkable
        row_ais[a:b] = has_ais[inv]
        # -- coverage: ships trusted channels see in the site's range, the site misses; a
        # radar excluded or failing in any sector is no witness anywhere (a registration
        # fault splits its tracks off the others' where it is not tested)
        doubt = (st.rad_excl | _suspect(grp, thr)).reshape(C, G + 1).any(axis=1)
        trusted = ~doubt[rad.site[a:b]]
        expected, missed = _coverage(inv, T, rad.site[a:b], trusted, has_ais, rad, a, s0, s1,
                                     ais, ra, rb, m_ref, pos, hit, st, t_k, timeout_ns, C, G,
                                     gate)
        expected = np.where(np.repeat(tracking[k], G + 1), expected, 0)
        below, checked = _radar_decisions(k, grp, expected, missed, scan_down[k],
                                          site_sectors, G, thr, ic, ro)
        upper = ~below & checked
        if ic.exclusion:
            in_fault = st.rad_age > lasting
            # only an upper-tail failure excludes: a NIS sum below d1 (the channel agrees
            # better than its sigmas say) is flagged by eq. 23 but harms no fusion
            # and a group that cannot be checked while its site publishes scans and fails
            # nowhere counts a pass (after an outage, a sector where the radar has no
            # testable track would otherwise stay excluded for good)
            failing = upper.reshape(C, G + 1).any(axis=1) | scan_down[k]
            idle = st.rad_excl & ~checked & ~np.repeat(failing, G + 1)
            st.rad_fail = np.where(checked, np.where(upper, st.rad_fail + 1, 0), st.rad_fail)
            confirmed = upper & (st.rad_fail >= ic.radar_confirm)
            st.rad_excl, st.rad_run = step_exclusion(st.rad_excl, st.rad_run, confirmed,
                                                     below | idle, checked | idle,
                                                     ic.readmit_run)
            if (in_fault & ~st.rad_excl).any():
                _release(st, in_fault & ~st.rad_excl, ais.mmsi_near, G)
            st.rad_age = np.where(st.rad_excl, st.rad_age + 1, 0)
        ro.excluded[k] = st.rad_excl
        in_service = ~st.rad_excl[g]
        used[a:b] = in_service
        if T:
            st.ais_ref_seen[_lookup(tracks, st.ais_ref)[1]] = t_k
        da, db = int(ais.rep_bounds[k]), int(ais.rep_bounds[k + 1])
        if db > da:
            lapsed = (st.ais_ref >= 0) & (st.ais_ref_seen < t_k - timeout_ns)
            st.ais_ref[lapsed] = -1
            # a radar failing now is no reference for the transponders, confirmed or not
            trusted_now = in_service & ~(upper[g] if ic.exclusion else False)
            pic = _picture(rad, a, b, s0, s1, trusted_now, (st.rad_age > lasting)[g])
            _ais_epoch(da, db, ais, pic, st, ~st.rad_excl & seeing[k], gate, thr, ic, ao)

    health = _health_frame(ro, ao, epochs, scan_gap, ais, cfg, sector_names, thr, ic)
    excl = ao.excluded
    ais_excluded = pl.DataFrame({"mmsi": ais.mmsi[ais.rep_m[excl]], "time_ns": ais.rep_t[excl]},
                                schema={"mmsi": pl.Int64, "time_ns": pl.Int64})
    k_row = np.repeat(np.arange(K), np.diff(rad.bounds))
    pair_info, pair_b, pair_nis, pair_n = _pair_evidence(rad, k_row, row_ais, K, C, thr)
    evidence = RegistrationEvidence(
        epochs=epochs, A=ro.A.reshape(K, n_groups, DIM, DIM), b=ro.b, nis=ro.nis, n=ro.n,
        trace=ro.trace, n_ais=ro.n_ais, blocked=ro.checked & ro.eta & (ro.check == 3),
        excluded=ro.excluded, row_k=k_row, row_group=rad.group, H=rad.H, row_r=row_r,
        row_innov_cov=row_innov_cov, row_tested=row_tested, row_cov=rad.P,
        row_velocity=assoc.select("speed_mps", "course_rad", "sigma_speed_mps",
                                  "sigma_course_rad").to_numpy(),
        row_ais_velocity=row_ais_velocity, G=G, C=C,
        pair_info=pair_info, pair_b=pair_b, pair_nis=pair_nis, pair_n=pair_n)
    return IntegrityResult(health=health, associations=assoc.with_columns(
        pl.Series("used", used)), ais_excluded=ais_excluded, evidence=evidence)


def _pair_evidence(rad: _Radar, k_row: np.ndarray, row_ais: np.ndarray, K: int, C: int,
                   thr: _Tables) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The radar-radar evidence the leave-one-out test cannot use (``pair_*`` of
    :class:`RegistrationEvidence`): tracks that carry no transponder and are reported by
    exactly two sites c < d at the epoch. Their difference r = p_c - p_d, S = P_c + P_d,
    is H_c theta_c - H_d theta_d + e whatever the two radars' registrations: one
    equation in both, (K, 4C, 4C) sums A = sum J^T S^-1 J with J = [.. H_c .. -H_d ..],
    b = sum J^T S^-1 r, the NIS sum and the pairs per site (K, C). Which of the two is
    off is not a test here (xi_1 = xi_2): the joint estimate of every site's
    registration (:mod:`pipeline.maritime.registration`) tells them apart by their
    geometry and their AIS evidence. Outliers (xi above chi2_2(1 - outlier_q)) fewer than
    half of a site pair's pairs at an epoch are left out, as in :func:`_radar_groups`."""
    D = DIM * C
    gslot = rad.slot_bounds[k_row] + rad.slot  # rows are in slot order
    count = np.bincount(gslot, minlength=int(rad.slot_bounds[-1]))
    first = np.r_[True, gslot[1:] != gslot[:-1]] if gslot.size else np.zeros(0, bool)
    a = np.flatnonzero(first & (count[gslot] == 2) & ~row_ais)
    a = a[rad.site[a] != rad.site[a + 1]]
    b = a + 1
    r, S = rad.xy[a] - rad.xy[b], rad.P[a] + rad.P[b]
    xi = _d2(r, S)
    key = (k_row[a] * C + rad.site[a]) * C + rad.site[b]
    out = xi > thr.outlier
    drop = 2 * np.bincount(key, weights=out, minlength=K * C * C) < np.bincount(
        key, minlength=K * C * C)
    keep = ~(out & drop[key])
    a, b, r, S, xi = a[keep], b[keep], r[keep], S[keep], xi[keep]
    k, ca, cb = k_row[a], rad.site[a], rad.site[b]
    J = np.concatenate([rad.H[a], -rad.H[b]], axis=2)  # (m, 2, 2 DIM)
    JtSiJ, JtSir, _ = _normal_terms(J, S, r)
    p = np.arange(2 * DIM)
    gi = np.where(p < DIM, ca[:, None] * DIM + p, cb[:, None] * DIM + p - DIM)  # (m, 2 DIM)
    cell = (k[:, None, None] * D + gi[:, :, None]) * D + gi[:, None, :]
    A = np.bincount(cell.ravel(), weights=JtSiJ.ravel(), minlength=K * D * D)
    bb = np.bincount((k[:, None] * D + gi).ravel(), weights=JtSir.ravel(), minlength=K * D)
    n = (np.bincount(k * C + ca, minlength=K * C) + np.bincount(k * C + cb, minlength=K * C))
    return (A.reshape(K, D, D), bb.reshape(K, D), np.bincount(k, weights=xi, minlength=K),
            n.reshape(K, C).astype(float))


def _release(st: _State, readmitted: np.ndarray, mmsi_near: np.ndarray, G: int) -> None:
    """A radar readmitted after a lasting fault in a sector: the transponders last
    reported there in its range take their reference track anew (the association may
    have exchanged track ids while the radar was faulty)."""
    groups = np.flatnonzero(readmitted)
    hit = np.isin(st.ais_sector, groups % (G + 1)) & mmsi_near[:, groups // (G + 1)].any(axis=1)
    st.ais_ref[hit] = -1
    st.ais_alt[hit] = -1
    st.ais_alt_n[hit] = 0


def _lookup(tracks: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(position in ``tracks`` (sorted), found) of each id (-1: none)."""
    if tracks.size == 0:
        return np.zeros(ids.size, np.int64), np.zeros(ids.size, bool)
    pos = np.minimum(np.searchsorted(tracks, ids), tracks.size - 1)
    return pos, (ids >= 0) & (tracks[pos] == ids)


def _normal_terms(H: np.ndarray, S: np.ndarray, r: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per row, H^T S^-1 H (n, p, p), H^T S^-1 r (n, p) and det S of residuals ``r`` (n,
    2), covariances ``S`` (n, 3: xx, yy, xy) and Jacobians ``H`` (n, 2, p)."""
    det = S[:, 0] * S[:, 1] - S[:, 2] ** 2
    # H^T S^-1 (n, p, 2) with S^-1 = [[S_yy, -S_xy], [-S_xy, S_xx]] / det
    HtSi = np.stack([H[:, 0, :] * S[:, 1, None] - H[:, 1, :] * S[:, 2, None],
                     H[:, 1, :] * S[:, 0, None] - H[:, 0, :] * S[:, 2, None]],
                    axis=2) / det[:, None, None]
    # the two-term sums written out (einsum's generic loop is ~4x slower on these 2-long
    # contractions; the same products, the same sums)
    HtSiH = HtSi[:, :, 0, None] * H[:, None, 0, :] + HtSi[:, :, 1, None] * H[:, None, 1, :]
    HtSir = HtSi[:, :, 0] * r[:, 0, None] + HtSi[:, :, 1] * r[:, 1, None]
    return HtSiH, HtSir, det


def _radar_groups(
    xi: np.ndarray, r: np.ndarray, S: np.ndarray, P: np.ndarray, checkable: np.ndarray,
    with_ais: np.ndarray, H: np.ndarray, g: np.ndarray, n_groups: int, thr: _Tables,
) -> dict[str, np.ndarray]:
    """Per (site, sector) group: tracks tested (outliers of a minority left out), NIS
    sum, outliers left out, registration statistic T and theta_hat, and the sums A, b
    and sum tr(S^-1 P) of :class:`RegistrationEvidence`."""
    out = checkable & (xi > thr.outlier)
    counts = _sums(g, np.column_stack([checkable, out]), n_groups)
    drop = 2 * counts[:, 1] < counts[:, 0]
    kept = checkable & ~(out & drop[g])
    gk = g[kept]
    Sk = S[kept]
    HtSiH, HtSir, det = _normal_terms(H[kept], Sk, r[kept])
    Pk = P[kept]
    trace = (Sk[:, 1] * Pk[:, 0] - 2 * Sk[:, 2] * Pk[:, 2] + Sk[:, 0] * Pk[:, 1]) / det
    terms = np.concatenate([np.ones((gk.size, 1)), xi[kept, None], HtSiH.reshape(-1, DIM * DIM),
                            HtSir, trace[:, None], with_ais[kept, None]], axis=1)
    tot = _sums(gk, terms, n_groups)
    nk = tot[:, 0].astype(np.int64)
    a_end = 2 + DIM * DIM
    A_all, b_all = tot[:, 2:a_end], tot[:, a_end:a_end + DIM]
    # the test's model: the first TESTED parameters (the range gain is the registration's)
    A = (A_all.reshape(-1, DIM, DIM)[:, :TESTED, :TESTED]
         + np.diag(THETA_PRIOR[:TESTED] ** -2.0))
    bvec = b_all[:, :TESTED]
    theta = np.linalg.solve(A, bvec[..., None])[..., 0]
    stat = np.einsum("ni,ni->n", bvec, theta)
    few = nk < 2
    stat[few] = np.nan
    theta[few] = np.nan
    return {"n": nk, "nis": tot[:, 1], "outliers": np.where(drop, counts[:, 1], 0).astype(
        np.int64), "T": stat, "theta": theta, "A": A_all, "b": b_all,
        "trace": tot[:, a_end + DIM], "n_ais": tot[:, a_end + DIM + 1]}


def _ais_odd(xi: np.ndarray, tot: np.ndarray, own: np.ndarray, info: np.ndarray,
             xy: np.ndarray, P: np.ndarray, n_other: np.ndarray, has_ais: np.ndarray,
             inv: np.ndarray, T: int, thr: _Tables) -> np.ndarray:
    """Rows of tracks whose radars agree with one another but every one of them is an
    outlier against the track's transponder: the transponder is the odd one out (an AIS
    fault), the track says nothing of the radars (the minority rule of
    :func:`_radar_groups` cannot tell one of two tracks from the radar's fault)."""
    multi = has_ais[inv] & (n_other >= 1)
    if not multi.any():
        return np.zeros(xi.size, bool)
    p, Pr = _estimate(tot[inv] - own)  # the other radars alone
    m = np.flatnonzero(multi)
    agree = np.ones(xi.size, bool)
    agree[m] = _d2(xy[m] - p[m], P[m] + Pr[m]) < thr.outlier
    odd_row = multi & agree & (xi > thr.outlier)
    n_rows = np.bincount(inv, minlength=T)
    odd_track = np.bincount(inv, weights=odd_row, minlength=T) == n_rows
    return odd_track[inv] & multi


def _suspect(grp: dict[str, np.ndarray], thr: _Tables) -> np.ndarray:
    """Groups whose NIS sum or registration test exceeds its upper threshold now: not a
    trusted witness of what the other radars should see."""
    n = grp["n"]
    return ((n >= 1) & (grp["nis"] >= thr.nis_d2[n])) | (
        (n >= 2) & (np.nan_to_num(grp["T"]) >= thr.bias_d2))


def _coverage(
    inv: np.ndarray, T: int, site: np.ndarray, trusted: np.ndarray, has_ais: np.ndarray,
    rad: _Radar, a0: int, s0: int, s1: int, ais: _Ais, ra: int, rb: int, m_ref: np.ndarray,
    pos: np.ndarray, hit: np.ndarray, st: _State, t_k: int, timeout_ns: int, C: int, G: int,
    gate: float,
) -> tuple[np.ndarray, np.ndarray]:
    """(expected, missed) per (site, sector) group: ships trusted channels see in the
    site's range that the site does not detect. Ships = the epoch's tracks (sector of
    their first row) seen by another trusted radar or by their transponder, and the
    transponders in service whose reference track is gone (the radars lost the ship)."""
    by_site = np.bincount(inv * C + site, weights=trusted, minlength=T * C).reshape(T, C)
    other = (by_site.sum(axis=1, keepdims=True) - by_site) > 0
    # a transponder vouches for a track only where no untrusted radar reports it (a
    # faulty radar's track may hold a ship the association split off the others')
    clean = np.bincount(inv, weights=~trusted, minlength=T) == 0
    exp = (other | (has_ais & clean)[:, None]) & rad.near[s0:s1]
    miss = exp & ~rad.detected[s0:s1]
    idx = (np.arange(C)[None, :] * (G + 1) + rad.slot_sector[s0:s1, None]).ravel()
    n = C * (G + 1)
    # (np.bincount of an empty index is int64 whatever the weights: float, for the +=)
    expected = np.bincount(idx, weights=exp.ravel(), minlength=n).astype(np.float64)
    missed = np.bincount(idx, weights=miss.ravel(), minlength=n).astype(np.float64)
    ref = st.ais_ref[m_ref]
    lost = (ref >= 0) & ~hit & ~st.ais_excl[m_ref] & (st.ais_ref_seen[m_ref] >= t_k - timeout_ns)
    if lost.any():
        # the ship of a transponder whose track vanished: missed by a site with no
        # detection at the transponder's position (the association may have given the
        # ship a new track id, which its transponder does not know yet)
        near = ais.ref_near[ra:rb][lost]
        xy = ais.ref_xy[ra:rb][lost]
        rows = slice(a0, a0 + site.size)
        d2 = _pair_d2(xy, rad.xy[rows], rad.P[rows] + ais.var)
        seen = (d2 < gate) & (rad.detected_row[rows])[None, :]
        by = np.stack([(seen & (site == c)[None, :]).any(axis=1) for c in range(C)], axis=1)
        idx = (np.arange(C)[None, :] * (G + 1) + ais.ref_sector[ra:rb][lost, None]).ravel()
        expected += np.bincount(idx, weights=near.ravel(), minlength=n)
        missed += np.bincount(idx, weights=(near & ~by).ravel(), minlength=n)
    return expected, missed


def _radar_decisions(
    k: int, grp: dict[str, np.ndarray], expected: np.ndarray, missed: np.ndarray,
    scan_down: np.ndarray, site_sectors: np.ndarray, G: int, thr: _Tables,
    ic: ChannelIntegrityConfig, ro: _RadarOut,
) -> tuple[np.ndarray, np.ndarray]:
    """eta per (site, sector) group from its NIS sum, registration, coverage and scan
    checks (recorded in ``ro``): (passing: below every upper threshold, checked).

    A registration or NIS-sum failure in one sector fails the site in every sector it
    covers (check ``site``): a range, azimuth or clock fault, or a noisy receiver, is
    the site's, also where no track of it can be tested; a coverage failure (a blanked
    sector) stays the sector's."""
    n, nis = grp["n"], grp["nis"]
    nis_dec = n >= 1
    nis_flag = nis_dec & ((nis <= thr.nis_d1[n]) | (nis >= thr.nis_d2[n]))
    nis_high = nis_dec & (nis >= thr.nis_d2[n])
    bias_flag = (n >= 2) & (np.nan_to_num(grp["T"]) >= thr.bias_d2)
    cov_dec = expected >= ic.coverage_min_targets
    cov_flag = cov_dec & (missed > ic.coverage_miss_share * expected)
    scan_flag = np.repeat(scan_down, G + 1) & site_sectors
    site_flag = np.repeat((nis_high | bias_flag).reshape(-1, G + 1).any(axis=1), G + 1)
    site_flag &= site_sectors & ~(nis_high | bias_flag)
    flagged = nis_flag | bias_flag | cov_flag | scan_flag  # eta: the tests made here
    below = (~nis_dec | (nis < thr.nis_d2[n])) & ~bias_flag & ~cov_flag & ~scan_flag
    below &= ~site_flag
    checked = nis_dec | cov_dec | scan_flag | site_flag
    ro.checked[k], ro.eta[k], ro.n[k], ro.nis[k], ro.T[k] = checked, flagged, n, nis, grp["T"]
    ro.check[k] = np.where(scan_flag, 3, np.where(cov_flag, 2, np.where(
        bias_flag, 1, np.where(site_flag, 4, np.where(nis_dec, 0, 2)))))
    ro.theta[k], ro.A[k], ro.b[k], ro.trace[k] = grp["theta"], grp["A"], grp["b"], grp["trace"]
    ro.n_ais[k] = grp["n_ais"]
    ro.expected[k], ro.missed[k], ro.outliers[k] = expected, missed, grp["outliers"]
    return below, checked


@dataclass(frozen=True, eq=False)
class _Picture:
    """The tracks (slots s0:s1) of one epoch as the radars in service fuse them
    (``served``: by at least one): estimate, velocity and its sigmas."""

    s0: int
    tracks: np.ndarray
    served: np.ndarray
    tainted: np.ndarray
    p: np.ndarray
    P: np.ndarray
    v: np.ndarray
    sigma_v: np.ndarray
    sigma_c: np.ndarray


def _picture(rad: _Radar, a: int, b: int, s0: int, s1: int, in_service: np.ndarray,
             faulty: np.ndarray) -> _Picture:
    T = s1 - s0
    inv = rad.slot[a:b]
    w = in_service * 1.0
    p, P = _estimate(_sums(inv, rad.info[a:b] * w[:, None], T))
    vals = np.column_stack([rad.v[a:b], rad.sv[a:b], rad.sc[a:b], np.ones(b - a)]) * w[:, None]
    s = _sums(inv, np.column_stack([vals, faulty]), T)
    n = np.maximum(s[:, 4], 1e-12)
    return _Picture(s0, rad.track[s0:s1], s[:, 4] > 0, s[:, 5] > 0, p, P, s[:, :2] / n[:, None],
                    s[:, 2] / n, s[:, 3] / n)


def _ais_epoch(
    da: int, db: int, ais: _Ais, pic: _Picture, st: _State, witness: np.ndarray,
    gate: float, thr: _Tables, ic: ChannelIntegrityConfig, ao: _AisOut,
) -> None:
    """Decide the AIS reports of one epoch against the radar-only picture of the radars
    in service (module docstring), in rounds of at most one report per transponder (the
    exclusion rule advances one report at a time). ``witness``: per radar group (site,
    sector), in service and not silent there (module docstring)."""
    n_rounds = int(ais.rep_round[da:db].max()) + 1
    for rnd in range(n_rounds):
        j = np.arange(da, db)
        if n_rounds > 1:
            j = j[ais.rep_round[da:db] == rnd]
        mj = ais.rep_m[j]
        st.ais_nrep[mj] += 1
        st.ais_jumped[mj] |= ais.rep_jump[j]
        st.ais_sector[mj] = ais.rep_sector[j]
        covered = (ais.rep_near[j] & witness[ais.rep_groups[j]]).any(axis=1)
        # the nearest free track (no transponder refers to it) in the gate; while a radar
        # is in service there, only a track it serves (not one of an excluded radar alone)
        T = pic.tracks.size
        cand = np.where(ais.rep_cand[j] >= 0, ais.rep_cand[j] - pic.s0, T)
        taken = np.zeros(T + 1, bool)
        held = np.zeros(T + 1, bool)  # by a transponder in service
        pos, found = _lookup(pic.tracks, st.ais_ref)
        taken[pos[found]] = True
        held[pos[found & ~st.ais_excl]] = True
        gated = (ais.rep_cand_d2[j] < gate) & (np.r_[pic.served, False][cand]
                                               | ~covered[:, None])
        free = gated & ~taken[cand]
        nearest = _first(free, cand, pic.tracks)
        new = (st.ais_ref[mj] < 0) & (nearest >= 0)
        st.ais_ref[mj[new]] = nearest[new]
        # a failing transponder whose stream did not jump may also move to a track that
        # only excluded transponders hold (two ships' radar track ids exchanged)
        alt = np.where(nearest >= 0, nearest, _first(
            gated & ~held[cand] & ~st.ais_jumped[mj][:, None], cand, pic.tracks))
        pos, have = _lookup(pic.tracks, st.ais_ref[mj])
        # not decided on a track a radar in a lasting fault reports (the fault corrupts
        # the picture, its association included: the disagreements are the radar's)
        test = have.copy()  # (no radar tracks at all: AIS only, the gaps scene)
        test[have] = pic.served[pos[have]] & ~pic.tainted[pos[have]]
        r = np.full((j.size, 2), np.nan)
        xi = np.full(j.size, np.nan)
        if test.any():
            p, P = _extrapolated(pic, pos[test], ais.rep_dt[j[test]])
            r[test] = ais.rep_xy[j[test]] - p
            xi[test] = _d2(r[test], P + ais.var)
        # no reference track after the warm-up: the nearest track served (a spoofer)
        alone = (st.ais_ref[mj] < 0) & covered & (st.ais_nrep[mj] > ic.ais_warmup_reports)
        if alone.any():
            _unmatched(pic, ais, j, alone, xi, r)
        # and the transponder against itself (a stuck position, a jump)
        radar_dec = (test | alone) & covered
        self_xi = ais.rep_self[j]
        self_dec = np.isfinite(self_xi)
        decided = (radar_dec | self_dec) & ~ais.rep_lead[j]
        radar_flag = radar_dec & (eta(np.where(radar_dec, xi, 1.0), thr.ais_d1, thr.ais_d2) == 1)
        self_flag = self_dec & (np.nan_to_num(self_xi) >= np.where(
            radar_dec, thr.self_d2, thr.self_alone_d2))  # one decision: q
        flag = decided & (radar_flag | self_flag)
        radar_pass = radar_dec & (xi < thr.ais_d2)
        passed = decided & (~radar_dec | radar_pass) & ~self_flag
        if ic.exclusion and decided.any():
            md = mj[decided]
            st.ais_excl[md], st.ais_run[md] = step_exclusion(
                st.ais_excl[md], st.ais_run[md], ~passed[decided], passed[decided],
                np.ones(md.size, bool), ic.readmit_run)
        failed = decided & test & ~radar_pass
        st.ais_jumped[mj[passed]] = False
        if failed.any() or (st.ais_alt_n[mj] > 0).any():
            _reacquire(st, mj, failed, alt, decided & radar_pass, ic.readmit_run)
        kind = np.where(radar_flag | (radar_dec & ~self_flag), alone.astype(np.int8), 2)
        ao.decided[j], ao.kind[j], ao.xi[j], ao.eta[j] = decided, kind, xi, flag
        ao.self_xi[j] = self_xi
        ao.excluded[j], ao.r[j], ao.track[j] = st.ais_excl[mj], r, st.ais_ref[mj]


def _first(ok: np.ndarray, cand: np.ndarray, tracks: np.ndarray) -> np.ndarray:
    """Per row, the track of the first candidate with ``ok`` (nearest first), -1 none."""
    first = np.argmax(ok, axis=1)
    rows = np.arange(ok.shape[0])
    return np.where(ok[rows, first], np.r_[tracks, -1][cand[rows, first]], -1)


def _unmatched(pic: _Picture, ais: _Ais, j: np.ndarray, alone: np.ndarray, xi: np.ndarray,
               r: np.ndarray) -> None:
    """xi (and r) of transponders without a reference track against the nearest track the
    radars in service fuse; +inf when they fuse none."""
    served = np.flatnonzero(pic.served)
    xi[alone] = np.inf
    if served.size:
        p, P = _extrapolated(pic, served, np.zeros(served.size))
        z = ais.rep_xy[j[alone]]
        d2 = _pair_d2(z, p, P + ais.var)
        best = np.argmin(d2, axis=1)
        xi[alone] = d2[np.arange(best.size), best]
        r[alone] = z - p[best]


def _reacquire(st: _State, mj: np.ndarray, failed: np.ndarray, nearest: np.ndarray,
               passed: np.ndarray, run: int) -> None:
    """A transponder whose reports fail against its reference track while they fall in
    the gate of one same track ``alt`` (free, or held only by excluded transponders while
    its stream did not jump) ``run`` times in a row takes that track as its reference
    (its first one was another ship, e.g. after its own track was lost in an outage, or
    the radar track ids of two ships were exchanged); a passing report resets the count.
    A swapped MMSI jumps onto the other ship's track: no switch."""
    alt = failed & (nearest >= 0)
    same = alt & (st.ais_alt[mj] == nearest)
    st.ais_alt_n[mj[alt]] = np.where(same[alt], st.ais_alt_n[mj[alt]] + 1, 1)
    st.ais_alt[mj[alt]] = nearest[alt]
    reset = passed | (failed & (nearest < 0))
    st.ais_alt[mj[reset]] = -1
    st.ais_alt_n[mj[reset]] = 0
    switch = alt & (st.ais_alt_n[mj] >= run)
    st.ais_ref[mj[switch]] = st.ais_alt[mj[switch]]
    st.ais_alt[mj[switch]] = -1
    st.ais_alt_n[mj[switch]] = 0


def _pair_d2(z: np.ndarray, p: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(n, T) squared Mahalanobis distances of points z (n, 2) to estimates p (T, 2) with
    covariances S (T, 3)."""
    dx = z[:, None, 0] - p[None, :, 0]
    dy = z[:, None, 1] - p[None, :, 1]
    sxx, syy, sxy = S[None, :, 0], S[None, :, 1], S[None, :, 2]
    return (syy * dx * dx - 2 * sxy * dx * dy + sxx * dy * dy) / (sxx * syy - sxy * sxy)


def _extrapolated(pic: _Picture, pos: np.ndarray, dt: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The radar-only fused estimate of tracks ``pos`` moved by ``dt`` s with its velocity
    (multi-radar paper eq. 9) and the covariance that adds (eq. 12-13, variance form)."""
    v = pic.v[pos]
    speed = np.hypot(v[:, 0], v[:, 1])
    course = np.arctan2(v[:, 0], v[:, 1])
    dxx, dyy, dxy = extrapolation_covariance(speed, course, np.abs(dt), pic.sigma_v[pos],
                                             pic.sigma_c[pos], 0.0)
    p = pic.p[pos] + v * dt[:, None]
    return p, pic.P[pos] + np.column_stack([dxx, dyy, dxy])


# --- output ------------------------------------------------------------------------------

_CHECKS_RADAR = np.array(["nis", "bias", "coverage", "scan", "site"], dtype=object)
_CHECKS_AIS = np.array(["ais", "ais_unmatched", "ais_kinematics"], dtype=object)


def _health_frame(
    ro: _RadarOut, ao: _AisOut, epochs: np.ndarray, scan_gap: np.ndarray, ais: _Ais,
    cfg: Config,
    sector_names: list[str], thr: _Tables, ic: ChannelIntegrityConfig,
) -> pl.DataFrame:
    """``maritime_channel_health`` rows (:data:`HEALTH_COLUMNS`)."""
    G = len(sector_names)
    names = [*sector_names, None]
    sites = [s.site_id for s in cfg.radar_sites]
    kk, gg = np.nonzero(ro.checked)
    n = ro.n[kk, gg]
    theta = ro.theta[kk, gg]
    radar = pl.DataFrame({
        "time_ns": epochs[kk],
        "channel": pl.Series([sites[i] for i in (gg // (G + 1)).tolist()], dtype=pl.String),
        "sensor_kind": pl.Series(["radar"] * kk.size, dtype=pl.String),
        "sector": pl.Series([names[i] for i in (gg % (G + 1)).tolist()], dtype=pl.String),
        "check": pl.Series(_CHECKS_RADAR[ro.check[kk, gg]].tolist(), dtype=pl.String),
        "targets": n.astype(np.int32),
        "nis": np.where(n >= 1, ro.nis[kk, gg], np.nan),
        "dof": (2 * n).astype(np.int32),
        "d1": thr.nis_d1[n],
        "d2": thr.nis_d2[n],
        "bias_stat": ro.T[kk, gg],
        "bias_d2": np.full(kk.size, thr.bias_d2),
        # a group failed for its site's sake was not tested: no decision (null eta)
        "eta": pl.Series(ro.eta[kk, gg].astype(np.int16)).set(
            pl.Series(ro.check[kk, gg] == 4), None),
        "excluded": ro.excluded[kk, gg],
        "range_bias_m": theta[:, 0],
        "azimuth_bias_rad": theta[:, 1],
        "time_offset_s": theta[:, 2],
        "expected": ro.expected[kk, gg].astype(np.int32),
        "missed": ro.missed[kk, gg].astype(np.int32),
        "outliers": ro.outliers[kk, gg].astype(np.int32),
        "scan_gap_s": scan_gap[kk, gg // (G + 1)],
    })
    d = np.flatnonzero(ao.decided)
    r = ao.r[d]
    mm = ais.mmsi[ais.rep_m[d]]
    aisf = pl.DataFrame({
        "time_ns": ais.rep_t[d],
        "channel": pl.Series(mm.astype(str).tolist(), dtype=pl.String),
        "sensor_kind": pl.Series(["ais"] * d.size, dtype=pl.String),
        "sector": pl.Series([names[i] for i in ais.rep_sector[d].tolist()], dtype=pl.String),
        "check": pl.Series(_CHECKS_AIS[ao.kind[d]].tolist(), dtype=pl.String),
        "targets": np.ones(d.size, np.int32),
        "nis": ao.xi[d],
        "dof": np.full(d.size, 2, np.int32),
        "d1": np.full(d.size, thr.ais_d1),
        "d2": np.full(d.size, thr.ais_d2),
        "eta": ao.eta[d].astype(np.int16),
        "excluded": ao.excluded[d],
        "offset_east_m": r[:, 0],
        "offset_north_m": r[:, 1],
        "innovation_m": np.hypot(r[:, 0], r[:, 1]),
        "kinematic_nis": ao.self_xi[d],
        "mmsi": mm.astype(np.int64),
        "system_track_id": pl.Series(np.where(ao.track[d] >= 0, ao.track[d], 0)).set(
            pl.Series(ao.track[d] < 0), None),
    })
    out = pl.concat([radar, aisf], how="diagonal_relaxed").with_columns(
        pl.when(pl.col("sensor_kind") == "radar").then(ic.radar_q).otherwise(ic.ais_q)
        .alias("q"))
    return (
        out.with_columns(pl.col(pl.Float64).fill_nan(None))
        .select(pl.col(c).cast(t) if c in out.columns else pl.lit(None, t).alias(c)
                for c, t in _SCHEMA.items())
        .with_columns(pl.col("expected", "missed", "outliers").fill_null(0))
        .sort("time_ns", "sensor_kind", "channel", "sector", nulls_last=True)
    )


_SCHEMA: dict[str, pl.DataType] = {
    "time_ns": pl.Int64(), "channel": pl.String(), "sensor_kind": pl.String(),
    "sector": pl.String(), "check": pl.String(), "targets": pl.Int32(), "nis": pl.Float64(),
    "dof": pl.Int32(), "d1": pl.Float64(), "d2": pl.Float64(), "q": pl.Float64(),
    "bias_stat": pl.Float64(), "bias_d2": pl.Float64(), "eta": pl.Int16(),
    "excluded": pl.Boolean(), "range_bias_m": pl.Float64(), "azimuth_bias_rad": pl.Float64(),
    "time_offset_s": pl.Float64(), "offset_east_m": pl.Float64(),
    "offset_north_m": pl.Float64(), "innovation_m": pl.Float64(), "expected": pl.Int32(),
    "missed": pl.Int32(), "outliers": pl.Int32(), "scan_gap_s": pl.Float64(),
    "kinematic_nis": pl.Float64(),
    "mmsi": pl.Int64(), "system_track_id": pl.Int64(),
}  # fmt: skip
