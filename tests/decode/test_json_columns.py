"""The compiled JSON column parser (``pipeline/decode/_json_columns.c``) against the reference.

The contract (header of ``_json_columns.c``): a row is either decoded EXACTLY as the
reference path decodes it (``json_bulk.parse_json_payloads``: polars + ``json.loads``) or
flagged, and then the reference decodes it. So ``json_bulk.parse_columns`` (native parse,
flagged rows through the fallback) must give the same frame, bit for bit, and the same
rejects as ``parse_json_payloads`` on the same payloads. Number conversion
(``_json_columns.to_double``) must be ``float()`` bit for bit or ``None``.

``FORMER_DISCREPANCIES`` are the differences these tests first found (each fixed: in the
parser, or in the reference for newlines between tokens); they stay as regression cases.
"""

from __future__ import annotations

import json
import struct
from decimal import ROUND_CEILING, ROUND_FLOOR, Context, Decimal

import numpy as np
import polars as pl
import pyarrow as pa
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from polars.testing import assert_frame_equal

from pipeline.decode import json_bulk, json_columns
from pipeline.io.mcap_read import ChannelBatch, ChunkData

needs_ext = pytest.mark.skipif(not json_columns.AVAILABLE, reason="C extension not built")

SCHEMA = {
    "x": pl.Float64(),
    "y": pl.Float64(),
    "n": pl.Int64(),
    "name": pl.String(),
    "ok": pl.Boolean(),
}
FLOATS = [k for k, t in SCHEMA.items() if t == pl.Float64()]
I64_MIN, I64_MAX = -(2**63), 2**63 - 1


def to_double(tok: bytes) -> float | None:
    return json_columns._json_columns.to_double(tok)


def bits(v: float) -> bytes:
    return struct.pack("<d", v)


# == number conversion ========================================================================


def assert_tokens_convert(tokens: list[bytes]) -> list[bytes]:
    """Every token converts to ``float(token)`` bit for bit or to ``None``; returns the
    tokens that gave ``None``."""
    wrong, none = [], []
    for tok in tokens:
        got = to_double(tok)
        if got is None:
            none.append(tok)
        elif bits(got) != bits(float(tok)):
            wrong.append((tok, got, float(tok)))
    assert not wrong, f"{len(wrong)} tokens converted wrongly, e.g. {wrong[:5]}"
    return none


@needs_ext
def test_to_double_repr_of_random_bit_patterns():
    rng = np.random.default_rng(20240611)
    values = rng.integers(0, 2**64, size=200_000, dtype=np.uint64).view(np.float64)
    values = values[np.isfinite(values)]
    tokens = [repr(v).encode() for v in values.tolist()]
    none = assert_tokens_convert(tokens)
    # None only for subnormal doubles (documented), never for a normal one
    subnormal = [t for t in none if float(t) != 0.0 and abs(float(t)) < 2.2250738585072014e-308]
    assert none == subnormal, none[:5]
    assert len(none) < 0.001 * len(tokens)


@needs_ext
def test_to_double_realistic_values():
    rng = np.random.default_rng(5)
    values = (rng.normal(size=60_000) * 1e4).tolist()
    tokens = [repr(v).encode() for v in values]
    tokens += [f"{v:.6f}".encode() for v in values[:20_000]]
    tokens += [f"{v:.3f}".encode() for v in values[20_000:40_000]]
    tokens += [f"{v:.17g}".encode() for v in values[40_000:]]
    tokens += [f"{v:.9e}".encode() for v in values[:10_000]]
    none = assert_tokens_convert(tokens)
    assert len(none) < 0.001 * len(tokens), none[:5]
    assert none == []


def _digit_tokens(rng: np.random.Generator, n: int, max_digits: int) -> list[bytes]:
    out = []
    for _ in range(n):
        k = int(rng.integers(1, max_digits + 1))
        digits = "".join(map(str, rng.integers(0, 10, size=k).tolist()))
        point = int(rng.integers(0, k + 1))
        whole = digits[:point].lstrip("0") or "0"
        frac = digits[point:]
        tok = whole + ("." + frac if frac else "")
        if rng.random() < 0.7:
            tok += "eE"[int(rng.integers(0, 2))]
            tok += ["", "+", "-"][int(rng.integers(0, 3))]
            tok += str(int(rng.integers(0, 41)))
        if rng.random() < 0.5:
            tok = "-" + tok
        out.append(tok.encode())
    return out


@needs_ext
def test_to_double_random_digit_strings():
    rng = np.random.default_rng(11)
    tokens = _digit_tokens(rng, 100_000, 19)
    none = assert_tokens_convert(tokens)
    # at most 19 significant digits, exponent in [-40, 40]: always a normal double or zero
    assert none == [], none[:5]


@needs_ext
def test_to_double_more_than_19_digits():
    rng = np.random.default_rng(12)
    tokens = _digit_tokens(rng, 20_000, 40)
    tokens += [b"1" + b"0" * k for k in range(18, 40)]
    tokens += [b"1." + b"0" * k for k in range(18, 40)]
    tokens += [b"123456789012345678" + b"0" * k + b"e-5" for k in range(1, 10)]
    none = assert_tokens_convert(tokens)
    # more than 19 significant digits (trailing zeros count) go to the fallback
    assert b"1" + b"0" * 18 not in none and b"1." + b"0" * 17 not in none
    assert b"1" + b"0" * 19 in none and b"1." + b"0" * 19 in none


def _halfway_tokens() -> list[bytes]:
    """Integers at, next to and exactly halfway between doubles from 2**53 to 2**64, and
    the same scaled by powers of ten (trailing zeros, scientific notation)."""
    rng = np.random.default_rng(3)
    ints = []
    for e in range(53, 64):
        ulp = 2 ** (e - 52)
        ks = [0, 1, 2, 3, 2**52 - 1, *rng.integers(0, 2**52, size=40).tolist()]
        for k in ks:
            m = 2**e + k * ulp
            half = m + ulp // 2
            ints += [m, m + 1, m - 1, half, half - 1, half + 1]
    tokens = []
    for v in ints:
        s = str(v)
        tokens += [s, "-" + s, s + "0", s + "000", s + "e0", s + "e3", s + "e-3"]
        tokens.append(f"{s[0]}.{s[1:]}e{len(s) - 1}")
    return [t.encode() for t in tokens]


