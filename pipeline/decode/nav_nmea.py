"""Field decoding of navigation and ARPA NMEA 0183 sentences, one formatter at a time.

Input: the well-formed sentences of one formatter as a polars frame (``fields``: the
list of field strings after the address field; index 0 is the first field). Output: the
columns of the target table in SI units, plus ``tod_ns`` (UTC time of day of the
sentence, ns, null when it has none), ``date_days`` (its date as days since 1970-01-01,
RMC/ZDA only) and ``code``/``reason`` (a problem that makes it a reject, else null).
Every formatter is decoded with column expressions over all its sentences at once.

Field layouts follow NMEA 0183 v4.10 (IEC 61162-1 ed. 5) §6.3; units converted at
decode: knots -> m/s (× 1852/3600), km/h -> m/s (/3.6), degrees -> rad, nautical miles
-> m (× 1852), statute miles -> m (× 1609.344), minutes -> s, rate of turn deg/min ->
rad/s. Latitude/longitude ``ddmm.mmmm`` + hemisphere -> signed degrees.

============  ================  ==================================================
formatter     table             columns
============  ================  ==================================================
GGA           nav_gnss          lat, lon, fix_quality, n_satellites, hdop, altitude
RMC           nav_gnss          lat, lon, fix_valid (status A), sog, cog, date
VTG           nav_gnss          cog (true), sog (knots, else km/h)
GSA           nav_gnss          n_satellites (PRNs listed), hdop
GLL           nav_gnss          lat, lon, fix_valid (status A)
ZDA           nav_gnss          date and time only (a row with no measurement)
HDT / HDM     nav_heading       heading (HDM: is_magnetic)
HDG           nav_heading       sensor + deviation (+ variation -> true heading)
THS           nav_heading       true heading, mode
ROT           nav_heading       rate of turn, status A/V in ``mode``
VHW           nav_speed_log     speed through water (knots, else km/h), true heading
VBW           nav_speed_log     water/ground longitudinal + transverse speeds, valid
TTM           arpa_targets      number, range, bearing, speed, course, CPA, TCPA, status
TLL           arpa_targets      number, lat, lon, name, status
OSD           arpa_own_ship     heading, course, speed, set, drift and references
============  ================  ==================================================
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import polars as pl

from pipeline.units import KNOT_MPS, NM_M, TIME_MAX_DAYS

KMH_MPS = 1.0 / 3.6
SM_M = 1609.344
DEG = math.pi / 180.0
_DIST_M = {"N": NM_M, "K": 1000.0, "S": SM_M}

Case = tuple[pl.Expr, str, pl.Expr]
YEAR_MIN, YEAR_MAX = 1970, 2262
"""Calendar years of the representable range (``pipeline.units.TIME_MAX_NS``)."""


# -- field expressions ------------------------------------------------------------------


def fld(i: int) -> pl.Expr:
    """Field ``i`` as a stripped string, null when absent or empty."""
    x = pl.col("fields").list.get(i, null_on_oob=True).str.strip_chars()
    return pl.when(x.str.len_chars() > 0).then(x)


def num(i: int) -> pl.Expr:
    """Field ``i`` as float64, null when empty or not a number."""
    return fld(i).cast(pl.Float64, strict=False)


def not_number(*idx: int) -> pl.Expr:
    """True when one of the fields is present but not a number."""
    return pl.any_horizontal(
        [fld(i).is_not_null() & num(i).is_null() for i in idx] or [pl.lit(False)]
    )


def latlon(i: int, j: int, pos: str) -> pl.Expr:
    """``ddmm.mmmm`` (field i) + hemisphere (field j, ``pos`` = N or E) -> signed deg."""
    v = num(i)
    deg = (v / 100.0).floor()
    sign = pl.when(fld(j) == pos).then(1.0).otherwise(-1.0)
    return (deg + (v - 100.0 * deg) / 60.0) * sign


def latlon_bad(i: int, j: int, pos: str, neg: str) -> pl.Expr:
    """Coordinate present with a missing/wrong hemisphere, or minutes >= 60."""
    v = num(i)
    minutes = v - 100.0 * (v / 100.0).floor()
    bad_hemi = ~fld(j).is_in([pos, neg]).fill_null(False)
    return v.is_not_null() & (bad_hemi | (minutes >= 60.0) | (v < 0))


def tod_ns(i: int) -> pl.Expr:
    """``hhmmss(.sss)`` -> ns since midnight (Int64), null when empty or malformed."""
    s = fld(i)
    ok = s.str.contains(r"^\d{6}(\.\d*)?$")
    h = s.str.slice(0, 2).cast(pl.Int64, strict=False)
    m = s.str.slice(2, 2).cast(pl.Int64, strict=False)
    sec = s.str.slice(4).cast(pl.Float64, strict=False)
    total = ((h * 3600 + m * 60).cast(pl.Float64) + sec) * 1e9
    valid = ok & (h < 24) & (m < 60) & (sec < 61.0)
    return pl.when(valid).then(total.round(0).cast(pl.Int64))


def tod_bad(i: int) -> pl.Expr:
    return fld(i).is_not_null() & tod_ns(i).is_null()


def days_from_civil(y: np.ndarray, m: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Days since 1970-01-01 of a proleptic Gregorian date (H. Hinnant's algorithm)."""
    y = y - (m <= 2)
    era = np.floor_divide(y, 400)
    yoe = y - era * 400
    doy = (153 * (m + np.where(m > 2, -3, 9)) + 2) // 5 + d - 1
    doe = yoe * 365 + yoe // 4 - yoe // 100 + doy
    return era * 146097 + doe - 719468


