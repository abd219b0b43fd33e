"""Layouts of our own MCAP messages, read from their JSON schemas (``schemas/*.schema.json``).

The JSON schema of a message is its one declaration: it travels in every MCAP file as the
channel's schema, the simulators write exactly its properties in its order, the decoders
take their field lists from it (:meth:`MessageLayout.polars_schema`), and the other
encodings of the radar report are generated from it:

- ``schemas/radar_track_report.proto`` (protobuf ``surveil.RadarTrackReport``) and
- ``schemas/radar_track_report.msg`` (ROS 2 ``surveil_msgs/msg/RadarTrackReport``),

written by ``python -m pipeline.messages`` (``tests/test_messages.py`` checks that the
checked-in files are what it writes, byte for byte). Field numbers (protobuf) and field
order (CDR) follow the order of the schema's properties: they are wire formats, so a new
field goes at the end.

Types (JSON schema -> polars / protobuf / ROS 2): ``integer`` -> Int64 / int64 / int64,
``number`` -> Float64 / double / float64, ``string`` -> String / string / string,
``boolean`` -> Boolean / bool / bool. ``["<type>", "null"]`` marks a nullable field.
Units are in the field names (``_m``, ``_rad``, ``_mps``, ``_s``, ``_ns``); each
property's ``description`` says what the field means.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import polars as pl

from pipeline.resources import resource_path

_POLARS = {"integer": pl.Int64(), "number": pl.Float64(), "string": pl.String(),
           "boolean": pl.Boolean()}  # fmt: skip
_PROTO = {"integer": "int64", "number": "double", "string": "string", "boolean": "bool"}
_ROS2 = {"integer": "int64", "number": "float64", "string": "string", "boolean": "bool"}
# google/protobuf/descriptor.proto FieldDescriptorProto.Type
PROTO_TYPE_NUMBERS = {"int64": 3, "double": 1, "string": 9, "bool": 8}


@dataclass(frozen=True)
class MessageField:
    """One property of a message schema: ``type`` is the JSON schema type (``integer``,
    ``number``, ``string``, ``boolean``), ``nullable`` when ``null`` is allowed too."""

    name: str
    type: str
    nullable: bool
    required: bool
    doc: str

    @property
    def polars_type(self) -> pl.DataType:
        return _POLARS[self.type]

    @property
    def proto_type(self) -> str:
        return _PROTO[self.type]

    @property
    def ros2_type(self) -> str:
        return _ROS2[self.type]


@dataclass(frozen=True)
class MessageLayout:
    """A message as its JSON schema declares it: ``name`` (the schema's ``$id``, also the
    MCAP schema name), ``fields`` in the schema's order, ``data`` the schema file's bytes
    (what MCAP files carry as the channel's schema)."""

    file_name: str
    name: str
    doc: str
    fields: tuple[MessageField, ...]
    data: bytes

    @property
    def names(self) -> list[str]:
        return [f.name for f in self.fields]

    @property
    def required(self) -> list[str]:
        return [f.name for f in self.fields if f.required]

    @property
    def required_numbers(self) -> list[str]:
        """The required fields of type ``number`` (those a NaN/infinity check covers)."""
        return [f.name for f in self.fields if f.required and f.type == "number"]

    def field(self, name: str) -> MessageField:
        for f in self.fields:
            if f.name == name:
                return f
        raise KeyError(f"{self.name} has no field {name!r}")

    def polars_schema(self, *, omit: tuple[str, ...] = ()) -> dict[str, pl.DataType]:
        """Field -> polars type, in schema order, without the fields in ``omit`` (each
        must exist: a renamed field fails here instead of being silently dropped)."""
        for name in omit:
            self.field(name)
        return {f.name: f.polars_type for f in self.fields if f.name not in omit}


@cache
def message_layout(file_name: str) -> MessageLayout:
    """The layout declared by ``schemas/<file_name>`` (e.g. ``radar_track_report.schema.json``)."""
    data = (resource_path("schemas") / file_name).read_bytes()
    doc = json.loads(data)
    required = set(doc.get("required", []))
    fields = []
    for name, prop in doc["properties"].items():
        types = prop["type"] if isinstance(prop["type"], list) else [prop["type"]]
        base = [t for t in types if t != "null"]
        if len(base) != 1 or base[0] not in _POLARS:
            raise ValueError(f"{file_name}: field {name!r} has type {prop['type']!r}")
        doc_text = prop.get("description", "")
        fields.append(MessageField(name, base[0], "null" in types, name in required, doc_text))
    unknown = required - {f.name for f in fields}
    if unknown:
        raise ValueError(f"{file_name}: required fields without a property: {sorted(unknown)}")
    return MessageLayout(file_name, doc["$id"], doc.get("description", ""), tuple(fields), data)


# -- generated encodings ------------------------------------------------------------------

RADAR_REPORT = "radar_track_report.schema.json"
RADAR_ROS2_NAME = "surveil_msgs/msg/RadarTrackReport"


def _generated_note(layout: MessageLayout, comment: str) -> list[str]:
    return [
        f"{comment} GENERATED from {layout.file_name} by `python -m pipeline.messages`: edit",
        f"{comment} the JSON schema and regenerate. Field order = the order of its properties",
        f"{comment} (a wire format: new fields go at the end). Units are in the field names.",
    ]


def proto_text(layout: MessageLayout) -> str:
    """The ``.proto`` (proto3) of ``layout``: package and message from its name
    (``surveil.RadarTrackReport``), field ``k`` of the schema is field number ``k``."""
    package, _, message = layout.name.rpartition(".")
    lines = [
        f"// {layout.name} in protobuf: the same message as {layout.file_name}",
        '// (MCAP: message encoding "protobuf", schema encoding "protobuf", schema name',
        f'// "{layout.name}", schema data = the FileDescriptorSet of this file).',
        *_generated_note(layout, "//"),
        'syntax = "proto3";',
        f"package {package};",
        "",
        f"message {message} {{",
    ]
    decls = [f"{f.proto_type} {f.name} = {k};" for k, f in enumerate(layout.fields, start=1)]
    width = max(map(len, decls))
    for decl, f in zip(decls, layout.fields, strict=True):
        lines.append(f"  {decl:<{width}}  // {f.doc}" if f.doc else f"  {decl}")
    lines.append("}")
    return "\n".join(lines) + "\n"


def ros2_msg_text(layout: MessageLayout, ros2_name: str) -> str:
    """The ROS 2 ``.msg`` definition of ``layout`` (a flat message, fields in order)."""
    lines = [
        f"# {ros2_name}: the same message as {layout.file_name}, for ROS 2",
        '# recordings (MCAP: message encoding "cdr", schema encoding "ros2msg", schema name',
        f'# "{ros2_name}", schema data = this text).',
        *_generated_note(layout, "#"),
    ]
    decls = [f"{f.ros2_type} {f.name}" for f in layout.fields]
    width = max(map(len, decls))
    for decl, f in zip(decls, layout.fields, strict=True):
        lines.append(f"{decl:<{width}}  # {f.doc}" if f.doc else decl)
    return "\n".join(lines) + "\n"


def generated_files() -> dict[str, str]:
    """File name (in ``schemas/``) -> the text ``python -m pipeline.messages`` writes."""
    radar = message_layout(RADAR_REPORT)
    return {
        "radar_track_report.proto": proto_text(radar),
        "radar_track_report.msg": ros2_msg_text(radar, RADAR_ROS2_NAME),
    }


def write_generated(folder: Path | None = None) -> list[Path]:
    """Write :func:`generated_files` into ``folder`` (default: ``schemas/``)."""
    root = Path(folder) if folder is not None else resource_path("schemas")
    out = []
    for name, text in generated_files().items():
        path = root / name
        path.write_bytes(text.encode())
        out.append(path)
    return out


if __name__ == "__main__":  # python -m pipeline.messages
    for written in write_generated():
        sys.stdout.write(f"wrote {written}\n")
