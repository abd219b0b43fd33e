"""ASTERIX data blocks -> ``airfield_obs`` (target reports), ``asterix_service`` (service
messages) and ``rejects``.

MCAP channel convention: message encoding ``asterix``; no schema, or a schema named
``asterix``; each payload is ONE ASTERIX data block (CAT 1 octet, LEN 2 octets, records;
EUROCONTROL ASTERIX Part 1). Several concatenated blocks in one payload are accepted and
split by their LEN fields. Channel metadata may carry ``sensor_id`` and
``sensor_kind`` (``smr`` | ``mlat`` | ...): they then override what the records say.

Records are parsed by ``asterix_decoder`` (Croatia Control's C++ decoder, PyPI) with the
category definitions it ships; the editions we read, and the items used:

=====  =============================  =======  ===============  ==============================
CAT    content                        edition  table            items read
=====  =============================  =======  ===============  ==============================
010    SMR / MLAT target reports      1.1      airfield_obs     010 000 020 140 040 041 042
                                                                200 202 161 220 245 500
020    MLAT target reports            1.10     airfield_obs     010 140 041 042 161 202 220
                                                                245 500
021    ADS-B reports                  2.6      airfield_obs     010 071/073/075/077 130 131
                                                                160 161 080 170
048    monoradar target reports       1.21     airfield_obs     010 020 140 040 042 161 200
                                                                220 240
062    SDPS system tracks             1.18     airfield_obs     010 040 070 100 105 185 245
                                                                380(ADR, ID) 500(APC)
034    radar service messages         1.27     asterix_service  000 010 020 030 041 (+ rest
                                                                as JSON)
065    SDPS service status            1.3      asterix_service  000 010 015 020 030 (+ rest)
=====  =============================  =======  ===============  ==============================

Units are converted at decode: NM -> m (1852), kt -> m/s, degrees -> rad (azimuth and
track angle clockwise from north), ``vx``/``vy`` east/north. ``sensor_kind`` from the
record: CAT010 I020 TYP (0, 1, 5 multilateration -> ``mlat``; 2 -> ``adsb``; 3 PSR ->
``smr``; else ``other``), CAT020 -> ``mlat``, CAT021 -> ``adsb``, CAT048 I020 TYP (1
single PSR -> ``psr``, else ``ssr``), CAT062 -> ``system_track``.

Time: ``time_ns`` = the record's time of day (CAT010/020/048 I140, CAT062 I070, CAT021
I071 else I073, I075, I077; CAT034/065 I030) placed on the UTC date of the block's
log_time, shifted by one day when that lands more than 12 h from the log_time (midnight
rollover, see :func:`tod_to_time_ns`). A record without a time item takes the log_time.

Rejects (``raw`` = the whole data block, or the bytes that do not frame):

- ``undecodable``: bytes that do not frame as data blocks (LEN < 3 or past the end of
  the payload), or a block whose records do not parse under the edition above (the
  decoder reports an unparsed record, a record has no item, or the records do not fill
  LEN exactly). The whole block is rejected: after one bad record the record boundaries
  are unknown.
- ``out_of_range``: a record carries a value its encoding should never hold: latitude
  outside [-90, 90], longitude outside [-180, 180], time of day outside [0, 86400) s. That
  is the mark of a block written in another edition (another UAP) read with ours, so the
  WHOLE block is rejected (one row naming the first bad record): its other records share
  the same source and edition.
- ``no_position``: a target report (CAT010 message type 1, or any CAT020/021/048/062
  record) with neither polar, Cartesian nor WGS-84 position; one row per record.
  CAT010 status messages (start of update cycle, periodic / event-triggered status) are
  service messages: rows of ``asterix_service`` (their other items in ``status_json``),
  like every record of the service categories (:data:`SERVICE_LAYOUTS`, CAT034, CAT065).
- categories we do not decode (CAT001, CAT004, CAT030, ...) are valid input we do not
  keep: counted per channel and category in ``not_stored`` (``asterix_cat004``: the
  ingest ledger's ``not_stored_json``), not rejected.
- ``decoder_missing``: the optional ``asterix`` extra (``asterix_decoder``, GPL) is not
  installed: ONE row per channel with the message count (see
  :class:`AsterixChannelDecoder`).

``asterix_decoder`` ships definitions of CAT048 1.21 and CAT065 1.3 whose UAP lists the
RE/SP fields without defining them, so any record carrying RE fails to parse. Before the
first parse, :func:`_ensure_definitions` loads patched copies of those two definitions
that declare the missing fields as opaque explicit-length items (ASTERIX Part 1: an
explicit field starts with its own length octet, so skipping it is always well defined).
"""

from __future__ import annotations

import json
import logging
import math
import re
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from pipeline.decode.asterix_editions import (
    DEFAULT_EDITIONS,
    definition_file,
    definitions_folder,
    known_editions,
    parse_edition_metadata,
)
from pipeline.decode.registry import make_rejects
from pipeline.io.mcap_read import ChannelBatch
from pipeline.tables import conform, empty
from pipeline.time_sources import channel_synthetic, fallback_label
from pipeline.units import NM_M, NS

