"""Where an airfield sensor stands, from its data: the positions ``surveil config init``
writes when the recordings do not carry them.

An SMR reports range/azimuth from its antenna and an MLAT x/y from its reference point;
neither position is in a CAT010 record. A source that reports WGS-84 positions of the
same targets (ADS-B CAT021, SDPS CAT062 I105, CAT010 I010/041), or a sensor already
located (the MLAT at the reference point the user gives), fixes them: the same targets
seen by two sensors at the same second differ, in one local tangent plane, by the
offset between the two frames' origins. Over all the pairs of reports of the same
second (true pairs and false ones), the true pairs pile up at that offset and the false
ones spread out: the offset is the mode of the pairs' differences (a 2-D histogram,
:data:`COARSE_BIN_M` bins), refined by the median of the pairs within
:data:`REFINE_M` of it. It is accepted when at least :data:`MIN_MATCHED_SHARE` of the
located sensor's reports then have a partner within :data:`REFINE_M` (else the sensor
stays unlocated and the config says so). Rotation (north alignment) is not estimated:
sensors are taken as aligned to true north.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import polars as pl

from pipeline.frames import geodetic_to_enu, polar_to_enu
from pipeline.units import NS

COARSE_BIN_M = 25.0
REFINE_M = 50.0
MAX_OFFSET_M = 20_000.0
MAX_PAIRS = 3_000_000
MIN_MATCHED_SHARE = 0.3


@dataclass(frozen=True)
class Offset:
    """The origin of frame B in frame A, east/north, m; with its support."""

    east_m: float
    north_m: float
    pairs: int  # pairs within REFINE_M of the offset
    matched_share: float  # share of B's reports with a partner there


def local_xy(obs: pl.DataFrame, lat0: float | None = None, lon0: float | None = None
             ) -> pl.DataFrame:
    """``second, x, y`` of a source's reports in its own frame: range/azimuth from the
    sensor, else x/y, else (with ``lat0``/``lon0``) WGS-84 mapped to the tangent plane
    there. ``second``: the report time rounded to the second."""
    t = obs["time_ns"].to_numpy()
    x = np.full(obs.height, np.nan)
    y = np.full(obs.height, np.nan)
    if "lat_deg" in obs.columns and lat0 is not None:
        lat = obs["lat_deg"].cast(pl.Float64).fill_null(np.nan).to_numpy()
        lon = obs["lon_deg"].cast(pl.Float64).fill_null(np.nan).to_numpy()
        ok = np.isfinite(lat) & np.isfinite(lon)
        if ok.any():
            e, n = geodetic_to_enu(lat[ok], lon[ok], lat0, lon0)
            x[ok], y[ok] = e, n
    for a, b in (("x_m", "y_m"),):
        if a in obs.columns:
            xs = obs[a].cast(pl.Float64).fill_null(np.nan).to_numpy()
            ys = obs[b].cast(pl.Float64).fill_null(np.nan).to_numpy()
            use = np.isnan(x) & np.isfinite(xs) & np.isfinite(ys)
            x[use], y[use] = xs[use], ys[use]
    if "range_m" in obs.columns:
        rho = obs["range_m"].cast(pl.Float64).fill_null(np.nan).to_numpy()
        az = obs["azimuth_rad"].cast(pl.Float64).fill_null(np.nan).to_numpy()
        use = np.isnan(x) & np.isfinite(rho) & np.isfinite(az)
        px, py = polar_to_enu(rho[use], az[use])
        x[use], y[use] = px, py
    ok = np.isfinite(x) & np.isfinite(y)
    return pl.DataFrame({"second": (t[ok] + NS // 2) // NS, "x": x[ok], "y": y[ok]})


def frame_offset(a: pl.DataFrame, b: pl.DataFrame, *, max_offset_m: float = MAX_OFFSET_M
                 ) -> Offset | None:
    """The origin of B's frame in A's frame from reports of the same targets at the same
    seconds (``second, x, y`` frames, :func:`local_xy`); None when the data do not show
    one (module docstring)."""
    if a.height == 0 or b.height == 0:
        return None
    seconds = np.intersect1d(a["second"].unique().to_numpy(), b["second"].unique().to_numpy())
    if seconds.size == 0:
        return None
    a = a.filter(pl.col("second").is_in(seconds))
    b = b.filter(pl.col("second").is_in(seconds))
    per = (a.group_by("second").len().join(b.group_by("second").len(), on="second")
           .with_columns(pairs=pl.col("len") * pl.col("len_right")))
    total = int(per["pairs"].sum())
    if total > MAX_PAIRS:  # every k-th second (evenly): the mode needs no more
        keep = per.sort("second").gather_every(int(np.ceil(total / MAX_PAIRS)))["second"]
        a = a.filter(pl.col("second").is_in(keep))
        b = b.filter(pl.col("second").is_in(keep))
    pairs = a.join(b, on="second", suffix="_b")
    dx = (pairs["x"] - pairs["x_b"]).to_numpy()
    dy = (pairs["y"] - pairs["y_b"]).to_numpy()
    inside = (np.abs(dx) < max_offset_m) & (np.abs(dy) < max_offset_m)
    dx, dy = dx[inside], dy[inside]
    if dx.size == 0:
        return None
    n_bins = int(2 * max_offset_m / COARSE_BIN_M)
    ix = ((dx + max_offset_m) // COARSE_BIN_M).astype(np.int64)
    iy = ((dy + max_offset_m) // COARSE_BIN_M).astype(np.int64)
    counts = np.bincount(ix * n_bins + iy, minlength=n_bins * n_bins)
    peak = int(np.argmax(counts))
    cx = (peak // n_bins + 0.5) * COARSE_BIN_M - max_offset_m
    cy = (peak % n_bins + 0.5) * COARSE_BIN_M - max_offset_m
    near = np.hypot(dx - cx, dy - cy) <= REFINE_M
    ex, ey = float(np.median(dx[near])), float(np.median(dy[near]))
    near = np.hypot(dx - ex, dy - ey) <= REFINE_M
    ex, ey = float(np.median(dx[near])), float(np.median(dy[near]))
    # B's reports with a partner at the offset
    sel = pairs.filter(pl.Series(inside)).with_columns(
        near=pl.Series(np.hypot(dx - ex, dy - ey) <= REFINE_M))
    matched = sel.filter("near").select("second", "x_b", "y_b").unique().height
    share = matched / b.height
    if share < MIN_MATCHED_SHARE:
        return None
    return Offset(ex, ey, int(near.sum()), share)


def ais_at_seconds(ais: pl.DataFrame, seconds: np.ndarray, lat0: float, lon0: float,
                   max_gap_s: float = 30.0) -> pl.DataFrame:
    """``second, x, y`` of every transponder at each of ``seconds`` (int s since the
    epoch), linearly interpolated between its two reports around it when they are at
    most ``max_gap_s`` apart, on the tangent plane at (lat0, lon0): the partner of a
    radar report for :func:`frame_offset` (AIS and radar are not sampled together).
    Loops over the transponders (thousands at most), each vectorised over the seconds."""
    seconds = np.unique(np.asarray(seconds, np.int64))
    out_s, out_x, out_y = [], [], []
    e, n = geodetic_to_enu(ais["lat_deg"].to_numpy(), ais["lon_deg"].to_numpy(), lat0, lon0)
    frame = ais.select("mmsi", "time_ns").with_columns(x=pl.Series(np.atleast_1d(e)),
                                                      y=pl.Series(np.atleast_1d(n)))
    for _, part in frame.sort("mmsi", "time_ns").group_by("mmsi", maintain_order=True):
        t = part["time_ns"].to_numpy() / NS
        if t.size < 2:
            continue
        s = seconds[(seconds >= t[0]) & (seconds <= t[-1])]
        if s.size == 0:
            continue
        i = np.clip(np.searchsorted(t, s), 1, t.size - 1)
        ok = (t[i] - t[i - 1]) <= max_gap_s
        s = s[ok]
        out_s.append(s)
        out_x.append(np.interp(s, t, part["x"].to_numpy()))
        out_y.append(np.interp(s, t, part["y"].to_numpy()))
    if not out_s:
        return pl.DataFrame({"second": [], "x": [], "y": []},
                            schema={"second": pl.Int64, "x": pl.Float64, "y": pl.Float64})
    return pl.DataFrame({"second": np.concatenate(out_s), "x": np.concatenate(out_x),
                         "y": np.concatenate(out_y)})
