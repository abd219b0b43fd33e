"""The audit's registration time series from literal ``sensor_registration`` rows through
the ``registration_over_time`` report (issue 38): a site whose sectors are registered on
their own draws each of them as a line of its own, not their mean."""

from __future__ import annotations

import duckdb
import polars as pl

from pipeline.audit import charts
from pipeline.reports import load_report, run_report
from pipeline.tables import empty, table_specs

NS = 1_000_000_000
T0 = 1_768_435_200 * NS  # 2026-01-15 00:00 UTC


def registration_rows() -> pl.DataFrame:
    """R1 for two minutes, three sectors: one registration in the first minute, each
    sector's own in the second (inner_channel's range bias 100 m, approach_sw's 0 m)."""
    base = dict(site="channel", site_id="R1", azimuth_bias_rad=0.0, time_offset_s=0.0,
                range_gain=0.0, sigma_range_bias_m=5.0, sigma_azimuth_bias_rad=0.001,
                sigma_time_offset_s=0.5, sigma_range_gain=0.001, window="both", tracks=100,
                tracks_ais=100, tracks_pair=0, registration_applied=True, variance_scale=1.0,
                scale_tracks=50, scale_applied=False, readmitted=False)
    rows = []
    for sector in ("approach_ne", "approach_sw", "inner_channel"):
        rows.append({**base, "time_ns": T0 + 10 * NS, "sector": sector, "range_bias_m": 60.0,
                     "registration_scope": "site"})
        own = {"approach_sw": 0.0}.get(sector, 100.0)
        rows.append({**base, "time_ns": T0 + 70 * NS, "sector": sector, "range_bias_m": own,
                     "registration_scope": "sector"})
    return pl.DataFrame(rows)


def _report(rows: pl.DataFrame) -> pl.DataFrame:
    con = duckdb.connect()
    for t in table_specs():
        con.register(t, empty(t))
    like = pl.from_arrow(empty("sensor_registration"))
    con.register("sensor_registration", pl.concat([like, rows], how="diagonal_relaxed")
                 .with_columns(pl.lit(None, pl.Date).alias("date")).to_arrow())
    return pl.from_arrow(run_report(con, load_report("registration_over_time"),
                                    start_ns=T0, end_ns=T0 + 3600 * NS))


def test_a_site_registered_per_sector_has_a_row_and_a_line_per_sector():
    got = _report(registration_rows())
    site = got.filter(pl.col("registered_sector").is_null())
    assert site.height == 1 and site["range_bias_m"].item() == 60.0
    own = dict(got.filter(pl.col("registered_sector").is_not_null())
               .select("registered_sector", "range_bias_m").iter_rows())
    assert own == {"approach_ne": 100.0, "approach_sw": 0.0, "inner_channel": 100.0}
    fig = charts.registration_over_time(got.to_dicts(), T0, T0 + 3600 * NS)
    lines = {t.name: t.line.dash for t in fig.data if t.mode == "lines+markers"}
    assert lines == {"R1": "solid", "R1 · approach_ne": "dash", "R1 · approach_sw": "dot",
                     "R1 · inner_channel": "dashdot"}
    # the site's interval as a band, the sectors' in the hover only
    assert sum(t.fill == "toself" for t in fig.data) == 4  # one per panel with an interval