def _date_days(y: pl.Series, m: pl.Series, d: pl.Series) -> pl.Series:
    """Days since 1970-01-01, null for an invalid date or one outside the representable
    range (1970-01-01 .. 2262-04-10: its ns would not fit an int64)."""
    ok = (m >= 1) & (m <= 12) & (d >= 1) & (d <= 31) & y.is_not_null()
    ok = ok & (y >= YEAR_MIN) & (y <= YEAR_MAX)
    yy, mm, dd = (s.fill_null(1970).to_numpy().astype(np.int64) for s in (y, m, d))
    days = days_from_civil(yy, mm, dd)
    valid = ok.fill_null(False).to_numpy() & (days >= 0) & (days <= TIME_MAX_DAYS)
    return pl.Series("date_days", np.where(valid, days, 0), pl.Int64).scatter(
        np.flatnonzero(~valid), None
    )


def first_problem(cases: list[Case]) -> tuple[pl.Expr, pl.Expr]:
    """``(code, reason)`` expressions of the first case whose condition holds."""
    code: pl.Expr = pl.lit(None, pl.String)
    reason: pl.Expr = pl.lit(None, pl.String)
    for cond, k, why in reversed(cases):
        hit = cond.fill_null(False)
        code = pl.when(hit).then(pl.lit(k)).otherwise(code)
        reason = pl.when(hit).then(why).otherwise(reason)
    return code, reason


def _range(col: str, lo: float, hi: float, what: str) -> Case:
    c = pl.col(col)
    return (
        (c.is_not_null() & ((c < lo) | (c > hi))),
        "out_of_range",
        pl.format(f"{what}={{}} outside [{lo:g}, {hi:g}]", c.round(4)),
    )


def _speed(col: str, max_mps: float) -> Case:
    c = pl.col(col)
    return (
        (c.abs() > max_mps),
        "out_of_range",
        pl.format(
            f"{col}={{}} above {max_mps:g} m/s ({{}} kn)", c.round(3), (c / KNOT_MPS).round(1)
        ),
    )


def _no_data(cols: list[str]) -> Case:
    return (
        pl.all_horizontal([pl.col(c).is_null() for c in cols]),
        "no_data",
        pl.lit("no measurement: every field is empty"),
    )


def _undecodable(cond: pl.Expr, what: str) -> Case:
    return cond, "undecodable", pl.lit(what)


# -- nav_gnss ---------------------------------------------------------------------------

_GGA_DATA = ["lat_deg", "lon_deg", "fix_quality", "n_satellites", "hdop", "altitude_m"]
_RMC_DATA = ["lat_deg", "lon_deg", "fix_valid", "sog_mps", "cog_rad"]


