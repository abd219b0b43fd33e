"""Logging for every command: readable on a terminal (rich), JSON lines otherwise."""

from __future__ import annotations

import json
import logging
import sys
from datetime import UTC, datetime


class _JsonLines(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        doc = {
            "time": datetime.fromtimestamp(record.created, UTC).isoformat(),
            "level": record.levelname.lower(),
            "logger": record.name,
            "message": record.getMessage(),
        }
        if record.exc_info:
            doc["exception"] = self.formatException(record.exc_info)
        return json.dumps(doc)


def setup_logging(level: str = "INFO", json_lines: bool | None = None) -> None:
    """Readable logs on a terminal (rich), JSON lines otherwise (cron, orchestrators)."""
    root = logging.getLogger()
    root.handlers.clear()
    root.setLevel(level.upper())
    as_json = (not sys.stderr.isatty()) if json_lines is None else json_lines
    if as_json:
        handler: logging.Handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(_JsonLines())
    else:
        from rich.logging import RichHandler

        handler = RichHandler(show_path=False, rich_tracebacks=False)
    root.addHandler(handler)
