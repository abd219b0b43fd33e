"""pipeline.nav.config: the [ownship] section -> dataclasses (deg -> rad)."""

from __future__ import annotations

import math
import tomllib

import pytest

from pipeline.config import ConfigError
from pipeline.families import config_from_mapping
from pipeline.nav.config import ownship_config
from pipeline.resources import resource_path


def test_shipped_section_parses(cfg):
    oc = ownship_config(cfg)
    assert oc.nav.filter_step_s == 1.0 and oc.nav.gnss_timeout_s == 2.5
    assert oc.model.gyro.mount_height_m == 3.0
    assert oc.model.roll.variance_rad2 == 0.12 and oc.model.roll.frequency_radps == 0.6
    assert oc.model.settings.gnss_accel_sigma_mps2 == 0.019
    assert oc.model.settings.accelerometer_sigma_rad == pytest.approx(math.radians(0.0057))
    assert oc.scenario.initial_heading_rad == pytest.approx(math.pi / 2)
    assert oc.scenario.outages_s == ((960.0, 30.0), (1320.0, 120.0))
    assert oc.nav.gnss_position_sigma_m == pytest.approx(3.22, abs=0.01)


def test_bad_value_is_a_config_error():
    raw = tomllib.loads((resource_path("config") / "surveil.toml").read_text())
    raw["ownship"]["gnss_timeout_s"] = "soon"
    with pytest.raises(ConfigError, match="gnss_timeout_s"):
        config_from_mapping(raw, "test")
