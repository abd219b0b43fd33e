"""`surveil calibrate-radars --from --to`: estimate each radar's registration bias (range,
azimuth / north alignment, time offset) from the AIS reports of cooperative ships in a
window (e.g. a night), write it to the ``radar_bias_by_site`` table (one atomic commit
replacing the window) and print the ``[radar_bias.correction]`` lines to configure.
See pipeline/bias.py for the model."""

from __future__ import annotations

from pathlib import Path

import polars as pl

from jobs.common import UsageError, iso
from pipeline import tables
from pipeline.bias import correction_toml, estimate_biases, radar_bias_config
from pipeline.config import Config
from pipeline.warehouse.delta import read_table, replace_window
from pipeline.warehouse.views import rebuild_views_file

NS = 1_000_000_000


def run_calibration(cfg: Config, warehouse: Path, *, start_ns: int, end_ns: int) -> pl.DataFrame:
    """Estimate the biases of [start_ns, end_ns), commit them, return the rows."""
    gap_ns = round(radar_bias_config(cfg).max_ais_gap_s * NS)
    radar = pl.from_arrow(read_table(warehouse, "radar_tracks", start_ns=start_ns, end_ns=end_ns))
    ais = pl.from_arrow(read_table(warehouse, "ais_reports", start_ns=start_ns - gap_ns,
                                   end_ns=end_ns + gap_ns))
    if radar.height == 0 or ais.height == 0:
        raise UsageError(f"no radar or no AIS reports in [{iso(start_ns)}, {iso(end_ns)}): "
                         "ingest the archive of that window first")
    est = estimate_biases(radar, ais, cfg, start_ns=start_ns, end_ns=end_ns)
    if est.height == 0:
        raise UsageError("no radar track followed an AIS ship in the window: nothing to fit")
    replace_window(warehouse, "radar_bias_by_site", tables.conform("radar_bias_by_site", est),
                   start_ns=start_ns, end_ns=end_ns)
    rebuild_views_file(warehouse)
    return est


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
        ]
    lines += ["", "# to apply in batch: [radar_bias] apply = true, and", correction_toml(est)]
    return "\n".join(lines)