def _position_cases(i_lat: int, i_lon: int) -> list[Case]:
    return [
        _undecodable(latlon_bad(i_lat, i_lat + 1, "N", "S"), "bad latitude or hemisphere"),
        _undecodable(latlon_bad(i_lon, i_lon + 1, "E", "W"), "bad longitude or hemisphere"),
        _range("lat_deg", -90.0, 90.0, "lat_deg"),
        _range("lon_deg", -180.0, 180.0, "lon_deg"),
    ]


def _gga(df: pl.DataFrame, max_speed_mps: float) -> pl.DataFrame:
    out = df.with_columns(
        tod_ns=tod_ns(0),
        lat_deg=latlon(1, 2, "N"),
        lon_deg=latlon(3, 4, "E"),
        fix_quality=num(5).cast(pl.Int16, strict=False),
        n_satellites=num(6).cast(pl.Int16, strict=False),
        hdop=num(7),
        altitude_m=num(8),
    )
    cases = [
        _undecodable(tod_bad(0), "bad UTC time field"),
        _undecodable(not_number(1, 3, 5, 6, 7, 8), "a numeric field is not a number"),
        *_position_cases(1, 3),
        _no_data(_GGA_DATA),
    ]
    return _finish(out, cases)


def _rmc(df: pl.DataFrame, max_speed_mps: float) -> pl.DataFrame:
    d = fld(8)
    out = df.with_columns(
        tod_ns=tod_ns(0),
        fix_valid=pl.when(fld(1).is_not_null()).then(fld(1) == "A"),
        lat_deg=latlon(2, 3, "N"),
        lon_deg=latlon(4, 5, "E"),
        sog_mps=num(6) * KNOT_MPS,
        cog_deg=num(7),
        _dd=d.str.slice(0, 2).cast(pl.Int64, strict=False),
        _mm=d.str.slice(2, 2).cast(pl.Int64, strict=False),
        _yy=d.str.slice(4, 2).cast(pl.Int64, strict=False),
        _date_bad=d.is_not_null() & ~d.str.contains(r"^\d{6}$").fill_null(False),
    )
    yy = out["_yy"]
    year = (yy + 1900).zip_with(yy >= 80, yy + 2000)  # NMEA two-digit year, pivot 1980
    out = out.with_columns(
        date_days=_date_days(year, out["_mm"], out["_dd"]),
        cog_rad=pl.col("cog_deg") * DEG,
    )
    cases = [
        _undecodable(tod_bad(0), "bad UTC time field"),
        _undecodable(pl.col("_date_bad"), "bad date field (ddmmyy)"),
        _undecodable(not_number(2, 4, 6, 7), "a numeric field is not a number"),
        *_position_cases(2, 4),
        _speed("sog_mps", max_speed_mps),
        _range("cog_deg", 0.0, 360.0, "cog_deg"),
        _no_data(_RMC_DATA),
    ]
    return _finish(out, cases)


def _vtg(df: pl.DataFrame, max_speed_mps: float) -> pl.DataFrame:
    out = df.with_columns(
        cog_deg=num(0),
        sog_mps=pl.coalesce(num(4) * KNOT_MPS, num(6) * KMH_MPS),
    ).with_columns(cog_rad=pl.col("cog_deg") * DEG)
    cases = [
        _undecodable(not_number(0, 2, 4, 6), "a numeric field is not a number"),
        _speed("sog_mps", max_speed_mps),
        _range("cog_deg", 0.0, 360.0, "cog_deg"),
        _no_data(["sog_mps", "cog_rad"]),
    ]
    return _finish(out, cases)


def _gsa(df: pl.DataFrame, max_speed_mps: float) -> pl.DataFrame:
    prns = pl.sum_horizontal([fld(i).is_not_null().cast(pl.Int16) for i in range(2, 14)])
    out = df.with_columns(
        n_satellites=pl.when(fld(1).is_not_null()).then(prns).cast(pl.Int16),
        hdop=num(15),
    )
    cases = [
        _undecodable(not_number(1, 14, 15, 16), "a numeric field is not a number"),
        _no_data(["n_satellites", "hdop"]),
    ]
    return _finish(out, cases)


