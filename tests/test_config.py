"""The config file: the shipped config parses to the objects it always gave; the
declared-values reader (pipeline/configspec.py)."""

from __future__ import annotations

import dataclasses
import math
import pickle
from pathlib import Path

import pytest

from pipeline.config import AisConfig, Config
from pipeline.configspec import ConfigError, Document, locate_line, render_path, setting
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


# --- the reader's pieces ---------------------------------------------------------------------


def test_render_path():
    assert render_path(("airfield", "sensors", 1, "pd")) == "[airfield.sensors][1].pd"
    assert render_path(("radar_sites", 2, "sigma_range_m")) == "[radar_sites][2].sigma_range_m"
    assert render_path(("execution", "max_workers")) == "[execution].max_workers"
    assert render_path(("airfield", "filter"), table=True) == "[airfield.filter]"
    assert render_path(("fairway_legs", 0, "start", 1)) == "[fairway_legs][0].start[1]"


def test_locate_line():
    text = ("# c\ntop = 1\n[a]\nx = 1\n[[b]]\ny = 1\n[[b]]\nz = 2\ny = 3\n"
            "[a.c]\n'q' = { r = 1 }\n")
    assert locate_line(text, ("top",)) == 2
    assert locate_line(text, ("a", "x")) == 4
    assert locate_line(text, ("a", "nope")) == 3
    assert locate_line(text, ("b", 1, "y")) == 9
    assert locate_line(text, ("b", 0, "y")) == 6
    assert locate_line(text, ("b",)) == 5
    assert locate_line(text, ("a", "c", "q", "r")) == 11
    assert locate_line(text, ("zzz", "k")) is None


def test_declared_conversions_and_ranges_in_memory():
    @dataclasses.dataclass(frozen=True)
    class Demo:
        heading_rad: float = setting(90.0, unit="deg", ge=0.0, lt=360.0)
        n: int = setting(3, ge=1)
        pair: tuple[float, float] = setting([1.0, 2.0], ge=0.0)

    assert Demo() == Demo(math.radians(90.0), 3, (1.0, 2.0))
    doc = Document({"demo": {"heading_deg": 180, "pair": [0.5, 4.0]}}, "mem")
    assert doc.read(Demo, "demo") == Demo(math.pi, 3, (0.5, 4.0))
    doc.finish()
    doc = Document({"demo": {"heading_deg": 360.0, "n": 0, "pair": [1.0, -1.0], "x": 1}}, "mem")
    assert doc.read(Demo, "demo") is None
    with pytest.raises(ConfigError) as exc:
        doc.finish()
    assert str(exc.value).splitlines() == [
        "mem: [demo].heading_deg: must be in [0, 360), got 360",
        "mem: [demo].n: must be >= 1, got 0",
        "mem: [demo].pair: element [1] must be >= 0, got -1",
        "mem: [demo] unknown key 'x'",
    ]
