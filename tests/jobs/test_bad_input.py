"""Bad input: the run goes on, good data is kept, every bad item is a rejects row with a
reason, and the summary and exit code say what happened."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import polars as pl
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from jobs.simulate import run_simulate
from pipeline.ingest.driver import run_ingest
from pipeline.units import NS
from pipeline.warehouse.delta import read_table

START = 1_768_435_200 * NS  # 2026-01-15T00:00:00Z


def _radar_payload(**over) -> bytes:
    msg = {
        "site_id": "R1", "track_id": 7, "time_ns": START + NS, "range_m": 5000.0,
        "azimuth_rad": 1.0, "x_m": 4207.3, "y_m": 2701.5, "course_rad": 0.5, "speed_mps": 5.0,
        "sigma_range_m": 15.0, "sigma_azimuth_rad": 0.00785, "sigma_course_rad": 0.035,
        "sigma_speed_mps": 0.25, "scan_period_s": 3.0, "scan_end_azimuth_rad": 6.283185307179586,
    }
    msg.update(over)
    return json.dumps(msg, allow_nan=True).encode()


def write_bad_content(path: Path) -> None:
    """An intact MCAP file whose messages are partly bad."""
    schema_json = (Path(__file__).resolve().parents[2] / "schemas"
                   / "radar_track_report.schema.json").read_bytes()
    with path.open("wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start()
        sid = w.register_schema("surveil.RadarTrackReport", "jsonschema", schema_json)
        radar = w.register_channel("/radar/R1/tracks", "json", sid)
        ais = w.register_channel("/ais/nmea", "nmea0183", 0)
        odd_schema = w.register_schema("acme.Secret", "acmebinary", b"?")
        odd = w.register_channel("/acme/secret", "acmebinary", odd_schema)
        t = START + 2 * NS
        payloads = [
            _radar_payload(),
            _radar_payload(track_id=8, range_m=math.nan),           # NaN coordinate
            _radar_payload(track_id=9, azimuth_rad=123.0),           # impossible azimuth
            b'{"site_id": "R1", "track_id": ',                       # undecodable
            _radar_payload(track_id=10),
        ]
        for i, p in enumerate(payloads):
            w.add_message(radar, log_time=t + i, data=p, publish_time=t + i)
        good = b"!AIVDM,1,1,,A,15M67FC000G?ufbE`FepT@3n00Sa,0*5F"
        bad = b"!AIVDM,1,1,,A,15M67FC000G?ufbE`FepT@3n00Sa,0*5E"    # checksum off by one
        w.add_message(ais, log_time=t + 10, data=good, publish_time=t + 10)
        w.add_message(ais, log_time=t + 11, data=bad, publish_time=t + 11)
        w.add_message(odd, log_time=t + 12, data=b"\x00\x01", publish_time=t + 12)
        w.finish()


def make_archive(root: Path, cfg) -> tuple[Path, Path]:
    archive = root / "archive"
    good = run_simulate("channel", 300.0, 3, archive, cfg, start_ns=START)[0]
    data = good.read_bytes()
    (archive / "truncated.mcap").write_bytes(data[: len(data) // 2])
    (archive / "not_mcap.mcap").write_text("this is a spreadsheet, not an MCAP file\n")
    write_bad_content(archive / "bad_content.mcap")
    return archive, good


def test_bad_input_is_rejected_and_good_data_kept(tmp_path, cfg):
    archive, good = make_archive(tmp_path, cfg)
    warehouse = tmp_path / "wh"
    summary = run_ingest([archive], cfg, warehouse, executor="serial")
    assert summary.exit_code == 1
    text = summary.render()
    assert "quarantined" in text and "partial" in text

    rejects = pl.from_arrow(read_table(warehouse, "rejects"))
    by_file = {Path(f).name: set(g["reason_code"]) for (f,), g in rejects.group_by("source_file")}
    assert "not_mcap" in by_file["not_mcap.mcap"]
    assert by_file["truncated.mcap"] & {"truncated", "corrupt_chunk"}
    assert {"out_of_range", "undecodable", "bad_checksum", "unknown_schema"} <= by_file[
        "bad_content.mcap"]
    assert good.name not in by_file  # the simulator writes clean data

    radar = pl.from_arrow(read_table(warehouse, "radar_tracks"))
    with good.open("rb") as f:
        messages = make_reader(f).iter_messages()
        n_good = sum(1 for _, ch, _ in messages if ch.topic.startswith("/radar"))
    assert radar.filter(pl.col("source_file") == str(good.resolve())).height == n_good
    bad_rows = radar.filter(pl.col("source_file").str.ends_with("bad_content.mcap"))
    assert sorted(bad_rows["local_track_id"]) == [7, 10]
    ledger = {Path(r["source_file"]).name: r["status"]
              for r in read_table(warehouse, "ingest_ledger").to_pylist()}
    assert ledger == {good.name: "ok", "truncated.mcap": "partial",
                      "not_mcap.mcap": "quarantined", "bad_content.mcap": "ok"}


def test_cli_ingest_exit_code_and_summary(tmp_path, cfg):
    archive, _ = make_archive(tmp_path, cfg)
    repo = Path(__file__).resolve().parents[2]
    cmd = [sys.executable, "-m", "jobs.cli", "--warehouse", str(tmp_path / "wh"),
           "ingest", str(archive), "--executor", "serial"]
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=repo, check=False)
    assert res.returncode == 1, res.stderr
    assert "Traceback" not in res.stderr
    assert "quarantined" in res.stdout
