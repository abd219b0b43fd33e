"""Calibration jobs: read a window, fit, commit the fit (one atomic commit replacing the
window), rebuild the views.

- ``surveil calibrate-radars --from --to``: each radar's registration bias (range,
  azimuth / north alignment, time offset) from the AIS reports of cooperative ships
  (``radar_bias_by_site``); prints the ``[radar_bias.correction]`` lines to configure.
  Model: pipeline/maritime/bias.py.
- ``surveil calibrate --from --to``: each airfield sensor's coloured-error AR models
  against the reference channel (``sensor_error_models``, predicate on
  ``fit_start_ns``). Model: pipeline/airfield/calibrate.py.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import polars as pl

from pipeline import tables
from pipeline.airfield.config import airfield_config
from pipeline.airfield.stage import calibration
from pipeline.config import Config
from pipeline.errors import EXIT_VIEWS_STALE, UsageError, views_stale_note
from pipeline.maritime.bias import correction_toml, estimate_biases
from pipeline.maritime.config import radar_bias_config
from pipeline.units import NS, iso
from pipeline.warehouse.delta import read_table, replace_window
from pipeline.warehouse.views import rebuild_views_after_commits


@dataclass
class RadarCalibration:
    """What ``calibrate-radars`` wrote: the estimates (with their ``site``), and why the
    views file could not be rebuilt after the commits (a full disk), else None."""

    estimates: pl.DataFrame
    views_error: str | None = None

    @property
    def exit_code(self) -> int:
        return EXIT_VIEWS_STALE if self.views_error else 0

    def render(self) -> str:
        text = render(self.estimates)
        return text + "\n" + views_stale_note("calibration", self.views_error) \
            if self.views_error else text


def run_calibration(cfg: Config, warehouse: Path, *, start_ns: int, end_ns: int,
                    site: str | None = None) -> RadarCalibration:
    """Estimate the biases of [start_ns, end_ns), site by site (``site``: that one only),
    commit each site's, return the rows (with their ``site``)."""
    gap_ns = round(radar_bias_config(cfg).max_ais_gap_s * NS)
    radar = pl.from_arrow(read_table(warehouse, "radar_tracks", start_ns=start_ns, end_ns=end_ns,
                                     site=site))
    ais = pl.from_arrow(read_table(warehouse, "ais_reports", start_ns=start_ns - gap_ns,
                                   end_ns=end_ns + gap_ns, site=site))
    if radar.height == 0 or ais.height == 0:
        raise UsageError(f"no radar or no AIS reports in [{iso(start_ns)}, {iso(end_ns)}): "
                         "ingest the archive of that window first")
    out = []
    for name in sorted(radar["site"].unique().to_list()):
        est = estimate_biases(radar.filter(pl.col("site") == name),
                              ais.filter(pl.col("site") == name), cfg, start_ns=start_ns,
                              end_ns=end_ns)
        if est.height:
            table = tables.conform("radar_bias_by_site", est, site=name)
            replace_window(warehouse, "radar_bias_by_site", table, start_ns=start_ns,
                           end_ns=end_ns, site=name)
            out.append(pl.from_arrow(table))
    if not out:
        raise UsageError("no radar track followed an AIS ship in the window: nothing to fit")
    return RadarCalibration(pl.concat(out), rebuild_views_after_commits(warehouse))


def render(est: pl.DataFrame) -> str:
    """Estimates with their intervals, then the config lines."""
    lines = []
    for r in est.iter_rows(named=True):
        lines += [
            f"{r['site_id']}: {r['reports_used']} reports ({r['reports_rejected']} rejected), "
            f"{r['tracks_used']} tracks, {r['ships_used']} AIS ships, "
            f"reduced chi2 {r['reduced_chi2']:.2f}",
            f"  range bias   {r['range_bias_m']:+9.2f} m    [{r['range_bias_ci_low_m']:+.2f}, "
            f"{r['range_bias_ci_high_m']:+.2f}]",
            f"  azimuth bias {r['azimuth_bias_deg']:+9.4f} deg  "
            f"[{r['azimuth_bias_ci_low_deg']:+.4f}, {r['azimuth_bias_ci_high_deg']:+.4f}]",
            f"  time offset  {r['time_offset_s']:+9.3f} s    [{r['time_offset_ci_low_s']:+.3f}, "
            f"{r['time_offset_ci_high_s']:+.3f}]",
            f"  range gain   {r['range_gain'] * 1e3:+9.3f} m/km "
            f"[{r['range_gain_ci_low'] * 1e3:+.3f}, {r['range_gain_ci_high'] * 1e3:+.3f}]",
        ]
    lines += ["", "# to apply in batch: [radar_bias] apply = true, and", correction_toml(est)]
    return "\n".join(lines)


@dataclass
class CalibrateSummary:
    start_ns: int
    end_ns: int
    rows: int
    fits: dict[str, str]
    views_error: str | None = None  # the views rebuild after the commits failed: why

    @property
    def exit_code(self) -> int:
        return EXIT_VIEWS_STALE if self.views_error else 0

    def render(self) -> str:
        lines = [f"sensor_error_models: {self.rows} rows for fit window "
                 f"[{self.start_ns}, {self.end_ns})"]
        lines += [f"  {k:<18} {v}" for k, v in sorted(self.fits.items())]
        if self.views_error:
            lines.append(views_stale_note("calibration", self.views_error))
        return "\n".join(lines)


def run_calibrate(cfg: Config, warehouse: Path, *, start_ns: int, end_ns: int,
                  max_order: int = 4, min_speed_mps: float = 0.0,
                  site: str | None = None) -> CalibrateSummary:
    """Fit and store every configured airfield sensor's error models for the window,
    site by site (``site``: that one only): each site's sensors against its own
    reference, stored with its ``site`` (the airfield batch of a site reads its own)."""
    acfg = airfield_config(cfg)
    obs = pl.from_arrow(read_table(warehouse, "airfield_obs", start_ns=start_ns, end_ns=end_ns,
                                   site=site))
    truth = pl.from_arrow(read_table(warehouse, "airfield_truth", start_ns=start_ns,
                                     end_ns=end_ns, site=site))
    if obs.height == 0:
        raise UsageError("no airfield_obs rows in the window: ingest the archive first")
    if truth.height == 0:
        raise UsageError("no airfield_truth rows in the window: calibrate needs a reference "
                         "(simulated truth, or DGNSS reference vehicles on the truth channel)")
    sites = sorted(set(obs["site"].unique().to_list()) & set(truth["site"].unique().to_list()))
    n_rows, desc = 0, {}
    for name in sites:
        rows, fits = calibration(obs.filter(pl.col("site") == name),
                                 truth.filter(pl.col("site") == name), acfg,
                                 start_ns=start_ns, end_ns=end_ns, max_order=max_order,
                                 min_speed_mps=min_speed_mps)
        if rows.height == 0:
            continue
        table = tables.conform("sensor_error_models", rows, site=name)
        replace_window(warehouse, "sensor_error_models", table, start_ns=start_ns,
                       end_ns=end_ns, site=name)
        n_rows += table.num_rows
        at = f"{name}/" if len(sites) > 1 else ""
        desc |= {f"{at}{k}": f"AR({f.model.order}) on {f.n_rows} rows, BIC "
                 + ", ".join(f"{p}:{b:.0f}" for p, b in sorted(f.bic_by_order.items()))
                 for k, f in fits.items()}
    if n_rows == 0:
        raise UsageError("too few matched reports in the window to fit any error model")
    return CalibrateSummary(start_ns, end_ns, n_rows, desc,
                            rebuild_views_after_commits(warehouse))
