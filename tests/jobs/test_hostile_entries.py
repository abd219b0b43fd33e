"""Issue 40 item 6: exit codes that tell the truth for nonsense parameters, a sector
name that is not a file name, and awkward entries in an archive folder.

`report --param step_s=0 / inf / nan` and `audit --sector 'a/b'` ended in tracebacks;
FIFOs, dangling links and links in an archive folder were skipped without a word and
`ingest` of a FIFO hung. Now: exit 2 with the reason; a FIFO is never opened; every
entry left out is named with why; a link to a regular file is followed."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.audit.page import chart_count
from pipeline.reports import ReportError, load_report
from tests.jobs.test_cli import REPO
from tests.mcap_fixtures import radar_messages, write_mcap


def _surveil(*args: str, timeout_s: float = 120) -> subprocess.CompletedProcess:
    """The CLI with a timeout: a hang (a FIFO opened) fails the test instead of it."""
    return subprocess.run([sys.executable, "-m", "jobs.cli", *args], capture_output=True,
                          text=True, cwd=REPO, check=False, timeout=timeout_s)


@pytest.mark.parametrize("value", ["0", "inf", "nan", "-20", "1e-300"])
def test_a_step_that_cannot_be_used_is_refused(value):
    step = load_report("map_tracks").param("step_s")
    with pytest.raises(ReportError, match=r"\$step_s must be"):
        step.convert(value)


@pytest.mark.parametrize("value", ["0", "inf", "nan"])
def test_report_with_a_nonsense_step_is_exit_2(e2e, value):
    res = _surveil("--warehouse", str(e2e.warehouse), "report", "map_tracks",
                   "--param", f"step_s={value}")
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr and "$step_s must be" in res.stderr


def test_any_double_parameter_must_be_finite():
    p = load_report("dubious_tracks").params
    doubles = [x for x in p if x.sql_type == "DOUBLE"]
    assert doubles
    for x in doubles:
        with pytest.raises(ReportError, match="finite"):
            x.convert("inf")


def test_an_audit_of_a_sector_named_like_a_path_and_a_tag(e2e, tmp_path):
    sector = "a/b</script><b>x"
    config = tmp_path / "surveil.toml"
    text = Path(e2e.cfg.source).read_text()
    assert 'name = "approach_ne"' in text
    config.write_text(text.replace('name = "approach_ne"', f'name = "{sector}"'))
    out = tmp_path / "audit"
    res = _surveil("--config", str(config), "--warehouse", str(e2e.warehouse), "audit",
                   "--from", str(e2e.start_ns), "--to", str(e2e.end_ns), "--sector", sector,
                   "--out", str(out))
    assert res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr
    (page,) = out.iterdir()  # one file, in the folder asked for
    assert page.name.endswith("_a_b__script__b_x.html")
    html = page.read_text()
    assert sector not in html  # escaped everywhere, the metadata block included
    start = html.index("id='audit-meta'>") + len("id='audit-meta'>")
    assert json.loads(html[start:html.index("</script>", start)])["sector"] == sector
    assert chart_count(html) > 0


@pytest.fixture
def awkward_folder(tmp_path) -> Path:
    """A folder with one recording, a link to it, a dangling link, a FIFO and a link to
    a folder, each named like a recording."""
    folder = tmp_path / "archive"
    folder.mkdir()
    real = write_mcap(folder / "real.mcap", radar_messages(30))
    (folder / "link.mcap").symlink_to(real)
    (folder / "dangling.mcap").symlink_to(tmp_path / "gone.mcap")
    os.mkfifo(folder / "pipe.mcap")
    (tmp_path / "elsewhere").mkdir()
    (folder / "dir.mcap").symlink_to(tmp_path / "elsewhere")
    return folder


def test_ingest_of_a_folder_names_what_it_skips_and_never_opens_a_fifo(awkward_folder,
                                                                       tmp_path):
    res = _surveil("--warehouse", str(tmp_path / "wh"), "ingest", str(awkward_folder),
                   "--executor", "serial", timeout_s=120)
    assert res.returncode == 0, res.stdout + res.stderr
    out = res.stdout
    assert "1 files: 1 ok" in out  # the link is its target: one file
    assert f"SKIPPED {awkward_folder / 'pipe.mcap'}: a FIFO" in out
    assert f"SKIPPED {awkward_folder / 'dangling.mcap'}: a dangling symbolic link" in out
    assert f"SKIPPED {awkward_folder / 'dir.mcap'}: a symbolic link to a folder" in out


def test_ingest_of_a_fifo_is_exit_2_at_once(awkward_folder, tmp_path):
    res = _surveil("--warehouse", str(tmp_path / "wh"), "ingest",
                   str(awkward_folder / "pipe.mcap"), timeout_s=60)
    assert res.returncode == 2, res.stderr
    assert "a FIFO (named pipe)" in res.stderr and "Traceback" not in res.stderr


def test_run_over_a_folder_names_what_it_skips(awkward_folder, tmp_path):
    res = _surveil("--warehouse", str(tmp_path / "wh"), "run", str(awkward_folder),
                   "--executor", "serial", timeout_s=300)
    assert "Traceback" not in res.stderr, res.stderr
    out = res.stdout
    assert "1 file(s) ingested" in out, out
    assert f"skipped {awkward_folder / 'pipe.mcap'}: a FIFO" in out
    assert f"skipped {awkward_folder / 'dangling.mcap'}: a dangling symbolic link" in out
    assert f"skipped {awkward_folder / 'dir.mcap'}: a symbolic link to a folder" in out
