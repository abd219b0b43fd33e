"""Data-gap forecast commands: ``surveil gaps-montecarlo``. Registered in jobs/cli.py
under ``# (family commands)``."""

from __future__ import annotations

import click


@click.command("gaps-montecarlo")
@click.option(
    "--runs",
    type=click.IntRange(1, 1000),
    default=20,
    show_default=True,
    help="simulated runs (seeds first-seed .. first-seed + runs - 1)",
)
@click.option("--first-seed", type=int, default=1, show_default=True)
@click.option(
    "--duration",
    default="3h",
    show_default=True,
    help="length of each simulated run (1h, 90m, 3h, seconds)",
)
@click.option(
    "--particles",
    type=click.IntRange(100, 100_000),
    default=None,
    help="particles per gap (default: [gaps] particles)",
)
@click.option("--by-lead", is_flag=True, help="one row per lead-time band and variant")
@click.option(
    "--executor",
    type=click.Choice(["serial", "process", "ray"]),
    default=None,
    help="how the runs are spread (default: [execution] executor)",
)
@click.option(
    "--format",
    "fmt",
    type=click.Choice(["table", "csv", "json"]),
    default="table",
    show_default=True,
)
@click.option(
    "--out",
    "out_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="also write every forecast (both variants) to this Parquet file",
)
@click.pass_obj
def gaps_montecarlo(
    st, runs, first_seed, duration, particles, by_lead, executor, fmt, out_path
) -> None:
    """Seeded Monte Carlo of the data-gap forecasts on the `gaps` scenario, with and
    without the admissible-area constraint: share of true positions inside the 90%
    region, forecast errors, probability of the zone the ship actually reached."""
    from jobs.common import UsageError
    from jobs.report import format_report
    from jobs.simulate import parse_duration
    from pipeline.experiments.gaps_montecarlo import run_montecarlo, summarise

    try:
        duration_s = parse_duration(duration)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    cfg = st.cfg
    forecasts = run_montecarlo(
        cfg,
        seeds=range(first_seed, first_seed + runs),
        duration_s=duration_s,
        particles=particles,
        executor=executor or cfg.execution.executor,
    )
    if out_path:
        forecasts.write_parquet(out_path)
    table = summarise(forecasts, by_lead=by_lead)
    click.echo(format_report(table.to_arrow(), fmt, title="gaps Monte Carlo"))
