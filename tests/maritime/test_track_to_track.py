"""Track-to-track association: gates, least summed Mahalanobis distance, stable ids."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import polars as pl
import pytest
from batch_builders import (
    NS,
    T0_NS,
    Ship,
    crossing_pair,
    epochs_for,
    lane_ships,
    radar_reports,
    vessel_of,
)
from scipy.optimize import linear_sum_assignment
from scipy.stats import chi2

from pipeline.config import Config
from pipeline.families import load_config
from pipeline.maritime.align import align_reports
from pipeline.maritime.associate import (
    BIRTH_RANK_LIMIT,
    Kinematics,
    _cluster_epoch,
    assign,
    associate_tracks,
    association_gate,
    gate_threshold,
    gated_d2,
    split_parents,
    velocity_covariance,
)
from pipeline.maritime.config import AssociationConfig, maritime_config
from pipeline.maritime.fuse import fuse
from pipeline.maritime.hypothesis import state_vectors
from pipeline.maritime.sync import synchronise


@pytest.fixture(scope="module")
def cfg() -> Config:
    return load_config()


def _synced(rows: list[dict]) -> pl.DataFrame:
    base = {"time_ns": 0, "report_time_ns": 0, "P_xx": 100.0, "P_yy": 100.0, "P_xy": 0.0,
            "course_rad": 1.0, "speed_mps": 5.0, "sigma_course_rad": 0.035,
            "sigma_speed_mps": 0.25}
    return pl.DataFrame([{**base, **r} for r in rows],
                        schema_overrides={"time_ns": pl.Int64, "local_track_id": pl.Int64})


def _run(ships, cfg: Config, seed: int, duration_s: float) -> pl.DataFrame:
    radar = radar_reports(ships, cfg, np.random.default_rng(seed), duration_s=duration_s,
                          scan_end_azimuth_rad={"R1": 0.0, "R2": 2.5})
    aligned, _ = align_reports(radar, cfg)
    sync = maritime_config(cfg).sync
    synced = synchronise(aligned, epochs_ns=epochs_for(duration_s, cfg), sync=sync)
    return associate_tracks(synced, cfg=maritime_config(cfg).association)


def _assert_no_swaps(out: pl.DataFrame, min_share: float) -> None:
    """No system id ever holds two vessels; each local track keeps one id (>= share of
    its epochs, and the same id at its start and end)."""
    v = out.with_columns(vessel_of(pl.col("local_track_id")).alias("v"))
    mixed = v.group_by("system_track_id").agg(pl.col("v").n_unique().alias("n"))
    assert mixed["n"].max() == 1
    per_track = v.sort("time_ns").group_by("site_id", "local_track_id").agg(
        (pl.col("system_track_id").mode().first() == pl.col("system_track_id")).mean()
        .alias("share"),
        (pl.col("system_track_id").first() == pl.col("system_track_id").last()).alias("same"),
    )
    assert per_track["share"].min() >= min_share, per_track
    assert per_track["same"].all()


def test_gated_d2_inline_and_gates():
    cfg = AssociationConfig()
    gate = gate_threshold(cfg.gate_probability)
    assert gate == pytest.approx(chi2.ppf(0.999, 2))
    P = np.array([[400.0, 120.0], [120.0, 900.0]])
    a = Kinematics(*(np.array([v]) for v in (0.0, 0.0, 100.0, 200.0, 30.0, 5.0, np.radians(359))))
    b = Kinematics(np.array([40.0, 40.0, 40.0, 40.0]), np.array([-30.0] * 4),
                   np.full(4, 300.0), np.full(4, 700.0), np.full(4, 90.0),
                   np.array([5.5, 5.5, 9.0, 0.5]),
                   np.radians([1.0, 40.0, 1.0, 40.0]))
    d2 = gated_d2(a, b, cfg, gate)
    D = np.array([-40.0, 30.0])
    assert d2[0, 0] == pytest.approx(D @ np.linalg.solve(P, D))  # wraps 359 -> 1 deg
    assert np.isinf(d2[0, 1])  # course differs by 41 deg
    assert np.isinf(d2[0, 2])  # speed differs by 4 m/s
    a_slow = replace(a, speed_mps=np.array([0.3]))
    assert np.isfinite(gated_d2(a_slow, b, cfg, gate)[0, 3])  # both slow: no course gate


def _kin(x, y, pxx, pyy, pxy, v, c, sv, sc) -> Kinematics:
    return Kinematics(*(np.atleast_1d(np.asarray(a, float)) for a in (x, y, pxx, pyy, pxy, v, c,
                                                                      sv, sc)))


def test_gated_d2_position_and_velocity_against_the_4x4_form():
    """Two paths agree: the broadcast d^2 (position + velocity, closed-form 2x2 blocks) and
    D^T (P_a + P_b)^-1 D with the 4x4 state covariances of the hypothesis module
    (velocity covariance J diag(sigma_V^2, sigma_C^2) J^T), recomputed with numpy."""
    cfg = AssociationConfig()
    assert cfg.velocity_cost and association_gate(cfg) == pytest.approx(chi2.ppf(0.999, 4))
    a = _kin(0.0, 0.0, 400.0, 900.0, 120.0, 6.0, np.radians(40.0), 0.3, np.radians(3.0))
    b = _kin([30.0, -20.0, 50.0], [10.0, 40.0, -30.0], [300.0, 250.0, 500.0],
             [700.0, 300.0, 200.0], [90.0, -40.0, 0.0], [6.4, 5.2, 7.0],
             np.radians([48.0, 35.0, 20.0]), [0.2, 0.25, 0.4], np.radians([2.0, 4.0, 2.5]))
    d2 = gated_d2(a, b, cfg, 1e9)
    Xa, Pa = state_vectors(a.x_m, a.y_m, a.P_xx, a.P_yy, a.P_xy, a.speed_mps, a.course_rad,
                           a.sigma_speed_mps, a.sigma_course_rad)
    Xb, Pb = state_vectors(b.x_m, b.y_m, b.P_xx, b.P_yy, b.P_xy, b.speed_mps, b.course_rad,
                           b.sigma_speed_mps, b.sigma_course_rad)
    for j in range(3):
        D = Xa[0] - Xb[j]
        assert d2[0, j] == pytest.approx(D @ np.linalg.solve(Pa[0] + Pb[j], D), rel=1e-9)
    # velocity_cost = false, or a side without velocity sigmas: the position d^2 alone
    pos = gated_d2(a, b, replace(cfg, velocity_cost=False), 1e9)
    for j in range(3):
        D = Xa[0, :2] - Xb[j, :2]
        assert pos[0, j] == pytest.approx(D @ np.linalg.solve(Pa[0, :2, :2] + Pb[j, :2, :2], D))
    no_sigmas = replace(b, sigma_speed_mps=None, sigma_course_rad=None)
    np.testing.assert_allclose(gated_d2(a, no_sigmas, cfg, 1e9), pos)
    # the 4-dof gate: a pair whose courses differ by 20 deg at 6 m/s (sigmas 3 and 2 deg)
    # passes the course gate (30 deg) but not chi2.ppf(0.999, 4)
    c = _kin(0.0, 0.0, 400.0, 400.0, 0.0, 6.0, np.radians(60.0), 0.25, np.radians(2.0))
    assert np.isinf(gated_d2(a, c, cfg, association_gate(cfg))[0, 0])
    assert np.isfinite(gated_d2(a, c, replace(cfg, velocity_cost=False),
                                gate_threshold(cfg.gate_probability))[0, 0])


def test_velocity_covariance_of_a_stopped_ship_is_not_degenerate():
    """sigma_V along, V sigma_C across the course; below course_gate_min_speed_mps the
    course is noise and the across-course sigma is at least sigma_V."""
    k = _kin([0.0, 0.0], [0.0, 0.0], [1.0, 1.0], [1.0, 1.0], [0.0, 0.0], [8.0, 0.2],
             [0.0, 0.0], [0.3, 0.3], [np.radians(2.0)] * 2)
    vxx, vyy, vxy = velocity_covariance(k, 1.0)
    assert vyy.tolist() == pytest.approx([0.09, 0.09])  # along the course (north)
    assert vxx[0] == pytest.approx((8.0 * np.radians(2.0)) ** 2)  # across: V sigma_C
    assert vxx[1] == pytest.approx(0.09) and np.allclose(vxy, 0.0)  # slow: sigma_V


def test_least_summed_distance_beats_greedy_case_a():
    # two-radar paper, case A: H(a1-b1, a2-b2) = 11 vs H(a1-b2, a2-b1) = 4
    rows, cols = assign(np.array([[1.0, 2.0], [2.0, 10.0]]), 13.8)
    assert sorted(zip(rows.tolist(), cols.tolist(), strict=True)) == [(0, 1), (1, 0)]


def test_case_b_one_radar_sees_fewer_targets():
    rows, cols = assign(np.array([[3.0], [1.0]]), 13.8)
    assert rows.tolist() == [1] and cols.tolist() == [0]
    rows, cols = assign(np.array([[np.inf], [np.inf]]), 13.8)
    assert rows.size == 0


@pytest.mark.parametrize("seed", range(5))
def test_sparse_shortcut_agrees_with_the_plain_augmented_assignment(seed):
    rng = np.random.default_rng(seed)
    cost = rng.uniform(0.0, 20.0, (30, 25))
    cost[rng.uniform(size=cost.shape) < 0.9] = np.inf
    gate = 13.8
    rows, cols = assign(cost, gate)
    aug = np.full((30, 55), np.inf)
    aug[:, :25] = np.where(cost < gate, cost, np.inf)
    aug[np.arange(30), 25 + np.arange(30)] = gate
    r, c = linear_sum_assignment(aug)
    plain = aug[r, c].sum()
    ours = cost[rows, cols].sum() + gate * (30 - rows.size)
    assert ours == pytest.approx(plain)
    assert np.unique(cols).size == cols.size


def test_one_epoch_pairs_and_leave_one_out_d2():
    syn = _synced([
        {"site_id": "R1", "local_track_id": 1, "x_enu_m": 0.0, "y_enu_m": 0.0},
        {"site_id": "R1", "local_track_id": 2, "x_enu_m": 500.0, "y_enu_m": 0.0},
        {"site_id": "R2", "local_track_id": 9, "x_enu_m": 510.0, "y_enu_m": 12.0,
         "P_xx": 300.0, "P_xy": 40.0},
    ])
    out = associate_tracks(syn, cfg=AssociationConfig())
    ids = dict(zip(out["local_track_id"], out["system_track_id"], strict=True))
    assert ids[2] == ids[9] != ids[1]
    assert min(ids.values()) // BIRTH_RANK_LIMIT == syn["time_ns"][0] // 1_000_000
    d2 = dict(zip(out["local_track_id"], out["mahalanobis_d2"], strict=True))
    D = np.array([10.0, 12.0])
    S = np.array([[100.0 + 300.0, 40.0], [40.0, 200.0]])
    assert d2[9] == pytest.approx(D @ np.linalg.solve(S, D))
    assert d2[2] == pytest.approx(d2[9])
    assert d2[1] is None


def test_ids_persist_over_ten_minutes_without_swaps(cfg):
    out = _run(lane_ships(5, np.random.default_rng(21)), cfg, 22, 600.0)
    assert not out.select("time_ns", "site_id", "local_track_id").is_duplicated().any()
    assert not out.select("time_ns", "system_track_id", "site_id").is_duplicated().any()
    _assert_no_swaps(out, 0.98)
    pairs = out.group_by("time_ns", "system_track_id").len()
    assert (pairs["len"] == 2).mean() > 0.98  # both radars fused nearly always


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_two_ships_crossing_150_m_apart_are_kept_apart(cfg, seed):
    # (without the continuity rule 9 of 10 seeds swap here: measured when written)
    ships = crossing_pair(cpa_m=150.0, t_cross_s=300.0)
    out = _run(ships, cfg, seed, 600.0)
    _assert_no_swaps(out, 0.95)
    # the case is ambiguous near the crossing: the wrong pairing also passes the gates
    near = out.filter((pl.col("time_ns") - T0_NS).is_between(270 * NS, 330 * NS))
    a = near.filter((pl.col("site_id") == "R1") & (vessel_of(pl.col("local_track_id")) == 1))
    b = near.filter((pl.col("site_id") == "R2") & (vessel_of(pl.col("local_track_id")) == 2))
    ka, kb = (Kinematics(*(f[c].to_numpy() for c in ("x_enu_m", "y_enu_m", "P_xx", "P_yy",
                                                       "P_xy", "speed_mps", "course_rad")))
              for f in (a, b))
    d2 = np.diag(gated_d2(ka, kb, maritime_config(cfg).association, gate_threshold(0.999)))
    assert np.isfinite(d2).any()


def _overtaking_pair_mixed(cfg: Config, seed: int, velocity_cost: bool) -> int:
    """Epochs where one system track holds both ships of an overtaking pair: same lane
    (20 m apart, course 090), 4.8 and 6.9 m/s (inside the 2.5 m/s speed gate), abeam at
    300 s, when R2 drops and re-initiates both tracks (new local ids, no continuity)."""
    ships = [Ship(1, -4.8 * 300, 0.0, np.pi / 2, 4.8), Ship(2, -6.9 * 300, 20.0, np.pi / 2, 6.9)]
    radar = radar_reports(ships, cfg, np.random.default_rng(seed), duration_s=600,
                          scan_end_azimuth_rad={"R1": 0.0, "R2": 2.5})
    restart = (pl.col("time_ns") >= T0_NS + 300 * NS) & (pl.col("site_id") == "R2")
    radar = radar.with_columns(pl.when(restart).then(pl.col("local_track_id") + 1000)
                               .otherwise(pl.col("local_track_id")).alias("local_track_id"))
    aligned, _ = align_reports(radar, cfg)
    synced = synchronise(aligned, epochs_ns=epochs_for(600, cfg), sync=maritime_config(cfg).sync)
    assoc = replace(maritime_config(cfg).association, velocity_cost=velocity_cost)
    out = associate_tracks(synced, cfg=assoc)
    return out.group_by("time_ns", "system_track_id").agg(
        vessel_of(pl.col("local_track_id")).n_unique().alias("n")).filter(pl.col("n") > 1).height


def test_velocity_cost_keeps_an_overtaking_pair_apart(cfg):
    """Position alone cannot tell the two new R2 tracks apart (20 m, both abeam): on some
    seeds the least summed position distance pairs each with the other ship's R1 track,
    and the continuity rule then keeps the wrong pairing; the velocity term (2.1 m/s of
    speed difference, sigma 0.35 m/s) never does (measured when written: position cost
    mixed on seed 3, 14 epochs; velocity cost on none of 8 seeds)."""
    pos = [_overtaking_pair_mixed(cfg, seed, False) for seed in range(8)]
    vel = [_overtaking_pair_mixed(cfg, seed, True) for seed in range(8)]
    assert sum(pos) > 0, pos
    assert vel == [0] * 8, vel


def test_n_radars_one_row_per_site_per_system_track(cfg):
    r3 = replace(cfg.radar_sites[0], site_id="R3", lat_deg=46.33, lon_deg=30.90,
                 scan_period_s=2.5)
    cfg3 = replace(cfg, radar_sites=(*cfg.radar_sites, r3))
    out = _run(lane_ships(4, np.random.default_rng(41)), cfg3, 42, 240.0)
    assert not out.select("time_ns", "system_track_id", "site_id").is_duplicated().any()
    sizes = out.group_by("time_ns", "system_track_id").len()["len"]
    assert (sizes == 3).mean() > 0.95
    _assert_no_swaps(out, 0.97)


def test_restarted_local_track_joins_its_system_track(cfg):
    ships = lane_ships(3, np.random.default_rng(51))
    radar = radar_reports(ships, cfg, np.random.default_rng(52), duration_s=300)
    later = (pl.col("time_ns") > T0_NS + 150 * NS) & (pl.col("local_track_id") == 101)
    radar = radar.with_columns(
        pl.when(later).then(pl.lit(191, pl.Int64)).otherwise(pl.col("local_track_id"))
        .alias("local_track_id"))
    aligned, _ = align_reports(radar, cfg)
    synced = synchronise(aligned, epochs_ns=epochs_for(300, cfg), sync=maritime_config(cfg).sync)
    out = associate_tracks(synced, cfg=maritime_config(cfg).association)
    ids = out.filter(pl.col("local_track_id").is_in([101, 191, 201]))["system_track_id"]
    assert ids.mode().len() == 1 and (ids == ids.mode()[0]).mean() > 0.98


@pytest.mark.parametrize(("gap_s", "same_id"), [(8.0, True), (60.0, False)])
def test_single_radar_track_renumbered_after_a_gap(cfg, gap_s, same_id):
    ships = lane_ships(2, np.random.default_rng(61))
    radar = radar_reports(ships, cfg, np.random.default_rng(62), duration_s=300)
    radar = radar.filter(pl.col("site_id") == "R1")
    t_cut = T0_NS + 150 * NS
    gap = (pl.col("time_ns") > t_cut) & (pl.col("time_ns") < t_cut + int(gap_s * NS))
    radar = radar.filter(~(gap & (pl.col("local_track_id") == 101))).with_columns(
        pl.when((pl.col("time_ns") >= t_cut) & (pl.col("local_track_id") == 101))
        .then(pl.lit(181, pl.Int64)).otherwise(pl.col("local_track_id")).alias("local_track_id"))
    aligned, _ = align_reports(radar, cfg)
    synced = synchronise(aligned, epochs_ns=epochs_for(300, cfg), sync=maritime_config(cfg).sync)
    out = associate_tracks(synced, cfg=maritime_config(cfg).association)
    before = out.filter(pl.col("local_track_id") == 101)["system_track_id"].unique()
    after = out.filter(pl.col("local_track_id") == 181)["system_track_id"].unique()
    assert before.len() == 1 and after.len() == 1
    assert (before[0] == after[0]) is same_id
    other = out.filter(pl.col("local_track_id") == 102)["system_track_id"].unique()
    assert other.len() == 1 and other[0] != after[0]


def test_empty_input(cfg):
    out = associate_tracks(_synced([{"site_id": "R1", "local_track_id": 1, "x_enu_m": 0.0,
                                     "y_enu_m": 0.0}]).clear(),
                           cfg=maritime_config(cfg).association)
    assert out.height == 0 and {"system_track_id", "mahalanobis_d2"} <= set(out.columns)


# --- one eq. 14 (matrix form) for association and fusion --------------------------------


def _ellipse(a_m: float, b_m: float, angle_rad: float) -> np.ndarray:
    """Covariance (m^2) with semi-axes sigmas a_m along angle_rad (from east), b_m across."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    R = np.array([[c, -s], [s, c]])
    return R @ np.diag([a_m**2, b_m**2]) @ R.T


