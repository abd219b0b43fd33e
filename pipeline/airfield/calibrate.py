"""``surveil calibrate``: fit each channel's coloured-error model from the archive
(airfield paper eq. 2, 7, 8) and turn stored fits back into filter models.

Errors are report minus reference at the same epoch: the reference is the truth channel
(simulation) or, in real use, reference vehicles with DGNSS logged on that channel. A
report is matched to the reference target nearest to it at most epochs of its sensor
track (within ``association_gate_m``); errors beyond the gate are dropped (mismatches).
Each sensor's position errors (and the VASN's velocity errors) are fitted with
:func:`pipeline.filters.ar_errors.select_order`, per sensor track as independent
segments, with the wire quantisation as the known white noise.

Table ``sensor_error_models`` is long: one row per coefficient of one fit,
(sensor_id, quantity, term B|Gamma, lag, row, col) with value, standard error and 95%
interval, plus the fit window, order, rows used and BIC by order. The filter uses, per
sensor and quantity, the fit with the latest ``fit_end_ns`` not after the batch
window's end; else the config's nominal model.
"""

from __future__ import annotations

import numpy as np
import polars as pl

from pipeline.airfield.associate import sensor_tracks
from pipeline.airfield.config import AirfieldConfig
from pipeline.airfield.fusion import ChannelModels, config_models
from pipeline.airfield.score import reference_frame
from pipeline.filters.ar_errors import VarFit, VarModel, select_order
from pipeline.units import NS

MAX_ORDER = 4