def _near_halfway_decimal_tokens() -> tuple[list[bytes], list[bytes]]:
    """19-digit decimals just below and above the exact midpoint of two adjacent doubles
    (the hardest cases for Eisel-Lemire), and the exact midpoints (> 19 digits)."""
    rng = np.random.default_rng(4)
    values = np.concatenate(
        [
            rng.integers(0, 2**64, size=3000, dtype=np.uint64).view(np.float64),
            rng.normal(size=2000) * 10.0 ** rng.integers(-30, 30, size=2000),
        ]
    )
    values = values[np.isfinite(values) & (np.abs(values) > 1e-300) & (np.abs(values) < 1e300)]
    exact = Context(prec=2000)  # a midpoint of two doubles has at most ~770 digits
    down, up = Context(prec=19, rounding=ROUND_FLOOR), Context(prec=19, rounding=ROUND_CEILING)
    mids, near = [], []
    for v in np.abs(values).tolist():
        mid = exact.divide(exact.add(Decimal(v), Decimal(float(np.nextafter(v, np.inf)))), 2)
        mids.append(str(mid).encode())
        near += [str(down.plus(mid)).encode(), str(up.plus(mid)).encode()]
    return mids, near


@needs_ext
def test_to_double_halfway_cases():
    tokens = _halfway_tokens()
    none = assert_tokens_convert(tokens)
    # every token with at most 19 significant digits converts
    assert all(
        len(t.lstrip(b"-").split(b"e")[0].replace(b".", b"").lstrip(b"0")) > 19 for t in none
    )
    mids, near = _near_halfway_decimal_tokens()
    assert assert_tokens_convert(near) == []  # 19 digits, normal: always converted
    none = assert_tokens_convert(mids)  # mostly > 19 digits: left to the fallback
    assert len(none) > 0.5 * len(mids)


SPECIAL = [
    b"0",
    b"-0",
    b"0.0",
    b"-0.0",
    b"0e0",
    b"-0e-5",
    b"0.000000000000000000000000000000",
    b"0e99999999999",
    b"1",
    b"-1",
    b"1e23",
    b"8.41e21",
    b"1e22",
    b"9007199254740992",
    b"9007199254740993",
    b"9007199254740995",
    b"18014398509481983",
    b"9223372036854775807",
    b"9223372036854775808",
    b"18446744073709551615",
    b"18446744073709551616",
    b"2.2250738585072014e-308",
    b"2.2250738585072011e-308",
    b"4.9406564584124654e-324",
    b"5e-324",
    b"1.7976931348623157e308",
    b"1.7976931348623158e308",
    b"1.7976931348623159e308",
    b"1e308",
    b"1e309",
    b"1e400",
    b"-1e400",
    b"1e-400",
    b"1e99999999999",
    b"1e-99999999999",
    b"0.1",
    b"0.2",
    b"0.3",
    b"3.141592653589793",
    b"2.718281828459045235360287",
    b"123456789012345678",
    b"1234567890123456789",
    b"12345678901234567890",
    b"1.00000000000000011102230246251565404236316680908203125",
    b"7.1e-10",
    b"1E+2",
    b"1e-0",
    b"100000000000000000000000",
]


@needs_ext
@pytest.mark.parametrize("tok", SPECIAL)
def test_to_double_special_tokens(tok):
    got = to_double(tok)
    assert got is None or bits(got) == bits(float(tok))


@needs_ext
@pytest.mark.parametrize(
    "tok, want",
    [
        (b"0", 0.0),
        (b"-0.0", -0.0),
        (b"1e23", 1e23),
        (b"9007199254740993", 9007199254740992.0),
        (b"2.2250738585072014e-308", 2.2250738585072014e-308),
        (b"1.7976931348623157e308", 1.7976931348623157e308),
    ],
)
def test_to_double_converts_these(tok, want):
    got = to_double(tok)
    assert got is not None and bits(got) == bits(want)


@needs_ext
@pytest.mark.parametrize(
    "tok",
    [b"5e-324", b"1e400", b"-1e400", b"1e-400", b"1e309", b"0e99999999999", b"1e1000",
     b"12345678901234567890", b"1" + b"0" * 40],
)  # fmt: skip
def test_to_double_leaves_these_to_the_fallback(tok):
    # subnormal, infinite, zero by underflow, exponent beyond 999, > 19 digits
    assert to_double(tok) is None


@needs_ext
@pytest.mark.parametrize(
    "tok",
    [
        b"",
        b"01",
        b"-01",
        b"00",
        b"1.",
        b".5",
        b"-.5",
        b"+1",
        b"1e",
        b"1e+",
        b"1E-",
        b"-",
        b"--1",
        b"1.e5",
        b"NaN",
        b"-NaN",
        b"Infinity",
        b"-Infinity",
        b"inf",
        b"0x10",
        b"1_000",
        b"1.5.1",
        b"1e5.5",
        b" 1",
        b"1 ",
        b"1,",
        b"\xd9\xa1",
        b"true",
        b"null",
        b'"1"',
    ],
)
def test_to_double_rejects_invalid_tokens(tok):
    assert to_double(tok) is None


# == parse_columns against the reference ======================================================


def _message(channel: int, seq: int, payload: bytes) -> tuple[bytes, int]:
    """An MCAP Message record and the offset of its payload in it."""
    body = struct.pack("<HIQQ", channel, seq, 1000 + seq, 1000 + seq) + payload
    return struct.pack("<BQ", 5, len(body)) + body, 31