def _gll(df: pl.DataFrame, max_speed_mps: float) -> pl.DataFrame:
    out = df.with_columns(
        tod_ns=tod_ns(4),
        lat_deg=latlon(0, 1, "N"),
        lon_deg=latlon(2, 3, "E"),
        fix_valid=pl.when(fld(5).is_not_null()).then(fld(5) == "A"),
    )
    cases = [
        _undecodable(tod_bad(4), "bad UTC time field"),
        _undecodable(not_number(0, 2), "a numeric field is not a number"),
        *_position_cases(0, 2),
        _no_data(["lat_deg", "lon_deg"]),
    ]
    return _finish(out, cases)


def _zda(df: pl.DataFrame, max_speed_mps: float) -> pl.DataFrame:
    out = df.with_columns(
        tod_ns=tod_ns(0),
        _d=num(1).cast(pl.Int64, strict=False),
        _m=num(2).cast(pl.Int64, strict=False),
        _y=num(3).cast(pl.Int64, strict=False),
    )
    out = out.with_columns(date_days=_date_days(out["_y"], out["_m"], out["_d"]))
    partial_date = (fld(1).is_not_null() | fld(2).is_not_null() | fld(3).is_not_null()) & (
        pl.col("date_days").is_null()
    )
    year_out = pl.col("_y").is_not_null() & ~pl.col("_y").is_between(YEAR_MIN, YEAR_MAX)
    cases = [
        _undecodable(tod_bad(0), "bad UTC time field"),
        _undecodable(not_number(1, 2, 3, 4, 5), "a numeric field is not a number"),
        (
            year_out,
            "out_of_range",
            pl.format(
                f"ZDA year {{}} outside {YEAR_MIN}..{YEAR_MAX} (a two-digit year?): its "
                "time cannot be represented",
                pl.col("_y"),
            ),
        ),
        _undecodable(partial_date, "bad date fields (dd, mm, yyyy)"),
        _no_data(["tod_ns"]),
    ]
    return _finish(out, cases)


# -- nav_heading ------------------------------------------------------------------------


def _heading_cases(col: str, *numeric: int) -> list[Case]:
    return [
        _undecodable(not_number(*numeric), "a numeric field is not a number"),
        _range(col, 0.0, 360.0, col),
        _no_data(["heading_rad"]),
    ]


def _hdt(df: pl.DataFrame, max_speed_mps: float) -> pl.DataFrame:
    out = df.with_columns(heading_deg=num(0), is_magnetic=pl.lit(False))
    out = out.with_columns(heading_rad=pl.col("heading_deg") * DEG)
    return _finish(out, _heading_cases("heading_deg", 0))


def _hdm(df: pl.DataFrame, max_speed_mps: float) -> pl.DataFrame:
    out = df.with_columns(heading_deg=num(0), is_magnetic=pl.lit(True))
    out = out.with_columns(heading_rad=pl.col("heading_deg") * DEG)
    return _finish(out, _heading_cases("heading_deg", 0))


def _signed(i_val: int, i_dir: int) -> pl.Expr:
    return num(i_val) * pl.when(fld(i_dir) == "W").then(-1.0).otherwise(1.0)


def _hdg(df: pl.DataFrame, max_speed_mps: float) -> pl.DataFrame:
    """Magnetic sensor heading + deviation = magnetic heading; + variation = true."""
    out = df.with_columns(
        sensor_deg=num(0),
        deviation_rad=_signed(1, 2) * DEG,
        variation_rad=_signed(3, 4) * DEG,
    )
    magnetic = pl.col("sensor_deg") * DEG + pl.col("deviation_rad").fill_null(0.0)
    true = magnetic + pl.col("variation_rad")
    out = out.with_columns(
        heading_rad=pl.coalesce(true, magnetic) % (2 * math.pi),
        is_magnetic=pl.when(pl.col("sensor_deg").is_not_null()).then(
            pl.col("variation_rad").is_null()
        ),
    )
    return _finish(out, _heading_cases("sensor_deg", 0, 1, 3))


