"""One frame for every channel (airfield paper eq. 3–4) and the airfield's areas.

Each sensor measures in its own frame: the SMR range/azimuth from its antenna, MLAT and
VASN x/y (east/north) from their reference point. Eq. 3 maps a sensor's coordinates to
the common geodetic frame (φ, λ) with a known matrix C_P^i; we apply the exact map
(sensor ENU -> WGS-84 -> ENU at the airfield reference point, through ``pymap3d``), and
eq. 4's C_PW^i for velocities is the rotation between the sensor's north and the
reference point's north (meridian convergence). Every row gets ``lat_deg``/``lon_deg``
(the geodetic frame of eq. 3) and ``xc_m``/``yc_m`` (east/north, m, on the tangent
plane at the reference point — the frame the filter works in: at airfield scale a
fixed linear image of (φ, λ), so a metric state costs nothing and keeps units in m).

The white part of each report's error (its quantisation on the wire) is given as a
covariance ``r_xx_m2, r_yy_m2, r_xy_m2`` in the common frame: CAT010 positions carry a
1 m LSB (σ² = 1/12 m² per axis; for the SMR along the range, and (ρ · LSB_θ)²/12
across it); VASN JSON carries mm.
"""

from __future__ import annotations

import math

import numpy as np
import polars as pl
import shapely

from pipeline.airfield.config import AirfieldConfig, AirfieldSector
from pipeline.decode import asterix_encode as cat010
from pipeline.frames import enu_to_geodetic, geodetic_to_enu, polar_to_enu, site_rotation_rad

R_FLOOR_M2 = 1e-4
"""Smallest white variance we model (keeps S invertible for mm-resolution channels)."""


def config_sensor_id(obs: pl.DataFrame, cfg: AirfieldConfig) -> pl.Series:
    """The config ``sensor_id`` of each row, null for sensors not in the config.

    A row belongs to a sensor when its ``sensor_id`` is the config id, or its
    ``sac``/``sic`` are the sensor's (the decoder's 'SAC/SIC' fallback id)."""
    ids = {s.sensor_id: s.sensor_id for s in cfg.sensors}
    ids.update({s.sac_sic: s.sensor_id for s in cfg.sensors if s.kind != "vasn"})
    by_sac = pl.concat_str(
        [pl.col("sac").cast(pl.String), pl.col("sic").cast(pl.String)], separator="/"
    )
    named = pl.coalesce(
        pl.col("sensor_id").replace_strict(ids, default=None),
        by_sac.replace_strict(ids, default=None),
    )
    return obs.select(named.alias("sensor_id"))["sensor_id"]


def sensor_rows(obs: pl.DataFrame, cfg: AirfieldConfig) -> pl.DataFrame:
    """The rows of the config's sensors, named by config ``sensor_id`` and kind."""
    kinds = {s.sensor_id: s.kind for s in cfg.sensors}
    return (
        obs.with_columns(config_sensor_id(obs, cfg))
        .filter(pl.col("sensor_id").is_not_null())
        .with_columns(pl.col("sensor_id").replace_strict(kinds).alias("sensor_kind"))
    )


def _cols(df: pl.DataFrame, name: str) -> np.ndarray:
    """Column as float64 with nan for nulls (all-nan when the frame lacks it)."""
    if name not in df.columns:
        return np.full(df.height, np.nan)
    return df[name].cast(pl.Float64).fill_null(np.nan).to_numpy()