DAY_NS = 86_400 * NS
KT_MPS = NM_M / 3600.0
TARGET_CATEGORIES = frozenset({10, 20, 21, 48, 62})
SERVICE_CATEGORIES = frozenset({2, 19, 23, 25, 31, 34, 63, 65, 247, 252})
SUPPORTED_CATEGORIES = TARGET_CATEGORIES | SERVICE_CATEGORIES
OBS_COLUMNS = (
    "sac", "sic", "message_type", "sensor_kind", "track_number", "target_address",
    "callsign", "range_m", "azimuth_rad", "x_m", "y_m", "vx_mps", "vy_mps", "lat_deg",
    "lon_deg", "sigma_x_m", "sigma_y_m",
)  # fmt: skip
SERVICE_COLUMNS = (
    "sac", "sic", "message_type", "sector_azimuth_rad", "antenna_period_s", "service_id",
    "batch_number", "status_json",
)  # fmt: skip
TARGET_REPORT = "target report"
CAT010_MESSAGE_TYPES = {
    1: TARGET_REPORT,
    2: "start of update cycle",
    3: "periodic status",
    4: "event-triggered status",
}
CAT034_MESSAGE_TYPES = {
    1: "north marker",
    2: "sector crossing",
    3: "geographical filtering",
    4: "jamming strobe",
    5: "solar storm",
    6: "ssr jamming strobe",
    7: "mode s jamming strobe",
}
CAT065_MESSAGE_TYPES = {1: "sdps status", 2: "end of batch", 3: "service status report"}
CAT010_KINDS = {0: "mlat", 1: "mlat", 2: "adsb", 3: "smr", 5: "mlat"}


# -- framing -----------------------------------------------------------------------------


def split_blocks(payload: bytes) -> tuple[list[bytes], bytes]:
    """Consecutive data blocks of ``payload`` framed by their LEN octets (ASTERIX Part 1:
    CAT, LEN = length of the whole block incl. CAT and LEN), and the trailing bytes
    that do not frame (LEN < 3, or LEN past the end), ``b""`` when everything frames."""
    blocks: list[bytes] = []
    pos, n = 0, len(payload)
    while pos < n:
        if n - pos < 3:
            return blocks, payload[pos:]
        length = int.from_bytes(payload[pos + 1 : pos + 3], "big")
        if length < 3 or pos + length > n:
            return blocks, payload[pos:]
        blocks.append(payload[pos : pos + length])
        pos += length
    return blocks, b""


# -- asterix_decoder ---------------------------------------------------------------------

_DEFINITIONS_READY = False
_OPAQUE_ITEM = (
    '<DataItem id="{id}"><DataItemName>{id} (opaque, added by surveil)</DataItemName>'
    "<DataItemDefinition>explicit-length field, skipped</DataItemDefinition>"
    '<DataItemFormat desc="Explicit"><Explicit><Fixed length="1"><Bits from="8" to="1">'
    "<BitsShortName>VAL</BitsShortName></Bits></Fixed></Explicit></DataItemFormat>"
    "</DataItem>\n"
)


def _patched_definition(xml: str) -> str | None:
    """The definition with opaque RE/SP items added where its UAP uses them undefined."""
    defined = set(re.findall(r'<DataItem\s+id="([^"]+)"', xml))
    used = set(re.findall(r"<UAPItem[^>]*>\s*(RE|SP)\s*</UAPItem>", xml))
    missing = sorted(used - defined)
    if not missing:
        return None
    items = "".join(_OPAQUE_ITEM.format(id=m) for m in missing)
    return xml.replace("<UAP>", items + "<UAP>", 1)


def _ensure_definitions() -> None:
    """Load patched CAT048/CAT065 definitions into ``asterix_decoder`` once per process
    (see the module docstring); idempotent."""
    global _DEFINITIONS_READY
    if _DEFINITIONS_READY:
        return
    import asterix

    for name in ("cat048", "cat065"):
        src = Path(asterix.get_configuration_file(name))
        patched = _patched_definition(src.read_text())
        if patched is None:
            continue
        tmp = definitions_folder() / f"surveil_{name}.xml"
        tmp.write_text(patched)
        _SHIPPED_FILES[int(name[3:])] = str(tmp)  # kept: loaded again after another edition
        asterix.init(str(tmp))
    _DEFINITIONS_READY = True


_SHIPPED_FILES: dict[int, str] = {}
_LOADED: dict[int, str] = {}  # category -> edition loaded in asterix_decoder (else default)


def shipped_file(cat: int) -> str:
    """The decoder's definition file of ``cat`` (our patched copy for CAT048/065)."""
    import asterix

    _ensure_definitions()
    return _SHIPPED_FILES.get(cat) or asterix.get_configuration_file(f"cat{cat:03d}_")


def use_edition(cat: int, edition: str) -> None:
    """Load ``edition`` of ``cat`` into ``asterix_decoder`` unless it is loaded (the
    decoder keeps one definition per category: :mod:`pipeline.decode.asterix_editions`)."""
    import asterix

    _ensure_definitions()
    default = DEFAULT_EDITIONS.get(cat)
    if _LOADED.get(cat, default) == edition:
        return
    if edition == default:
        asterix.init(shipped_file(cat))
    else:
        asterix.init(definition_file(cat, edition, shipped_file(cat)))
    _LOADED[cat] = edition


