"""Stone Soup's GNN tracker on the radar track reports of a warehouse window (used by
bench/batch.py; stonesoup is a dev dependency).

Every radar report read is one detection: its position in the regional frame (our
``align_reports``), extrapolated to its scan end with its own speed and course (the
multi-radar paper's eq. 7, our synchronisation step 1), timestamped at the scan end, so
that the detections of one site's scan share a timestamp and form one detection set.
Each site has one measurement model (so that Stone Soup's per-model caches work, as in the
published 7.4 ms per target-scan anchor): isotropic, sigma = the larger axis of the
site's polar covariance at its median range in the window, max(sigma_r, r sigma_az).
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np
import polars as pl
from scipy.stats import chi2
from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
from stonesoup.deleter.time import UpdateTimeDeleter
from stonesoup.hypothesiser.distance import DistanceHypothesiser
from stonesoup.initiator.simple import MultiMeasurementInitiator
from stonesoup.measures import Mahalanobis
from stonesoup.models.measurement.linear import LinearGaussian
from stonesoup.models.transition.linear import (
    CombinedLinearGaussianTransitionModel,
    ConstantVelocity,
)
from stonesoup.predictor.kalman import KalmanPredictor
from stonesoup.tracker.simple import MultiTargetTracker
from stonesoup.types.array import CovarianceMatrix, StateVector
from stonesoup.types.detection import Detection
from stonesoup.types.state import GaussianState
from stonesoup.updater.kalman import KalmanUpdater

from pipeline.config import Config
from pipeline.maritime.align import align_reports
from pipeline.maritime.sync import extrapolate_position, scan_end_offset_s
from pipeline.warehouse.delta import read_table

PROCESS_NOISE = 0.05
"""Constant-velocity process noise q, m^2/s^3 per axis (ships: gentle manoeuvres)."""
GATE = float(np.sqrt(chi2.ppf(0.999, 2)))
"""Mahalanobis distance gate (not squared): chi2(0.999, 2 dof), as our association."""
TIMEOUT = dt.timedelta(seconds=30)
"""A track not updated for this long is deleted (our track timeout)."""
_EPOCH = dt.datetime(1970, 1, 1)


def detections(warehouse: Path, cfg: Config, start_ns: int, end_ns: int
               ) -> tuple[list[tuple[dt.datetime, set[Detection]]], int]:
    """Detection sets (scan-end time, detections) in time order, and their count."""
    radar = pl.from_arrow(read_table(warehouse, "radar_tracks", start_ns=start_ns, end_ns=end_ns))
    aligned, _ = align_reports(radar, cfg)
    dt1 = scan_end_offset_s(aligned["azimuth_rad"].to_numpy(),
                            aligned["scan_end_azimuth_rad"].to_numpy(),
                            aligned["scan_period_s"].to_numpy())
    x, y = extrapolate_position(aligned["x_enu_m"].to_numpy(), aligned["y_enu_m"].to_numpy(),
                                aligned["speed_mps"].to_numpy(), aligned["course_rad"].to_numpy(),
                                dt1)
    scan_end = aligned["time_ns"].to_numpy() + np.round(dt1 * 1e9).astype(np.int64)
    models = {}
    for site in cfg.radar_sites:
        rng = aligned.filter(pl.col("site_id") == site.site_id)["range_m"].median() or 1e4
        sigma = max(site.sigma_range_m, float(rng) * site.sigma_azimuth_rad)
        models[site.site_id] = LinearGaussian(ndim_state=4, mapping=(0, 2),
                                              noise_covar=CovarianceMatrix(np.eye(2) * sigma**2))
    frame = pl.DataFrame({"site": aligned["site_id"], "log": aligned["log_time_ns"],
                          "t": scan_end, "x": x, "y": y}).with_row_index("i")
    sets: list[tuple[dt.datetime, set[Detection]]] = []
    for (site, _log), g in frame.sort("log", "site", "i").group_by(["site", "log"],
                                                                  maintain_order=True):
        stamp = _EPOCH + dt.timedelta(microseconds=int(g["t"].max()) // 1000)
        model = models[site]
        sets.append((stamp, {Detection(StateVector([px, py]), timestamp=stamp,
                                       measurement_model=model)
                             for px, py in zip(g["x"].to_list(), g["y"].to_list(),
                                               strict=True)}))
    sets.sort(key=lambda s: s[0])
    return sets, frame.height


def run_tracker(sets: list[tuple[dt.datetime, set[Detection]]]) -> set:
    """Run the GNN tracker over the detection sets; returns every track it made."""
    transition = CombinedLinearGaussianTransitionModel(
        [ConstantVelocity(PROCESS_NOISE), ConstantVelocity(PROCESS_NOISE)])
    predictor = KalmanPredictor(transition)
    updater = KalmanUpdater(measurement_model=None)
    hypothesiser = DistanceHypothesiser(predictor, updater, Mahalanobis(), missed_distance=GATE)
    initiator = MultiMeasurementInitiator(
        prior_state=GaussianState(StateVector([0.0, 0.0, 0.0, 0.0]),
                                  CovarianceMatrix(np.diag([0.0, 100.0, 0.0, 100.0]))),
        deleter=UpdateTimeDeleter(TIMEOUT),
        data_associator=GNNWith2DAssignment(
            DistanceHypothesiser(predictor, updater, Mahalanobis(), missed_distance=GATE)),
        updater=updater,
        measurement_model=None,
        min_points=2,
    )
    tracker = MultiTargetTracker(
        initiator=initiator,
        deleter=UpdateTimeDeleter(TIMEOUT),
        detector=iter(sets),
        data_associator=GNNWith2DAssignment(hypothesiser),
        updater=updater,
    )
    every: set = set()
    for _, tracks in tracker:
        every |= tracks
    return every