def make_order(payloads: list[bytes], chunks: int = 2, channels: int = 3) -> json_bulk.MessageOrder:
    """The payloads as messages of ``channels`` interleaved channels in ``chunks`` chunks
    (real record headers around them), merged back into file order by ``message_order``."""
    bounds = np.linspace(0, len(payloads), chunks + 1).astype(int).tolist()
    batches = []
    for c in range(chunks):
        raw = bytearray()
        spans: dict[int, tuple[list[int], list[int], list[int]]] = {}
        for i in range(bounds[c], bounds[c + 1]):
            ch = 1 + i % channels
            rec, off = _message(ch, i, payloads[i])
            t, s, e = spans.setdefault(ch, ([], [], []))
            t.append(1000 + i)
            s.append(len(raw) + off)
            e.append(len(raw) + len(rec))
            raw += rec
        chunk = ChunkData(bytes(raw))
        for ch, (t, s, e) in sorted(spans.items()):
            batches.append(
                ChannelBatch(
                    ch,
                    f"/t{ch}",
                    "json",
                    "",
                    "",
                    b"",
                    np.array(t),
                    chunk=chunk,
                    start=np.array(s, dtype=np.int64),
                    end=np.array(e, dtype=np.int64),
                )
            )
    order = json_bulk.message_order(batches)
    assert order.payloads(np.arange(len(order))) == list(payloads)
    return order


def _rows(parse: json_bulk.JsonParse) -> dict[int, tuple]:
    """``_idx`` -> row, floats as their bits (so -0.0 != 0.0 and NaNs compare)."""
    out = {}
    for row in parse.frame.iter_rows(named=True):
        key = row.pop("_idx")
        out[key] = tuple(bits(v) if k in FLOATS and v is not None else v for k, v in row.items())
    return out


def assert_native_matches_reference(payloads: list[bytes], **order_kw) -> json_bulk.JsonParse:
    payloads = list(payloads)
    order = make_order(payloads, **order_kw)
    got = json_bulk.parse_columns(order, SCHEMA)
    assert got is not None
    want = json_bulk.parse_json_payloads(payloads, SCHEMA)
    # a readable account first: which payloads decode differently
    g, w = _rows(got), _rows(want)
    diff = sorted(i for i in set(g) | set(w) if g.get(i) != w.get(i))
    assert not diff, "\n".join(
        f"payload {payloads[i]!r}: native {g.get(i)} reference {w.get(i)}" for i in diff[:5]
    )
    # then exactly: same frame (dtypes, order, _idx) and the same rejects in the same order
    assert_frame_equal(got.frame, want.frame)
    assert got.frame["_idx"].is_sorted()
    assert list(zip(got.bad_idx, got.bad_code, got.bad_reason, strict=True)) == list(
        zip(want.bad_idx, want.bad_code, want.bad_reason, strict=True)
    )
    assert got.frame.height + len(got.bad_idx) == len(payloads)
    return got


def dumps(obj: object, **kw) -> bytes:
    return json.dumps(obj, **kw).encode()


def good(i: int) -> dict:
    return {
        "x": 1.5 + i * 0.37,
        "y": -2.25e-3 * i,
        "n": 1000 * i - 7,
        "name": f"t{i}",
        "ok": i % 2 == 1,
    }


def good_bytes(i: int) -> bytes:
    return dumps(good(i), separators=(",", ":"))


def _shuffled(d: dict, rng: np.random.Generator) -> dict:
    keys = list(d)
    rng.shuffle(keys)
    return {k: d[k] for k in keys}


