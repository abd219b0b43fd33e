"""Default error models scaled to the data, in the batch (issue 35: a new site cannot
know its sensors' AR coefficients, and its recordings hold no reference to calibrate
them against).

A sensor declared without ``position_ar`` starts from its kind's documented default
(``pipeline.airfield.config.DEFAULT_POSITION_AR``: AR(1), a few metres). A wrong scale
would make the NIS test (airfield paper eq. 21-23) flag a healthy channel (too small) or
blind it (too large). The scale is read from the channel's own innovations: with the
right model the normalised innovation squared of a 2-D report is chi-square with 2 dof,
median 2 ln 2; if the model's covariance is off by a factor k², the NIS is off by about
k² too. This is covariance matching (Mehra 1972, "Approaches to adaptive filtering",
IEEE TAC 17(5), sec. IV), made robust by the median: a fault that lasts less than half
of the unit (a jamming burst, a bias jump) does not move it.

Each default model's Gamma is multiplied by ``k = sqrt(median NIS / (2 ln 2))`` (its AR
coefficients, the correlation, are kept), over :data:`PASSES` passes of the filter with
exclusion off (an excluded channel's innovations would not be seen), all default
channels at once (their scales interact through the fused track); then the stage runs
once more with the configured integrity settings. A channel with fewer than
:data:`MIN_CHECKS` checks in the unit keeps its default unscaled. Configured and fitted
models (``surveil calibrate``) are never touched. The model's source says what was done:
``default smr AR(1) x1.83 (median NIS, 12,345 checks)``; every ``channel_health`` row
carries it (``error_model``).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import polars as pl

from pipeline.airfield.config import AirfieldConfig
from pipeline.airfield.fusion import ChannelModels, fuse_airfield
from pipeline.filters.ar_errors import VarModel

PASSES = 3
MIN_CHECKS = 50
MEDIAN_CHI2_2 = 2.0 * math.log(2.0)  # chi-square, 2 dof: F(x) = 1 - exp(-x / 2)
MAX_SCALE = 100.0  # one pass moves a scale by at most this factor (and its inverse)


def scaled_models(common: pl.DataFrame, cfg: AirfieldConfig, models: ChannelModels, *,
                  start_ns: int, end_ns: int) -> ChannelModels:
    """``models`` with every channel whose source is ``default`` scaled to the data of
    the unit (``common``: its reports in the common frame; module docstring)."""
    todo = [sid for sid, src in models.source.items() if src == "default"]
    if not todo or common.height == 0:
        return models
    kinds = {s.sensor_id: s.kind for s in cfg.sensors}
    probe = cfg.with_integrity(exclusion=False)
    position = dict(models.position)
    total = dict.fromkeys(todo, 1.0)
    checks = dict.fromkeys(todo, 0)
    for _ in range(PASSES):
        trial = replace(models, position=position)
        _, health = fuse_airfield(common, probe, trial, start_ns=start_ns, end_ns=end_ns)
        if health.height == 0:
            break
        nis = health.filter((pl.col("check") == "nis") & pl.col("nis").is_not_null())
        moved = False
        for sid in todo:
            xi = nis.filter(pl.col("channel") == sid)["nis"].to_numpy()
            checks[sid] = int(xi.size)
            if xi.size < MIN_CHECKS:
                continue
            k = math.sqrt(float(np.median(xi)) / MEDIAN_CHI2_2)
            k = min(max(k, 1.0 / MAX_SCALE), MAX_SCALE)
            if abs(k - 1.0) > 0.02:
                moved = True
            total[sid] *= k
            m = position[sid]
            position[sid] = VarModel(m.B, m.Gamma * k)
        if not moved:
            break
    source = dict(models.source)
    for sid in todo:
        if checks[sid] >= MIN_CHECKS:
            source[sid] = (f"default {kinds.get(sid, '?')} AR(1) x{total[sid]:.2f} "
                           f"(median NIS, {checks[sid]:,} checks)")
        else:
            source[sid] = (f"default {kinds.get(sid, '?')} AR(1), unscaled ({checks[sid]} "
                           f"checks < {MIN_CHECKS})")
    return ChannelModels(position, models.velocity, source)