def to_common_frame(obs: pl.DataFrame, cfg: AirfieldConfig) -> pl.DataFrame:
    """Add ``xc_m, yc_m`` (common frame), ``lat_deg, lon_deg``, ``vxc_mps, vyc_mps`` and
    the white covariance ``r_xx_m2, r_yy_m2, r_xy_m2`` to rows of config sensors
    (output of :func:`sensor_rows`). Rows without a usable position are dropped."""
    parts = []
    for s in cfg.sensors:  # one vectorised pass per sensor (three)
        d = obs.filter(pl.col("sensor_id") == s.sensor_id)
        if d.height == 0:
            continue
        lat, lon = _cols(d, "lat_deg"), _cols(d, "lon_deg")
        has_ll = np.isfinite(lat) & np.isfinite(lon)
        rho, theta = _cols(d, "range_m"), _cols(d, "azimuth_rad")
        xs, ys = _cols(d, "x_m"), _cols(d, "y_m")
        polar = ~has_ll & np.isfinite(rho) & np.isfinite(theta)
        px, py = polar_to_enu(rho, theta)
        xs = np.where(polar, px, xs)
        ys = np.where(polar, py, ys)
        la2, lo2 = enu_to_geodetic(np.nan_to_num(xs), np.nan_to_num(ys), s.lat_deg, s.lon_deg)
        lat = np.where(has_ll, lat, la2)
        lon = np.where(has_ll, lon, lo2)
        ok = has_ll | np.isfinite(xs) & np.isfinite(ys)
        xc, yc = geodetic_to_enu(lat, lon, cfg.reference_lat_deg, cfg.reference_lon_deg)
        rot = site_rotation_rad(s.lat_deg, s.lon_deg, cfg.reference_lat_deg, cfg.reference_lon_deg)
        c, sn = math.cos(rot), math.sin(rot)
        vx, vy = _cols(d, "vx_mps"), _cols(d, "vy_mps")
        rxx, ryy, rxy = white_covariance(s.kind, rho, theta, polar, rot)
        parts.append(
            d.with_columns(
                pl.Series("lat_deg", lat),
                pl.Series("lon_deg", lon),
                pl.Series("xc_m", xc),
                pl.Series("yc_m", yc),
                pl.Series("vxc_mps", c * vx + sn * vy).fill_nan(None),
                pl.Series("vyc_mps", -sn * vx + c * vy).fill_nan(None),
                pl.Series("r_xx_m2", rxx),
                pl.Series("r_yy_m2", ryy),
                pl.Series("r_xy_m2", rxy),
            ).filter(pl.Series(ok))
        )
    if not parts:
        return obs.clear().with_columns(
            *(
                pl.lit(None, pl.Float64).alias(c)
                for c in ("xc_m", "yc_m", "vxc_mps", "vyc_mps", "r_xx_m2", "r_yy_m2", "r_xy_m2")
            )
        )
    return pl.concat(parts, how="vertical_relaxed")


def white_covariance(
    kind: str, rho: np.ndarray, theta: np.ndarray, polar: np.ndarray, rot_rad: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quantisation covariance of each report in the common frame, m² (see module doc).

    ``rot_rad``: rotation of the sensor's north in the common frame."""
    n = rho.size
    if kind == "vasn":
        v = np.full(n, R_FLOOR_M2)
        return v, v.copy(), np.zeros(n)
    if kind == "smr":
        vr = np.full(n, cat010.RHO_LSB_M**2 / 12.0)
        vt = (np.nan_to_num(rho) * cat010.THETA_LSB_RAD) ** 2 / 12.0
        az = np.nan_to_num(theta) + rot_rad
        s, c = np.sin(az), np.cos(az)
        rxx = s * s * vr + c * c * vt
        ryy = c * c * vr + s * s * vt
        rxy = s * c * (vr - vt)
        cart = np.full(n, cat010.XY_LSB_M**2 / 12.0)
        return (
            np.where(polar, rxx, cart) + R_FLOOR_M2,
            np.where(polar, ryy, cart) + R_FLOOR_M2,
            np.where(polar, rxy, 0.0),
        )
    v = np.full(n, cat010.XY_LSB_M**2 / 12.0 + R_FLOOR_M2)
    return v, v.copy(), np.zeros(n)


def sector_polygons(
    sectors: tuple[AirfieldSector, ...], cfg: AirfieldConfig
) -> list[shapely.Polygon]:
    """Each sector polygon in the common frame (m)."""
    polys = []
    for s in sectors:
        lat, lon = np.array(s.polygon_lat_lon_deg, float).T
        e, n = geodetic_to_enu(lat, lon, cfg.reference_lat_deg, cfg.reference_lon_deg)
        polys.append(shapely.Polygon(np.column_stack([e, n])))
    return polys


def assign_areas(
    x_m: np.ndarray, y_m: np.ndarray, cfg: AirfieldConfig
) -> tuple[np.ndarray, np.ndarray]:
    """(sector name, area class) of each point: the first configured polygon containing
    it; None outside every polygon. Object arrays."""
    idx = np.full(np.size(x_m), -1)
    for k, poly in enumerate(sector_polygons(cfg.sectors, cfg)):
        idx[(idx < 0) & shapely.contains_xy(poly, x_m, y_m)] = k
    names = np.array([s.name for s in cfg.sectors] + [None], dtype=object)
    areas = np.array([s.area for s in cfg.sectors] + [None], dtype=object)
    return names[idx], areas[idx]