def corpus() -> dict[str, list[bytes]]:
    """Payload groups: each is compared on its own and all together."""
    rng = np.random.default_rng(99)
    g = {}
    g["normal"] = [good_bytes(i) for i in range(20)] + [
        dumps(good(i) | {"ok": True}) for i in range(5)
    ]
    g["shuffled"] = [dumps(_shuffled(good(i) | {"ok": False}, rng)) for i in range(20)]
    nested = {
        "a": [1, 2.5, {"b": [None, True, False, "s"]}],
        "c": {},
        "d": [],
        "e": {"f": {"g": 1}},
    }
    g["extra_keys"] = [
        dumps({"pre": nested, **good(1), "ok": True, "post": "tail"}),
        dumps({"u": 'esc " \\ \n \t \u00e9 \u2603 \U0001f600 /', "x": 1.0}),
        dumps({"u": "raw \u00e9 \u2603 \U0001f600", "x": 2.0}, ensure_ascii=False),
        dumps({"x": 3.0, "u": "\ud800 lone surrogate"}),
        dumps({"x": 4.0, "big": 10**38, "neg": -(2**127), "f": 1.5e300, "tiny": 1e-300}),
        dumps({"x": 5.0, "nan_text": "NaN", "arr": [[], [[]], [{}], [1e-5, -0.0]]}),
        dumps({"name": "k", "\u00e9": 1, "é2": "é"}, ensure_ascii=False),
        dumps({"name": "k", 'esc"key': 1, "x\\y": 2}),
        dumps({"xx": 1, "x ": 2, "nam": "no", "names": "no", "x": 6.0}),
        b'{"x": 7.0, "u": "\\ud83d\\ude00", "v": "\\/\\b\\f\\r"}',
        b'{"x": 8.0, "dup": 1, "dup": 2}',
        b'{"\\u0078": 9.0}',  # an escaped key spelling a wanted one
        b'{"x": 10.0, "u": 1E+2, "v": -0, "w": 0.0e-0}',
        b'{"x": 11.0, "u": "\x7f"}',
        b'{"n": 12, "u": "a\\"b", "name": "after"}',
    ]
    g["whitespace"] = [
        b' { "x" : 1.5 , "n" : 2 , "name" : "a" , "ok" : true } ',
        b'\t{\t"x"\t:\t1.5\t}\t',
        b'\r{\r"x"\r:\r1.5,"y":\r2}\r',
        b'{  "ok"  :  false  ,  "y"  :  -1e-3  }',
        b'{"x":1}\n',
        b'{"x":1}\r\n',
        b'\n{"x":1}',
        b'{"x":1}   \n   ',
        b"{}",
        b"{ }",
        b"{\t}",
    ]
    drops = [["x"], ["y", "n"], ["name"], ["ok"], list(SCHEMA)]
    g["missing"] = [
        dumps({k: v for k, v in good(i).items() if k not in drop}) for i, drop in enumerate(drops)
    ]
    g["nulls"] = [
        dumps({"x": None, "y": 1.0, "n": None, "name": None, "ok": None}),
        dumps({"x": 1.0, "y": None}),
        b'{"name": null, "u": null}',
        b'{"x": nul}',
        b'{"x": nulll}',
        b'{"x": Null}',
    ]
    g["wrong_types"] = [
        b'{"x": "1.5"}',
        b'{"x": "abc"}',
        b'{"n": 1.5}',
        b'{"n": 1e3}',
        b'{"n": 1.0}',
        b'{"n": 10E0}',
        b'{"n": "7"}',
        b'{"n": true}',
        b'{"x": true}',
        b'{"x": false}',
        b'{"name": 5}',
        b'{"name": 1.5}',
        b'{"name": true}',
        b'{"name": ["a"]}',
        b'{"name": {"a": 1}}',
        b'{"ok": 1}',
        b'{"ok": 0}',
        b'{"ok": "true"}',
        b'{"ok": tru}',
        b'{"x": [1.0]}',
        b'{"x": {"v": 1.0}}',
        b'{"n": [1]}',
        b'{"ok": [true]}',
    ]
    g["strings"] = [
        b'{"name": "q\\"uote"}',
        b'{"name": "back\\\\slash"}',
        b'{"name": "new\\nline"}',
        b'{"name": "\\u00e9t\\u00e9"}',
        b'{"name": "\\ud83d\\ude00"}',
        b'{"name": "\\/"}',
        b'{"name": "\\ud800"}',
        '{"name": "été ☃ 😀"}'.encode(),
        b'{"name": ""}',
        b'{"name": " spaces "}',
        b'{"name": "tab\there"}',
        b'{"name": "\xff\xfe"}',
        b'{"name": "\xc3"}',
        b'{"name": "bad \\q escape"}',
        b'{"name": "bad \\u12 escape"}',
        b'{"name": "unterminated}',
        b'{"name": "~\x7f"}',
    ]
    g["duplicates"] = [
        b'{"x": 1.0, "x": 2.0}',
        b'{"n": 1, "y": 3.0, "n": 2}',
        b'{"name": "a", "name": "b"}',
        b'{"ok": true, "ok": null}',
        b'{"x": null, "x": 2.0}',
        b'{"u": 1, "u": 2, "x": 3.0}',
    ]
    ints = [I64_MAX, I64_MIN, I64_MAX + 1, I64_MIN - 1, 2**64 - 1, 2**64, 10**19, 10**30, -(10**30)]
    g["int_limits"] = [b'{"n": %d}' % v for v in ints] + [
        b'{"n": -0}',
        b'{"n": 0}',
        b'{"n": 00}',
        b'{"n": 01}',
        b'{"n": -}',
        b'{"n": 9223372036854775807, "x": 9223372036854775807}',
        b'{"x": -9223372036854775808}',
        b'{"x": 18446744073709551615}',
        b'{"x": 18446744073709551616}',
        b'{"x": %d}' % (10**30),
        b'{"x": 9007199254740993}',
    ]
    g["long_numbers"] = [
        b'{"x": 3.14159265358979323846264338327950288}',
        b'{"x": 123456789012345678901234567890}',
        b'{"x": 0.1000000000000000000000001}',
        b'{"x": 1.000000000000000000000000}',
        b'{"x": 100000000000000000000000}',
        b'{"x": 1.00000000000000011102230246251565404236316680908203125}',
        b'{"y": 2.2250738585072011e-308}',
        b'{"y": 0.000000000000000000000000000000000000001234567890123456789}',
        b'{"y": 12345678901234567890e-30}',
    ]
    g["nonfinite"] = [
        b'{"x": NaN}',
        b'{"x": -NaN}',
        b'{"x": Infinity}',
        b'{"x": -Infinity}',
        b'{"y": 1.0, "x": NaN}',
        b'{"x": 1.0, "u": NaN}',
        b'{"x": 1.0, "u": Infinity}',
        b'{"x": 1e400}',
        b'{"x": -1e400}',
        b'{"x": 1e-400}',
        b'{"x": 5e-324}',
        b'{"x": 2.5e-310}',
        b'{"x": 1.7976931348623157e308}',
        b'{"x": 1.7976931348623159e308}',
        b'{"x": inf}',
        b'{"x": nan}',
    ]
    full = b'{"x": 1.5, "y": -2.0, "n": 42, "name": "abc", "ok": true, "u": [1, {"v": "w"}]}'
    g["truncated"] = [full[:k] for k in range(1, len(full), 3)] + [b"{", b'{"x"', b'{"x":']
    g["trailing"] = [
        good_bytes(1) + b"x",
        good_bytes(2) + b"{}",
        good_bytes(3) + b",",
        good_bytes(4) + b"\n" + good_bytes(5),
        good_bytes(6) + b" }",
        good_bytes(7) + b"\x00",
        good_bytes(8) + b"\x0c",
        b'{"x": 1.0,}',
        b'{"x": 1.0 "y": 2.0}',
        b'{"x" 1.0}',
        b"{x: 1.0}",
        b"{'x': 1.0}",
        b'{"x": 1.0}}',
        b"\xef\xbb\xbf" + good_bytes(9),
    ]
    g["empty"] = [b"", b" ", b"  \t ", b"\n"]
    g["not_object"] = [b"[1, 2]", b"[]", b"1", b'"s"', b"null", b"true", b"[{}]", b'[{"x": 1}]']
    g["deep"] = []
    for depth in (30, 31, 32, 33, 40):
        arr = b"[" * depth + b"]" * depth
        obj = b'{"a":' * depth + b"1" + b"}" * depth
        g["deep"] += [b'{"x": 1.0, "u": ' + arr + b"}", b'{"u": ' + obj + b', "n": 3}']
    g["deep"].append(b'{"u": ' + b"[" * 40 + b"}")  # deep and broken
    return g


CORPUS = corpus()

