"""Issue 35, done when: from real recordings, each as its own site, `import` -> `config
init` -> `ingest` -> `batch` -> `report` -> `audit` with no hand-written config, no
traceback, no fault flagged that the data does not show, and every empty section saying
why. Real `surveil` processes (tests/realdata/site_walk.py), one walk per class of input:
an AIS log with its receiver's GPS, an AIS CSV export, a sailing yacht's NMEA log, a real
ASTERIX CAT062 capture, and an SMR + MLAT capture (the development set has only single
CAT010 blocks: the airfield scenario's CAT010 records written as a raw capture without
truth, its fault schedule in it). Skips when ../shared/data/real is absent."""

from __future__ import annotations

import json
from pathlib import Path

import polars as pl
import pytest

from pipeline.audit.data import collect
from pipeline.families import load_config
from pipeline.reports import open_warehouse, run_named_report
from tests.real_data import real_data_dir
from tests.realdata.site_walk import Walk, walk, write_cat010_capture

pytestmark = pytest.mark.realdata

REPORTS = ("accuracy_by_sector", "identification_by_sector", "siap_by_sector", "gap_forecasts",
           "surface_accuracy_by_area", "channel_faults_by_sector", "nav_quality",
           "fault_timeline")
FAMILIES = ("maritime", "airfield", "gaps", "nav")
CAPTURE_S = 1500.0  # 25 minutes: the demo schedule's first SMR jamming, 20:00-23:00
CAPTURE_FAULTS_S = {"SMR": [(1200.0, 1380.0)], "MLAT": []}
GENERIC = "but none the report keeps"  # the old catch-all when no cause was found

# recording -> (site, families that must run)
RECORDINGS = {
    "ais/gpsd_ais-nmea.log": ("nl-receiver", {"maritime", "nav"}),
    "ais/csv/stonesoup_SolentAIS_20160112_130211.csv": ("solent", {"maritime", "gaps"}),
    "nav/signalk_plaka_first20000lines.log": ("plaka", {"nav"}),
    "asterix/croatiacontrol_asterix.pcap": ("cat062", set()),
}


def _walk(tmp_path_factory: pytest.TempPathFactory, rel: str) -> Walk:
    site, _ = RECORDINGS[rel]
    return walk(real_data_dir() / rel, tmp_path_factory.mktemp(site), site, reports=REPORTS)


@pytest.fixture(scope="module", params=sorted(RECORDINGS))
def real_walk(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory):
    return request.param, _walk(tmp_path_factory, request.param)


@pytest.fixture(scope="module")
def capture_walk(tmp_path_factory: pytest.TempPathFactory) -> Walk:
    real_data_dir()  # the same skip as the real walks
    root = tmp_path_factory.mktemp("tower")
    cap = write_cat010_capture(root / "in" / "tower.ast", duration_s=CAPTURE_S, seed=11)
    return walk(cap, root / "walk", "tower", base_time="2026-01-15T00:00:00Z",
                reports=REPORTS)


def _check_walk(w: Walk, must_run: set[str]) -> None:
    """No traceback, the exit codes of the docs, a config that loads, one line per family
    the batch skips, every empty report saying why (no simulator hint, no catch-all)."""
    for s in [*w.steps, *w.reports.values()]:
        assert not s.traceback(), f"{s.command}\n{s.err}"
        assert s.code in (0, 1), f"{s.command} -> {s.code}\n{s.err}"
        if s.code == 1:  # only ingest and import, and only for rejected pieces
            assert s.args[0] in ("ingest", "import") and "reject" in s.out, s.out
    assert [s.args[0] for s in w.steps][-4:] == ["config", "ingest", "batch", "audit"]
    cfg = load_config(w.config)
    text = w.config.read_text()
    assert "[[channel_faults]]" not in text and "position_ar =" not in text
    batch = w.step("batch").out
    for fam in FAMILIES:  # one line per family the site lacks (gaps: where AIS is)
        skipped = f"{fam}: skipped" in batch
        assert skipped == (fam not in must_run and fam != "gaps") or fam == "gaps", (fam, batch)
    if "maritime" in must_run and not cfg.radar_sites:
        assert "maritime: no radar site declared" in batch
    reasons = w.empty_reports()
    for name, why in reasons.items():
        assert why and "simulate" not in why and GENERIC not in why, (name, why)
    for name, s in w.reports.items():
        rows = json.loads(s.out or "[]")
        assert rows or name in reasons, f"{name}: no rows and no reason\n{s.err}"


