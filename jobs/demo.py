"""`surveil demo`: simulate one hour (the `channel`, `airfield` and `ownship` scenarios:
every family's tables, so the audit page has every section; with the scenarios' fault
schedules, ``config/scenarios/*.toml``: ``[[channel_faults]]``, ``[[airfield.faults]]``,
the own ship's GNSS outages and jump) into an archive, ingest it, run the batch over the
hour and print the accuracy, identification and channel-fault reports."""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from jobs.common import iso
from jobs.simulate import DEFAULT_START_NS, run_simulate
from pipeline.batch import SitesSummary, run_batch
from pipeline.config import Config
from pipeline.ingest.driver import IngestSummary, run_ingest
from pipeline.render import format_report
from pipeline.reports import run_named_report
from pipeline.simulate.scenarios import with_scenario
from pipeline.warehouse.location import as_location

DEMO_REPORTS = ("accuracy_by_sector", "identification_by_sector", "channel_faults_by_sector")
DEMO_SCENARIOS = ("channel", "airfield", "ownship")


@dataclass
class DemoResult:
    archive: list[Path]
    ingest: IngestSummary
    batch: SitesSummary

    @property
    def exit_code(self) -> int:
        return max(self.ingest.exit_code, self.batch.exit_code)


def run_demo(
    cfg: Config,
    warehouse: Path,
    *,
    seed: int = 7,
    duration_s: float = 3600.0,
    echo: Callable[[str], None] = print,
    executor_kind: str | None = None,
    scenarios: Sequence[str] = DEMO_SCENARIOS,
) -> DemoResult:
    cfg = with_scenario(cfg, scenarios)  # the demo site's fault schedules (config/scenarios)
    local = as_location(warehouse).is_local
    # the simulator writes files: beside a local warehouse, else in a temporary folder
    archive_dir = (warehouse / "demo-archive" if local
                   else Path(tempfile.mkdtemp(prefix="surveil-demo-archive-")))
    echo(f"1/4 simulate: {', '.join(scenarios)} scenario(s), {duration_s:.0f} s, seed {seed} "
         f"-> {archive_dir}")
    files = []
    for scenario in scenarios:
        files += run_simulate(scenario, duration_s, seed, archive_dir, cfg,
                              start_ns=DEFAULT_START_NS)
    echo(f"    {len(files)} MCAP file(s): " + ", ".join(f.name for f in files))
    echo(f"2/4 ingest -> {warehouse}")
    ingest = run_ingest(files, cfg, warehouse, executor=executor_kind)
    echo(ingest.render())
    start_ns = DEFAULT_START_NS
    end_ns = start_ns + int(duration_s * 1e9)
    echo("3/4 batch: every sensor family (maritime: align, sync, associate, channel integrity, "
         "fuse, identify, score; nav: own-ship solution and GNSS integrity)")
    batch = run_batch(cfg, warehouse, start_ns=start_ns, end_ns=end_ns, executor_kind=executor_kind)
    echo(batch.render())
    echo("4/4 reports")
    for name in DEMO_REPORTS:
        table = run_named_report(warehouse, name, start_ns=start_ns, end_ns=end_ns)
        echo(format_report(table, "table", title=name))
    echo(
        f"warehouse: {warehouse} (open {warehouse / 'surveil.duckdb'} in DuckDB for your own SQL)"
        if local else f"warehouse: {warehouse} (surveil sql for your own SQL)"
    )
    window = f"--from {iso(start_ns)} --to {iso(end_ns)}"
    echo(f"audit page: surveil audit {window} --out audit/   (docs/audit.md)")
    echo(f"Foxglove:   surveil export {window} --out demo.mcap   (docs/foxglove.md)")
    return DemoResult(archive=files, ingest=ingest, batch=batch)
