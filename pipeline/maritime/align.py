"""Regional frame alignment of radar track reports.

Every site's reports go to one regional frame: local ENU (x east, y north, m) on the
tangent plane at the region origin (``cfg.region``). Per site (multi-radar paper,
"partial track processing"; two-radar identification paper section 2, "bring the
measurements to one coordinate system"):

1. registration: the site's ``north_alignment_rad`` is added to the reported azimuth
   (and to ``scan_end_azimuth_rad``, read from the same encoder) and to the course;
2. site frame: ``x_site_m, y_site_m = r sin(az), r cos(az)`` from the aligned polar pair;
3. regional frame: ``frames.site_to_region`` (exact, through WGS-84), and the course is
   rotated by the meridian convergence ``frames.site_rotation_rad`` (rho, ~1e-3 rad);
4. position covariance: ``frames.polar_covariance`` (the covariance form of the
   multi-radar paper's eq. 3) with the report's own sigma_range_m / sigma_azimuth_rad,
   rotated into the regional frame. A polar covariance rotated by rho is the polar
   covariance at azimuth ``az + rho`` (J depends on the azimuth only), which is how it
   is computed: R(rho) P R(rho)^T == polar_covariance(r, az + rho, sr, sa).

Before these steps, when ``[radar_bias] apply = true``, each site's estimated
registration bias (``[radar_bias.correction]``: range, azimuth, time offset; see
pipeline/maritime/bias.py and ``surveil calibrate-radars``) is removed from its raw reports.
"""

from __future__ import annotations

import numpy as np
import polars as pl

from pipeline import frames
from pipeline.config import Config, RadarSite
from pipeline.maritime.bias import correct_registration
from pipeline.maritime.config import radar_bias_config

UNKNOWN_SITE = "unknown_site"


def align_reports(
    radar_tracks: pl.DataFrame, cfg: Config, *, correct_bias: bool = True
) -> tuple[pl.DataFrame, pl.DataFrame]:
    """Align radar track reports to the regional frame (first removing the configured
    registration biases when ``[radar_bias] apply`` and ``correct_bias``).

    Consumes (radar_tracks): site_id, range_m, azimuth_rad, course_rad, sigma_range_m,
    sigma_azimuth_rad, scan_end_azimuth_rad (all other columns pass through).

    Returns ``(aligned, unknown)``:

    - ``aligned``: the reports of configured sites with azimuth_rad, scan_end_azimuth_rad
      (site frame, registration-corrected, rad in [0, 2pi)), x_site_m, y_site_m (site
      ENU, m) and course_rad (regional frame, rad in [0, 2pi)) replaced, plus x_enu_m,
      y_enu_m (regional ENU, m) and P_xx, P_yy, P_xy (regional position covariance, m^2);
    - ``unknown``: the reports of sites missing from the config, unchanged, plus
      ``reason_code`` ("unknown_site") and ``reason``: for the rejects table, so that
      nothing is dropped silently.
    """
    bias = radar_bias_config(cfg)
    if correct_bias and bias.apply:
        radar_tracks = correct_registration(radar_tracks, bias.correction)
    known = [s.site_id for s in cfg.radar_sites]
    is_known = pl.col("site_id").is_in(known)
    unknown = radar_tracks.filter(~is_known).with_columns(
        pl.lit(UNKNOWN_SITE).alias("reason_code"),
        (pl.lit("radar site not in config: ") + pl.col("site_id")).alias("reason"),
    )
    parts = [
        _align_site(part, cfg.site(site_id), cfg)
        for (site_id,), part in radar_tracks.filter(is_known)
        .partition_by("site_id", as_dict=True, maintain_order=True)
        .items()
    ]
    if not parts:  # no report of a configured site (or no site: an AIS-only site)
        nowhere = RadarSite("", cfg.region.origin_lat_deg, cfg.region.origin_lon_deg, 0.0, 0.0,
                            1.0, 1.0)
        return _align_site(radar_tracks.clear(), nowhere, cfg), unknown
    return pl.concat(parts), unknown


def _align_site(reports: pl.DataFrame, site: RadarSite, cfg: Config) -> pl.DataFrame:
    """Align the reports of one site (see the module docstring for the steps)."""
    rho = frames.site_rotation_rad(
        site.lat_deg, site.lon_deg, cfg.region.origin_lat_deg, cfg.region.origin_lon_deg
    )
    r = reports["range_m"].to_numpy().astype(float)
    az = np.mod(reports["azimuth_rad"].to_numpy() + site.north_alignment_rad, frames.TWO_PI)
    x_site, y_site = frames.polar_to_enu(r, az)
    x, y = frames.site_to_region(
        x_site,
        y_site,
        site.lat_deg,
        site.lon_deg,
        cfg.region.origin_lat_deg,
        cfg.region.origin_lon_deg,
    )
    P = frames.polar_covariance(
        r, az + rho, reports["sigma_range_m"].to_numpy(), reports["sigma_azimuth_rad"].to_numpy()
    )
    course = np.mod(
        reports["course_rad"].to_numpy() + site.north_alignment_rad + rho, frames.TWO_PI
    )
    scan_end = np.mod(
        reports["scan_end_azimuth_rad"].to_numpy() + site.north_alignment_rad, frames.TWO_PI
    )
    return reports.with_columns(
        pl.Series("azimuth_rad", az),
        pl.Series("scan_end_azimuth_rad", scan_end),
        pl.Series("x_site_m", x_site),
        pl.Series("y_site_m", y_site),
        pl.Series("course_rad", course),
        pl.Series("x_enu_m", np.asarray(x, float)),
        pl.Series("y_enu_m", np.asarray(y, float)),
        pl.Series("P_xx", P[:, 0, 0]),
        pl.Series("P_yy", P[:, 1, 1]),
        pl.Series("P_xy", P[:, 0, 1]),
    )
