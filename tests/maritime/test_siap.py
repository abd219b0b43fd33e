"""SIAP measures: a hand-built scenario with known answers (a track change, a swap of two
close ships, ambiguity, a spurious track, an untracked ship, right/wrong/missing MMSIs),
the same scenario through Stone Soup's SIAPMetrics/IDSIAPMetrics, and the batch's
siap_by_sector on the end-to-end warehouse."""

from __future__ import annotations

import datetime as dt

import numpy as np
import polars as pl
import pytest

from pipeline.config import Config
from pipeline.frames import enu_to_geodetic
from pipeline.maritime.siap import SiapConfig, siap_by_sector
from pipeline.units import NS
from pipeline.warehouse.delta import read_table

T0 = 1_768_435_200 * NS
PERIOD_S = 4.0
K = 50  # epochs
EPOCHS = T0 + np.arange(K, dtype=np.int64) * round(PERIOD_S * NS)
MMSI = {1: 211_000_001, 2: 211_000_002, 3: 211_000_003, 4: 211_000_004, 5: 211_000_005}
# truths: (x0, y0, vx, vy) in regional ENU; 3 and 4 sail side by side 80 m apart
SHIPS = {1: (-3000.0, 0.0, 5.0, 0.0), 2: (0.0, -3000.0, 0.0, 4.0), 3: (-2000.0, 2000.0, 5.0, 0.0),
         4: (-2000.0, 2080.0, 5.0, 0.0), 5: (3000.0, 3000.0, 0.0, -3.0)}
OFFSET_M = 3.0       # every track is 3 m east of its truth...
AMBIG_OFFSET_M = 20.0  # ...except the duplicate track 11
DV_MPS = 0.1         # and 0.1 m/s faster east


def _truth(cfg: Config) -> pl.DataFrame:
    t_s = np.arange(0, K * PERIOD_S + 1.0)  # 1 Hz truth covering every epoch
    rows = []
    for vid, (x0, y0, vx, vy) in SHIPS.items():
        lat, lon = enu_to_geodetic(x0 + vx * t_s, y0 + vy * t_s, cfg.region.origin_lat_deg,
                                   cfg.region.origin_lon_deg)
        rows.append(pl.DataFrame({
            "time_ns": T0 + (t_s * NS).astype(np.int64), "vessel_id": vid, "mmsi": MMSI[vid],
            "lat_deg": lat, "lon_deg": lon, "course_rad": np.arctan2(vx, vy) % (2 * np.pi),
            "speed_mps": np.hypot(vx, vy)}))
    return pl.concat(rows)


def _followed() -> list[tuple[int, int, int, int | None, float]]:
    """(track id, epoch k, truth followed, track MMSI, east offset) rows."""
    rows = []
    for k in range(K):
        rows.append((10, k, 1, MMSI[1], OFFSET_M))
        if 10 <= k < 15:
            rows.append((11, k, 1, MMSI[5], AMBIG_OFFSET_M))   # duplicate, wrong MMSI
        if k < 25:
            rows.append((20, k, 2, MMSI[2], OFFSET_M))
        elif k >= 27:
            rows.append((21, k, 2, None, OFFSET_M))            # new number, no MMSI yet
        rows.append((30, k, 3 if k < 20 else 4, MMSI[3], OFFSET_M))  # the swap at k = 20
        rows.append((40, k, 4 if k < 20 else 3, MMSI[4], OFFSET_M))
        rows.append((99, k, 0, None, 0.0))                      # spurious
    return rows


def _tracks() -> pl.DataFrame:
    out = []
    for tid, k, vid, mmsi, off in _followed():
        t = k * PERIOD_S
        if vid == 0:
            x, y, vx, vy = 9000.0, -9000.0, 1.0, 0.0
        else:
            x0, y0, vx, vy = SHIPS[vid]
            x, y, vx = x0 + vx * t + off, y0 + vy * t, vx + DV_MPS
        out.append({"time_ns": int(EPOCHS[k]), "system_track_id": tid, "x_enu_m": x,
                    "y_enu_m": y, "sigma_x_m": 10.0, "sigma_y_m": 10.0, "cov_xy_m2": 0.0,
                    "speed_mps": float(np.hypot(vx, vy)),
                    "course_rad": float(np.arctan2(vx, vy) % (2 * np.pi)), "mmsi": mmsi,
                    "sector": "inner_channel"})
    return pl.DataFrame(out, schema_overrides={"mmsi": pl.Int64})


@pytest.fixture(scope="module")
def siap_row(cfg) -> dict:
    out = siap_by_sector(_tracks(), _truth(cfg), epochs_ns=EPOCHS, epoch_period_s=PERIOD_S,
                         region=cfg.region, sectors=cfg.sectors, cfg=SiapConfig(),
                         start_ns=T0, end_ns=int(EPOCHS[-1]) + 1)
    assert out["sector"].to_list() == ["inner_channel"]
    return out.row(0, named=True)


