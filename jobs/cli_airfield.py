"""Airfield commands: ``surveil calibrate --from --to``. Registered in jobs/cli.py under
``# (family commands)``."""

from __future__ import annotations

import click


@click.command()
@click.option("--from", "from_", required=True, help="fit window start (ISO 8601 or ns)")
@click.option("--to", required=True, help="fit window end, exclusive")
@click.option("--max-order", type=click.IntRange(1, 8), default=4, show_default=True,
              help="highest AR order compared by BIC")
@click.option("--min-speed", type=float, default=0.0, show_default=True,
              help="use only reports of reference targets at least this fast, m/s")
@click.pass_obj
def calibrate(st, from_, to, max_order, min_speed) -> None:
    """Fit each airfield sensor's coloured-error AR model against the reference channel
    (airfield paper eq. 2, 7, 8; order by BIC) into sensor_error_models."""
    from jobs.calibrate import run_calibrate
    from jobs.cli import _window

    start, end = _window(from_, to, required=True)
    summary = run_calibrate(st.cfg, st.warehouse, start_ns=start, end_ns=end,
                            max_order=max_order, min_speed_mps=min_speed)
    click.echo(summary.render())
