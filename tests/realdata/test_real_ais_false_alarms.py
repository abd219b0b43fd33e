"""AIS integrity on real receivers with real times (issue 36, item 6): every real AIS
recording whose lines carry a time, each as its own site the way docs/site.md walks it
(``import`` -> ``config init`` -> ``ingest`` -> ``batch``, the maritime family, no
hand-written config), flags a share of its AIS reports within [0.5 q, 2 q] at the
config's ``ais_q``. With no radar at these sites every decision is the kinematic
self-test (pipeline/maritime/integrity.py ``self_test``). A file too small to tell
(fewer than 40 flags expected at 0.5 q) is held to its count instead: no more flags
than 2 q makes likely (one-sided p >= 0.001), no fewer than 0.5 q does. Before the
self-test took each report at its time stamp with a variance from its time source, the
shares were 3.5 %, 16.6 % and 62 % (Solent, NAIS-400, AISdb) against q = 1 %.

Skips when ../shared/data/real is absent (set SURVEIL_REAL_DATA)."""

from __future__ import annotations

import math
from pathlib import Path

import polars as pl
import pytest

from pipeline.batch import run_batch
from pipeline.convert.importer import run_import
from pipeline.families import load_config
from pipeline.ingest.driver import run_ingest
from pipeline.maritime.config import maritime_config
from pipeline.siteconfig.init import run_config_init
from pipeline.units import NS
from pipeline.warehouse.delta import read_table
from tests.conftest import real_data_dir

pytestmark = pytest.mark.realdata
HOUR_NS = 3600 * NS

# recording -> (site, the fewest AIS decisions it gives: the test is not vacuous)
RECORDINGS = {
    "ais/csv/stonesoup_SolentAIS_20160112_130211.csv": ("solent", 16_000),
    "ais/signalk_nais400-merrimac.log": ("merrimac", 150),
    # a worldwide feed: the place check refuses it (97 % of its positions beyond 100 km
    # of their median); the self-test does not depend on the origin, so it is batched
    # with --ignore-place
    "ais/aisdb_test_data_20211101.nm4": ("aisdb", 60),
    "ais/gpsd_ais-nmea.log": ("nl-receiver", 100),
    "ais/gpsd_ait250.log": ("ait250", 35),
}
P_MIN = 1e-3


def binomial_tail(k: int, n: int, p: float, *, upper: bool) -> float:
    """P(X >= k) (upper) or P(X <= k) for X ~ Binomial(n, p), summed in log space."""
    terms = range(k, n + 1) if upper else range(0, k + 1)
    return min(1.0, sum(math.exp(math.lgamma(n + 1) - math.lgamma(i + 1) - math.lgamma(n - i + 1)
                                 + i * math.log(p) + (n - i) * math.log1p(-p)) for i in terms))


def walk(recording: Path, root: Path, site: str) -> tuple[pl.DataFrame, float]:
    """import -> config init -> ingest -> batch (maritime): the AIS decisions and q."""
    assert run_import([recording], root / "archive", site=site).exit_code == 0
    cfg_path = root / f"{site}.toml"
    run_config_init(load_config(), [root / "archive"], cfg_path, warehouse=None, name=site)
    cfg = load_config(cfg_path)
    assert not cfg.radar_sites  # AIS only: the self-test alone
    wh = root / "warehouse"
    ingest = run_ingest([root / "archive"], cfg, wh, executor="serial")
    assert ingest.exit_code in (0, 1) and ingest.rows["ais_reports"] > 0  # 1: rejects kept
    t = pl.from_arrow(read_table(wh, "ais_reports", columns=["time_ns"]))["time_ns"]
    lo, hi = int(t.min()) // HOUR_NS * HOUR_NS, (int(t.max()) // HOUR_NS + 1) * HOUR_NS
    b = run_batch(cfg, wh, start_ns=lo, end_ns=hi, executor_kind="serial",
                  families=("maritime",), ignore_place=site == "aisdb")
    assert b.committed and not b.failed_units
    health = pl.from_arrow(read_table(wh, "maritime_channel_health")).filter(
        pl.col("sensor_kind") == "ais")
    return health, maritime_config(cfg).integrity.ais_q


@pytest.mark.parametrize("rel", sorted(RECORDINGS))
def test_real_ais_false_alarms_within_half_to_twice_q(rel, tmp_path):
    path = real_data_dir() / rel
    if not path.is_file():
        pytest.skip(f"{rel} not in the real recordings")
    site, fewest = RECORDINGS[rel]
    health, q = walk(path, tmp_path, site)
    n, k = health.height, int(health["eta"].sum())
    assert set(health["check"].unique()) == {"ais_kinematics"}
    assert n >= fewest, (n, k)
    if n * 0.5 * q >= 40:
        assert 0.5 * q <= k / n <= 2 * q, (n, k, k / n)
    else:
        assert binomial_tail(k, n, 2 * q, upper=True) >= P_MIN, (n, k)
        assert binomial_tail(k, n, 0.5 * q, upper=False) >= P_MIN, (n, k)