def test_counts_of_the_hand_built_scenario(siap_row):
    r = siap_row
    assert r["truths"] == 5 and r["truth_epochs"] == 5 * K
    assert r["tracked_truth_epochs"] == 50 + 48 + 50 + 50 + 0
    assert r["track_epochs"] == 50 + 5 + 25 + 23 + 50 + 50 + 50
    assert r["spurious_track_epochs"] == 50
    assert r["associated_track_epochs"] == 203
    assert r["track_number_changes"] == 3  # truth 2: 20 -> 21; truths 3, 4: the swap
    assert r["track_swaps"] == 1
    assert r["longest_segment_s"] == (50 + 25 + 30 + 30) * PERIOD_S
    assert r["tracked_time_s"] == 198 * PERIOD_S and r["truth_time_s"] == 250 * PERIOD_S
    assert (r["id_truth_epochs"], r["id_correct_epochs"], r["id_unknown_epochs"],
            r["id_incorrect_epochs"], r["id_ambiguous_epochs"]) == (198, 110, 23, 60, 5)


def test_measures_of_the_hand_built_scenario(siap_row):
    r = siap_row
    assert r["completeness"] == pytest.approx(198 / 250)
    assert r["ambiguity"] == pytest.approx(203 / 198)
    assert r["spuriousness"] == pytest.approx(50 / 253)
    assert r["position_accuracy_m"] == pytest.approx((198 * OFFSET_M + 5 * AMBIG_OFFSET_M) / 203,
                                                     rel=1e-6)
    assert r["velocity_accuracy_mps"] == pytest.approx(DV_MPS, rel=1e-6)
    assert r["track_number_changes_per_h"] == pytest.approx(3 * 3600 / (198 * PERIOD_S))
    assert r["longest_segment"] == pytest.approx(135 / 250)
    assert r["id_completeness"] == pytest.approx(175 / 198)
    assert r["id_correctness"] == pytest.approx(110 / 198)
    assert r["id_ambiguity"] == pytest.approx(5 / 198)


def test_without_truth_the_table_is_empty(cfg):
    out = siap_by_sector(_tracks(), None, epochs_ns=EPOCHS, epoch_period_s=PERIOD_S,
                         region=cfg.region, sectors=cfg.sectors, cfg=SiapConfig(),
                         start_ns=T0, end_ns=T0 + 1)
    assert out.height == 0


def test_against_stone_soup_siap(cfg, siap_row):
    """Stone Soup's SIAPMetrics / IDSIAPMetrics with its own TrackToTruth association on
    the same states. Per-epoch measures agree exactly; R and LS differ only by the time
    convention (Stone Soup: last - first timestamp, we: epochs x period), which is
    checked through their numerators and per-truth durations."""
    pytest.importorskip("stonesoup")
    from stonesoup.dataassociator.tracktotrack import TrackToTruth
    from stonesoup.measures import Euclidean
    from stonesoup.metricgenerator.manager import MultiManager
    from stonesoup.metricgenerator.tracktotruthmetrics import IDSIAPMetrics
    from stonesoup.types.groundtruth import GroundTruthPath, GroundTruthState
    from stonesoup.types.state import State
    from stonesoup.types.track import Track

    def when(t_ns: int) -> dt.datetime:
        return dt.datetime(2026, 1, 15) + dt.timedelta(seconds=(t_ns - T0) / NS)

    truths = []
    for vid, (x0, y0, vx, vy) in SHIPS.items():
        states = [GroundTruthState([[x0 + vx * k * PERIOD_S], [vx], [y0 + vy * k * PERIOD_S],
                                    [vy]], timestamp=when(int(EPOCHS[k])),
                                   metadata={"mmsi": MMSI[vid]}) for k in range(K)]
        truths.append(GroundTruthPath(states))
    tracks = []
    for _tid, g in _tracks().sort("time_ns").group_by("system_track_id", maintain_order=True):
        vx = g["speed_mps"] * np.sin(g["course_rad"])
        vy = g["speed_mps"] * np.cos(g["course_rad"])
        tr = Track([State([[x], [a], [y], [b]], timestamp=when(t)) for x, a, y, b, t in zip(
            g["x_enu_m"], vx, g["y_enu_m"], vy, g["time_ns"], strict=True)])
        tr.metadatas = [{"mmsi": m} for m in g["mmsi"].to_list()]
        tracks.append(tr)
    gen = IDSIAPMetrics(position_measure=Euclidean((0, 2)), velocity_measure=Euclidean((1, 3)),
                        truth_id="mmsi", track_id="mmsi")
    # gate radius of our chi-square gate for a 10 m isotropic sigma: 3.717 sigma
    mgr = MultiManager([gen], associator=TrackToTruth(
        association_threshold=37.17, consec_pairs_confirm=1, consec_misses_end=1))
    mgr.add_data({"groundtruth_paths": truths, "tracks": tracks})
    ss = {m.title: m.value for m in mgr.generate_metrics()[gen.generator_name].values()
          if not isinstance(m.value, list)}
    r = siap_row
    for ours, theirs in [("completeness", "SIAP Completeness"), ("ambiguity", "SIAP Ambiguity"),
                         ("spuriousness", "SIAP Spuriousness"),
                         ("position_accuracy_m", "SIAP Position Accuracy"),
                         ("velocity_accuracy_mps", "SIAP Velocity Accuracy"),
                         ("id_completeness", "SIAP ID Completeness"),
                         ("id_correctness", "SIAP ID Correctness"),
                         ("id_ambiguity", "SIAP ID Ambiguity")]:
        # (1e-6: our truth goes through WGS-84 and back, millimetres)
        assert r[ours] == pytest.approx(ss[theirs], rel=1e-6), ours
    # R: the same number of changes (Stone Soup: sum NU_j - 1), over its own TT
    tt_ss = sum(gen.total_time_tracked(mgr, t) for t in truths)
    assert ss["SIAP Rate of Track Number Change"] * tt_ss == pytest.approx(
        r["track_number_changes"])
    # Stone Soup counts intervals between timestamps: one period less per association run
    # (4 tracked truths, each run of one track; every change starts another run)
    assert tt_ss == r["tracked_time_s"] - (4 + r["track_number_changes"]) * PERIOD_S
    # LS: Stone Soup's durations are ours minus one epoch per truth (tracked or not)
    tl_ss = sum(gen.longest_track_time_on_truth(mgr, t) for t in truths)
    t_ss = sum(gen.truth_lifetime(t) for t in truths)
    assert tl_ss == r["longest_segment_s"] - 4 * PERIOD_S
    assert t_ss == r["truth_time_s"] - 5 * PERIOD_S
    assert ss["SIAP Longest Track Segment"] == pytest.approx(tl_ss / t_ss)


