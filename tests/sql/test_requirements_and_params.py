"""[requirements] are validated at load and bound as report parameters (no limits in
SQL); report headers declare parameters; user report folders list beside sql/."""

from __future__ import annotations

import tomllib

import pytest

from pipeline.config import ConfigError
from pipeline.families import config_from_mapping
from pipeline.render import format_report
from pipeline.reports import (
    ReportError,
    list_reports,
    load_report,
    parse_params,
    reports_config,
    run_named_report,
)
from pipeline.requirements import (
    FAIL,
    NOT_ENOUGH,
    PASS,
    RequirementsConfig,
    evaluate,
    requirements_config,
    rule_of_three_samples,
)
from pipeline.resources import resource_path


def _raw() -> dict:
    return tomllib.loads((resource_path("config") / "surveil.toml").read_text())


def test_shipped_requirements_are_the_ed87_figures(cfg):
    req = requirements_config(cfg)
    assert req.ed87_position_p95_m == {"manoeuvring": 12.0, "apron_taxiway": 20.0, "stand": 25.0}
    assert req.p_identification == 0.999 and req.sensor_position_p95_m == 7.5
    assert req.p_identification_min_samples == rule_of_three_samples(0.999) == 3000


@pytest.mark.parametrize("section, match", [
    ({"ed87_position_p95_m": {"stand": -1}}, r"ed87_position_p95_m\]\.stand: must be > 0"),
    ({"ed87_position_p95_m": {"manoeuvring": 12, "apron_taxiway": 20, "stand": 25,
                              "hangar": 3}}, "unknown key 'hangar'"),
    ({"airfield": {"p_identification": 1.5}}, r"p_identification: must be in \(0, 1\]"),
    ({"maritime": {"position_p95": 10}}, "did you mean 'position_p95_m'"),
    ({"min_samples": 0}, "min_samples: must be >= 1"),
    ({"typo": 1}, "unknown key 'typo'"),
])
def test_bad_requirements_fail_the_load(section, match):
    raw = _raw()
    raw["requirements"] = section
    with pytest.raises(ConfigError, match=match):
        config_from_mapping(raw)


def test_limits_are_bound_not_written_in_sql(e2e):
    import re

    body = re.sub(r"--[^\n]*", "", load_report("surface_accuracy_by_area").text)
    for literal in ("12.0", "20.0", "25.0", "7.5", "0.999"):
        assert literal not in body
    raw = _raw()
    raw["requirements"]["ed87_position_p95_m"]["stand"] = 30.0
    raw["requirements"]["airfield"] = {"p_identification": 0.99}
    cfg = config_from_mapping(raw)
    req = requirements_config(cfg)
    assert req.sql_params()["ed87_stand_p95_m"] == 30.0
    assert req.sql_params()["p_identification_min"] == 0.99
    assert req.p_identification_min_samples == 300  # rule of three for the new P


def test_verdicts_pass_fail_and_not_enough_samples():
    req = RequirementsConfig(min_samples=10)
    import pyarrow as pa

    acc = pa.table({"sector": ["a", "b", "c"], "source": ["fused"] * 3,
                    "reference": ["truth"] * 3, "samples": [100, 100, 5],
                    "p95_error_m": [50.0, 150.0, 10.0]})
    got = {v.scope: v.status for v in evaluate({"accuracy_by_sector": acc}, req,
                                               sectors=["a", "b", "c", "d"], airfield=False)
           if v.report == "accuracy_by_sector"}
    assert got == {"a, fused": PASS, "b, fused": FAIL, "c, fused": NOT_ENOUGH,
                   "d, fused": NOT_ENOUGH}


def test_header_parameters():
    params = parse_params("$start_ns (BIGINT, inclusive), $end_ns (BIGINT), $sector (VARCHAR),"
                          " $a, $b (DOUBLE, from [requirements]), $step_s (DOUBLE, default 20)")
    by = {p.name: p for p in params}
    assert by["a"].sql_type == by["b"].sql_type == "DOUBLE"
    assert by["step_s"].default == "20" and by["step_s"].convert("7.5") == 7.5
    with pytest.raises(ReportError):
        by["start_ns"].convert("soon")


def test_user_report_folder(tmp_path, e2e):
    folder = tmp_path / "my_reports"
    folder.mkdir()
    (folder / "fused_points.sql").write_text(
        "-- name: fused_points\n-- description: fused points per sector, mine\n"
        "-- grain: one row per sector\n-- params: $start_ns (BIGINT), $end_ns (BIGINT), "
        "$min_n (BIGINT, default 1)\n"
        "SELECT coalesce(sector, '-') AS sector, count(*) AS n FROM system_tracks\n"
        "WHERE time_ns >= $start_ns AND time_ns < $end_ns GROUP BY 1 HAVING count(*) >= $min_n"
        " ORDER BY 1;\n")
    conf = tmp_path / "surveil.toml"
    conf.write_text((resource_path("config") / "surveil.toml").read_text().replace(
        "[reports]\ndirs = []", '[reports]\ndirs = ["my_reports"]'))
    from pipeline.families import load_config

    cfg = load_config(conf)
    assert reports_config(cfg).dirs == (folder.resolve(),)
    assert "fused_points" in list_reports(reports_config(cfg).dirs)
    t = run_named_report(e2e.warehouse, "fused_points", start_ns=e2e.start_ns,
                         end_ns=e2e.end_ns, cfg=cfg, params={"min_n": "100000000"})
    assert t.num_rows == 0
    t = run_named_report(e2e.warehouse, "fused_points", start_ns=e2e.start_ns,
                         end_ns=e2e.end_ns, cfg=cfg)
    assert t.num_rows >= 3
    (folder / "accuracy_by_sector.sql").write_text("-- name: accuracy_by_sector\n")
    with pytest.raises(ReportError, match="defined twice"):
        list_reports(reports_config(cfg).dirs)


def test_a_missing_report_folder_fails_the_load(tmp_path):
    raw = _raw()
    raw["reports"] = {"dirs": [str(tmp_path / "nope")]}
    with pytest.raises(ConfigError, match="not a folder"):
        config_from_mapping(raw)


def test_tables_never_cut_a_number():
    import pyarrow as pa

    t = pa.table({"sector": ["inner_channel"], "value_with_a_long_name_m": [0.0812345678],
                  "note": ["a long free text that may wrap at word boundaries " * 3]})
    wide = format_report(t, "table", width=300)
    assert "0.0812345678" in wide and "…" not in wide
    narrow = format_report(t, "table", width=60)
    assert "0.0812345678" in narrow and "…" not in narrow
    assert all(len(line) <= 60 for line in narrow.splitlines())