def restore_default_editions() -> None:
    """Load the shipped edition again wherever another one is loaded (~3 ms per
    category), so that direct ``asterix.parse`` callers see the decoder's defaults."""
    for cat, ed in list(_LOADED.items()):
        if ed != DEFAULT_EDITIONS.get(cat):
            use_edition(cat, DEFAULT_EDITIONS[cat])


def parse_block(block: bytes, edition: str | None = None) -> list[dict] | str:
    """Records of one data block as ``asterix_decoder`` dicts (``verbose=False``), or the
    reason why the block does not decode; ``edition`` of the block's category (default:
    the edition the decoder ships)."""
    import asterix

    _ensure_definitions()
    cat = block[0] if block else 0
    edition = edition or DEFAULT_EDITIONS.get(cat)
    if edition is not None:
        use_edition(cat, edition)
    try:
        records = asterix.parse(block, verbose=False)
    except Exception as exc:  # the C extension raises on malformed input
        return f"asterix_decoder raised {type(exc).__name__}: {exc}"
    cat = block[0]
    if not records:
        return f"CAT{cat:03d} block of {len(block)} B holds no record"
    for i, rec in enumerate(records):
        if rec.get("hexdata") is None or rec.get("category") != cat:
            return f"CAT{cat:03d} record {i + 1} does not parse under edition {edition}"
        if not any(k.startswith("I") for k in rec):
            return f"CAT{cat:03d} record {i + 1} has no data item (empty FSPEC)"
    filled = sum(int(r["len"]) for r in records)
    if filled != len(block) - 3:
        return f"CAT{cat:03d} records fill {filled} B of a {len(block) - 3} B block"
    return records


# -- item access -------------------------------------------------------------------------


def _v(rec: Mapping[str, Any], item: str, *path: str) -> Any:
    """``rec[item][path...]["val"]`` or ``None`` when the item or field is absent."""
    try:
        node = rec[item]
        for key in path:
            node = node[key]
        return node["val"]
    except (KeyError, TypeError, IndexError):  # absent item/field, or a list item
        return None


def _f(x: Any) -> float | None:
    return None if x is None else float(x)


def _rad(deg: Any) -> float | None:
    return None if deg is None else math.radians(deg)


def _hex_int(x: Any) -> int | None:
    if x is None:
        return None
    try:
        return int(x, 16) if isinstance(x, str) else int(x)
    except ValueError:
        return None


def _text(x: Any) -> str | None:
    if x is None:
        return None
    s = str(x).strip()
    return s or None


def _scaled(x: Any, k: float) -> float | None:
    return None if x is None else float(x) * k


def _ground_vector(speed_mps: float | None, angle_deg: Any) -> tuple[float | None, ...]:
    """East/north velocity from a speed and a track angle clockwise from north."""
    if speed_mps is None or angle_deg is None:
        return None, None
    a = math.radians(angle_deg)
    return speed_mps * math.sin(a), speed_mps * math.cos(a)


def _name(names: Mapping[int, str], code: Any) -> str | None:
    """The name of a message type code (``message type N`` when undefined)."""
    if code is None:
        return None
    return names.get(code, f"message type {code}")


def _source(rec: Mapping[str, Any]) -> dict[str, Any]:
    return {"sac": _v(rec, "I010", "SAC"), "sic": _v(rec, "I010", "SIC")}


# -- per-category extraction -------------------------------------------------------------
# One dict per record: asterix_decoder returns one nested dict per record (records are
# FSPEC-driven and variable-length), so this step is per record by construction.


def _cat010(rec: Mapping[str, Any]) -> dict[str, Any]:
    """CAT010 ed 1.1 (SMR/MLAT target reports and status messages)."""
    msg = _v(rec, "I000", "MsgTyp")
    typ = _v(rec, "I020", "TYP")
    vx, vy = _f(_v(rec, "I202", "Vx")), _f(_v(rec, "I202", "Vy"))
    if vx is None:  # polar velocity I200: GS in NM/s, TA in degrees
        vx, vy = _ground_vector(_scaled(_v(rec, "I200", "GS"), NM_M), _v(rec, "I200", "TA"))
    return {
        **_source(rec),
        "tod_s": _v(rec, "I140", "ToD"),
        "message_type": TARGET_REPORT if msg is None else _name(CAT010_MESSAGE_TYPES, msg),
        "sensor_kind": None if typ is None else CAT010_KINDS.get(typ, "other"),
        "track_number": _v(rec, "I161", "TrkNb"),
        "target_address": _hex_int(_v(rec, "I220", "TAddr")),
        "callsign": _text(_v(rec, "I245", "TId")),
        "range_m": _f(_v(rec, "I040", "RHO")),
        "azimuth_rad": _rad(_v(rec, "I040", "Theta")),
        "x_m": _f(_v(rec, "I042", "X")),
        "y_m": _f(_v(rec, "I042", "Y")),
        "vx_mps": vx,
        "vy_mps": vy,
        "lat_deg": _f(_v(rec, "I041", "Lat")),
        "lon_deg": _f(_v(rec, "I041", "Lon")),
        "sigma_x_m": _f(_v(rec, "I500", "Qx")),
        "sigma_y_m": _f(_v(rec, "I500", "Qy")),
    }