# Differences between the native path and the reference that these tests found, with what
# was wrong; fixed, kept as regression cases.
FORMER_DISCREPANCIES = {
    "newline_between_tokens": (
        [b'{"x":\n1.5}', b'{\n"n": 1}', b'{"x": 1.0,\n"name": "a"}'],
        "native accepts a valid object with a raw newline between tokens; the reference "
        "(read_ndjson is line based) rejects it as undecodable 'wrong field type: error "
        "parsing line: Syntax ...'",
    ),
    "minus_zero_integer_token": (
        [b'{"x": -0}'],
        "float field with the integer token -0: native gives -0.0, the reference 0.0 "
        "(polars reads an integer and casts it)",
    ),
    "unknown_key_invalid_escape": (
        [b'{"x": 1.0, "u": "\\q"}', b'{"x": 1.0, "u": "\\u00zz"}'],
        "an invalid escape in the string value of an UNKNOWN key is skipped by native "
        "(row accepted); the reference rejects the row: undecodable 'Invalid \\escape'",
    ),
    "unknown_key_invalid_utf8": (
        [b'{"x": 1.0, "u": "\xff"}', b'{"x": 1.0, "u": "\xc3"}'],
        "invalid UTF-8 in the string value of an UNKNOWN key is skipped by native (row "
        "accepted); the reference rejects the row: undecodable 'utf-8 codec can't decode'",
    ),
    "number_polars_cannot_read": (
        [
            b'{"x": 10000000000000000000000000000000000000000}',
            b'{"x": 0e99999999999}',
            b'{"x": 1.0, "u": 340282366920938463463374607431768211456}',
            b'{"x": 1.0, "u": 1e-99999999999}',
        ],
        "integer tokens outside [-2**127, 2**128) and exponents of ~19+ digits are valid "
        "JSON that polars refuses (InvalidNumber): the reference rejects the row as "
        "undecodable, native decodes it (1e40 / 0.0 in a float field; skipped under an "
        "unknown key)",
    ),
    "unknown_key_number_overflow": (
        [b'{"x": 1.0, "u": 1e400}', b'{"x": 1.0, "u": -1e999}', b'{"x": 1.0, "u": [1e309]}'],
        "a number that overflows a double under an UNKNOWN key is skipped by native (row "
        "accepted); the reference rejects the row: out_of_range 'non-finite value in u'",
    ),
}


@needs_ext
@pytest.mark.parametrize("group", sorted(CORPUS))
def test_group_matches_reference(group):
    payloads = CORPUS[group]
    # each group between well-formed rows, and alone
    mixed = [p for i, bad in enumerate(payloads) for p in (good_bytes(i), bad)] + [good_bytes(-1)]
    assert_native_matches_reference(mixed)
    assert_native_matches_reference(payloads, chunks=1, channels=1)


@needs_ext
def test_well_formed_rows_are_not_flagged():
    rows = CORPUS["normal"] + CORPUS["shuffled"] + CORPUS["whitespace"] + CORPUS["missing"]
    order = make_order(rows)
    kinds = json_columns.native_kinds(SCHEMA)
    _, flagged = json_columns.parse_spans(
        [c.raw for c in order.chunks], order.chunk, order.start, order.end, SCHEMA, kinds
    )
    assert flagged.tolist() == []
    got = assert_native_matches_reference(rows)
    assert got.bad_idx == []


@needs_ext
def test_parse_spans_unflagged_rows_equal_the_reference():
    """parse_spans directly: unflagged rows equal the reference's rows; every row the
    reference rejects or alters is flagged."""
    payloads = [p for group in sorted(CORPUS) for p in CORPUS[group]]
    order = make_order(payloads)
    table, flagged = json_columns.parse_spans(
        [c.raw for c in order.chunks],
        order.chunk,
        order.start,
        order.end,
        SCHEMA,
        json_columns.native_kinds(SCHEMA),
    )
    assert isinstance(table, pa.Table)
    frame = pl.from_arrow(table)
    assert frame.height == len(payloads) and flagged.dtype == np.int64
    assert np.all(np.diff(flagged) > 0)
    ref = json_bulk.parse_json_payloads(payloads, SCHEMA)
    assert set(ref.bad_idx) <= set(flagged.tolist())
    ok = np.setdiff1d(np.arange(len(payloads)), flagged)
    native = frame.with_row_index("_idx").filter(pl.col("_idx").is_in(ok.tolist()))
    native = native.with_columns(pl.col("_idx").cast(pl.Int64)).select([*SCHEMA, "_idx"])
    reference = ref.frame.filter(pl.col("_idx").is_in(ok.tolist()))
    assert_frame_equal(native, reference)
    # wanted strings with an escape or a non-ASCII byte are always left to the fallback
    for i, p in enumerate(payloads):
        if p.startswith(b'{"name": "') and (b"\\" in p or any(c >= 0x80 for c in p)):
            assert i in set(flagged.tolist()), p


@needs_ext
def test_whole_corpus_matches_reference():
    rng = np.random.default_rng(1)
    payloads = [p for group in sorted(CORPUS) for p in CORPUS[group]]
    payloads += [good_bytes(i) for i in range(300)]
    rng.shuffle(payloads)
    assert_native_matches_reference(payloads, chunks=3, channels=4)


@needs_ext
@pytest.mark.parametrize(
    "payload",
    [
        pytest.param(p, id=f"{name}-{i}")
        for name, (payloads, _why) in FORMER_DISCREPANCIES.items()
        for i, p in enumerate(payloads)
    ],
)
def test_former_discrepancy(payload):
    """Each minimal payload alone; then between a good row and a bad one (so the
    reference goes through its per-payload fallback too)."""
    assert_native_matches_reference([payload], chunks=1, channels=1)
    assert_native_matches_reference([good_bytes(0), payload, b"garbage"])


@needs_ext
def test_number_tokens_in_a_float_field_match_reference():
    """The hard conversion cases as field values: native equals polars' parse bit for bit
    (or flags the row)."""
    rng = np.random.default_rng(21)
    mids, near = _near_halfway_decimal_tokens()
    tokens = [*_halfway_tokens(), *mids[:2000], *near, *SPECIAL]
    tokens += _digit_tokens(rng, 5000, 19) + _digit_tokens(rng, 2000, 40)
    payloads = [b'{"n": 1, "x": ' + t + b"}" for t in tokens]
    for i in range(0, len(payloads), 8000):
        assert_native_matches_reference(payloads[i : i + 8000], chunks=2, channels=1)


