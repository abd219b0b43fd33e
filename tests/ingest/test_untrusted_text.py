"""Issue 40 item 4: untrusted text stays text.

A string from data (an AIS name, a site, a topic, a file name) is printed as written by
every table-format output, never parsed as rich markup; the audit page's metadata block
stays inside its script element; an MCAP file whose metadata names a site that is not a
site name is refused alone (quarantined, a rejects row saying why), the other files of
the run kept."""

from __future__ import annotations

import json

import polars as pl
import pyarrow as pa
import pytest

from pipeline.audit.page import script_json
from pipeline.ingest.driver import run_ingest
from pipeline.render import format_report
from pipeline.warehouse.delta import read_table
from tests.jobs.test_cli import surveil
from tests.mcap_fixtures import radar_messages, write_mcap

HOSTILE = ["[/]", "[#FF0]", "[bold]MV NORD[/bold]", "[link=http://x]y", "a\x1b[31mred"]


@pytest.mark.parametrize("width", [200, 12])  # a table, and the row blocks of a narrow one
def test_a_table_prints_markup_like_values_as_written(width):
    table = pa.table({"ship_name": HOSTILE, "[b]col": list(range(len(HOSTILE)))})
    text = format_report(table, "table", title="[/]", width=width)
    for value in HOSTILE[:4]:
        assert value in text
    assert "[b]col" in text
    assert "\x1b" not in text and "a\\x1b[31mred" in text  # no escape reaches the terminal


def test_csv_and_json_keep_the_values():
    table = pa.table({"ship_name": HOSTILE})
    assert json.loads(format_report(table, "json")) == [{"ship_name": v} for v in HOSTILE]
    assert pl.read_csv(format_report(table, "csv").encode())["ship_name"].to_list() == HOSTILE


def test_surveil_sql_prints_a_closing_tag_value(e2e):
    res = surveil("--warehouse", str(e2e.warehouse), "sql", "SELECT '[/]' AS name, "
                  "'[#FF0]' AS colour, '[bold]x' AS b")
    assert res.returncode == 0, res.stderr
    assert "[/]" in res.stdout and "[#FF0]" in res.stdout and "[bold]x" in res.stdout


def test_the_audit_metadata_block_cannot_close_its_script():
    text = script_json({"sector": "</script><script>alert(1)</script>", "charts": 3})
    assert "<" not in text and ">" not in text
    assert json.loads(text)["sector"] == "</script><script>alert(1)</script>"


@pytest.mark.parametrize("site", [None, "harbour"])  # with and without ingest --site
def test_a_file_whose_metadata_site_is_invalid_is_refused_alone(tmp_path, cfg, site):
    good = write_mcap(tmp_path / "good.mcap", radar_messages(20),
                      metadata={"surveil": {"site": "harbour"}})
    bad = write_mcap(tmp_path / "bad.mcap", radar_messages(20, site="R2"),
                     metadata={"surveil": {"site": "[/]"}})
    wh = tmp_path / "wh"
    s = run_ingest([good, bad], cfg, wh, executor="serial", site=site)
    assert (s.files_ok, s.files_quarantined, s.exit_code) == (1, 1, 1), s.render()
    assert s.rejects == {"invalid_site": 1}
    assert f"QUARANTINED {bad}" in s.render() and "'[/]'" in s.render()
    radar = pl.from_arrow(read_table(wh, "radar_tracks"))
    assert radar["source_file"].unique().to_list() == [str(good)]
    assert radar["site"].unique().to_list() == ["harbour"]
    rejects = pl.from_arrow(read_table(wh, "rejects")).filter(pl.col("source_file") == str(bad))
    assert rejects["reason_code"].to_list() == ["invalid_site"]
    assert "1-64 letters" in rejects["reason"][0]
    ledger = pl.from_arrow(read_table(wh, "ingest_ledger")).filter(
        pl.col("source_file") == str(bad))
    assert ledger["status"].to_list() == ["quarantined"]


def test_a_file_name_with_control_characters_is_shown_escaped_in_the_summary(tmp_path, cfg):
    """The ingest summary prints the archive's file names (QUARANTINED lines, warnings):
    a name carrying a terminal escape or a newline cannot colour the terminal or forge a
    line of its own (the code before printed it raw)."""
    evil = tmp_path / "in" / "x\x1b[2J\nexit code 0.mcap"
    evil.parent.mkdir()
    evil.write_bytes(b"not an mcap file at all")
    text = run_ingest([evil.parent], cfg, tmp_path / "wh", executor="serial").render()
    assert "QUARANTINED" in text
    assert "\x1b" not in text and "x\\x1b[2J\\x0aexit code 0.mcap" in text
    assert text.splitlines()[-1] == "exit code 1"