def _cat020(rec: Mapping[str, Any]) -> dict[str, Any]:
    """CAT020 ed 1.10 (multilateration target reports)."""
    return {
        **_source(rec),
        "tod_s": _v(rec, "I140", "ToD"),
        "message_type": TARGET_REPORT,
        "sensor_kind": "mlat",
        "track_number": _v(rec, "I161", "TrkNb"),
        "target_address": _hex_int(_v(rec, "I220", "TAddr")),
        "callsign": _text(_v(rec, "I245", "TId")),
        "x_m": _f(_v(rec, "I042", "X")),
        "y_m": _f(_v(rec, "I042", "Y")),
        "vx_mps": _f(_v(rec, "I202", "Vx")),
        "vy_mps": _f(_v(rec, "I202", "Vy")),
        "lat_deg": _f(_v(rec, "I041", "Lat")),
        "lon_deg": _f(_v(rec, "I041", "Lon")),
        "sigma_x_m": _f(_v(rec, "I500", "SDP", "SDPx")),
        "sigma_y_m": _f(_v(rec, "I500", "SDP", "SDPy")),
    }


def _cat021(rec: Mapping[str, Any]) -> dict[str, Any]:
    """CAT021 ed 2.6 (ADS-B reports); position time I071, else I073, I075, I077."""
    tod = next(
        (t for t in (
            _v(rec, "I071", "time_applicability_position"),
            _v(rec, "I073", "time_reception_position"),
            _v(rec, "I075", "time_reception_velocity"),
            _v(rec, "I077", "time_report_transmission"),
            _v(rec, "I030", "ToD"),  # edition 0.26
        ) if t is not None),
        None,
    )  # fmt: skip
    lat, lon = _v(rec, "I131", "Lat"), _v(rec, "I131", "Lon")
    if lat is None:
        lat, lon = _v(rec, "I130", "Lat"), _v(rec, "I130", "Lon")
    vx, vy = _ground_vector(_scaled(_v(rec, "I160", "GS"), NM_M), _v(rec, "I160", "TA"))
    return {
        **_source(rec),
        "tod_s": tod,
        "message_type": TARGET_REPORT,
        "sensor_kind": "adsb",
        "track_number": _v(rec, "I161", "TrackN"),
        "target_address": _hex_int(_v(rec, "I080", "TAddr")),
        "callsign": _text(_v(rec, "I170", "TId")),
        "vx_mps": vx,
        "vy_mps": vy,
        "lat_deg": _f(lat),
        "lon_deg": _f(lon),
    }


def _cat048(rec: Mapping[str, Any]) -> dict[str, Any]:
    """CAT048 ed 1.21 (monoradar target reports); NM and kt converted to m and m/s."""
    typ = _v(rec, "I020", "TYP")
    vx, vy = _ground_vector(_scaled(_v(rec, "I200", "CGS"), KT_MPS), _v(rec, "I200", "CHdg"))
    return {
        **_source(rec),
        "tod_s": _v(rec, "I140", "ToD"),
        "message_type": TARGET_REPORT,
        "sensor_kind": None if typ is None else ("psr" if typ == 1 else "ssr"),
        "track_number": _v(rec, "I161", "Tn"),
        "target_address": _hex_int(_v(rec, "I220", "ACAddr")),
        "callsign": _text(_v(rec, "I240", "TId")),
        "range_m": _scaled(_v(rec, "I040", "RHO"), NM_M),
        "azimuth_rad": _rad(_v(rec, "I040", "THETA")),
        "x_m": _scaled(_v(rec, "I042", "X"), NM_M),
        "y_m": _scaled(_v(rec, "I042", "Y"), NM_M),
        "vx_mps": vx,
        "vy_mps": vy,
    }


def _cat062(rec: Mapping[str, Any]) -> dict[str, Any]:
    """CAT062 ed 1.18 (SDPS system tracks); x/y in the system's reference frame."""
    callsign = _text(_v(rec, "I245", "TId")) or _text(_v(rec, "I380", "ID", "ACID"))
    vx, vy = _f(_v(rec, "I185", "Vx")), _f(_v(rec, "I185", "Vy"))
    if vx is None:  # edition 0.17: polar velocity I180 (speed m/s, heading deg)
        vx, vy = _ground_vector(_f(_v(rec, "I180", "Spd")), _v(rec, "I180", "Hdg"))
    return {
        **_source(rec),
        "tod_s": _v(rec, "I070", "ToT"),
        "message_type": TARGET_REPORT,
        "sensor_kind": "system_track",
        "track_number": _v(rec, "I040", "TrkN"),
        "target_address": _hex_int(_v(rec, "I380", "ADR", "ADR")),
        "callsign": callsign,
        "x_m": _f(_v(rec, "I100", "X")),
        "y_m": _f(_v(rec, "I100", "Y")),
        "vx_mps": vx,
        "vy_mps": vy,
        "lat_deg": _f(_v(rec, "I105", "Lat")),
        "lon_deg": _f(_v(rec, "I105", "Lon")),
        "sigma_x_m": _f(_v(rec, "I500", "APC", "APC_X")),
        "sigma_y_m": _f(_v(rec, "I500", "APC", "APC_Y")),
    }


def _plain(node: Any) -> Any:
    """asterix_decoder's ``{"field": {"val": v}}`` nesting without the ``val`` level."""
    if isinstance(node, Mapping):
        if set(node) == {"val"}:
            return node["val"]
        return {k: _plain(v) for k, v in node.items() if k not in ("spare", "FX", "fx")}
    if isinstance(node, list):
        return [_plain(v) for v in node]
    return node


