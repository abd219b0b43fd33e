"""Raw navigation tables -> one uniform time grid per vessel and continuous segment.

Each sample goes to the grid step whose interval (t_{k-1}, t_k] holds its time (steps
of ``step_s`` aligned to multiples of it since the Unix epoch); per step: the GNSS fix
(position, fix quality, velocity from SOG/COG), the true heading (HDT, THS, HDG with
variation; a magnetic heading without variation is not used), the log speed through
water, the mean accelerometer signal and the last amplifier output of the gyro. A vessel
silent on every sensor for longer than ``max_gap_s`` starts a new segment (the filter
restarts). All binning is polars group-bys; no Python per sample.

Fix validity of a step: GGA fix quality >= 1 when a GGA is present, else the RMC/GLL
status (A), else a position without either. ``gnss_msg`` marks steps with any GNSS
message (valid or not), to tell a no-fix outage from silence.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import polars as pl

from pipeline.units import NS


@dataclass(frozen=True)
class Segment:
    """One vessel's continuous stretch of data on the grid (arrays (T,), NaN = none)."""

    platform_id: str
    times_ns: np.ndarray  # int64 end of each step
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    fix_quality: np.ndarray  # float, NaN: no GGA at the step
    fix_valid: np.ndarray  # bool: a valid fix at the step
    gnss_msg: np.ndarray  # bool: any GNSS message at the step
    vel_east_mps: np.ndarray  # GNSS velocity of a valid fix
    vel_north_mps: np.ndarray
    heading_rad: np.ndarray  # gyro (true) heading
    log_speed_mps: np.ndarray
    accel_signal_rad: np.ndarray
    amplifier_rad: np.ndarray

    @property
    def n(self) -> int:
        return int(self.times_ns.size)


def _bin(df: pl.DataFrame, t0_ns: int, step_ns: int) -> pl.DataFrame:
    return df.with_columns(((pl.col("time_ns") - t0_ns + step_ns - 1) // step_ns).alias("k"))


def _last(col: str) -> pl.Expr:
    return pl.col(col).drop_nulls().last().alias(col)


def _gnss_steps(gnss: pl.DataFrame) -> pl.DataFrame:
    has_pos = pl.col("lat_deg").is_not_null() & pl.col("lon_deg").is_not_null()
    agg = gnss.group_by("k").agg(
        _last("lat_deg"), _last("lon_deg"), pl.col("fix_quality").max(),
        _last("fix_valid"), _last("sog_mps"), _last("cog_rad"),
        has_pos.any().alias("has_pos"),
    )
    valid = (
        pl.when(pl.col("fix_quality").is_not_null()).then(pl.col("fix_quality") >= 1)
        .when(pl.col("fix_valid").is_not_null()).then(pl.col("fix_valid"))
        .otherwise(pl.col("has_pos"))
    ) & pl.col("has_pos")
    return agg.with_columns(valid.alias("valid"))


def _heading_steps(heading: pl.DataFrame) -> pl.DataFrame:
    true_heading = heading.filter(
        pl.col("heading_rad").is_not_null() & ~pl.col("is_magnetic").fill_null(False))
    return true_heading.group_by("k").agg(_last("heading_rad"))


def segments(
    gnss: pl.DataFrame, heading: pl.DataFrame, speed_log: pl.DataFrame, gyro: pl.DataFrame,
    *, step_s: float, max_gap_s: float,
) -> list[Segment]:
    """Grid segments of every vessel in the four tables (canonical columns)."""
    step_ns = round(step_s * NS)
    frames = {"gnss": gnss, "heading": heading, "log": speed_log, "gyro": gyro}
    times = pl.concat([f.select("platform_id", "time_ns") for f in frames.values()
                       if f.height]) if any(f.height for f in frames.values()) else None
    if times is None:
        return []
    spans = (
        times.sort(["platform_id", "time_ns"])
        .with_columns((pl.col("time_ns").diff().over("platform_id") > round(max_gap_s * NS))
                      .fill_null(True).cum_sum().over("platform_id").alias("seg"))
        .group_by("platform_id", "seg", maintain_order=True)
        .agg(pl.col("time_ns").min().alias("t_lo"), pl.col("time_ns").max().alias("t_hi"))
    )
    out = []
    for pid, t_lo, t_hi in spans.select("platform_id", "t_lo", "t_hi").iter_rows():
        # one iteration per (vessel, segment): a handful
        t0 = (t_lo // step_ns) * step_ns - step_ns  # step 0 ends before the first sample
        sel = {name: _bin(f.filter((pl.col("platform_id") == pid)
                                   & pl.col("time_ns").is_between(t_lo, t_hi)), t0, step_ns)
               for name, f in frames.items()}
        out.append(_segment(pid, t0, step_ns, int((t_hi - t0 + step_ns - 1) // step_ns), sel))
    return out


def _segment(pid: str, t0: int, step_ns: int, last_k: int,
             sel: dict[str, pl.DataFrame]) -> Segment:
    grid = pl.DataFrame({"k": np.arange(1, last_k + 1, dtype=np.int64)})
    g = grid.join(_gnss_steps(sel["gnss"]), on="k", how="left")
    h = grid.join(_heading_steps(sel["heading"]), on="k", how="left")
    lg = grid.join(sel["log"].filter(pl.col("speed_water_mps").is_not_null())
                   .group_by("k").agg(_last("speed_water_mps")), on="k", how="left")
    gy = grid.join(sel["gyro"].group_by("k").agg(
        pl.col("accel_signal_rad").mean(), _last("amplifier_rad")), on="k", how="left")

    def arr(df: pl.DataFrame, col: str) -> np.ndarray:
        return df[col].cast(pl.Float64).fill_null(np.nan).to_numpy()

    valid = g["valid"].fill_null(False).to_numpy()
    sog, cog = arr(g, "sog_mps"), arr(g, "cog_rad")
    ve = np.where(valid, sog * np.sin(cog), np.nan)
    vn = np.where(valid, sog * np.cos(cog), np.nan)
    return Segment(
        platform_id=pid,
        times_ns=t0 + grid["k"].to_numpy() * step_ns,
        lat_deg=np.where(valid, arr(g, "lat_deg"), np.nan),
        lon_deg=np.where(valid, arr(g, "lon_deg"), np.nan),
        fix_quality=arr(g, "fix_quality"),
        fix_valid=valid,
        gnss_msg=g["has_pos"].is_not_null().to_numpy(),
        vel_east_mps=ve,
        vel_north_mps=vn,
        heading_rad=arr(h, "heading_rad"),
        log_speed_mps=arr(lg, "speed_water_mps"),
        accel_signal_rad=arr(gy, "accel_signal_rad"),
        amplifier_rad=arr(gy, "amplifier_rad"),
    )


def emergency_steps(seg: Segment, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
    """``(emergency, last_fix_index)``: no valid fix within ``timeout_s`` (or none yet),
    and the index of the latest valid fix at or before each step (-1: none yet)."""
    idx = np.where(seg.fix_valid, np.arange(seg.n), -1)
    last = np.maximum.accumulate(idx) if seg.n else idx
    since_s = (seg.times_ns - seg.times_ns[np.maximum(last, 0)]) / NS
    return (last < 0) | (since_s > timeout_s), last