def _matrix_eq14(P: list[np.ndarray], p: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(p_hat, P_hat) of eq. 14 in matrix form, recomputed inline."""
    P_hat = np.linalg.inv(sum(np.linalg.inv(Pi) for Pi in P))
    return P_hat @ sum(np.linalg.solve(Pi, pi) for Pi, pi in zip(P, p, strict=True)), P_hat


def _per_axis_eq14(P: list[np.ndarray], p: list[np.ndarray]) -> np.ndarray:
    """The old per-axis mean (weights 1/P_xx, 1/P_yy): what the tests must tell apart."""
    w = np.array([[1 / Pi[0, 0], 1 / Pi[1, 1]] for Pi in P])
    return (w * np.array(p)).sum(0) / w.sum(0)


def _epoch_rows(rng: np.random.Generator, n_ships: int, sites: tuple[str, ...]) -> pl.DataFrame:
    """One synchronised epoch: n_ships 3 km apart, each seen by every site with a
    rotated, elongated error ellipse (different per site) and its noise drawn from it."""
    rows = []
    for k in range(n_ships):
        truth = np.array([3000.0 * k, 500.0 * (k % 2)])
        for s_i, site in enumerate(sites):
            P = _ellipse(rng.uniform(40, 90), rng.uniform(8, 20),
                         rng.uniform(0, np.pi) + s_i * np.pi / len(sites))
            x, y = rng.multivariate_normal(truth, P)
            rows.append({"site_id": site, "local_track_id": 100 * (s_i + 1) + k,
                         "x_enu_m": x, "y_enu_m": y, "P_xx": P[0, 0], "P_yy": P[1, 1],
                         "P_xy": P[0, 1], "course_rad": 1.0 + rng.normal(0, 0.03),
                         "speed_mps": 5.0 + rng.normal(0, 0.2),
                         "sigma_course_rad": rng.uniform(0.02, 0.05),
                         "sigma_speed_mps": rng.uniform(0.15, 0.4)})
    return _synced(rows).sort("site_id", "local_track_id")


@pytest.mark.parametrize("seed", range(3))
def test_candidate_state_equals_fuse_for_the_same_members(seed):
    """Two paths agree: the association's candidate system tracks (numpy running sums,
    the state its ids are decided on) and fuse() (polars group sums, the state that is
    published), for the same members, to 1e-9."""
    syn = _epoch_rows(np.random.default_rng(seed), 6, ("R1", "R2", "R3"))
    cfg = AssociationConfig()
    kin = Kinematics(*(syn[c].to_numpy() for c in (
        "x_enu_m", "y_enu_m", "P_xx", "P_yy", "P_xy", "speed_mps", "course_rad")))
    site = syn["site_id"].replace_strict(["R1", "R2", "R3"], [0, 1, 2]).to_numpy()
    cand, member = _cluster_epoch(
        kin, syn["sigma_speed_mps"].to_numpy(), syn["sigma_course_rad"].to_numpy(),
        np.full(syn.height, -1), site, 3, cfg, association_gate(cfg))
    assert cand.n == 6 and np.bincount(member).tolist() == [3] * 6  # one per ship
    state, sigma_v, sigma_c = cand.state()
    fused = fuse(syn.with_columns(pl.Series("system_track_id", member, pl.Int64)))
    assert fused["system_track_id"].to_list() == list(range(6))
    for got, col in ((state.x_m, "x_enu_m"), (state.y_m, "y_enu_m"),
                     (state.speed_mps, "speed_mps"), (sigma_v, "sigma_speed_mps"),
                     (sigma_c, "sigma_course_rad"), (state.P_xy, "cov_xy_m2")):
        np.testing.assert_allclose(got, fused[col].to_numpy(), rtol=0, atol=1e-9, err_msg=col)
    np.testing.assert_allclose(np.sqrt(state.P_xx), fused["sigma_x_m"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.sqrt(state.P_yy), fused["sigma_y_m"], rtol=0, atol=1e-9)
    dc = np.abs(np.angle(np.exp(1j * (state.course_rad - fused["course_rad"].to_numpy()))))
    assert dc.max() < 1e-9


def test_candidate_state_is_the_matrix_form_not_per_axis():
    """Rotated ellipses (+-45 deg, 100 m x 10 m): the matrix form of eq. 14 and the
    per-axis mean differ by metres; candidates, fuse() and the inline matrix form agree."""
    P = [_ellipse(100.0, 10.0, np.pi / 4), _ellipse(100.0, 10.0, -np.pi / 4),
         _ellipse(60.0, 15.0, np.pi / 3)]
    p = [np.array([1000.0, 2000.0]), np.array([1040.0, 1985.0]), np.array([990.0, 2030.0])]
    p_hat, P_hat = _matrix_eq14(P, p)
    assert np.linalg.norm(_per_axis_eq14(P, p) - p_hat) > 5.0  # the old form differs
    syn = _synced([{"site_id": f"R{i + 1}", "local_track_id": i + 1, "x_enu_m": pi[0],
                    "y_enu_m": pi[1], "P_xx": Pi[0, 0], "P_yy": Pi[1, 1], "P_xy": Pi[0, 1]}
                   for i, (Pi, pi) in enumerate(zip(P, p, strict=True))])
    cfg = AssociationConfig()
    kin = Kinematics(*(syn[c].to_numpy() for c in (
        "x_enu_m", "y_enu_m", "P_xx", "P_yy", "P_xy", "speed_mps", "course_rad")))
    cand, member = _cluster_epoch(
        kin, syn["sigma_speed_mps"].to_numpy(), syn["sigma_course_rad"].to_numpy(),
        np.full(3, -1), np.arange(3), 3, cfg, association_gate(cfg))
    assert member.tolist() == [0, 0, 0]
    state, _, _ = cand.state()
    np.testing.assert_allclose([state.x_m[0], state.y_m[0]], p_hat, rtol=0, atol=1e-9)
    np.testing.assert_allclose([[state.P_xx[0], state.P_xy[0]], [state.P_xy[0], state.P_yy[0]]],
                               P_hat, rtol=1e-12)
    f = fuse(syn.with_columns(pl.lit(1, pl.Int64).alias("system_track_id"))).row(0, named=True)
    assert [f["x_enu_m"], f["y_enu_m"]] == pytest.approx(p_hat.tolist(), abs=1e-9)


def test_leave_one_out_d2_is_to_the_matrix_fusion_of_the_others():
    """Three radars, rotated ellipses: each row's mahalanobis_d2 is to the matrix-form
    eq. 14 fusion of the two others (recomputed inline), not to their per-axis mean."""
    P = [_ellipse(90.0, 10.0, np.pi / 4), _ellipse(90.0, 10.0, -np.pi / 4),
         _ellipse(70.0, 12.0, np.pi / 2.5)]
    p = [np.array([0.0, 0.0]), np.array([30.0, 20.0]), np.array([-15.0, 25.0])]
    syn = _synced([{"site_id": f"R{i + 1}", "local_track_id": i + 1, "x_enu_m": pi[0],
                    "y_enu_m": pi[1], "P_xx": Pi[0, 0], "P_yy": Pi[1, 1], "P_xy": Pi[0, 1]}
                   for i, (Pi, pi) in enumerate(zip(P, p, strict=True))])
    out = associate_tracks(syn, cfg=AssociationConfig()).sort("site_id")
    assert out["system_track_id"].n_unique() == 1
    for i, d2 in enumerate(out["mahalanobis_d2"]):
        others = [j for j in range(3) if j != i]
        p_o, P_o = _matrix_eq14([P[j] for j in others], [p[j] for j in others])
        D, S = p[i] - p_o, P[i] + P_o
        assert d2 == pytest.approx(D @ np.linalg.solve(S, D), rel=1e-9)
        D_axis = p[i] - _per_axis_eq14([P[j] for j in others], [p[j] for j in others])
        assert abs(D_axis @ np.linalg.solve(S, D_axis) - d2) > 0.1 * d2  # would differ


def test_split_parents_from_the_first_epoch_of_each_track():
    """A track's parent: the one system track its local tracks were on at their previous
    report (within the timeout). Track 20 splits from 10 (R2's track 2 leaves it);
    track 30 is born of a new local track; track 40 of local tracks from two tracks;
    track 50 of one last seen on track 10 longer than the timeout ago."""
    s = NS
    rows = [  # time_s, site, local, system
        (0, "R1", 1, 10), (0, "R2", 2, 10), (4, "R1", 1, 10), (4, "R2", 2, 20),
        (8, "R2", 2, 20), (8, "R1", 1, 10),
        (4, "R3", 7, 30),
        (0, "R1", 5, 11), (0, "R2", 6, 12), (4, "R1", 5, 40), (4, "R2", 6, 40),
        (0, "R3", 9, 10), (60, "R3", 9, 50),
    ]
    t, site, local, sid = zip(*rows, strict=True)
    a = pl.DataFrame({"time_ns": [v * s for v in t], "site_id": site,
                      "local_track_id": local, "system_track_id": sid},
                     schema_overrides={"local_track_id": pl.Int64, "system_track_id": pl.Int64})
    got = split_parents(a, track_timeout_s=30.0)
    assert got.rows() == [(20, 10, 4 * s)]
