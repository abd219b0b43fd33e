"""ASTERIX editions beside the ones ``asterix_decoder`` ships: their layouts, and the
definition files built from them for the decoder.

``asterix_decoder`` holds ONE definition per category (global state; loading a file for a
category replaces the previous one: ``AsterixDefinition::setCategory``). The editions it
ships are the defaults (:data:`DEFAULT_EDITIONS`); for the older editions below we declare
the User Application Profile (the item of each Field Reference Number) and the framing of
each item here, from the EUROCONTROL editions as the public decoders read them
(CroatiaControl's ``install/config`` definitions, jASTERIX's ``definitions/categories``),
and build a definition file at run time: an item whose layout is the same as in the
shipped edition is taken from the installed definition file, the others are written from
the declarations below (opaque octets of the right framing where we read nothing, named
and scaled fields where :mod:`pipeline.decode.asterix` reads them). Nothing of those
GPL-licensed files is copied into this repository: only the facts of the layouts.

===  =======  ====================================================================
CAT  edition  differences from the shipped edition that matter here
===  =======  ====================================================================
010  0.24     Sensis MLAT edition: another UAP (FRN 5 = I041, 7 = I042, 9 = I202,
              11 = I170, 17/18 = I090/I091, 20 = I550, 22 = I500), I202 is 3 octets
              (Vx, Vy 12 bits each, LSB 1 m/s as jASTERIX reads it: the Sensis
              document is not public)
021  0.26     another UAP (I030 time of day, I130 position 2 x 4 octets of
              180/2^25 deg, I131 signal amplitude, I040/I090 2 octets, I032, I095,
              I165 variable); no track number
062  0.17     pre-1.0 UAP (FRN 8-15 = I130 I135 I136 I180 I200 I220 I240 I210), I100
              2 x 2 octets of 1/64 NM, I105 2 x 3 octets of 180/2^23 deg, I180 polar
              velocity (2^-14 NM/s, 360/2^16 deg), other compounds for I290 I380 I390
              I500, I110 one octet
===  =======  ====================================================================

Choosing an edition: ``[asterix] editions`` in the config, channel metadata
``asterix_editions`` (``"010=0.24,021=0.26"``, written by ``surveil import`` from the
config), else detected per block: the edition that decoded the channel's previous block of
the category first, then the shipped one, then the others; a block is taken with the
first edition under which every record parses, fills the block exactly and carries
plausible values (:func:`pipeline.decode.asterix.implausible`).
"""

from __future__ import annotations

import atexit
import os
import re
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

DEFAULT_EDITIONS = {
    1: "1.2", 2: "1.0", 4: "1.13", 8: "1.0", 10: "1.1", 11: "1.2", 15: "1.2", 19: "1.3",
    20: "1.10", 21: "2.6", 23: "1.3", 25: "1.5", 30: "6.2", 31: "6.2", 32: "7.0", 34: "1.27",
    48: "1.21", 62: "1.18", 63: "1.3", 65: "1.3", 205: "1.0", 240: "1.3", 247: "1.2",
    252: "7.0",
}  # fmt: skip
"""The edition of each category in ``asterix_decoder`` 0.7.11's definition files."""


# -- item layouts -------------------------------------------------------------------------


@dataclass(frozen=True)
class Bits:
    """A named field of a fixed part: bits ``hi``..``lo`` (1 = least significant bit of
    the part), ``scale`` per LSB (in the unit the extractor expects), two's complement
    when ``signed``."""

    name: str
    hi: int
    lo: int
    scale: float | None = None
    signed: bool = False


@dataclass(frozen=True)
class Fixed:
    """``length`` octets; ``fields`` named, the rest opaque."""

    length: int
    fields: tuple[Bits, ...] = ()


@dataclass(frozen=True)
class Variable:
    """Parts of ``length`` octets each, the last bit of each an FX bit."""

    parts: int = 1
    length: int = 1


@dataclass(frozen=True)
class Repetitive:
    """A repetition factor octet, then that many elements of ``length`` octets."""

    length: int


@dataclass(frozen=True)
class Explicit:
    """A length octet (counting itself), then opaque octets."""


@dataclass(frozen=True)
class Compound:
    """A primary subfield of ``primary`` octets (7 presence bits + FX each: bit k of the
    primary announces subfield k, in order), then the subfields present."""

    primary: int
    subfields: tuple[Fixed | Variable | Repetitive | Explicit, ...]


SAME = "same"
"""The item's layout is that of the shipped edition: its definition is reused."""

Layout = Fixed | Variable | Repetitive | Explicit | Compound | str


@dataclass(frozen=True)
class Edition:
    """One edition: ``uap`` = item id per FRN (``"-"`` spare), ``items`` its layouts."""

    category: int
    version: str
    uap: tuple[str, ...]
    items: dict[str, Layout] = field(default_factory=dict)


F = Fixed
NM_M = 1852.0

