"""`surveil experiment`: the identification experiment with the batch association code,
checked against the paper's test and an independently coded closed form."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from jobs.cli import cli
from pipeline.maritime.experiment import (
    closed_form_probability,
    identification_experiment,
    velocity_experiment,
    wilson,
)

REPO = Path(__file__).resolve().parents[2]


def _surveil(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "jobs.cli", *args], capture_output=True,
                          text=True, cwd=REPO, check=False)


def test_closed_form_against_a_brute_force_estimate():
    """The quadrature against a plain Monte Carlo of (s + u) . (s + v) > 0 (no
    association code involved), and its limits."""
    rng = np.random.default_rng(0)
    n, sigma, s = 400_000, 30.0, np.array([50.0, 0.0])
    u = rng.normal(0, math.sqrt(2) * sigma, (n, 2))
    v = rng.normal(0, math.sqrt(2) * sigma, (n, 2))
    brute = np.mean(np.einsum("ij,ij->i", s + u, s + v) > 0)
    assert closed_form_probability(sigma, 50.0, 0.0) == pytest.approx(brute, abs=0.003)
    assert closed_form_probability(10.0, 1000.0, 0.0) == pytest.approx(1.0, abs=1e-9)
    assert closed_form_probability(40.0, 0.0, 0.0) == pytest.approx(0.5, abs=1e-9)
    # isotropic errors: x and y separations give the same probability
    assert closed_form_probability(20.0, 0.0, 30.0) == pytest.approx(
        closed_form_probability(20.0, 30.0, 0.0), abs=1e-12)


@pytest.mark.parametrize(("sigma", "dx", "dy"), [(20.0, 30.0, 0.0), (40.0, 0.0, 50.0)])
def test_batch_association_reproduces_the_closed_form(cfg, sigma, dx, dy):
    r = identification_experiment(cfg, sigma_m=sigma, dx_m=dx, dy_m=dy, trials=2000, seed=3)
    assert r["trials"] == 2000 and 0.5 < r["probability_correct"] < 1.0
    assert r["ci_low"] <= r["closed_form"] <= r["ci_high"], r
    hyp = r["hypothesis_test"]
    assert hyp["ci_low"] <= r["closed_form"] <= hyp["ci_high"], r
    # the batch code is the paper's test plus a gate: it can only lose the rare trials
    # whose correct pair falls outside the gate
    assert hyp["correct"] - 0.01 * r["trials"] <= r["correct"] <= hyp["correct"]


def test_probability_grows_with_separation_over_sigma(cfg):
    p = [identification_experiment(cfg, sigma_m=30.0, dx_m=d, dy_m=0.0, trials=600,
                                   seed=1)["probability_correct"] for d in (30.0, 50.0, 100.0)]
    assert p[0] < p[1] < p[2] and p[2] > 0.95


def test_velocity_raises_the_probability(cfg):
    r = velocity_experiment(cfg, sigma_m=30.0, dx_m=30.0, dy_m=0.0, speed_mps=5.0,
                            course_difference_deg=10.0, trials=1000, seed=2)
    pos, vel = r["position_only"], r["position_velocity"]
    assert vel["ci_low"] > pos["ci_high"], r
    assert pos["ci_low"] <= closed_form_probability(30.0, 30.0, 0.0) <= pos["ci_high"]
    # the batch association with the velocity cost (default) follows the d = 4 test, with
    # the position cost the d = 2 one (same draws; they differ only by the gate)
    batch, batch_pos = r["batch_association"], r["batch_association_position_cost"]
    assert r["batch_velocity_cost"] is True
    assert abs(batch["correct"] - vel["correct"]) <= 5
    assert abs(batch_pos["correct"] - pos["correct"]) <= 5
    assert batch["ci_low"] > batch_pos["ci_high"]


def test_wilson_interval():
    e = wilson(50, 100)
    assert e.ci_low == pytest.approx(0.4038, abs=1e-4) and e.ci_high == pytest.approx(0.5962,
                                                                                        abs=1e-4)
    assert wilson(100, 100).ci_high == 1.0 and wilson(0, 10).ci_low == 0.0


def test_cli_json_and_usage_errors():
    runner = CliRunner()
    res = runner.invoke(cli, ["experiment", "identification", "--sigma", "20", "--dx", "50",
                              "--trials", "400", "--seed", "5", "--format", "json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    assert {"probability_correct", "ci_low", "ci_high", "trials"} <= doc.keys()
    assert doc["trials"] == 400 and doc["ci_low"] <= doc["probability_correct"] <= doc["ci_high"]
    text = runner.invoke(cli, ["experiment", "velocity", "--sigma", "20", "--dx", "30",
                               "--trials", "200"])
    assert text.exit_code == 0 and "position + velocity" in text.output
    bad = _surveil("experiment", "identification", "--sigma", "0", "--trials", "10")
    assert bad.returncode == 2 and "sigma" in bad.stderr and "Traceback" not in bad.stderr


def test_ownship_montecarlo_cli_per_seed_and_summary():
    """`surveil experiment ownship`: seeded per-seed rows (two seeds in one vectorised
    unit, serial) and their summary; the same seeds give the same figures."""
    runner = CliRunner()
    args = ["experiment", "ownship", "--runs", "2", "--first-seed", "4", "--duration", "700s",
            "--executor", "serial", "--format", "json"]
    res = runner.invoke(cli, [*args, "--per-seed"])
    assert res.exit_code == 0, res.output
    rows = json.loads(res.output)
    assert [r["seed"] for r in rows] == [4, 5]
    for r in rows:
        assert r["gyro_max_deg"] > 0.5 and r["heading_rms_deg"] < 0.5  # no turn yet
        assert r["rms_turn_deg"] is None  # 700 s end before the turn at 900 s
    again = json.loads(runner.invoke(cli, [*args, "--per-seed"]).output)
    assert again == rows
    summary = json.loads(runner.invoke(cli, args).output)
    assert summary[0]["seeds"] == 2
    assert summary[0]["rms_max_deg"] == pytest.approx(max(r["heading_rms_deg"] for r in rows))
