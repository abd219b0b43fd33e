"""The config file: the shipped config parses to the objects it always gave."""

from __future__ import annotations

import dataclasses
import math
import pickle
from pathlib import Path

import pytest

from pipeline.config import AisConfig, Config
from pipeline.families import load_config
from pipeline.maritime.config import AssociationConfig

GOLDEN = Path(__file__).parent / "data" / "shipped_config.repr"


# --- the shipped config parses to exactly the objects it gave before ----------------------


def _reprs(cfg: Config) -> str:
    return (repr(cfg).replace(repr(cfg.source), "'<source>'") + "\n"
            + repr(dict(cfg.families)) + "\n")


def test_shipped_config_parses_to_the_same_objects_as_before():
    """tests/data/shipped_config.repr was recorded from the hand-written parsers (9392eae)."""
    assert _reprs(load_config()) == GOLDEN.read_text()


def test_config_dataclasses_stay_frozen_picklable_and_keyword_constructible():
    cfg = load_config()
    again = pickle.loads(pickle.dumps(cfg))
    assert again == cfg and _reprs(again) == _reprs(cfg)
    a = AssociationConfig()
    assert a.max_course_difference_rad == math.radians(30.0)
    assert dataclasses.replace(a, gate_probability=0.99).gate_probability == 0.99
    assert AisConfig(max_report_age_s=5.0).max_report_age_s == 5.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.gate_probability = 0.5  # type: ignore[misc]