def test_siap_on_the_end_to_end_warehouse(e2e):
    siap = pl.from_arrow(read_table(e2e.warehouse, "siap_by_sector"))
    assert siap.height > 0 and siap["time_ns"].n_unique() == 2  # two hourly work units
    tot = siap.select(pl.col("truth_epochs", "tracked_truth_epochs", "associated_track_epochs",
                             "track_epochs", "spurious_track_epochs", "id_truth_epochs",
                             "id_correct_epochs", "sum_position_error_m").sum()).row(
        0, named=True)
    assert tot["tracked_truth_epochs"] / tot["truth_epochs"] > 0.95
    assert tot["spurious_track_epochs"] / tot["track_epochs"] < 0.05
    assert 1.0 <= tot["associated_track_epochs"] / tot["tracked_truth_epochs"] < 1.05
    assert tot["id_correct_epochs"] / tot["id_truth_epochs"] > 0.95
    # PA against the fused errors of track_errors (nearest-truth reference): same scale
    err = pl.from_arrow(read_table(e2e.warehouse, "track_errors")).filter(
        pl.col("source") == "fused")
    pa = tot["sum_position_error_m"] / tot["associated_track_epochs"]
    assert pa == pytest.approx(err["error_m"].mean(), rel=0.15)


def test_error_sums_add_in_row_order_per_sector_outside_sectors_too():
    """The per-sector error sums are the row-order sums, to the last digit (a polars
    group_by's float sum followed its threads: siap_by_sector differed in the last digits
    between two runs of one 1,000-ship slice)."""
    from pipeline.maritime.siap import _error_sums

    rng = np.random.default_rng(3)
    n = 200_000
    sector = [("a", "b", "c", None)[k] for k in rng.integers(0, 4, n)]
    a = pl.DataFrame({"sector": pl.Series(sector, dtype=pl.String),
                      "dist_m": rng.exponential(50.0, n), "vel_err": rng.exponential(1.0, n)})
    a = a.with_columns(pl.when(pl.int_range(n) % 97 == 0).then(None)
                       .otherwise(pl.col("vel_err")).alias("vel_err"))
    got = {r["sector"]: r for r in _error_sums(a).iter_rows(named=True)}
    assert set(got) == {"a", "b", "c", None}
    for s, rows in a.group_by("sector"):
        expect_pos = expect_vel = 0.0
        for d, v in zip(rows["dist_m"].to_list(), rows["vel_err"].to_list(), strict=True):
            expect_pos += d
            expect_vel += v or 0.0
        assert got[s[0]]["associated_track_epochs"] == rows.height
        assert got[s[0]]["sum_position_error_m"] == expect_pos
        assert got[s[0]]["sum_velocity_error_mps"] == expect_vel