EDITIONS: dict[int, dict[str, Edition]] = {
    10: {"0.24": Edition(10, "0.24", (
        "010", "000", "020", "140", "041", "-", "042",
        "-", "202", "161", "170", "060", "220", "245",
        "-", "-", "090", "091", "-", "550", "-",
        "500", "-", "-", "-", "-", "SP", "RE",
    ), {
        **dict.fromkeys(("010", "000", "020", "140", "041", "042", "161", "170", "060",
                         "220", "245", "090", "091", "550", "500"), SAME),
        "202": F(3, (Bits("Vx", 24, 13, 1.0, True), Bits("Vy", 12, 1, 1.0, True))),
        "SP": Explicit(), "RE": Explicit(),
    })},
    21: {"0.26": Edition(21, "0.26", (
        "010", "040", "030", "130", "080", "140", "090",
        "210", "230", "145", "150", "151", "152", "155",
        "157", "160", "165", "170", "095", "032", "200",
        "020", "220", "146", "148", "110", "070", "131",
        "-", "-", "-", "-", "-", "RE", "SP",
    ), {
        **dict.fromkeys(("010", "080", "140", "210", "230", "145", "150", "151", "152",
                         "155", "157", "160", "170", "200", "020", "220", "146", "148",
                         "110", "070"), SAME),
        "040": F(2), "090": F(2), "095": F(1), "032": F(1), "131": F(1),
        "030": F(3, (Bits("ToD", 24, 1, 1 / 128),)),
        "130": F(8, (Bits("Lat", 64, 33, 180 / 2**25, True),
                     Bits("Lon", 32, 1, 180 / 2**25, True))),
        "165": Variable(2),
        "RE": Explicit(), "SP": Explicit(),
    })},
    62: {"0.17": Edition(62, "0.17", (
        "010", "015", "070", "040", "105", "100", "060",
        "130", "135", "136", "180", "200", "220", "240",
        "210", "080", "290", "340", "380", "050", "390",
        "110", "120", "510", "-", "-", "RE", "SP",
    ), {
        **dict.fromkeys(("010", "015", "070", "040", "060", "130", "135", "136", "200",
                         "220", "210", "080", "340", "120", "510"), SAME),
        "105": F(6, (Bits("Lat", 48, 25, 180 / 2**23, True),
                     Bits("Lon", 24, 1, 180 / 2**23, True))),
        "100": F(4, (Bits("X", 32, 17, NM_M / 64, True), Bits("Y", 16, 1, NM_M / 64, True))),
        "180": F(4, (Bits("Spd", 32, 17, NM_M / 2**14), Bits("Hdg", 16, 1, 360 / 2**16))),
        "240": F(1), "110": F(1),  # I050 (FRN 20): layout not published, not declared
        "290": Compound(2, (F(1),) * 5 + (F(2),) + (F(1),) * 3),
        "380": Compound(1, (F(9), F(3), F(6), F(2), F(7))),
        "390": Compound(2, (F(2), F(7), F(4), F(1), F(4), F(1), F(4), F(4), F(3), F(2),
                            F(2), Repetitive(4), F(6), F(1))),
        "RE": Explicit(), "SP": Explicit(),
    })},
}  # fmt: skip
"""Editions we read beside :data:`DEFAULT_EDITIONS`, per category."""


def known_editions(cat: int) -> list[str]:
    """The shipped edition first, then the others we declare."""
    out = [DEFAULT_EDITIONS[cat]] if cat in DEFAULT_EDITIONS else []
    return out + sorted(e for e in EDITIONS.get(cat, {}) if e not in out)


# -- definition files ----------------------------------------------------------------------


def _bits_xml(b: Bits) -> str:
    enc = ' encode="signed"' if b.signed else ""
    unit = f'<BitsUnit scale="{b.scale!r}">u</BitsUnit>' if b.scale is not None else ""
    return (f'<Bits from="{b.hi}" to="{b.lo}"{enc}><BitsShortName>{b.name}</BitsShortName>'
            f"{unit}</Bits>")  # fmt: skip


def _opaque_bits(hi: int, lo: int, tag: str = "VAL") -> list[str]:
    """Opaque bits hi..lo in fields of at most 32 bits (the decoder's integer width)."""
    out, k = [], 0
    while hi >= lo:
        top = max(lo, hi - 31)
        out.append(f'<Bits from="{hi}" to="{top}"><BitsShortName>{tag}{k}</BitsShortName></Bits>')
        hi, k = top - 1, k + 1
    return out


def _fixed_xml(f: Fixed) -> str:
    bits = 8 * f.length
    parts, used = [], sorted(f.fields, key=lambda b: -b.hi)
    top = bits
    for b in used:
        if b.hi < top:
            parts += _opaque_bits(top, b.hi + 1, f"gap{top}_")
        parts.append(_bits_xml(b))
        top = b.lo - 1
    if top >= 1:
        parts += _opaque_bits(top, 1)
    return f'<Fixed length="{f.length}">' + "".join(parts) + "</Fixed>"


def _fx_part(length: int, k: int, presence: list[int] | None = None) -> str:
    bits = 8 * length
    if presence is None:
        body = _opaque_bits(bits, 2, f"P{k}_")
    else:
        body = [
            f'<Bits bit="{bits - j}"><BitsShortName>S{p}</BitsShortName>'
            f"<BitsPresence>{p}</BitsPresence></Bits>"
            for j, p in enumerate(presence)
        ]
    fx = '<Bits bit="1" fx="1"><BitsShortName>FX</BitsShortName></Bits>'
    return f'<Fixed length="{length}">' + "".join(body) + fx + "</Fixed>"