# forms at the edges of the parser's fast path for floats ([-]I.F, 1-7 integer digits,
# at most 19 digits in all, no exponent: fast_decimal in _json_columns.c)
FAST_DECIMAL_EDGES = [
    b"-0.0", b"0.0", b"0.5", b"-0.5", b"00.5", b"01.5", b"-01.5", b"1.", b"-1.", b"-.5",
    b".5", b"-", b"--1.5", b"1.5e3", b"1.5E-3", b"1.5e", b"1.5.5", b"1.5-", b"1.5x",
    b"1234567.123456789012", b"-1234567.123456789012", b"1234567.1234567890123",
    b"12345678.5", b"1.12345678", b"1.123456789", b"1.123456789012345",
    b"1.1234567890123456", b"0.000000000000000001", b"0.0000000000000000001234",
    b"9999999.999999999999", b"9999999.9999999999999", b"-9999999.99999999999999",
    b"1000000.0000000000001", b"4.9406564584124654", b"2.2250738585072014",
    b"1.7976931348623157", b"0.30000000000000004", b"12527.808180456033",
]  # fmt: skip


@needs_ext
def test_float_tokens_followed_by_more_fields_match_reference():
    """The float tokens again, now with a long field after them: the fast path for the
    usual [-]I.F form (it reads 25 bytes ahead) decodes them, or leaves them to the
    generic scan, exactly as the reference does."""
    rng = np.random.default_rng(22)
    mids, near = _near_halfway_decimal_tokens()
    values = rng.normal(size=6000) * 10.0 ** rng.integers(-8, 8, size=6000)
    tokens = [*_halfway_tokens(), *mids[:2000], *near, *SPECIAL, *FAST_DECIMAL_EDGES]
    tokens += _digit_tokens(rng, 5000, 19) + [repr(v).encode() for v in values.tolist()]
    tail = b', "name": "long enough for 25 bytes", "n": 1}'
    payloads = [b'{"x": ' + t + tail for t in tokens]
    for i in range(0, len(payloads), 8000):
        assert_native_matches_reference(payloads[i : i + 8000], chunks=2, channels=1)


@needs_ext
def test_large_random_corpus_matches_reference():
    """Many rows, mostly well formed, from every group, in random order."""
    rng = np.random.default_rng(2024)
    pool = [p for group in sorted(CORPUS) for p in CORPUS[group]]
    payloads = []
    for i in range(4000):
        if rng.random() < 0.1:
            payloads.append(pool[int(rng.integers(0, len(pool)))])
        else:
            d = good(i) | {"ok": bool(i % 3)}
            d["x"] = float(rng.normal() * 10.0 ** int(rng.integers(-20, 20)))
            d["n"] = int(rng.integers(I64_MIN, I64_MAX, endpoint=True))
            if rng.random() < 0.3:
                d = _shuffled(d, rng)
            if rng.random() < 0.2:
                d.pop(list(d)[int(rng.integers(0, len(d)))])
            if rng.random() < 0.2:
                d["extra"] = {"k": [1, "two", None], "s": "é"}
            payloads.append(dumps(d, ensure_ascii=bool(rng.random() < 0.5)))
    assert_native_matches_reference(payloads, chunks=4, channels=3)


# == hypothesis ===============================================================================

_WS = st.sampled_from(["", "", "", " ", "  ", "\t", "\r", " \t\r "])
_FINITE = st.floats(allow_nan=False, allow_infinity=False)
_PLAIN = st.text(st.characters(min_codepoint=0x20, max_codepoint=0x7E, exclude_characters='"\\'))
_ANY_TEXT = st.text(st.characters(exclude_categories=("Cs",)), max_size=12)
# mostly plain ASCII (decoded natively), sometimes anything (escapes, non-ASCII: flagged)
_TEXT = st.integers(0, 3).flatmap(lambda r: _ANY_TEXT if r == 0 else _PLAIN)
_KEY = st.integers(0, 7).flatmap(
    lambda r: (
        _ANY_TEXT
        if r == 0
        else st.sampled_from(["u", "xx", "nam", "x ", "é", 'a"b', "x\\", "X"])
        if r == 1
        else st.from_regex(r"[a-z_][a-z0-9_]{0,8}", fullmatch=True)
    )
)
_NUMBER_TOKEN = st.from_regex(
    r"-?(0|[1-9][0-9]{0,24})(\.[0-9]{1,24})?([eE][+-]?[0-9]{1,3})?", fullmatch=True
)
_JSON_VALUE = st.recursive(
    st.none() | st.booleans() | _FINITE | st.integers(-(2**80), 2**80) | _TEXT,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(_KEY, inner, max_size=4),
    max_leaves=12,
)


def _dump(value: object, ascii_only: bool) -> str:
    return json.dumps(value, ensure_ascii=ascii_only)


@st.composite
def _value_token(draw: st.DrawFn, dtype: pl.DataType, ascii_only: bool) -> str:
    """A value for a wanted field: mostly of its type, sometimes null or of another type."""
    roll = draw(st.integers(0, 11))
    if roll == 0:
        return "null"
    if roll == 1:  # any JSON value: a wrong type most of the time
        return _dump(draw(_JSON_VALUE), ascii_only)
    if dtype == pl.Float64():
        tok = draw(
            st.one_of(
                _FINITE.map(repr),
                _NUMBER_TOKEN,
                st.integers(-(2**70), 2**70).map(str),
                st.floats(-1e6, 1e6).map(lambda v: f"{v:.6f}"),
            )
        )
        return "0" if tok == "-0" else tok  # -0: a known discrepancy, tested above
    if dtype == pl.Int64():
        return str(draw(st.one_of(st.integers(I64_MIN, I64_MAX), st.integers(-(2**70), 2**70))))
    if dtype == pl.Boolean():
        return draw(st.sampled_from(["true", "false"]))
    return _dump(draw(_TEXT), ascii_only)


