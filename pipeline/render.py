"""Report tables as a person reads them: a terminal table that never cuts a value, CSV,
JSON; and ``surveil schema``'s tables (every table, or one table's columns).

Every value is data (an AIS name, a callsign, a site, a topic, a file name: untrusted
text, issue 40 item 4) and is printed as it is: the terminal table hands it to rich as
:class:`rich.text.Text`, never as markup (``[/]``, ``[bold]``, ``[#FF0]`` print as
written), and control characters (an ANSI escape, a carriage return, a newline) print
as ``\\xNN`` escapes in the table and the row blocks; CSV quotes as CSV does, JSON
escapes as JSON does."""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import sys

import pyarrow as pa
import pyarrow.csv as pacsv

from pipeline.tables import column_doc, column_unit, table_specs

_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")


def schema_table(name: str | None) -> pa.Table:
    """``surveil schema``: every table (name, kind, rows' meaning), or one table's
    columns (name, type, nullable, unit, meaning), from schemas/."""
    if name is None:
        specs = table_specs().values()
        return pa.table({"table": [s.name for s in specs], "kind": [s.kind for s in specs],
                         "one row is": [s.doc for s in specs]})
    fields = list(table_specs()[name].schema)
    return pa.table({
        "column": [f.name for f in fields],
        "type": [str(f.type).replace("date32[day]", "date32") for f in fields],
        "null": ["yes" if f.nullable else "no" for f in fields],
        "unit": [column_unit(f.name) for f in fields],
        "meaning": [column_doc(f) for f in fields],
    })


def terminal_width() -> int:
    """Columns of the terminal on stdout (``$COLUMNS`` first); not a terminal and no
    ``$COLUMNS``: no limit (a file or a pipe gets the table at its natural width)."""
    if not sys.stdout.isatty() and "COLUMNS" not in os.environ:
        return 100_000
    return shutil.get_terminal_size((100, 24)).columns


def format_report(table: pa.Table, fmt: str, title: str = "", width: int | None = None) -> str:
    """Render a report as a terminal table, CSV or JSON (a list of row objects).

    The table never cuts a value: text columns wrap at word boundaries to fit ``width``
    (the terminal's); when even then it does not fit (numbers are never wrapped), each
    row is printed as a block of ``column: value`` lines instead."""
    if fmt == "csv":
        buf = io.BytesIO()
        pacsv.write_csv(table, buf)
        return buf.getvalue().decode()
    if fmt == "json":
        return json.dumps(table.to_pylist(), indent=2, default=str)
    from rich.console import Console
    from rich.table import Table
    from rich.text import Text

    title = printable(title)
    if table.num_rows == 0:
        return f"{title + ': ' if title else ''}(no rows)\n"
    width = width or terminal_width()
    cells = [[("" if v is None else printable(str(v))) for v in row.values()]
             for row in table.to_pylist()]
    names = [printable(n) for n in table.column_names]
    fields = list(table.schema)
    numeric = [_numeric(f.type) for f in fields]
    # the narrowest each column can be: numbers and headers whole, text at its longest word
    least = []
    for j, n in enumerate(names):
        values = [r[j] for r in cells]
        if numeric[j]:
            least.append(max([len(n), *map(len, values)]))
        else:
            words = [len(w) for v in values for w in v.split()] or [0]
            least.append(max(len(n), min(max(words), 40)))
    if sum(least) + 3 * len(names) + 1 > width and names:
        return _vertical(names, cells, title)
    t = Table(title=Text(title) if title else None, show_lines=False)
    for j, name in enumerate(names):
        t.add_column(Text(name), justify="right" if numeric[j] else "left", no_wrap=numeric[j],
                     overflow="fold", min_width=least[j])
    for row in cells:  # Text: a value is never read as rich markup
        t.add_row(*map(Text, row))
    natural = sum(max([len(n), *(len(r[j]) for r in cells)]) for j, n in enumerate(names))
    console = Console(width=min(width, natural + 3 * len(names) + 1) if names else width,
                      record=True, file=io.StringIO())
    console.print(t)
    return console.export_text()


def printable(text: str) -> str:
    """``text`` with each control character as a visible ``\\xNN`` escape: a value
    cannot move the cursor, colour the terminal or start a line of its own."""
    return _CONTROL.sub(lambda m: f"\\x{ord(m.group()):02x}", text)


def _vertical(names: list[str], cells: list[list[str]], title: str) -> str:
    """One block per row, ``column  value`` per line: for tables wider than the terminal."""
    pad = max(len(n) for n in names)
    out = [title] if title else []
    for i, row in enumerate(cells, start=1):
        out.append(f"-- row {i} " + "-" * max(0, pad - 4))
        out += [f"{n:<{pad}}  {v}" for n, v in zip(names, row, strict=True)]
    if not cells:
        out.append("(no rows)")
    return "\n".join(out) + "\n"


def _numeric(t: pa.DataType) -> bool:
    return pa.types.is_integer(t) or pa.types.is_floating(t)