def _ths(df: pl.DataFrame, max_speed_mps: float) -> pl.DataFrame:
    out = df.with_columns(heading_deg=num(0), mode=fld(1), is_magnetic=pl.lit(False))
    out = out.with_columns(heading_rad=pl.col("heading_deg") * DEG)
    return _finish(out, _heading_cases("heading_deg", 0))


def _rot(df: pl.DataFrame, max_speed_mps: float) -> pl.DataFrame:
    out = df.with_columns(rate_of_turn_radps=num(0) * DEG / 60.0, mode=fld(1))
    cases = [
        _undecodable(not_number(0), "rate of turn is not a number"),
        _no_data(["rate_of_turn_radps"]),
    ]
    return _finish(out, cases)


# -- nav_speed_log ----------------------------------------------------------------------

_LOG_DATA = [
    "speed_water_mps",
    "transverse_speed_water_mps",
    "speed_ground_mps",
    "transverse_speed_ground_mps",
]


def _vhw(df: pl.DataFrame, max_speed_mps: float) -> pl.DataFrame:
    out = df.with_columns(
        heading_deg=num(0),
        speed_water_mps=pl.coalesce(num(4) * KNOT_MPS, num(6) * KMH_MPS),
    ).with_columns(heading_rad=pl.col("heading_deg") * DEG)
    cases = [
        _undecodable(not_number(0, 2, 4, 6), "a numeric field is not a number"),
        _speed("speed_water_mps", max_speed_mps),
        _range("heading_deg", 0.0, 360.0, "heading_deg"),
        _no_data(["speed_water_mps", "heading_rad"]),
    ]
    return _finish(out, cases)


def _vbw(df: pl.DataFrame, max_speed_mps: float) -> pl.DataFrame:
    statuses = [fld(2), fld(5)]
    out = df.with_columns(
        speed_water_mps=num(0) * KNOT_MPS,
        transverse_speed_water_mps=num(1) * KNOT_MPS,
        speed_ground_mps=num(3) * KNOT_MPS,
        transverse_speed_ground_mps=num(4) * KNOT_MPS,
        valid=pl.all_horizontal([s.fill_null("A") == "A" for s in statuses]),
    )
    cases = [
        _undecodable(not_number(0, 1, 3, 4), "a numeric field is not a number"),
        *[_speed(c, max_speed_mps) for c in _LOG_DATA],
        _no_data(_LOG_DATA),
    ]
    return _finish(out, cases)


# -- ARPA -------------------------------------------------------------------------------

_TTM_DATA = ["range_m", "bearing_rad", "speed_mps", "course_rad"]


def _unit_factor(i: int, table: dict[str, float]) -> pl.Expr:
    u = fld(i).fill_null("N")
    expr: pl.Expr = pl.lit(None, pl.Float64)
    for k, v in table.items():
        expr = pl.when(u == k).then(v).otherwise(expr)
    return expr


def _ttm(df: pl.DataFrame, max_speed_mps: float) -> pl.DataFrame:
    dist = _unit_factor(9, _DIST_M)
    speed = dist / 3600.0
    out = df.with_columns(
        target_number=num(0).cast(pl.Int64, strict=False),
        range_m=num(1) * dist,
        bearing_deg=num(2),
        bearing_is_relative=pl.when(fld(3).is_not_null()).then(fld(3) == "R"),
        speed_mps=num(4) * speed,
        course_deg=num(5),
        course_is_relative=pl.when(fld(6).is_not_null()).then(fld(6) == "R"),
        cpa_m=num(7) * dist,
        tcpa_s=num(8) * 60.0,
        target_name=fld(10),
        target_status=fld(11),
        is_reference=pl.when(fld(12).is_not_null()).then(fld(12) == "R"),
        tod_ns=tod_ns(13),
        acquisition=fld(14),
    ).with_columns(bearing_rad=pl.col("bearing_deg") * DEG, course_rad=pl.col("course_deg") * DEG)
    cases = [
        _undecodable(tod_bad(13), "bad UTC time field"),
        _undecodable(not_number(0, 1, 2, 4, 5, 7), "a numeric field is not a number"),
        _undecodable(fld(9).is_not_null() & ~fld(9).is_in(list(_DIST_M)), "unknown units"),
        _range("bearing_deg", 0.0, 360.0, "bearing_deg"),
        _range("course_deg", 0.0, 360.0, "course_deg"),
        _speed("speed_mps", max_speed_mps),
        _no_data(_TTM_DATA),
    ]
    return _finish(out, cases)