def _layout_xml(lay: Layout) -> str:
    if isinstance(lay, Fixed):
        return _fixed_xml(lay)
    if isinstance(lay, Variable):
        return "<Variable>" + "".join(_fx_part(lay.length, k) for k in range(lay.parts)) + (
            "</Variable>")  # fmt: skip
    if isinstance(lay, Repetitive):
        return "<Repetitive>" + _fixed_xml(Fixed(lay.length)) + "</Repetitive>"
    if isinstance(lay, Explicit):
        return "<Explicit>" + _fixed_xml(Fixed(1)) + "</Explicit>"
    if isinstance(lay, Compound):
        prim = [_fx_part(1, k, list(range(7 * k + 1, 7 * k + 8))) for k in range(lay.primary)]
        return ("<Compound><Variable>" + "".join(prim) + "</Variable>"
                + "".join(_layout_xml(s) for s in lay.subfields) + "</Compound>")  # fmt: skip
    raise TypeError(f"not a layout: {lay!r}")


def _item_xml(item: str, lay: Layout) -> str:
    return (f'<DataItem id="{item}"><DataItemName>{item}</DataItemName>'
            f"<DataItemDefinition>declared by surveil</DataItemDefinition>"
            f"<DataItemFormat>{_layout_xml(lay)}</DataItemFormat></DataItem>")  # fmt: skip


def _uap_xml(uap: tuple[str, ...]) -> str:
    out, bit = [], 0
    for frn, item in enumerate(uap, start=1):
        if bit % 8 == 7:  # the FX bit of each FSPEC octet
            out.append(f'<UAPItem bit="{bit}" frn="FX" len="-">-</UAPItem>')
            bit += 1
        out.append(f'<UAPItem bit="{bit}" frn="{frn}" len="-">{item}</UAPItem>')
        bit += 1
    while bit % 8:
        out.append(f'<UAPItem bit="{bit}" frn="FX" len="-">-</UAPItem>' if bit % 8 == 7 else
                   f'<UAPItem bit="{bit}" frn="{len(uap) + bit}" len="-">-</UAPItem>')  # fmt: skip
        bit += 1
    return "<UAP>" + "".join(out) + "</UAP>"


def definition_xml(ed: Edition, shipped_xml: str) -> str:
    """The definition file of ``ed``: SAME items cut from the shipped file's text."""
    items = []
    for item in dict.fromkeys(i for i in ed.uap if i != "-"):
        lay = ed.items.get(item)
        if lay is None:  # layout not published: a record carrying it does not parse
            continue
        if lay == SAME:
            m = re.search(rf'<DataItem id="{item}"[^>]*>.*?</DataItem>', shipped_xml, re.S)
            if m is None:
                raise ValueError(f"CAT{ed.category:03d} item {item} missing in the shipped file")
            items.append(m.group(0))
        else:
            items.append(_item_xml(item, lay))
    return (f'<?xml version="1.0" encoding="UTF-8"?>\n<Category id="{ed.category:03d}" '
            f'name="CAT{ed.category:03d} ed {ed.version} (surveil)" ver="{ed.version}">'
            + "".join(items) + _uap_xml(ed.uap) + "</Category>\n")  # fmt: skip


_FILES: dict[tuple[int, str], str] = {}
_FOLDER: dict[int, Path] = {}  # pid -> this process's folder of definition files


def definitions_folder() -> Path:
    """This process's folder for the definition files handed to ``asterix_decoder`` (it
    reads them by path while the process lives); removed when the process exits, so a
    nightly run leaves nothing in the temporary directory. A forked child makes its own."""
    pid = os.getpid()
    if pid not in _FOLDER:
        _FOLDER[pid] = Path(tempfile.mkdtemp(prefix=f"surveil-asterix-{pid}-"))
        atexit.register(shutil.rmtree, _FOLDER[pid], ignore_errors=True)
    return _FOLDER[pid]


def definition_file(cat: int, version: str, shipped_path: str) -> str:
    """Path of the definition file of an edition of :data:`EDITIONS` (written once per
    process into :func:`definitions_folder`)."""
    key = (cat, version)
    if key not in _FILES:
        xml = definition_xml(EDITIONS[cat][version], Path(shipped_path).read_text())
        path = definitions_folder() / f"asterix_cat{cat:03d}_{version.replace('.', '_')}.xml"
        path.write_text(xml)
        _FILES[key] = str(path)
    return _FILES[key]


def parse_edition_metadata(text: str | None) -> dict[int, str]:
    """Channel metadata ``asterix_editions`` (``"010=0.24,021=0.26"``) -> {cat: edition};
    unknown pairs are ignored."""
    out: dict[int, str] = {}
    for pair in (text or "").split(","):
        cat, _, ed = pair.partition("=")
        try:
            c = int(cat.strip())
        except ValueError:
            continue
        if ed.strip() in known_editions(c):
            out[c] = ed.strip()
    return out
