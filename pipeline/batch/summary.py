"""What a batch did: per site, its window, units, rows, failures and continued chain."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.errors import EXIT_VIEWS_STALE, views_stale_note


@dataclass
class BatchSummary:
    """One site's batch of one window: units, rows per table, failures, the commit, and
    the batches of the units after it that it continued (``continued``)."""

    start_ns: int
    end_ns: int
    requested: tuple[int, int] | None = None  # the window asked for, when widened
    site: str | None = None
    units_total: int = 0
    failed_units: list[str] = field(default_factory=list)
    rows: dict[str, int] = field(default_factory=dict)
    rejects: int = 0
    # the batch rejects by cause: "unknown_sensor: 6666 airfield_obs reports from ..."
    reject_reasons: list[str] = field(default_factory=list)
    # one line per family skipped (no config, no inputs) or run with a caveat
    notes: list[str] = field(default_factory=list)
    committed: bool = False
    family_s: dict[str, float] = field(default_factory=dict)  # summed unit wall time
    commit_s: float = 0.0
    # the committed units after the window whose ids continued the window's old rows,
    # when the batch changed those rows: (start, end) to batch again
    next_window: tuple[int, int] | None = None
    # the batches of those units (ids continued across the trailing edge)
    continued: list[BatchSummary] = field(default_factory=list)
    continuation: Path | None = None  # its record (``_continue/``) until they are

    @property
    def exit_code(self) -> int:
        own = 0 if self.committed and not self.failed_units else 1
        return max([own, *(c.exit_code for c in self.continued)])

    def render(self) -> str:
        at = f"site {self.site}: " if self.site is not None else ""
        lines = [
            f"{at}batch window [{iso_s(self.start_ns)}, {iso_s(self.end_ns)}): "
            f"{self.units_total} unit(s), {len(self.failed_units)} failed, "
            f"{'committed' if self.committed else 'NOT committed (previous data kept)'}"
        ]
        if self.requested is not None:
            lines.append(f"  (asked for [{iso_s(self.requested[0])}, {iso_s(self.requested[1])}): "
                         "widened to the committed units it overlaps, re-run whole)")
        lines += [f"  {note}" for note in self.notes]
        lines += [f"  {name:<16} {n:>9} rows" for name, n in self.rows.items()]
        if self.family_s:
            lines.append("  time: " + ", ".join(f"{fam} {s:.1f} s" for fam, s in
                                                 self.family_s.items())
                         + f" (summed over units); commit {self.commit_s:.1f} s")
        if self.rejects:
            lines.append(f"  rejects (batch)  {self.rejects:>9} rows")
            lines += [f"    {r}" for r in self.reject_reasons]
        lines += [f"  failed: {u}" for u in self.failed_units]
        for c in self.continued:
            lines.append("  the rows at the window's end changed: the next committed units "
                         "batched again so their ids continue them")
            lines += ["  " + line for line in c.render().splitlines()]
        return "\n".join(lines)


@dataclass
class SitesSummary:
    """A batch over several sites: one :class:`BatchSummary` per site, each reported
    apart (a site's rows, units and failures are its own)."""

    by_site: dict[str, BatchSummary]
    asked_start_ns: int
    asked_end_ns: int
    # chains a killed job left undone (``_continue/``), run before the window
    resumed: list[BatchSummary] = field(default_factory=list)
    # the views file's rebuild after the commits failed (a full disk): why, else None
    views_error: str | None = None

    @property
    def start_ns(self) -> int:
        """Start of the window batched (widened to committed units), earliest site's."""
        return min((b.start_ns for b in self.by_site.values()), default=self.asked_start_ns)

    @property
    def end_ns(self) -> int:
        return max((b.end_ns for b in self.by_site.values()), default=self.asked_end_ns)

    @property
    def requested(self) -> tuple[int, int] | None:
        """The window asked for, when some site's was widened."""
        widened = any(b.requested is not None for b in self.by_site.values())
        return (self.asked_start_ns, self.asked_end_ns) if widened else None

    @property
    def rejects(self) -> int:
        return sum(b.rejects for b in self.by_site.values())

    @property
    def committed(self) -> bool:
        return all(b.committed for b in self.by_site.values())

    @property
    def failed_units(self) -> list[str]:
        return [f"site {s}: {u}" for s, b in self.by_site.items() for u in b.failed_units]

    @property
    def units_total(self) -> int:
        return sum(b.units_total for b in self.by_site.values())

    @property
    def rows(self) -> dict[str, int]:
        """Rows written per table, all sites (for run records; reports stay per site),
        continued and resumed batches included."""
        out: dict[str, int] = {}
        todo = [*self.by_site.values(), *self.resumed]
        while todo:
            b = todo.pop()
            todo += b.continued
            for name, n in b.rows.items():
                out[name] = out.get(name, 0) + n
        return out

    @property
    def exit_code(self) -> int:
        """The sites' worst; :data:`EXIT_VIEWS_STALE` (3) when every window committed but
        the views file could not be rebuilt after."""
        code = max((b.exit_code for b in [*self.by_site.values(), *self.resumed]), default=0)
        return EXIT_VIEWS_STALE if code == 0 and self.views_error else code

    def render(self) -> str:
        lines = []
        for r in self.resumed:
            lines.append(f"site {r.site}: a killed job left the units after "
                         f"{iso_s(r.end_ns)} to batch again (the rows they continue changed)")
            lines += ["  " + line for c in r.continued for line in c.render().splitlines()]
        if not self.by_site and not self.resumed:
            lines.append(f"batch window [{iso_s(self.asked_start_ns)}, "
                         f"{iso_s(self.asked_end_ns)}): no site has data in it; nothing written")
        lines += [b.render() for b in self.by_site.values()]
        if self.views_error:
            lines.append(views_stale_note("batch", self.views_error))
        return "\n".join(lines)



def iso_s(t_ns: int) -> str:
    """int64 ns UTC -> ISO 8601 to the second, with a Z."""
    return str(np.datetime64(int(t_ns), "ns").astype("datetime64[s]")) + "Z"
