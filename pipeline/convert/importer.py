"""``surveil import PATH... --out DIR``: legacy captures wrapped into MCAP.

One work unit per input file, run in this process (files are small text logs; the work
is file I/O plus column operations). Each input gives ``<out>/<file name>.mcap`` (see
:mod:`pipeline.convert.legacy` for the formats, channels and log-time sources).

Inputs: files are taken as given; directories are walked recursively and every file
whose content is importable is taken (others are listed as skipped). Usage errors
(exit 2): a path that does not exist, a directory with no importable file, an explicitly
named file that is not importable, two inputs with the same file name (their outputs
would collide). A file that fails while being wrapped is listed as failed (exit 1); the
others are still written. A file written with some pieces rejected (a damaged stretch of
an ASTERIX or pcap file skipped up to the next good block or packet, a sentence whose
date cannot be represented: ``/import/rejects``, rejects rows at ingest) is ``partial``
and also makes the exit code 1; the summary says how many pieces.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.config import Config
from pipeline.convert.config import import_options
from pipeline.convert.legacy import ImportedFile, detect_format, import_file, output_path
from pipeline.convert.output import REJECTS_TOPIC
from pipeline.errors import UsageError
from pipeline.render import printable
from pipeline.units import describe_time, time_in_range


@dataclass
class ImportSummary:
    """What ``run_import`` did; ``exit_code`` 0 when every file was written."""

    out_dir: str
    imported: list[ImportedFile] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    failed: list[tuple[str, str]] = field(default_factory=list)

    @property
    def partial(self) -> list[ImportedFile]:
        """Files written with some pieces rejected (``/import/rejects``)."""
        return [f for f in self.imported if f.status == "partial"]

    @property
    def exit_code(self) -> int:
        """0: every file wrapped whole; 1: a file failed or was partial (pieces rejected)."""
        return 1 if self.failed or self.partial else 0

    def render(self) -> str:
        rejected = sum(f.rejected for f in self.imported)
        lines = [
            f"import: {len(self.imported)} files written to {self.out_dir} "
            f"({len(self.partial)} partial: {rejected} pieces rejected), "
            f"{len(self.skipped)} skipped (not importable), {len(self.failed)} failed"
        ]
        for f in self.imported:
            chans = ", ".join(
                f"{t} {n} (rejected)" if t == REJECTS_TOPIC
                else f"{t} {n} ({f.log_time_source.get(t, '?')})"
                for t, n in f.messages.items()
            )  # fmt: skip
            not_messages = ", ".join(f"{n} {k} lines" for k, n in sorted(f.skipped.items()) if n)
            lines.append(
                f"  {Path(f.source).name} [{f.format}] -> {Path(f.output).name}"
                + (" PARTIAL" if f.status == "partial" else "")
                + (f": {chans}" if chans else "")
                + (f"; not messages: {not_messages}" if not_messages else "")
            )
        for f in self.imported:
            if f.warning:
                lines.append(f"WARNING: {f.warning}")
        for path in self.skipped[:10]:
            lines.append(f"  skipped {path}")
        for path, err in self.failed:
            lines.append(f"  FAILED {path}: {err}")
        lines.append(f"exit code {self.exit_code}")
        # file names come from the archive: a control character in one is shown escaped
        return "\n".join(map(printable, lines))


def expand_inputs(paths: Sequence[Path | str]) -> tuple[list[Path], list[Path]]:
    """``(files to import, skipped files)``; raises :class:`UsageError` (see module)."""
    files: list[Path] = []
    skipped: list[Path] = []
    if not paths:
        raise UsageError("no input paths given")
    for raw in paths:
        p = Path(raw).expanduser()
        if not p.exists():
            raise UsageError(f"input path does not exist: {p}")
        if p.is_dir():
            found = sorted(q for q in p.rglob("*") if q.is_file() and not q.name.startswith("."))
            ok = [q for q in found if detect_format(q) != "unknown"]
            if not ok:
                raise UsageError(
                    "no importable files (NMEA text, AIS CSV, ASTERIX, pcap, ROS 1 bag) under "
                    f"directory: {p}"
                )
            files += ok
            skipped += [q for q in found if q not in ok]
        elif detect_format(p) == "unknown":
            raise UsageError(
                "not an importable file (NMEA 0183 text, AIS CSV, ASTERIX raw / framed / "
                f"pcap, ROS 1 bag): {p}"
            )
        else:
            files.append(p)
    files = list(dict.fromkeys(q.resolve() for q in files))
    names: dict[str, Path] = {}
    for q in files:
        if q.name in names:
            raise UsageError(
                f"two inputs named {q.name!r} would both become "
                f"{q.name}.mcap: {names[q.name]} and {q}"
            )
        names[q.name] = q
    return files, skipped


def run_import(
    paths: Sequence[Path | str],
    out_dir: Path | str,
    *,
    base_time_ns: int | None = None,
    cfg: Config | None = None,
    site: str | None = None,
) -> ImportSummary:
    """Wrap every input into ``out_dir`` (created); see the module docstring. ``cfg``:
    its ``[import.csv]`` / ``[asterix]`` sections (defaults without one). ``site``: written
    into every output's metadata (``surveil.import`` record, key ``site``)."""
    options = import_options(cfg)
    if base_time_ns is not None and not time_in_range(base_time_ns):
        raise UsageError(
            f"--base-time {describe_time(base_time_ns)} is outside 1970-01-01 .. 2262-04-11 UTC"
        )
    files, skipped = expand_inputs(paths)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summary = ImportSummary(str(out), skipped=[str(p) for p in skipped])
    for f in files:
        if output_path(f, out).resolve() == f:
            raise UsageError(f"output would overwrite the input: {f}")
        try:
            summary.imported.append(import_file(f, out, base_time_ns=base_time_ns, options=options,
                                                 site=site))
        except ValueError as exc:  # damaged or unrecognised content found while wrapping
            summary.failed.append((str(f), str(exc)))
    return summary