@st.composite
def payloads_strategy(draw: st.DrawFn) -> bytes:
    """One payload: wanted keys in any order (a duplicate now and then), unknown keys with
    any JSON value between them, optional whitespace, sometimes damaged."""
    ascii_only = draw(st.booleans())
    names = list(draw(st.permutations(list(SCHEMA))))[: draw(st.integers(0, len(SCHEMA)))]
    if names and draw(st.integers(0, 9)) == 0:
        names.insert(draw(st.integers(0, len(names))), draw(st.sampled_from(names)))
    items = [(json.dumps(k), draw(_value_token(SCHEMA[k], ascii_only))) for k in names]
    for _ in range(draw(st.integers(0, 3))):
        key = draw(_KEY)
        items.insert(
            draw(st.integers(0, len(items))),
            (_dump(key, ascii_only), _dump(draw(_JSON_VALUE), ascii_only)),
        )
    ws = [draw(_WS) for _ in range(4 * len(items) + 3)]
    body = ",".join(
        f"{ws[4 * i]}{k}{ws[4 * i + 1]}:{ws[4 * i + 2]}{v}{ws[4 * i + 3]}"
        for i, (k, v) in enumerate(items)
    )
    text = f"{ws[-3]}{{{body or ws[-2]}}}{ws[-1]}"
    raw = text.encode("utf-8")
    damage = draw(st.integers(0, 19))
    if damage == 0 and len(raw) > 1:
        raw = raw[: draw(st.integers(0, len(raw) - 1))]
    elif damage == 1:
        raw += draw(st.sampled_from([b"x", b"{}", b",", b" 1", b"]", b"\x00"]))
    elif damage == 2:
        raw = draw(st.sampled_from([b"", b"[", b"[]", b"1", b"null", b'"s"']))
    return raw


