"""Our message layouts are declared once, by their JSON schemas (pipeline.messages): the
generated .proto and .msg files are what the generator writes, and every field list of
the decoders and simulators is the schema's."""

from __future__ import annotations

import re

import pytest

from pipeline.messages import (
    RADAR_REPORT,
    generated_files,
    message_layout,
    write_generated,
)
from pipeline.resources import resource_path

SCHEMAS = sorted(p.name for p in resource_path("schemas").glob("*.schema.json"))


@pytest.mark.parametrize("name", sorted(generated_files()))
def test_generated_files_are_checked_in_as_generated(name, tmp_path):
    """Regenerate with ``python -m pipeline.messages`` after editing a JSON schema."""
    write_generated(tmp_path)
    checked_in = (resource_path("schemas") / name).read_bytes()
    assert (tmp_path / name).read_bytes() == checked_in


@pytest.mark.parametrize("file_name", SCHEMAS)
def test_every_channel_schema_is_a_layout(file_name):
    layout = message_layout(file_name)
    assert layout.name.startswith("surveil.") and layout.fields
    assert set(layout.required) <= set(layout.names)
    assert layout.data == (resource_path("schemas") / file_name).read_bytes()


def test_proto_text_and_descriptor_set_agree_with_the_schema():
    from google.protobuf.descriptor_pb2 import FileDescriptorSet

    from pipeline.decode.radar_binary import radar_descriptor_set

    layout = message_layout(RADAR_REPORT)
    text = (resource_path("schemas") / "radar_track_report.proto").read_text()
    declared = re.findall(r"^\s+(\w+) (\w+) = (\d+);", text, flags=re.M)
    expected = [(f.proto_type, f.name, str(k)) for k, f in enumerate(layout.fields, start=1)]
    assert declared == expected
    (file,) = FileDescriptorSet.FromString(radar_descriptor_set()).file
    names = {1: "double", 3: "int64", 8: "bool", 9: "string"}
    got = [(names[f.type], f.name, str(f.number)) for f in file.message_type[0].field]
    assert got == expected


def test_ros2_msg_agrees_with_the_schema():
    from pipeline.decode.radar_binary import radar_ros2_text, ros2_fields

    layout = message_layout(RADAR_REPORT)
    kinds = {"integer": "i8", "number": "f8", "string": "str", "boolean": "bool"}
    got = [(f.name, f.kind) for f in ros2_fields(radar_ros2_text())]
    assert got == [(f.name, kinds[f.type]) for f in layout.fields]


def _python_field_lists() -> list[tuple[str, dict, str, tuple[str, ...]]]:
    """(what, field dict, schema file, fields the dict leaves out on purpose)."""
    from pipeline.decode import ais_json, fault_truth, ownship, radar, truth, vasn
    from pipeline.simulate import channel, channel_faults

    sim_radar = {k: v for k, v in channel.RADAR_REPORT_SCHEMA.items() if k != "log_time_ns"}
    return [
        ("decode.radar.RADAR_FIELDS", radar.RADAR_FIELDS, RADAR_REPORT, ("status",)),
        ("simulate.channel.RADAR_REPORT_SCHEMA", sim_radar, RADAR_REPORT, ()),
        ("decode.truth.TRUTH_FIELDS", truth.TRUTH_FIELDS, "truth_state.schema.json", ()),
        ("simulate.channel.TRUTH_SCHEMA", channel.TRUTH_SCHEMA, "truth_state.schema.json", ()),
        ("decode.vasn.VASN_FIELDS", vasn.VASN_FIELDS, "vasn_report.schema.json", ("last",)),
        ("decode.vasn.TRUTH_FIELDS", vasn.TRUTH_FIELDS, "airfield_truth.schema.json", ()),
        ("decode.ownship.GYRO_FIELDS", ownship.GYRO_FIELDS, "gyro_signals.schema.json", ()),
        ("decode.ownship.TRUTH_FIELDS", ownship.TRUTH_FIELDS, "ownship_truth.schema.json", ()),
        ("decode.ais_json.SCHEMA", ais_json.SCHEMA, "ais_report.schema.json", ()),
        ("decode.fault_truth.FIELDS", fault_truth.FIELDS, "fault_truth.schema.json", ()),
        ("simulate.channel_faults.FAULT_TRUTH_SCHEMA", channel_faults.FAULT_TRUTH_SCHEMA,
         "fault_truth.schema.json", ()),
    ]


@pytest.mark.parametrize("what, fields, file_name, omitted", _python_field_lists())
def test_python_field_lists_are_the_schemas(what, fields, file_name, omitted):
    """Names, order and types of every Python field list equal its schema's."""
    layout = message_layout(file_name)
    expected = [(f.name, f.polars_type) for f in layout.fields if f.name not in omitted]
    assert list(fields.items()) == expected, what


def test_polars_schema_refuses_an_unknown_omission():
    with pytest.raises(KeyError, match="no field 'state'"):
        message_layout(RADAR_REPORT).polars_schema(omit=("state",))