def _status_json(rec: Mapping[str, Any], used: set[str]) -> str | None:
    rest = {k: _plain(v) for k, v in rec.items() if k.startswith("I") and k not in used}
    return json.dumps(rest, sort_keys=True, separators=(",", ":")) if rest else None


def _cat034(rec: Mapping[str, Any]) -> dict[str, Any]:
    """CAT034 ed 1.27 (radar service messages)."""
    msg = _v(rec, "I000", "MsgTyp")
    return {
        **_source(rec),
        "tod_s": _v(rec, "I030", "ToD"),
        "message_type": _name(CAT034_MESSAGE_TYPES, msg),
        "sector_azimuth_rad": _rad(_v(rec, "I020", "Azi")),
        "antenna_period_s": _f(_v(rec, "I041", "RotS")),
        "status_json": _status_json(rec, {"I000", "I010", "I020", "I030", "I041"}),
    }


@dataclass(frozen=True)
class ServiceLayout:
    """Where a service category keeps its time, message type and service id:
    ``(item, field)`` pairs, ``names`` of the message type codes."""

    tod: tuple[str, str]
    msg: tuple[str, str] | None = None
    names: Mapping[int, str] = field(default_factory=dict)
    service: tuple[str, str] | None = None


SERVICE_LAYOUTS = {
    2: ServiceLayout(("I030", "ToD"), ("I000", "type"), {
        1: "north marker", 2: "sector crossing", 3: "south marker",
        8: "activation of blind zone filtering", 9: "stop of blind zone filtering"}),
    19: ServiceLayout(("I140", "ToD"), ("I000", "MsgTyp"), {
        1: "start of update cycle", 2: "periodic status", 3: "event-triggered status"}),
    23: ServiceLayout(("I070", "ToD"), ("I000", "report_type"), {
        1: "ground station status", 2: "service status", 3: "service statistics"},
        ("I015", "SID")),
    25: ServiceLayout(("I070", "ToD"), ("I000", "Typ"), {
        1: "service and system status", 2: "component status", 3: "service statistics"},
        ("I015", "SID")),
    31: ServiceLayout(("I020", "ToM")),
    63: ServiceLayout(("I030", "ToD"), service=("I015", "ServiceID")),
    247: ServiceLayout(("I140", "ToD"), service=("I015", "SI")),
    252: ServiceLayout(("I020", "ToM")),
}  # fmt: skip
"""The service / status categories other than CAT034 and CAT065 (EUROCONTROL: CAT002
monoradar service, CAT019 MLAT system status, CAT023 and CAT025 ground station and
system status, CAT031 sensor information, CAT063 sensor status, CAT247 version number
exchange, CAT252 connection and service messages; item names of the decoder's
definitions). Every other item of the record goes to ``status_json``."""


def _service(cat: int) -> Callable[[Mapping[str, Any]], dict[str, Any]]:
    lay = SERVICE_LAYOUTS[cat]

    def extract(rec: Mapping[str, Any]) -> dict[str, Any]:
        used = {"I010", lay.tod[0]} | {x[0] for x in (lay.msg, lay.service) if x}
        msg = _v(rec, *lay.msg) if lay.msg else None
        row = {
            **_source(rec),
            "tod_s": _v(rec, *lay.tod),
            "message_type": _name(lay.names, msg),
            "service_id": _v(rec, *lay.service) if lay.service else None,
            "status_json": _status_json(rec, used),
        }
        if cat == 2:
            row["sector_azimuth_rad"] = _rad(_v(rec, "I020", "Azi"))
            row["antenna_period_s"] = _f(_v(rec, "I041", "RotS"))
        return row

    return extract


def cat010_status(rec: Mapping[str, Any]) -> dict[str, Any]:
    """A CAT010 status message (I000 = 2 start of update cycle, 3 periodic status, 4
    event-triggered status) as an ``asterix_service`` row; its other items (I550 system
    status, ...) in ``status_json``."""
    return {
        **_source(rec),
        "tod_s": _v(rec, "I140", "ToD"),
        "message_type": _name(CAT010_MESSAGE_TYPES, _v(rec, "I000", "MsgTyp")),
        "status_json": _status_json(rec, {"I000", "I010", "I140"}),
    }


def _cat065(rec: Mapping[str, Any]) -> dict[str, Any]:
    """CAT065 ed 1.3 (SDPS service status messages)."""
    msg = _v(rec, "I000", "Typ")
    return {
        **_source(rec),
        "tod_s": _v(rec, "I030", "ToD"),
        "message_type": _name(CAT065_MESSAGE_TYPES, msg),
        "service_id": _v(rec, "I015", "SID"),
        "batch_number": _v(rec, "I020", "BTN"),
        "status_json": _status_json(rec, {"I000", "I010", "I015", "I020", "I030"}),
    }


EXTRACTORS: dict[int, Callable[[Mapping[str, Any]], dict[str, Any]]] = {
    10: _cat010, 20: _cat020, 21: _cat021, 48: _cat048, 62: _cat062, 34: _cat034, 65: _cat065,
    **{c: _service(c) for c in SERVICE_LAYOUTS},
}  # fmt: skip


# -- time --------------------------------------------------------------------------------