def reference_errors(obs: pl.DataFrame, truth: pl.DataFrame, cfg: AirfieldConfig) -> pl.DataFrame:
    """Report rows (common frame) with ``ex_m, ey_m`` (and ``evx_mps, evy_mps``) = report
    minus its reference target at the same epoch, plus ``node`` (sensor track)."""
    step = round(cfg.filter.epoch_s * NS)
    ep = ((pl.col("time_ns") + step // 2) // step).alias("epoch")
    timeout = round(cfg.filter.track_timeout_s / cfg.filter.epoch_s)
    o = sensor_tracks(obs.with_columns(ep), timeout)
    ref = (
        reference_frame(truth, cfg)
        .join(
            truth.select(
                "time_ns",
                "target_id",
                pl.col("vx_mps").alias("tvx_mps"),
                pl.col("vy_mps").alias("tvy_mps"),
            ),
            on=["time_ns", "target_id"],
        )
        .with_columns(ep)
        .drop("time_ns")
    )
    gate2 = cfg.filter.association_gate_m**2
    j = (
        o.select("epoch", "node", "xc_m", "yc_m")
        .join(ref, on="epoch")
        .with_columns(
            ((pl.col("xc_m") - pl.col("tx_m")) ** 2 + (pl.col("yc_m") - pl.col("ty_m")) ** 2).alias(
                "d2"
            )
        )
        .filter(pl.col("d2") < gate2)
    )
    nearest = j.sort("d2").group_by(["epoch", "node"]).first()
    target = nearest.group_by("node").agg(pl.col("target_id").mode().sort().first())
    out = o.join(target, on="node").join(ref, on=["epoch", "target_id"])
    out = out.with_columns(
        (pl.col("xc_m") - pl.col("tx_m")).alias("ex_m"),
        (pl.col("yc_m") - pl.col("ty_m")).alias("ey_m"),
        (pl.col("vxc_mps") - pl.col("tvx_mps")).alias("evx_mps"),
        (pl.col("vyc_mps") - pl.col("tvy_mps")).alias("evy_mps"),
        (pl.col("tvx_mps") ** 2 + pl.col("tvy_mps") ** 2).sqrt().alias("ref_speed_mps"),
    ).filter(pl.col("ex_m") ** 2 + pl.col("ey_m") ** 2 < gate2)
    return out.sort(["node", "epoch"])


def _fit_rows(
    fit: VarFit, sensor_id: str, kind: str, quantity: str, start_ns: int, end_ns: int
) -> pl.DataFrame:
    m = fit.model
    p = m.order
    lo, hi = fit.b_ci()
    rows = []
    for lag in range(p):
        for r in range(2):
            for c in range(2):
                rows.append(
                    (
                        "B",
                        lag + 1,
                        r,
                        c,
                        m.B[lag, r, c],
                        fit.se_b[lag, r, c],
                        lo[lag, r, c],
                        hi[lag, r, c],
                    )
                )
    for r in range(2):
        for c in range(r + 1):
            rows.append(
                (
                    "Gamma",
                    0,
                    r,
                    c,
                    m.Gamma[r, c],
                    None,
                    fit.gamma_ci[0, r, c],
                    fit.gamma_ci[1, r, c],
                )
            )
    df = pl.DataFrame(
        rows,
        schema=["term", "lag", "row", "col", "value", "std_error", "ci_low", "ci_high"],
        orient="row",
    )
    bic = ",".join(f"{k}:{v:.1f}" for k, v in sorted(fit.bic_by_order.items()))
    return df.with_columns(
        pl.lit(start_ns, pl.Int64).alias("fit_start_ns"),
        pl.lit(end_ns, pl.Int64).alias("fit_end_ns"),
        pl.lit(sensor_id).alias("sensor_id"),
        pl.lit(kind).alias("sensor_kind"),
        pl.lit(quantity).alias("quantity"),
        pl.lit(p, pl.Int16).alias("order"),
        pl.lit(fit.n_rows, pl.Int64).alias("n_rows"),
        pl.lit(fit.bic).alias("bic"),
        pl.lit(bic).alias("bic_by_order"),
        pl.lit(float(np.trace(fit.white_cov)) / 2.0).alias("white_var"),
    )


def calibrate(
    obs: pl.DataFrame,
    truth: pl.DataFrame,
    cfg: AirfieldConfig,
    *,
    start_ns: int,
    end_ns: int,
    max_order: int = MAX_ORDER,
    min_speed_mps: float = 0.0,
) -> tuple[pl.DataFrame, dict[str, VarFit]]:
    """Fit every configured sensor's models over [start_ns, end_ns). Returns the
    ``sensor_error_models`` rows and the fits by ``<sensor_id>/<quantity>``. Sensors
    without enough error samples are skipped (absent from the result)."""
    obs = obs.filter((pl.col("time_ns") >= start_ns) & (pl.col("time_ns") < end_ns))
    err = reference_errors(obs, truth, cfg).filter(pl.col("ref_speed_mps") >= min_speed_mps)
    frames, fits = [], {}
    for s in cfg.sensors:  # three sensors
        e = err.filter(pl.col("sensor_id") == s.sensor_id)
        if e.height == 0:
            continue
        seg, step = e["node"].to_numpy(), e["epoch"].to_numpy()
        white = (
            e.select("r_xx_m2", "r_xy_m2", pl.col("r_xy_m2").alias("r_yx"), "r_yy_m2")
            .to_numpy()
            .reshape(-1, 2, 2)
        )
        todo = [("position", e.select("ex_m", "ey_m").to_numpy(), white, max_order)]
        if s.kind == "vasn":
            todo.append(("velocity", e.select("evx_mps", "evy_mps").to_numpy(), None, max_order))
        for quantity, series, wc, mo in todo:
            try:
                fit = select_order(series, seg, step, max_order=mo, white_cov=wc)
            except ValueError:
                continue
            fits[f"{s.sensor_id}/{quantity}"] = fit
            frames.append(_fit_rows(fit, s.sensor_id, s.kind, quantity, start_ns, end_ns))
    rows = pl.concat(frames) if frames else pl.DataFrame()
    return rows, fits


def model_from_rows(rows: pl.DataFrame) -> VarModel:
    """Rebuild a VarModel from the rows of ONE fit (one sensor, quantity, window)."""
    p = int(rows["order"][0])
    B = np.zeros((p, 2, 2))
    G = np.zeros((2, 2))
    for term, lag, r, c, v in rows.select("term", "lag", "row", "col", "value").iter_rows():
        if term == "B":
            B[lag - 1, r, c] = v
        else:
            G[r, c] = v
    return VarModel(B, G)


def stored_models(rows: pl.DataFrame, cfg: AirfieldConfig, end_ns: int) -> ChannelModels:
    """Per sensor and quantity the stored fit with the latest fit_end_ns <= end_ns,
    falling back to the config's nominal model."""
    base = config_models(cfg)
    pos, src = dict(base.position), dict(base.source)
    vel = base.velocity
    if rows.height == 0:
        return base
    usable = rows.filter(pl.col("fit_end_ns") <= end_ns)
    latest = usable.group_by("sensor_id", "quantity").agg(pl.col("fit_end_ns").max())
    for sid, quantity, fit_end in latest.iter_rows():
        if sid not in pos:
            continue
        sel = usable.filter(
            (pl.col("sensor_id") == sid)
            & (pl.col("quantity") == quantity)
            & (pl.col("fit_end_ns") == fit_end)
        )
        sel = sel.filter(pl.col("fit_start_ns") == sel["fit_start_ns"].max())
        model = model_from_rows(sel)
        window = f"fit [{sel['fit_start_ns'][0]}, {fit_end})"
        if quantity == "position":
            pos[sid] = model
            src[sid] = window
        elif quantity == "velocity" and cfg.sensor(sid).kind == "vasn" and model.order == 1:
            vel = model
            src[f"{sid}/velocity"] = window
    return ChannelModels(pos, vel, src)