def _tll(df: pl.DataFrame, max_speed_mps: float) -> pl.DataFrame:
    out = df.with_columns(
        target_number=num(0).cast(pl.Int64, strict=False),
        lat_deg=latlon(1, 2, "N"),
        lon_deg=latlon(3, 4, "E"),
        target_name=fld(5),
        tod_ns=tod_ns(6),
        target_status=fld(7),
        is_reference=pl.when(fld(8).is_not_null()).then(fld(8) == "R"),
    )
    cases = [
        _undecodable(tod_bad(6), "bad UTC time field"),
        _undecodable(not_number(0, 1, 3), "a numeric field is not a number"),
        *_position_cases(1, 3),
        _no_data(["lat_deg", "lon_deg"]),
    ]
    return _finish(out, cases)


def _osd(df: pl.DataFrame, max_speed_mps: float) -> pl.DataFrame:
    dist = _unit_factor(8, _DIST_M)
    speed = dist / 3600.0
    out = df.with_columns(
        heading_deg=num(0),
        heading_valid=pl.when(fld(1).is_not_null()).then(fld(1) == "A"),
        course_deg=num(2),
        course_reference=fld(3),
        speed_mps=num(4) * speed,
        speed_reference=fld(5),
        set_deg=num(6),
        drift_mps=num(7) * speed,
    ).with_columns(
        heading_rad=pl.col("heading_deg") * DEG,
        course_rad=pl.col("course_deg") * DEG,
        set_rad=pl.col("set_deg") * DEG,
    )
    cases = [
        _undecodable(not_number(0, 2, 4, 6, 7), "a numeric field is not a number"),
        _range("heading_deg", 0.0, 360.0, "heading_deg"),
        _range("course_deg", 0.0, 360.0, "course_deg"),
        _speed("speed_mps", max_speed_mps),
        _no_data(["heading_rad", "course_rad", "speed_mps", "set_rad", "drift_mps"]),
    ]
    return _finish(out, cases)


# -- table ------------------------------------------------------------------------------

Decoder = Callable[[pl.DataFrame, float], pl.DataFrame]

DECODERS: dict[str, tuple[str, Decoder]] = {
    "GGA": ("nav_gnss", _gga),
    "RMC": ("nav_gnss", _rmc),
    "VTG": ("nav_gnss", _vtg),
    "GSA": ("nav_gnss", _gsa),
    "GLL": ("nav_gnss", _gll),
    "ZDA": ("nav_gnss", _zda),
    "HDT": ("nav_heading", _hdt),
    "HDM": ("nav_heading", _hdm),
    "HDG": ("nav_heading", _hdg),
    "THS": ("nav_heading", _ths),
    "ROT": ("nav_heading", _rot),
    "VHW": ("nav_speed_log", _vhw),
    "VBW": ("nav_speed_log", _vbw),
    "TTM": ("arpa_targets", _ttm),
    "TLL": ("arpa_targets", _tll),
    "OSD": ("arpa_own_ship", _osd),
}
"""formatter -> (table, decoder)."""


def _finish(out: pl.DataFrame, cases: list[Case]) -> pl.DataFrame:
    code, reason = first_problem(cases)
    out = out.with_columns(code=code, reason=reason)
    for col, dtype in (("tod_ns", pl.Int64), ("date_days", pl.Int64)):
        if col not in out.columns:
            out = out.with_columns(pl.lit(None, dtype).alias(col))
    return out.drop([c for c in out.columns if c.startswith("_") or c == "fields"])


def decode_formatter(formatter: str, df: pl.DataFrame, max_speed_mps: float) -> pl.DataFrame:
    """Decode the sentences of one formatter (``df`` must carry ``fields``)."""
    _, fn = DECODERS[formatter]
    return fn(df, max_speed_mps)