def tod_to_time_ns(tod_s: np.ndarray, log_time_ns: np.ndarray) -> np.ndarray:
    """Absolute UTC ns of an ASTERIX time of day (s since UTC midnight, NaN when absent).

    .. math:: t = \\lfloor t_{log} / D \\rfloor D + \\mathrm{ToD};\\quad
              t \\mathrel{-}= D \\text{ if } t - t_{log} > D/2;\\quad
              t \\mathrel{+}= D \\text{ if } t - t_{log} < -D/2

    with D one day: a report stamped 23:59:59.9 and logged at 00:00:00.2 belongs to the
    previous day, and vice versa. Where ``tod_s`` is NaN the log time is returned.
    ToD has an LSB of 1/128 s, so ``tod * 1e9`` rounds exactly to integer ns.
    """
    log_time_ns = np.asarray(log_time_ns, dtype=np.int64)
    tod = np.asarray(tod_s, dtype=np.float64)
    have = np.isfinite(tod)
    day0 = np.floor_divide(log_time_ns, DAY_NS) * DAY_NS
    t = day0 + np.round(np.where(have, tod, 0.0) * NS).astype(np.int64)
    d = t - log_time_ns
    t = t - DAY_NS * (d > DAY_NS // 2) + DAY_NS * (d < -(DAY_NS // 2))
    return np.where(have, t, log_time_ns)


# -- decoding ----------------------------------------------------------------------------


@dataclass
class _Rows:
    """Column lists of extracted records (one dict per record, see the extractors)."""

    columns: tuple[str, ...]
    cols: dict[str, list] = field(default_factory=dict)
    tod: list[float] = field(default_factory=list)
    category: list[int] = field(default_factory=list)
    log_time: list[int] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.cols = {c: [] for c in self.columns}

    def add(self, row: Mapping[str, Any], cat: int, t: int) -> None:
        get = row.get
        for c, values in self.cols.items():
            values.append(get(c))
        tod = row.get("tod_s")
        self.tod.append(np.nan if tod is None else float(tod))
        self.category.append(cat)
        self.log_time.append(t)

    def __len__(self) -> int:
        return len(self.category)


@dataclass(frozen=True)
class Unsupported:
    """Data blocks of one category that is not decoded: count, first log time, first
    block (kept as the reject's raw bytes)."""

    count: int
    first_log_time_ns: int
    first_block: bytes

    def plus(self, other: Unsupported) -> Unsupported:
        return Unsupported(self.count + other.count, self.first_log_time_ns, self.first_block)


@dataclass(frozen=True)
class AsterixDecoded:
    """``obs``: airfield_obs rows; ``service``: asterix_service rows; ``rejects``: rejects
    rows (not including unsupported categories); ``unsupported``: per category;
    ``blocks``: data blocks framed."""

    obs: pa.Table
    service: pa.Table
    rejects: pa.Table
    unsupported: dict[int, Unsupported]
    blocks: int


@dataclass(frozen=True)
class _Context:
    source_file: str
    topic: str
    sensor_id: str | None
    sensor_kind: str | None
    time_source: tuple[str, str] = ("asterix_tod+mcap_log_time", "mcap_log_time")
    """``time_source`` of a record with a time of day, and of one without."""


def time_source_labels(meta: Mapping[str, str]) -> tuple[str, str]:
    """``(with time of day, without)`` labels of a channel's rows (``time_source``,
    :mod:`pipeline.time_sources`): the time of day on the day of the capture (``pcap``),
    of ``--base-time`` or the file name (``log_date_source``), of a framed recording's
    header, or of the MCAP log time; ``asterix_tod:undated`` when nothing gave the day
    (1970-01-01: synthetic, no batch input)."""
    src = meta.get("log_time_source") or ""
    without = fallback_label(meta)
    if channel_synthetic(meta):
        return "asterix_tod:undated", without
    if src == "pcap" or not src:
        return f"asterix_tod+{src or 'mcap_log_time'}", without
    if "log_date" in meta:
        return f"asterix_tod+{meta.get('log_date_source') or 'given'}", without
    return f"asterix_tod+{src}", without


@dataclass
class _Rejects:
    t: list[int] = field(default_factory=list)
    code: list[str] = field(default_factory=list)
    reason: list[str] = field(default_factory=list)
    raw: list[bytes] = field(default_factory=list)

    def add(self, t: int, code: str, reason: str, raw: bytes) -> None:
        self.t.append(t)
        self.code.append(code)
        self.reason.append(reason)
        self.raw.append(raw)


def implausible(row: Mapping[str, Any]) -> str | None:
    """Why an extracted record cannot be right (a value its encoding should never carry:
    the sign of a record read with another edition's UAP), else ``None``."""
    tod = row.get("tod_s")
    if tod is not None and not 0 <= tod < 86_400:
        return f"time of day {tod} s outside [0, 86400)"
    lat, lon = row.get("lat_deg"), row.get("lon_deg")
    if (lat is not None and abs(lat) > 90) or (lon is not None and abs(lon) > 180):
        return f"latitude {lat} / longitude {lon} deg out of range"
    return None


def has_position(row: Mapping[str, Any]) -> bool:
    """A polar, Cartesian or WGS-84 position is present."""
    return any(row.get(k) is not None for k in ("range_m", "x_m", "lat_deg"))


def decode_asterix(
    payloads: Sequence[bytes],
    log_time_ns: Sequence[int] | np.ndarray,
    *,
    source_file: str,
    topic: str,
    metadata: Mapping[str, str] | None = None,
    editions: Mapping[int, str] | None = None,
    learned: dict[int, str] | None = None,
) -> AsterixDecoded:
    """Decode one channel's ASTERIX payloads (one data block each) with their log times.

    ``metadata``: the channel's MCAP metadata; ``sensor_id`` / ``sensor_kind`` there
    override the record's SAC/SIC and kind, ``asterix_editions`` (``"010=0.24"``) forces
    editions. ``editions``: forced editions per category (the config's; they win over the
    metadata); ``learned``: the edition that decoded each category's last block (updated;
    pass the same dict for every batch of a channel). See the module docstring for the
    mapping and the reject rules.
    """
    meta = metadata or {}
    forced = {**parse_edition_metadata(meta.get("asterix_editions")), **(editions or {})}
    learned = {} if learned is None else learned
    ctx = _Context(source_file, topic, meta.get("sensor_id"), meta.get("sensor_kind"),
                   time_source_labels(meta))
    times = np.asarray(log_time_ns, dtype=np.int64)
    obs, svc, rej = _Rows(OBS_COLUMNS), _Rows(SERVICE_COLUMNS), _Rejects()
    unsupported: dict[int, Unsupported] = {}
    n_blocks = 0
    # one asterix_decoder call per data block (records are variable-length; the library
    # parses a block at a time, and a concatenation of blocks parses slower, measured)
    for payload, t in zip(payloads, times.tolist(), strict=True):
        blocks, rest = split_blocks(payload)
        if rest:
            rej.add(t, "undecodable", _framing_reason(rest), rest)
        for block in blocks:
            n_blocks += 1
            cat = block[0]
            if cat in SUPPORTED_CATEGORIES:
                _decode_block(block, t, obs, svc, rej, forced, learned)
            else:
                u = Unsupported(1, t, block)
                unsupported[cat] = unsupported[cat].plus(u) if cat in unsupported else u
    rejects = make_rejects(
        rej.t, source_file=source_file, topic=topic, reason_code=rej.code,
        reason=rej.reason, raw=rej.raw,
    )  # fmt: skip
    return AsterixDecoded(
        _table("airfield_obs", obs, ctx), _table("asterix_service", svc, ctx), rejects,
        unsupported, n_blocks,
    )  # fmt: skip


def extract_block(block: bytes, edition: str | None) -> tuple[str, str] | list[dict[str, Any]]:
    """Rows of a block under one edition, or ``(reason code, reason)`` when it does not
    decode under it (records do not parse / fill the block: ``undecodable``; a value its
    encoding should never carry: ``out_of_range``)."""
    cat = block[0]
    records = parse_block(block, edition)
    if isinstance(records, str):
        return "undecodable", records
    extracted = [EXTRACTORS[cat](rec) for rec in records]
    if cat == 10:  # status messages of CAT010 are service messages
        extracted = [
            row if row["message_type"] == TARGET_REPORT else cat010_status(rec)
            for row, rec in zip(extracted, records, strict=True)
        ]
    for k, row in enumerate(extracted):
        why = implausible(row)
        if why is not None:  # the whole block: its records share one source and edition
            return "out_of_range", f"CAT{cat:03d} record {k + 1}: {why}"
    return extracted


def candidate_editions(
    cat: int, forced: Mapping[int, str], learned: Mapping[int, str]
) -> list[str]:
    """Editions to try for a block of ``cat``: the forced one alone (config, channel
    metadata), else the one that decoded the channel's previous block, the shipped one,
    then the others (:mod:`pipeline.decode.asterix_editions`)."""
    if cat in forced:
        return [forced[cat]]
    out = [learned[cat]] if cat in learned else []
    return out + [e for e in known_editions(cat) if e not in out]


def _decode_block(
    block: bytes, t: int, obs: _Rows, svc: _Rows, rej: _Rejects,
    forced: Mapping[int, str] | None = None, learned: dict[int, str] | None = None,
) -> None:  # fmt: skip
    """Records of one block into ``obs`` (target reports) or ``svc`` (service and status
    messages, CAT010 status messages included); the block or a record into ``rej``. The
    first candidate edition under which the block decodes is taken (and learned)."""
    cat = block[0]
    learned = {} if learned is None else learned
    eds = candidate_editions(cat, forced or {}, learned) or [None]
    first: tuple[str, str] | None = None
    for ed in eds:
        out = extract_block(block, ed)
        if not isinstance(out, tuple):
            if ed is not None:
                learned[cat] = ed
            extracted = out
            break
        first = first or out
    else:
        assert first is not None
        tried = f" (editions tried: {', '.join(e for e in eds if e)})" if len(eds) > 1 else ""
        rej.add(t, first[0], first[1] + tried, block)
        return
    for k, row in enumerate(extracted):
        target = cat in TARGET_CATEGORIES and row.get("message_type") == TARGET_REPORT
        if target and not has_position(row):
            reason = f"CAT{cat:03d} record {k + 1}: target report without a position"
            rej.add(t, "no_position", reason, block)
        else:
            (obs if target else svc).add(row, cat, t)


def _framing_reason(rest: bytes) -> str:
    if len(rest) < 3:
        return f"{len(rest)} trailing bytes, shorter than a data block header"
    length = int.from_bytes(rest[1:3], "big")
    return (
        f"bytes do not frame as an ASTERIX data block: CAT {rest[0]}, LEN {length} with "
        f"{len(rest)} bytes left"
    )


def _table(name: str, rows: _Rows, ctx: _Context) -> pa.Table:
    """Conformed ``airfield_obs`` / ``asterix_service`` rows with time and provenance."""
    if not len(rows):
        return empty(name)
    log_t = np.asarray(rows.log_time, dtype=np.int64)
    data: dict[str, Any] = dict(rows.cols)
    if ctx.sensor_id is not None:
        data["sensor_id"] = [ctx.sensor_id] * len(rows)
    else:
        data["sensor_id"] = [
            ctx.topic if a is None or b is None else f"{a}/{b}"
            for a, b in zip(rows.cols["sac"], rows.cols["sic"], strict=True)
        ]
    if "sensor_kind" in data:
        data["sensor_kind"] = [ctx.sensor_kind or k or "other" for k in data["sensor_kind"]]
    tod = np.asarray(rows.tod, dtype=np.float64)
    data |= {
        "time_ns": tod_to_time_ns(tod, log_t),
        "time_source": np.where(np.isfinite(tod), *ctx.time_source).tolist(),
        "asterix_category": rows.category,
        "source_file": [ctx.source_file] * len(rows),
        "topic": [ctx.topic] * len(rows),
        "log_time_ns": log_t,
    }
    return conform(name, pa.table({k: pa.array(v) for k, v in data.items()}))


# -- per channel -------------------------------------------------------------------------


DECODER_MISSING = "decoder_missing"
INSTALL_HINT = "pip install 'surveil-pipeline[asterix]' (asterix_decoder, GPL-licensed)"
_log = logging.getLogger("surveil.decode.asterix")
_WARNED = False


def decoder_available() -> bool:
    """``asterix_decoder`` (the optional extra ``surveil-pipeline[asterix]``) imports."""
    try:
        import asterix  # noqa: F401
    except ImportError:
        return False
    return True


def _warn_missing() -> None:
    global _WARNED
    if not _WARNED:
        _log.warning("ASTERIX channels are not decoded: the ASTERIX decoder is not "
                     "installed; %s", INSTALL_HINT)  # fmt: skip
        _WARNED = True


@dataclass
class AsterixChannelDecoder:
    """Decode one channel batch by batch. Categories we do not decode are valid input we
    do not keep: counted per category over the whole channel in ``not_stored``
    (``asterix_cat004``), not rejected. Without the ``asterix`` extra nothing is decoded:
    one ``decoder_missing`` rejects row per channel with the message count, one warning
    per process, and ``missing_decoder`` tells ingest that the file was only partly read
    (exit code 1; the file is read again once the extra is installed)."""

    source_file: str
    topic: str
    metadata: Mapping[str, str] = field(default_factory=dict)
    unsupported: dict[int, Unsupported] = field(default_factory=dict)
    not_stored: Counter = field(default_factory=Counter)
    missing_decoder: str | None = None
    editions: Mapping[int, str] = field(default_factory=dict)
    learned: dict[int, str] = field(default_factory=dict)
    _missing: list[int] = field(default_factory=list)  # [count, first log time]
    takes_editions = True  # the registry passes the config's [asterix] editions

    @classmethod
    def for_channel(
        cls, batch: ChannelBatch, source_file: str, editions: Mapping[int, str] | None = None
    ) -> AsterixChannelDecoder:
        return cls(source_file, batch.topic, dict(batch.metadata), editions=dict(editions or {}))

    def feed(self, batch: ChannelBatch) -> dict[str, pa.Table]:
        if not decoder_available():
            _warn_missing()
            if not self._missing:
                self._missing = [0, int(batch.log_time_ns[0]) if len(batch) else 0]
            self._missing[0] += len(batch)
            self.missing_decoder = f"asterix ({INSTALL_HINT})"
            return {}
        out = decode_asterix(
            batch.payloads, batch.log_time_ns, source_file=self.source_file, topic=self.topic,
            metadata=self.metadata, editions=self.editions, learned=self.learned,
        )  # fmt: skip
        for cat, u in out.unsupported.items():
            prev = self.unsupported.get(cat)
            self.unsupported[cat] = u if prev is None else prev.plus(u)
        return {"airfield_obs": out.obs, "asterix_service": out.service, "rejects": out.rejects}

    def finish(self) -> dict[str, pa.Table]:
        if any(ed != DEFAULT_EDITIONS.get(c) for c, ed in self.learned.items()):
            restore_default_editions()  # once per channel that needed another edition
        for c, u in sorted(self.unsupported.items()):
            self.not_stored[f"asterix_cat{c:03d}"] += u.count
        self.unsupported = {}
        if not self._missing:
            return {}
        n, t = self._missing
        self._missing = []
        rejects = make_rejects(
            [t], source_file=self.source_file, topic=self.topic, reason_code=DECODER_MISSING,
            reason=f"{n} ASTERIX messages not decoded: the ASTERIX decoder is not "
                   f"installed; {INSTALL_HINT}",
        )  # fmt: skip
        return {"rejects": rejects}
