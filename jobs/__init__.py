"""Thin entry points composing pipeline stages: ingest, batch, report, reprocess, simulate, demo."""
