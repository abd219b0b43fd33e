"""Maritime audit commands: ``surveil experiment identification|velocity`` and
``surveil calibrate-radars``. Registered in jobs/cli.py under ``# (family commands)``."""

from __future__ import annotations

import json

import click


def _emit(result: dict, fmt: str) -> None:
    from pipeline.maritime.experiment import render

    click.echo(json.dumps(result, indent=2) if fmt == "json" else render(result))


_format_opt = click.option("--format", "fmt", type=click.Choice(["text", "json"]),
                           default="text", show_default=True)


@click.group()
def experiment() -> None:
    """Reproduce the source papers' simulation experiments with the production code."""


@experiment.command()
@click.option("--sigma", type=float, required=True, help="radar position sigma, m (x and y)")
@click.option("--dx", type=float, default=0.0, show_default=True, help="separation east, m")
@click.option("--dy", type=float, default=0.0, show_default=True, help="separation north, m")
@click.option("--trials", type=int, default=10_000, show_default=True)
@click.option("--seed", type=int, default=1, show_default=True)
@_format_opt
@click.pass_obj
def identification(st, sigma, dx, dy, trials, seed, fmt) -> None:
    """Two stationary targets, two radars: probability of correct identification
    (two-radar identification paper), with its 95 % Monte Carlo interval."""
    from pipeline.maritime.experiment import identification_experiment

    _emit(identification_experiment(st.cfg, sigma_m=sigma, dx_m=dx, dy_m=dy, trials=trials,
                                    seed=seed), fmt)


@experiment.command()
@click.option("--sigma", type=float, required=True, help="radar position sigma, m (x and y)")
@click.option("--dx", type=float, default=0.0, show_default=True, help="separation east, m")
@click.option("--dy", type=float, default=0.0, show_default=True, help="separation north, m")
@click.option("--speed", type=float, default=5.0, show_default=True, help="target speed, m/s")
@click.option("--course-difference", type=float, default=20.0, show_default=True,
              help="angle between the two targets' courses, deg")
@click.option("--trials", type=int, default=10_000, show_default=True)
@click.option("--seed", type=int, default=1, show_default=True)
@_format_opt
@click.pass_obj
def velocity(st, sigma, dx, dy, speed, course_difference, trials, seed, fmt) -> None:
    """Moving targets: probability of correct identification with and without the
    reported velocities."""
    from pipeline.maritime.experiment import velocity_experiment

    _emit(velocity_experiment(st.cfg, sigma_m=sigma, dx_m=dx, dy_m=dy, speed_mps=speed,
                              course_difference_deg=course_difference, trials=trials,
                              seed=seed), fmt)


@click.command("calibrate-radars")
@click.option("--from", "from_", required=True, help="window start (ISO 8601 or ns)")
@click.option("--to", required=True, help="window end, exclusive")
@click.option("--format", "fmt", type=click.Choice(["text", "json"]), default="text",
              show_default=True)
@click.pass_obj
def calibrate_radars(st, from_, to, fmt) -> None:
    """Estimate each radar's range, azimuth and time bias from AIS ships in a window,
    with 95 % intervals; write radar_bias_by_site and print the config lines."""
    from jobs.calibrate import render, run_calibration
    from jobs.common import UsageError, parse_time_ns

    start, end = parse_time_ns(from_), parse_time_ns(to)
    if end <= start:
        raise UsageError("--to must be after --from")
    est = run_calibration(st.cfg, st.warehouse, start_ns=start, end_ns=end)
    click.echo(est.write_json() if fmt == "json" else render(est))
