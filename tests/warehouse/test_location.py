"""A warehouse location is a local path or an s3:// prefix (issue 39, item 1): parsing
(an unknown scheme is refused, never a folder named ``s3:``), storage options from the
environment and the config (never printed), and on a real S3-compatible server
(moto's, tests/s3_server.py) the pieces a job relies on: pending markers, the lease
lock, a staged commit read back equal to local disk."""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import UsageError
from pipeline.warehouse import pending
from pipeline.warehouse.delta import read_table, table_exists
from pipeline.warehouse.location import Location, as_location, checked_warehouse, parse_location
from pipeline.warehouse.staged import TableStager, commit_window
from tests.warehouse.test_commit_window import T0_NS, truth_rows

ROOT = Path(__file__).resolve().parents[2]
S = 10**9


def test_a_local_path_stays_the_path_it_was(tmp_path):
    loc = parse_location(tmp_path / "wh")
    assert loc.is_local and Path(loc) == tmp_path / "wh" and str(loc / "tables") == str(
        tmp_path / "wh" / "tables")
    assert parse_location(f"file://{tmp_path}/wh") == loc
    assert loc.storage_options == {}


@pytest.mark.parametrize("uri", ["gs://b/wh", "az://c/wh", "http://host/wh", "S3X://b/wh"])
def test_an_unknown_scheme_is_a_usage_error(uri):
    with pytest.raises(UsageError, match="unknown scheme"):
        parse_location(uri)


def test_an_s3_location_is_no_local_path():
    loc = parse_location("s3a://surveil/wh/")
    assert loc.uri == "s3://surveil/wh" and not loc.is_local
    assert (loc / "tables" / "truth").fs_path == "surveil/wh/tables/truth"
    with pytest.raises(TypeError, match="object storage"):
        Path(loc)
    with pytest.raises(UsageError, match="no bucket"):
        parse_location("s3:///wh")


def test_ingest_into_an_unknown_scheme_is_exit_2_and_makes_no_folder(tmp_path):
    """On the code before, `--warehouse gs://surveil/wh` made ./gs:/surveil/wh and
    ingested there (exit 0)."""
    res = subprocess.run(
        [sys.executable, "-m", "jobs.cli", "--warehouse", "gs://surveil/wh", "ingest",
         str(tmp_path / "none.mcap")], cwd=tmp_path, capture_output=True, text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)}, check=False, timeout=120)
    assert res.returncode == 2, res.stderr
    assert "unknown scheme 'gs'" in res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_storage_options_the_config_over_the_environment_never_shown(monkeypatch):
    monkeypatch.setenv("AWS_ENDPOINT_URL", "http://127.0.0.1:9")
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", "from-env")
    monkeypatch.setenv("AWS_REGION", "eu-north-1")
    loc = checked_warehouse("s3://b/wh", {"AWS_SECRET_ACCESS_KEY": "from-config",
                                          "endpoint": "https://store.example:9000"})
    o = loc.storage_options
    assert o["aws_secret_access_key"] == "from-config" and o["aws_region"] == "eu-north-1"
    assert o["aws_endpoint_url"] == "https://store.example:9000"
    assert o["aws_conditional_put"] == "etag"  # Delta's commits: If-None-Match
    assert "from-config" not in repr(loc) and "from-config" not in str(loc)
    # pickled for a worker: the config's options travel, the environment's do not
    back = pickle.loads(pickle.dumps(loc / "tables"))
    assert back.config_options == {"aws_secret_access_key": "from-config",
                                   "aws_endpoint_url": "https://store.example:9000"}
    assert b"from-env" not in pickle.dumps(loc)


def test_config_check_masks_the_credentials(tmp_path):
    src = (ROOT / "config" / "surveil.toml").read_text()
    assert '[warehouse]\npath = "warehouse"' in src
    cfg = tmp_path / "s3.toml"
    cfg.write_text(src.replace('[warehouse]\npath = "warehouse"', (
        '[warehouse]\npath = "s3://surveil/wh"\nstorage_options = { aws_endpoint_url = '
        '"http://127.0.0.1:9000", aws_access_key_id = "KEYID-42", '
        'aws_secret_access_key = "TOPSECRET-42" }')))
    res = subprocess.run([sys.executable, "-m", "jobs.cli", "config", "check", str(cfg)],
                         capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT)},
                         check=False, timeout=120)
    assert res.returncode == 0, res.stderr
    assert "TOPSECRET-42" not in res.stdout and "KEYID-42" not in res.stdout
    assert 'aws_secret_access_key = "***"' in res.stdout
    assert 'aws_endpoint_url = "http://127.0.0.1:9000"' in res.stdout
    from pipeline.families import load_config

    loaded = load_config(cfg)
    assert loaded.warehouse_storage_options["aws_secret_access_key"] == "TOPSECRET-42"
    assert "TOPSECRET-42" not in repr(loaded)


