"""pipeline.tables helpers: the date partition column and constant string columns."""

from __future__ import annotations

import datetime as dt

import pyarrow as pa
import pytest

from pipeline.tables import ConstantStrings, constant_strings, with_date

NS_PER_DAY = 86_400 * 10**9
EPOCH = dt.date(1970, 1, 1)


def _day(ns: int) -> dt.date:
    return EPOCH + dt.timedelta(days=ns // NS_PER_DAY)  # Python floors toward -inf


def test_date_is_the_utc_day_at_midnight_edges_and_before_1970():
    times = [0, 1, -1, NS_PER_DAY - 1, NS_PER_DAY, -NS_PER_DAY, -NS_PER_DAY - 1,
             1_768_435_200_000_641_271, 2**62, -(2**62)]  # fmt: skip
    table = pa.table({"time_ns": pa.array(times, pa.int64())})
    got = with_date(table, "time_ns")["date"]
    assert got.type == pa.date32()
    assert got.to_pylist() == [_day(t) for t in times]


def test_date_with_null_times_and_an_existing_date_column():
    table = pa.table(
        {
            "time_ns": pa.array([-1, None, NS_PER_DAY], pa.int64()),
            "date": pa.array([None, None, None], pa.date32()),
        }
    )
    got = with_date(table, "time_ns")
    assert got.column_names == ["time_ns", "date"]
    assert got["date"].to_pylist() == [_day(-1), None, _day(NS_PER_DAY)]


def test_constant_strings_are_slices_of_one_array_per_value():
    held = ConstantStrings()
    a = constant_strings("/archive/a.mcap", 3, held)
    b = constant_strings("/archive/a.mcap", 5, held)  # longer: a new, longer array
    c = constant_strings("/radar/tracks", 2, held)
    assert a.to_pylist() == ["/archive/a.mcap"] * 3
    assert b.to_pylist() == ["/archive/a.mcap"] * 5
    assert c.to_pylist() == ["/radar/tracks"] * 2
    assert a.type == b.type == pa.string() and a.null_count == 0
    # a shorter one is a slice of the array kept for the value: the same data buffer
    d = constant_strings("/archive/a.mcap", 4, held)
    assert d.buffers()[2].address == b.buffers()[2].address
    assert constant_strings("x", 0, held).to_pylist() == []
    assert constant_strings("x", 2).to_pylist() == ["x", "x"]  # nothing held: built anew


def test_constant_strings_keep_the_values_used_last():
    held = ConstantStrings(limit=2)
    first = held.get("a", 3)
    held.get("b", 3)
    assert held.get("a", 2).buffers()[2].address == first.buffers()[2].address
    held.get("c", 3)  # "b" was used least recently: dropped
    assert set(held._held) == {"a", "c"}


@pytest.mark.parametrize("value", ["", "é/ñ.mcap", "/radar/tracks"])
def test_constant_strings_equal_arrows_own_repeat(value):
    got = constant_strings(value, 7, ConstantStrings())
    got.validate(full=True)
    assert got.equals(pa.repeat(pa.scalar(value, pa.string()), 7))
