"""Errors the command line maps to exit code 2 (usage or configuration)."""

from __future__ import annotations


class UsageError(ValueError):
    """Bad arguments or inputs the user must fix (exit code 2)."""