# --- on the S3 server -------------------------------------------------------------------


def _stage(folder, t_ns: np.ndarray, speed: float):
    st = TableStager(folder, threaded=False)
    st.add("truth", truth_rows(t_ns, speed=speed))
    return st.close()


def test_a_staged_window_commit_on_s3_reads_as_on_local_disk(s3, tmp_path):
    bucket = s3.bucket()
    wh_s3 = parse_location(f"s3://{bucket}/wh")
    t = T0_NS + np.arange(0, 120) * S
    for wh in (tmp_path / "wh", wh_s3):
        staging = as_location(wh) / "_staging" / "x"
        commit_window(wh, "truth", _stage(staging / "a", t, 1.0), start_ns=T0_NS,
                      end_ns=T0_NS + 120 * S)
        # a window inside: the straddling file is rewritten without it, the new one added
        commit_window(wh, "truth", _stage(staging / "b", t[30:60], 2.0), start_ns=t[30],
                      end_ns=t[60])
    assert table_exists(wh_s3, "truth")
    local, remote = read_table(tmp_path / "wh", "truth"), read_table(wh_s3, "truth")
    assert remote.num_rows == 120 and remote.equals(local)
    keys = s3.keys(bucket, "wh/")
    assert any(k.startswith("wh/tables/truth/_delta_log/") for k in keys)
    # moved into the table (pyarrow may leave empty "folder/" marker objects behind)
    assert not [k for k in keys if k.startswith("wh/_staging/") and not k.endswith("/")]


def test_pending_markers_pin_readers_on_s3(s3):
    wh = parse_location(f"s3://{s3.bucket()}/wh")
    t = T0_NS + np.arange(0, 10) * S
    commit_window(wh, "truth", _stage(wh / "_staging" / "a", t, 1.0), start_ns=T0_NS,
                  end_ns=T0_NS + 10 * S)
    marker = pending.begin(wh, ["truth"], job="batch", window=[0, 1])
    assert pending.pinned_versions(wh) == {"truth": 0}
    commit_window(wh, "truth", _stage(wh / "_staging" / "b", t, 2.0), start_ns=T0_NS,
                  end_ns=T0_NS + 10 * S)
    assert set(read_table(wh, "truth")["speed_mps"].to_pylist()) == {1.0}  # pinned: old
    pending.finish(wh, marker)
    assert pending.markers(wh) == []
    assert set(read_table(wh, "truth")["speed_mps"].to_pylist()) == {2.0}


def test_the_lease_lock_excludes_a_second_writer_and_is_taken_over_once_expired(s3):
    from pipeline.warehouse.lock import ObjectLease, WarehouseLockedError, holder

    wh = parse_location(f"s3://{s3.bucket()}/wh")
    first = ObjectLease(wh / ".surveil.lock", command="surveil batch", lease_s=2.0)
    first.acquire(wait=False)
    assert holder(wh)["command"] == "surveil batch"
    with pytest.raises(WarehouseLockedError, match="surveil batch"):
        ObjectLease(wh / ".surveil.lock", command="surveil run", lease_s=2.0).acquire(False)
    first.release()  # released: the next takes it at once
    second = ObjectLease(wh / ".surveil.lock", command="surveil run", lease_s=2.0)
    second.acquire(wait=False)
    # a holder that dies (never renews nor releases): free again once its lease is over
    time.sleep(2.5)
    third = ObjectLease(wh / ".surveil.lock", command="surveil ingest", lease_s=2.0)
    third.acquire(wait=False)
    assert holder(wh)["command"] == "surveil ingest"
    third.release()


def test_a_location_is_the_same_after_a_trip_through_pickle():
    loc = Location("s3://b/wh", {"aws_region": "eu-north-1"}.items())
    assert pickle.loads(pickle.dumps(loc)) == loc and hash(loc) == hash(Location(
        "s3://b/wh", [("AWS_REGION", "eu-north-1")]))


def test_a_warehouse_path_with_a_comma_is_exit_2_before_any_write(tmp_path):
    """Was: ingest into ``.../w,c`` committed its tables, then the views file (DuckDB's
    comma-separated ``file_search_path``) failed with a traceback."""
    import subprocess
    import sys

    with pytest.raises(UsageError, match="holds ','"):
        checked_warehouse(tmp_path / "w,c")
    res = subprocess.run([sys.executable, "-m", "jobs.cli", "--warehouse", str(tmp_path / "w,c"),
                          "ingest", str(tmp_path / "none.mcap")], cwd=ROOT, capture_output=True,
                         text=True, check=False)
    assert res.returncode == 2 and "holds ','" in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "w,c").exists()