@needs_ext
@settings(
    max_examples=200,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(st.lists(payloads_strategy(), min_size=1, max_size=24))
def test_hypothesis_payloads_match_reference(payloads):
    assert_native_matches_reference(payloads)


# == threads ==================================================================================


@needs_ext
def test_one_and_two_threads_give_identical_frames(monkeypatch):
    rng = np.random.default_rng(8)
    n = 60_000
    xs = (rng.normal(size=n) * 1e3).tolist()
    ns = rng.integers(-(10**12), 10**12, size=n).tolist()
    payloads = []
    for i in range(n):
        if i % 97 == 0:
            payloads.append(b'{"x": 1.0, "name": "esc\\"aped"}')  # flagged
        elif i % 89 == 0:
            payloads.append(b'{"n": 1.5}')  # flagged
        elif i % 13 == 0:
            payloads.append(b'{"y": null, "ok": false}')
        else:
            payloads.append(
                b'{"x":%r,"n":%d,"name":"r%d","ok":%s}'
                % (xs[i], ns[i], i, b"true" if i % 2 else b"false")
            )
    order = make_order(payloads, chunks=3, channels=2)
    chunks = [c.raw for c in order.chunks]
    kinds = json_columns.native_kinds(SCHEMA)
    calls: list[tuple[int, int]] = []
    real = json_columns._json_columns.parse_objects

    def spy(*args):
        calls.append((args[-2], args[-1]))
        return real(*args)

    monkeypatch.setattr(json_columns._json_columns, "parse_objects", spy)
    results = {}
    for count in (1, 2):
        monkeypatch.setattr(json_columns, "threads", lambda count=count: count)
        calls.clear()
        results[count] = json_columns.parse_spans(
            chunks, order.chunk, order.start, order.end, SCHEMA, kinds
        )
        assert len(calls) == count and sorted(calls)[0][0] == 0 and sorted(calls)[-1][1] == n
    (t1, flagged1), (t2, flagged2) = results[1], results[2]
    f1, f2 = pl.from_arrow(t1), pl.from_arrow(t2)
    assert_frame_equal(f1, f2)
    assert np.array_equal(flagged1, flagged2)
    expected = [i for i in range(n) if i % 97 == 0 or (i % 89 == 0 and i % 97)]
    assert flagged1.tolist() == expected
    assert f1["x"].to_numpy()[1].tobytes() == np.float64(xs[1]).tobytes()
    assert f1["name"][n - 1] == f"r{n - 1}" and f1["n"][n - 1] == ns[n - 1]


# == native_kinds =============================================================================


@needs_ext
def test_native_kinds_supported_schema():
    assert json_columns.native_kinds(SCHEMA) == "ffisb"
    assert json_columns.native_kinds({f"k{i}": pl.Float64() for i in range(64)}) == "f" * 64


@needs_ext
@pytest.mark.parametrize(
    "dtype",
    [
        pl.List(pl.Int64()),
        pl.List(pl.Float64()),
        pl.Struct({"a": pl.Int64()}),
        pl.Array(pl.Float64(), 2),
        pl.Float32(),
        pl.Int32(),
        pl.UInt64(),
        pl.Datetime("ns"),
        pl.Categorical(),
        pl.Null(),
        pl.Object(),
    ],
)
def test_native_kinds_unsupported_dtype(dtype):
    assert json_columns.native_kinds({"x": pl.Float64(), "other": dtype}) is None


@needs_ext
def test_native_kinds_too_many_fields_or_none():
    assert json_columns.native_kinds({f"k{i}": pl.Float64() for i in range(65)}) is None
    assert json_columns.native_kinds({}) is None


@needs_ext
def test_parse_columns_declines_unsupported_schema():
    order = make_order([good_bytes(0)])
    assert json_bulk.parse_columns(order, {"x": pl.List(pl.Float64())}) is None
    parsed, _ = json_bulk.parse_json_batches(
        [ChannelBatch(1, "/t", "json", "", "", b"", np.array([1]), [b'{"x": [1.5]}'])],
        {"x": pl.List(pl.Float64())},
    )
    assert parsed.frame["x"].to_list() == [[1.5]]


@needs_ext
def test_parse_json_batches_uses_the_native_path(monkeypatch):
    payloads = [good_bytes(i) for i in range(10)] + [b'{"name": "\\u00e9"}', b"bad"]
    batch = ChannelBatch(1, "/t", "json", "", "", b"", np.arange(len(payloads)), payloads)
    calls = []
    real = json_bulk.parse_columns
    monkeypatch.setattr(json_bulk, "parse_columns", lambda *a: calls.append(1) or real(*a))
    parsed, _ = json_bulk.parse_json_batches([batch], SCHEMA)
    assert calls == [1]
    want = json_bulk.parse_json_payloads(payloads, SCHEMA)
    assert_frame_equal(parsed.frame, want.frame)
    assert (
        (parsed.bad_idx, parsed.bad_code)
        == (want.bad_idx, want.bad_code)
        == ([11], ["undecodable"])
    )
    assert parsed.frame["name"][10] == "é"


def test_pow5_header_is_what_its_generator_writes():
    """The committed table of the Eisel-Lemire parser equals the generator's output."""
    from pathlib import Path

    from pipeline.decode import _pow5_table

    header = Path(_pow5_table.__file__).with_name("_pow5_128.h").read_text()
    assert header == _pow5_table.header()
    # spot checks against exact integer arithmetic: 5**0 and 5**1 normalised to 128 bits
    table = _pow5_table.pow5_128()
    assert table[-_pow5_table.SMALLEST] == (1 << 63, 0)
    assert table[1 - _pow5_table.SMALLEST] == (5 << 61, 0)


@needs_ext
def test_simulated_archive_ingests_the_same_without_the_extension(tmp_path, monkeypatch):
    """The simulator's radar and truth reports through ``surveil ingest`` with the
    compiled parser and with the polars path (what an install without a C compiler
    runs; forced here) give the same warehouse rows."""
    from jobs.simulate import run_simulate
    from pipeline.families import load_config
    from pipeline.ingest.driver import run_ingest
    from pipeline.warehouse.delta import read_table

    cfg = load_config()
    archive = run_simulate("channel", 240.0, 3, tmp_path / "archive", cfg)
    tables = {}
    for name, native in (("native", True), ("polars", False)):
        if not native:
            monkeypatch.setattr(json_bulk, "native_kinds", lambda schema: None)
        summary = run_ingest(archive, cfg, tmp_path / name, executor="serial")
        assert summary.exit_code == 0
        tables[name] = {t: read_table(tmp_path / name, t) for t in ("radar_tracks", "truth")}
    for t in ("radar_tracks", "truth"):
        assert tables["native"][t].num_rows > 1000
        assert tables["native"][t].equals(tables["polars"][t]), t


def test_keys_of_every_length_and_their_near_misses():
    """Keys of 1..24 bytes are compared word by word (the last word overlapping): a key
    that differs from a wanted one in its first, a middle or its last byte, or is one
    byte shorter or longer, is an unknown key; the values land in the right columns."""
    names = ["abcdefghijklmnopqrstuvwx"[:k] for k in range(1, 25)]
    schema = {name: pl.Float64() for name in names}
    rng = np.random.default_rng(11)
    payloads = []
    for i in range(400):
        obj: dict[str, float] = {}
        for k, name in enumerate(names):
            near = {
                0: name,
                1: "Z" + name[1:],
                2: name[:-1] + "Z",
                3: name[: len(name) // 2] + "Z" + name[len(name) // 2 + 1 :],
                4: name + "Z",
            }[int(rng.integers(0, 5))]
            obj.setdefault(near, float(i * 100 + k) + 0.25)
        payloads.append(dumps(_shuffled(obj, rng) if i % 3 else obj, separators=(",", ":")))
    order = make_order(payloads)
    got = json_bulk.parse_columns(order, schema)
    want = json_bulk.parse_json_payloads(payloads, schema)
    assert got is not None and got.bad_idx == want.bad_idx == []
    assert_frame_equal(got.frame, want.frame)
    assert 0 < got.frame.select(pl.all().exclude("_idx").null_count()).row(0)[5] < 400


@needs_ext
def test_rows_that_differ_from_the_previous_shape_by_one_byte():
    """Rows of one shape are read literal by literal; a row that differs from the shape
    of the row before it by one byte anywhere (replaced, deleted or inserted: a blank, a
    quote, an escape, a digit, a brace, a comma, a non-ASCII byte, ...) decodes exactly as
    the reference decodes it, and so does the well-formed row after it."""
    base = b'{"x":1.5,"u":"abc","y":-0.25e-1,"n":7,"name":"t1","ok":true,"v":[1,{"a":null}],"w":-3}'
    assert json.loads(base)["v"] == [1, {"a": None}]
    mutants = []
    for i in range(len(base)):
        for c in b' \n"\\x09-.e},:\xff':
            b = bytes([c])
            mutants.append(base[:i] + b + base[i + 1 :])
            mutants.append(base[:i] + b + base[i:])
        mutants.append(base[:i] + base[i + 1 :])
    mutants = list(dict.fromkeys(m for m in mutants if m != base))
    rows = [base, base]
    for m in mutants:
        rows += [m, base]
    got = assert_native_matches_reference(rows, chunks=3, channels=1)
    assert 0 < len(got.bad_idx) < len(mutants)  # some mutants are valid JSON, most are not


@needs_ext
def test_remembered_values_follow_the_rows():
    """Each slot of a shape remembers its last value; a slot that keeps missing stops
    trying until the shape is recorded again. Values that vary, then repeat, then vary
    again, longer and shorter ones sharing a prefix with the remembered bytes, nulls and
    booleans: every row decodes as the reference decodes it."""
    xs = [*(1.5 + i for i in range(20)), *([2.25] * 30), 2.255, 2.25, 22.5, 2.2, *range(9)]
    rows = []
    for i, x in enumerate(xs):
        obj = {"x": x, "y": None if i % 7 == 0 else -0.5, "n": 7 if i < 40 else i}
        obj |= {"name": "t1", "ok": i % 3 == 0, "u": "same" if i % 11 else "other"}
        rows.append(dumps(obj, separators=(",", ":")))
    rows.insert(35, dumps({"x": 1.0, "n": 1}))  # another shape in the middle
    got = assert_native_matches_reference(rows, chunks=2, channels=1)
    assert got.bad_idx == []