def _audit_reasons(w: Walk) -> tuple[dict[str, str], tuple]:
    frm, to = (int(x) for x in w.window)
    con = open_warehouse(w.warehouse)
    try:
        data = collect(con, load_config(w.config), w.warehouse, start_ns=frm, end_ns=to,
                       site=w.site)
    finally:
        con.close()
    return dict(data.empty_reasons), data.verdicts


def test_real_recording_walks_from_import_to_audit(real_walk):
    rel, w = real_walk
    _, must_run = RECORDINGS[rel]
    _check_walk(w, must_run)
    reasons, verdicts = _audit_reasons(w)
    for name, why in reasons.items():
        assert why and "simulate" not in why and GENERIC not in why, (name, why)
    # none of these sites has a radar: its maritime verdicts are not applicable, not short
    # of samples (was: "not enough samples" where the truth was "no radar at this site")
    maritime = [v for v in verdicts if v.report != "surface_accuracy_by_area"]
    assert all(v.status == "not applicable: no radar at this site" for v in maritime)
    assert "not applicable" in w.step("audit").out
    # no radar and no airfield channel at these sites: no such fault can be flagged
    faults = json.loads(w.reports["channel_faults_by_sector"].out or "[]")
    assert {r["family"] for r in faults} <= {"maritime", "nav"}
    assert {r["sensor_kind"] for r in faults} <= {"ais", "gnss"}


def test_an_ais_log_shorter_than_the_gap_threshold_says_so(tmp_path_factory):
    """Was: gap_forecasts blamed system_tracks when the log was shorter than
    [gaps] gap_threshold_s."""
    w = _walk(tmp_path_factory, "ais/gpsd_ais-nmea.log")
    why = w.empty_reports()["gap_forecasts"]
    con = open_warehouse(w.warehouse)
    try:
        (first, last), = con.sql("SELECT min(time_ns), max(time_ns) FROM ais_reports").fetchall()
    finally:
        con.close()
    length_s = (last - first) / 1e9
    assert 60 < length_s < 600  # the log is a few minutes long (its real receive times)
    assert f"the AIS log is {length_s:,.0f} s long" in why and "gap_threshold_s = 600 s" in why, why
    assert "system_tracks" not in why


def test_an_smr_mlat_capture_walks_and_flags_only_the_faults_it_holds(capture_walk):
    w = capture_walk
    _check_walk(w, {"airfield"})
    text = w.config.read_text()
    assert 'kind = "smr"' in text and 'kind = "mlat"' in text and "UNKNOWN" in text
    assert "estimated from its reports against the MLAT" in text
    con = open_warehouse(w.warehouse)
    try:
        models = con.sql("SELECT DISTINCT error_model FROM channel_health").fetchall()
        t0 = con.sql("SELECT min(time_ns) FROM airfield_obs").fetchall()[0][0]
    finally:
        con.close()
    assert models and all(m.startswith("default ") for (m,) in models)  # every row says so
    frm, to = (int(x) for x in w.window)
    eps = pl.from_arrow(run_named_report(w.warehouse, "channel_fault_episodes", start_ns=frm,
                                         end_ns=to, site=w.site))
    eps = eps.with_columns(((pl.col("start_ns") - t0) / 1e9).alias("start_s"))
    long_ = eps.filter(pl.col("duration_s") >= 30)
    # every long episode is an injected fault, and the injected SMR jamming is one
    for kind, start_s in zip(long_["sensor_kind"], long_["start_s"], strict=True):
        windows = CAPTURE_FAULTS_S[kind.upper()]
        assert any(a - 5 <= start_s <= b for a, b in windows), (kind, start_s)
    smr = long_.filter(pl.col("sensor_kind") == "smr")
    assert smr.height == 1 and abs(smr["start_s"][0] - 1200.0) < 5
    reasons, verdicts = _audit_reasons(w)
    assert all("simulate" not in why for why in reasons.values())
    assert {v.status for v in verdicts if v.report == "surface_accuracy_by_area"} == {
        "not applicable: no reference (airfield_truth) at this site: accuracy and "
        "identification are scored against one"}


def test_the_walk_finds_every_recording(tmp_path):
    assert all((real_data_dir() / rel).is_file() for rel in RECORDINGS)
    assert Path(__file__).with_name("site_walk.py").is_file()
