"""Declaring the config file's values once, and one reader that checks them all.

Every value a config dataclass reads from the TOML file is declared beside its field
with :func:`setting`: the file key (the field name unless given; ``unit="deg"`` reads
``*_deg`` into a ``*_rad`` field), the default *in file units*, the valid range and any
conversion. Its type is the field's annotation: ``bool``, ``int``, ``float`` (finite;
an integer is accepted), ``str``, ``tuple[...]`` (a TOML array), a nested config
dataclass (a table), ``tuple[Dataclass, ...]`` (an array of tables) or
``Mapping[str, Dataclass]`` (a table of tables); ``X | None``. Fields without a
``setting`` are not read from the file.

:class:`Document` walks the dataclasses over the parsed TOML and collects every
problem (wrong type, out of range, duplicate id, missing or unknown key or section)
with its key path and, when the TOML text is at hand, its line, so that one load
reports them all. It also records each value as resolved (file units, defaults marked)
for ``surveil config check``.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import json
import math
import re
import types
import typing
from collections.abc import Callable, Hashable, Mapping
from dataclasses import dataclass, field
from typing import Any

REQUIRED: Any = dataclasses.MISSING
_MISSING = object()  # a key absent from the file
_BAD = object()  # a value that failed its checks (the problem is recorded)

Path = tuple[str | int, ...]


class ConfigError(ValueError):
    """The configuration file is missing, malformed or inconsistent (exit code 2)."""


@dataclass(frozen=True)
class Spec:
    """How one dataclass field is read from the file (see :func:`setting`)."""

    default: Any = REQUIRED
    key: Path | None = None
    unit: str | None = None
    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    choices: tuple[Any, ...] | None = None
    min_len: int | None = None
    max_len: int | None = None
    unique: bool = False
    check: Callable[[Any], str | None] | None = None
    convert: Callable[..., Any] | None = None
    sources: tuple[str, ...] | None = None
    mask: Callable[[Any], Any] | None = None  # what `config check` shows of the value
    scenario: str | None = None  # a simulator setting: the scenario file that holds it
    why: str | None = None  # the reason for the range (physics, the sensor), told with it

    def file_key(self, name: str) -> Path:
        if self.key is not None:
            return self.key
        return (name.replace("_rad", "_deg", 1) if self.unit == "deg" else name,)

    def to_field(self, value: Any) -> Any:
        """A checked file value -> the field's value (unit conversion, then ``convert``)."""
        if self.unit == "deg":
            value = math.radians(value)
        return self.convert(value) if self.convert is not None else value


def setting(default: Any = REQUIRED, *, key: str | Path | None = None, unit: str | None = None,
            gt: float | None = None, ge: float | None = None, lt: float | None = None,
            le: float | None = None, choices: tuple[Any, ...] | None = None,
            min_len: int | None = None, max_len: int | None = None, unique: bool = False,
            check: Callable[[Any], str | None] | None = None,
            convert: Callable[..., Any] | None = None, sources: tuple[str, ...] | None = None,
            factory: Callable[[], Any] | None = None, file_only: bool = False,
            mask: Callable[[Any], Any] | None = None,
            scenario: str | None = None, why: str | None = None) -> Any:
    """A dataclass field read from the config file.

    ``default``: the value when the key is absent, in file units (``REQUIRED``: the key
    must be there; ``{}``: an absent table reads as empty, i.e. all its defaults; ``[]``:
    no entries). A scalar or list default, converted, is also the dataclass default
    unless ``file_only`` (field order forbids it); a table's dataclass default is
    ``factory``. ``key``: the file key, or a path (``("start", 0)``: the first element
    of ``start``; ``("fairway", "max_cross_track_m")``: a key of another table).
    ``unit="deg"``: the file key ends ``_deg``, the field holds radians.

    Checks: ``gt``/``ge``/``lt``/``le`` bound every number in the value (file units);
    ``why``: the reason for those bounds (physics, the sensor), appended to the problem
    (``must be in [0.5, 30], got 1e-09: a rotating antenna ...``); ``choices``;
    ``min_len``/``max_len`` of an array (``why`` for the latter too); ``unique`` within
    its array of tables ("" excepted); ``check``: value -> problem text or None.
    ``convert``: checked file value -> field value. ``sources``: several file keys, all
    or none present, passed to ``convert``, which raises ``ValueError(message)`` or
    ``ValueError(index of the key at fault, message)``. ``mask``: file value -> what
    ``surveil config check`` shows (credentials are never printed).

    ``scenario``: the value is the simulator's world, not the site's (a fault schedule,
    an injected bias): it is read only from a scenario file (``config/scenarios/
    <scenario>.toml``, :func:`scenario_problem`); in a site config it is a problem
    saying where it moved, and the field keeps its default."""
    spec = Spec(default, (key,) if isinstance(key, str) else key, unit, gt, ge, lt, le, choices,
                min_len, max_len, unique, check, convert, sources, mask, scenario, why)
    meta = {"setting": spec}
    if factory is not None:
        return field(default_factory=factory, metadata=meta)
    if default is REQUIRED or file_only or isinstance(default, dict):
        return field(metadata=meta)
    if isinstance(default, list):
        return field(default=_frozen(default), metadata=meta)
    return field(default=default if default is None else spec.to_field(default), metadata=meta)


def _frozen(v: Any) -> Any:
    return tuple(_frozen(x) for x in v) if isinstance(v, list) else v


# --- the common kinds of value ---------------------------------------------------------


def positive(default: Any = REQUIRED, **kw: Any) -> Any:
    """A number > 0 (sigmas, periods, distances, gains)."""
    return setting(default, gt=0.0, **kw)


def probability(default: Any = REQUIRED, **kw: Any) -> Any:
    """A probability in the open interval (0, 1)."""
    return setting(default, gt=0.0, lt=1.0, **kw)


def gate(default: Any = REQUIRED, **kw: Any) -> Any:
    """The probability that a chi-square gate keeps a true pairing, in [0.5, 1)."""
    return setting(default, ge=0.5, lt=1.0, why=(
        "a gate keeps a true pairing with this probability; below 0.5 it rejects most "
        "of them"), **kw)


def false_alarm(default: Any = REQUIRED, **kw: Any) -> Any:
    """The false-alarm probability of one integrity check, in (0, 0.1]."""
    return setting(default, gt=0.0, le=0.1, why=(
        "the share of healthy checks flagged; above 0.1 a healthy channel is excluded "
        "every few epochs"), **kw)


MAX_SECTORS = 100
"""The most sectors (maritime or airfield areas) a site declares: a VTS area or an
airfield is split into a few to a few tens; every sector is a row of each per-sector
report and a bar of each audit chart. `surveil audit` of a 15-minute channel scene took
5.8 s with the shipped 3 sectors and 8.5 s with the same water tiled into 100; with
10,000 it ran for more than 600 s (issue 40). A cap, not a grouped audit: past a hundred
the per-sector tables and charts are no longer read, and the sectors are the site's to
merge (they name what operators watch)."""


def sector_list(**kw: Any) -> Any:
    """An array of sector tables, at most :data:`MAX_SECTORS`."""
    return setting([], file_only=True, max_len=MAX_SECTORS, why=(
        "a site is split into a few to a few tens of sectors; each is a row of every "
        "per-sector report and a bar of every audit chart: merge small ones"), **kw)


def count(default: Any = REQUIRED, **kw: Any) -> Any:
    """An integer >= 1."""
    return setting(default, ge=1, **kw)


def latitude(default: Any = REQUIRED, **kw: Any) -> Any:
    return setting(default, ge=-90.0, le=90.0, **kw)


def longitude(default: Any = REQUIRED, **kw: Any) -> Any:
    return setting(default, ge=-180.0, le=180.0, **kw)


def height(default: Any = REQUIRED, **kw: Any) -> Any:
    """Metres above the ellipsoid, from the Dead Sea shore to Everest."""
    return setting(default, ge=-500.0, le=9000.0, **kw)


def _nonempty(v: str) -> str | None:
    return None if v.strip() else "must not be empty"


def text(default: Any = REQUIRED, **kw: Any) -> Any:
    """A non-empty string (an id: ``unique=True``)."""
    return setting(default, check=_nonempty, **kw)


def _polygon(points: tuple[tuple[float, float], ...]) -> str | None:
    if len(points) < 3:
        return f"a polygon needs at least 3 [lat_deg, lon_deg] vertices, got {len(points)}"
    for i, (lat, lon) in enumerate(points):
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            return f"vertex {i} [{lat}, {lon}] is not a [lat_deg, lon_deg] pair"
    return _simple_polygon(points)


_NO_AREA_DEG2 = 1e-10  # ~1 m^2 at mid latitudes
_INVALID = re.compile(r"^(?P<what>[A-Za-z -]+?)\s*\[(?P<lat>\S+) (?P<lon>\S+)\]$")


def _simple_polygon(points: tuple[tuple[float, float], ...]) -> str | None:
    """A polygon whose edges cross or touch (a bow-tie, a figure eight) or that encloses
    no area is refused naming the point: which side of a crossing is "inside" is not
    what the author meant (a bow-tie sector lost 17 % of its samples to "outside
    sectors", issue 40). shapely's validity (GEOS), in the file's [lat, lon] plane."""
    import shapely
    from shapely.validation import explain_validity

    shape = shapely.Polygon(points)
    if shapely.MultiPoint(points).convex_hull.area < _NO_AREA_DEG2 or (
            shape.is_valid and shape.area < _NO_AREA_DEG2):
        return "encloses no area (its vertices lie on one line)"
    if shape.is_valid:
        return None
    m = _INVALID.match(explain_validity(shape))
    if m is None:
        return f"is not a valid polygon ({explain_validity(shape)})"
    at = f"[{float(m['lat']):.6f}, {float(m['lon']):.6f}]"
    if "intersection" in m["what"]:
        return (f"its edges cross or touch at {at} (lat_deg, lon_deg): a polygon's "
                "boundary must not cross itself; list the vertices in order around it")
    return f"is not a valid polygon ({m['what'].lower()} at {at} (lat_deg, lon_deg))"


def polygon(**kw: Any) -> Any:
    """``polygon = [[lat_deg, lon_deg], ...]`` (at least 3 vertices)."""
    return setting(key="polygon", check=_polygon, **kw)


# --- reading --------------------------------------------------------------------------


class Document:
    """One parsed TOML document being read into config dataclasses.

    ``read`` returns the dataclass, or None when any of its values had a problem (the
    problems are collected); ``problem`` adds one found by a cross-field check;
    ``finish`` reports the keys no reader looked up and raises :class:`ConfigError` with
    every problem. ``resolved`` renders the values read, in file units, as TOML."""

    def __init__(self, raw: Mapping[str, Any], source: str, text: str | None = None,
                 *, scenario: bool = False) -> None:
        self.raw = raw
        self.source = source
        self.text = text
        # a site config (False) or a site config merged with scenario files (True): only
        # the latter may hold simulator settings (``setting(scenario=...)``)
        self.scenario = scenario
        self._problems: dict[str, Path] = {}  # message -> path (for its line)
        self._reported = 0  # problems reported, repeats included
        self._seen: set[Path] = set()  # every path a reader looked up, present or not
        self._shown: dict[Path, dict[str, list[Any]]] = {(): {}}  # table -> key -> [value, default]

    # - public -
    def read(self, cls: type, *path: str | int) -> Any:
        """The dataclass ``cls`` read from the table at ``path`` (absent: all defaults)."""
        table = self._get(self.raw, (), path)
        if table is _BAD:
            return None
        return self._dataclass(cls, {} if table is _MISSING else table, path)

    def has(self, *path: str | int) -> bool:
        return self._get(self.raw, (), path) is not _MISSING

    def problem(self, path: Path, message: str) -> None:
        """A problem with the value at ``path`` (e.g. ``("radar_sites", 2, "site_id")``)."""
        self._add(f"{render_path(path)}: {message}", path)

    def _add(self, text: str, path: Path) -> None:
        self._reported += 1
        self._problems.setdefault(text, path)

    def simulator_setting(self, path: Path, scenario: str) -> bool:
        """Whether the simulator setting at ``path`` may be read: True in a scenario
        document; in a site config False, and a problem when the file has it (where it
        moved: :func:`scenario_problem`). The path is marked as looked up either way."""
        if self.scenario:
            return True
        if self._get(self.raw, (), path) is not _MISSING:
            self._add(scenario_problem(path, scenario), path)
        return False

    def claim(self, *sections: str) -> None:
        """Top-level tables owned by a reader, known even when it does not look at them
        (an absent optional section; it is still suggested for a misspelt one)."""
        self._seen.update((s,) for s in sections)

    def finish(self) -> None:
        """Report the keys no reader looked up (unknown keys and sections) and raise
        :class:`ConfigError` listing every problem."""
        children: dict[Path, set[str | int]] = {}
        for p in self._seen:
            children.setdefault(p[:-1], set()).add(p[-1])
        self._unknown(self.raw, (), children)
        if self._problems:
            found = []  # (line or None, text), in file order
            for text, path in self._problems.items():
                line = locate_line(self.text, path) if self.text is not None else None
                found.append((line or math.inf, f"{self.source}{f' line {line}' if line else ''}"
                                                f": {text}"))
            found.sort(key=lambda lt: lt[0])
            raise ConfigError("\n".join(text for _, text in found))

    def resolved(self) -> str:
        """Every value read, as TOML in file units; ``# default``: not in the file."""
        out = []
        for table, entries in self._shown.items():
            if table:
                names = ".".join(p for p in table if isinstance(p, str))
                out.append(f"\n[[{names}]]" if isinstance(table[-1], int) else f"\n[{names}]")
            for key, (value, default) in entries.items():
                if value is _MISSING:
                    out.append(f"# {key}: not set")
                else:
                    out.append(f"{key} = {toml_value(value)}" + ("  # default" if default else ""))
        return "\n".join(out).lstrip("\n") + "\n"

    # - the walk -
    def _get(self, node: Any, at: Path, key: Path) -> Any:
        """``node[key...]`` (each step recorded as looked up), or _MISSING, or _BAD."""
        for k in key:
            self._seen.add((*at, k))
            if not isinstance(node, list if isinstance(k, int) else Mapping):
                what = "an array" if isinstance(k, int) else "a table"
                self.problem(at, f"expected {what}, got {_show(node)}")
                return _BAD
            node = (node[k] if k < len(node) else _MISSING) if isinstance(k, int) else node.get(
                k, _MISSING)
            at = (*at, k)
            if node is _MISSING:
                break
        return node

    def _dataclass(self, cls: type, table: Any, path: Path) -> Any:
        if not isinstance(table, Mapping):
            self.problem(path, f"expected a table, got {_show(table)}")
            return None
        self._shown.setdefault(path, {})
        before = self._reported
        hints = _hints(cls)
        kw = {}
        for f in dataclasses.fields(cls):
            spec = f.metadata.get("setting")
            if spec is not None:
                kw[f.name] = self._field(spec, f.name, hints[f.name], table, path)
        return cls(**kw) if self._reported == before else None

    def _field(self, spec: Spec, name: str, tp: Any, table: Mapping, path: Path) -> Any:
        if spec.scenario is not None and not self.simulator_setting(
                (*path, *spec.file_key(name)), spec.scenario):
            return _default_value(spec, tp)
        if spec.sources:
            return self._sources(spec, table, path)
        key = spec.file_key(name)
        at = (*path, *key)
        raw = self._get(table, path, key)
        if raw is _BAD:
            return None
        default = raw is _MISSING
        if default:
            if spec.default is REQUIRED:
                self._missing(at, tp)
                return None
            raw = spec.default
        value = self._typed(tp, raw, at)
        if value is _BAD:
            return None
        message = _check(spec, value)
        if message:
            self.problem(at, message)
            return None
        if not _is_table(tp):
            shown = spec.mask(raw) if spec.mask is not None else raw
            self._display(path, key, shown, default, table)
        return value if value is None else spec.to_field(value)

    def _sources(self, spec: Spec, table: Mapping, path: Path) -> Any:
        raws = [self._get(table, path, (k,)) for k in spec.sources]
        absent = [k for k, r in zip(spec.sources, raws, strict=True) if r is _MISSING]
        if len(absent) == len(raws):
            if spec.default is REQUIRED:
                self._missing((*path, absent[0]), None)
                return None
            self._shown[path][", ".join(spec.sources)] = [_MISSING, True]
            return spec.default
        if absent:
            together = " and ".join(spec.sources)
            self.problem((*path, absent[0]), f"missing ({together} go together)")
            return None
        if _BAD in raws:
            return None
        for k, r in zip(spec.sources, raws, strict=True):
            self._display(path, (k,), r, False, table)
        try:
            return spec.convert(*raws)
        except (ValueError, TypeError) as exc:  # (index of the source, message) or (message,)
            i = exc.args[0] if len(exc.args) == 2 and isinstance(exc.args[0], int) else 0
            self.problem((*path, spec.sources[i]), str(exc.args[-1]))
            return None

    def _missing(self, at: Path, tp: Any) -> None:
        if _is_table(tp):
            brackets = "[{}]" if dataclasses.is_dataclass(tp) or typing.get_origin(tp) in (
                Mapping, dict) else "[[{}]]"
            text = "missing required section " + brackets.format(".".join(map(str, at)))
        else:
            text = f"{render_path(at[:-1], table=True)} missing required key {at[-1]!r}"
        self._add(text.removeprefix("[] "), at)

    def _typed(self, tp: Any, raw: Any, at: Path) -> Any:
        """``raw`` checked against the annotation ``tp`` (problems recorded; _BAD)."""
        origin, args = typing.get_origin(tp), typing.get_args(tp)
        if origin in (typing.Union, types.UnionType):
            tp = next(a for a in args if a is not type(None))
            origin, args = typing.get_origin(tp), typing.get_args(tp)
        if dataclasses.is_dataclass(tp):
            value = self._dataclass(tp, raw, at)
            return _BAD if value is None else value
        if tp in _EXPECTED:
            if tp is float and isinstance(raw, int) and not isinstance(raw, bool):
                raw = float(raw)
            if not isinstance(raw, tp) or (tp is not bool and isinstance(raw, bool)):
                self.problem(at, f"expected {_EXPECTED[tp]}, got {_show(raw)}")
                return _BAD
            if tp is float and not math.isfinite(raw):
                self.problem(at, f"must be a finite number, got {raw}")
                return _BAD
            return raw
        if origin is tuple:
            return self._array(args, raw, at)
        if origin in (Mapping, dict):
            if not isinstance(raw, Mapping):
                self.problem(at, f"expected a table, got {_show(raw)}")
                return _BAD
            if dataclasses.is_dataclass(args[1]):  # a table of tables: shown as tables;
                self._shown.setdefault(at, {})  # a table of values shows inline (its field)
            items = {}
            for k, v in raw.items():
                self._seen.add((*at, k))
                items[k] = self._typed(args[1], v, (*at, k))
            return _BAD if any(v is _BAD for v in items.values()) else items
        return raw  # any other type is for the field's ``convert`` to check

    def _array(self, args: tuple[Any, ...], raw: Any, at: Path) -> Any:
        if not isinstance(raw, list | tuple):
            self.problem(at, f"expected an array, got {_show(raw)}")
            return _BAD
        variadic = len(args) == 2 and args[1] is Ellipsis
        if not variadic and len(raw) != len(args):
            self.problem(at, f"expected {len(args)} values, got {len(raw)}")
            return _BAD
        tables = variadic and dataclasses.is_dataclass(args[0])
        items = []
        for i, v in enumerate(raw):
            if tables:  # (the unknown-key walk descends only into arrays of tables)
                self._seen.add((*at, i))
            items.append(self._typed(args[0] if variadic else args[i], v, (*at, i)))
        if tables:
            self._unique(args[0], raw, at)
        return _BAD if any(x is _BAD for x in items) else tuple(items)

    def _unique(self, cls: type, tables: list[Any], at: Path) -> None:
        """Fields declared ``unique`` must differ between the tables of an array (the
        file values are compared, so a duplicate is found even in a table with other
        problems; "" is an unnamed entry)."""
        for f in dataclasses.fields(cls):
            spec = f.metadata.get("setting")
            if spec is None or not spec.unique:
                continue
            key = spec.file_key(f.name)
            first: dict[Any, int] = {}
            for i, t in enumerate(tables):
                v = t.get(key[0], "") if isinstance(t, Mapping) else ""
                if v == "" or not isinstance(v, Hashable):
                    continue
                if v in first:
                    also = render_path((*at, first[v]), table=True)
                    self.problem((*at, i, *key), f"duplicate {v!r} (also {also})")
                first.setdefault(v, i)

    def _display(self, path: Path, key: Path, raw: Any, default: bool, table: Mapping) -> None:
        """Record a value for :meth:`resolved`; an element of an array (``("start", 1)``)
        shows as the whole array."""
        n = next((i for i, k in enumerate(key) if isinstance(k, int)), len(key))
        entries = self._shown.setdefault((*path, *key[:n - 1]), {})
        name = str(key[n - 1])
        if n == len(key):
            entries[name] = [raw, default]
        elif not default:
            node: Any = table
            for k in key[:n]:
                node = node[k]
            entries[name] = [node, False]
        else:
            value = entries.setdefault(name, [[], True])[0]
            value.extend([None] * (key[n] + 1 - len(value)))
            value[key[n]] = raw

    def _unknown(self, node: Any, path: Path, children: dict[Path, set[str | int]]) -> None:
        known = children.get(path)
        if not known:
            return
        for k, v in node.items() if isinstance(node, Mapping) else enumerate(node):
            if k in known:
                if isinstance(v, Mapping | list):
                    self._unknown(v, (*path, k), children)
            elif isinstance(k, int):
                self.problem(path, f"{len(node)} values, expected {len(known)}")
            else:
                self._unknown_key(path, k, v, sorted(str(x) for x in known))

    def _unknown_key(self, path: Path, key: str, value: Any, known: list[str]) -> None:
        close = difflib.get_close_matches(key, known, n=1)
        table = isinstance(value, Mapping) or (
            isinstance(value, list) and value and all(isinstance(v, Mapping) for v in value))
        if table or not path:
            hint = f"; did you mean {render_path((*path, close[0]), table=True)}?" if close else ""
            text = f"unknown section {render_path((*path, key), table=True)}{hint}"
        else:
            hint = f"; did you mean {close[0]!r}?" if close else ""
            text = f"{render_path(path, table=True)} unknown key {key!r}{hint}"
        self._add(text, (*path, key))


SCENARIO_DIR = "config/scenarios"
"""Where the shipped scenario files are (``pipeline.resources.resource_path``)."""


def scenario_problem(path: Path, scenario: str) -> str:
    """What a site config holding a simulator setting is told: what it is and where it
    lives now."""
    what = render_path(path, table=True)
    if path and path[-1] in ("faults", "channel_faults"):
        what = f"[[{'.'.join(map(str, path))}]]"
    return (f"{what} is a simulator setting (the `{scenario}` scenario's world), not your "
            f"site's: it moved to {SCENARIO_DIR}/{scenario}.toml, which `surveil simulate "
            f"--scenario {scenario}` and `surveil demo` read (`--scenario-config FILE` for "
            "your own); delete it from this file")


def _default_value(spec: Spec, tp: Any) -> Any:
    """A field's value when the file does not set it (a simulator setting in a site
    config): its default, converted."""
    if spec.default is REQUIRED:
        return None
    typed = _frozen(spec.default) if isinstance(spec.default, list) else spec.default
    if isinstance(spec.default, dict):
        return {}
    return typed if typed is None or isinstance(typed, tuple) else spec.to_field(typed)


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    """The field annotations of a config dataclass, resolved (once per class)."""
    return typing.get_type_hints(cls)


_EXPECTED = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}


def _is_table(tp: Any) -> bool:
    """A table, an array of tables or a table of tables (not a single value)."""
    args = [a for a in typing.get_args(tp) if a is not Ellipsis]
    return dataclasses.is_dataclass(tp) or (
        typing.get_origin(tp) in (tuple, Mapping, dict) and bool(args)
        and dataclasses.is_dataclass(args[-1]))


def _numbers(value: Any, at: tuple[int, ...] = ()) -> list[tuple[tuple[int, ...], float]]:
    if isinstance(value, tuple):
        return [n for i, v in enumerate(value) for n in _numbers(v, (*at, i))]
    if isinstance(value, int | float) and not isinstance(value, bool):
        return [(at, value)]
    return []


def _check(spec: Spec, value: Any) -> str | None:
    """The first problem of a typed value against its declared range, or None."""
    if value is None:
        return None
    if spec.choices is not None and value not in spec.choices:
        return f"must be one of {', '.join(map(repr, spec.choices))}, got {value!r}"
    if spec.min_len is not None and len(value) < spec.min_len:
        noun = "entry" if spec.min_len == 1 else "entries"
        return f"needs at least {spec.min_len} {noun}, got {len(value)}"
    if spec.max_len is not None and len(value) > spec.max_len:
        return f"at most {spec.max_len} entries, got {len(value)}{_why(spec)}"
    for idx, x in _numbers(value):
        if ((spec.gt is not None and not x > spec.gt) or (spec.ge is not None and not x >= spec.ge)
                or (spec.lt is not None and not x < spec.lt)
                or (spec.le is not None and not x <= spec.le)):
            where = "".join(f"[{i}]" for i in idx)
            return (f"{'element ' + where + ' ' if where else ''}must be {_bounds(spec)}, "
                    f"got {x:g}{_why(spec)}")
    return spec.check(value) if spec.check is not None else None


def _why(spec: Spec) -> str:
    return f": {spec.why}" if spec.why else ""


def _bounds(s: Spec) -> str:
    lo = f"({s.gt:g}" if s.gt is not None else f"[{s.ge:g}" if s.ge is not None else ""
    hi = f"{s.lt:g})" if s.lt is not None else f"{s.le:g}]" if s.le is not None else ""
    if lo and hi:
        return f"in {lo}, {hi}"
    if lo:
        return f"> {s.gt:g}" if s.gt is not None else f">= {s.ge:g}"
    return f"< {s.lt:g}" if s.lt is not None else f"<= {s.le:g}"


def render_path(path: Path, *, table: bool = False) -> str:
    """``("airfield", "sensors", 1, "pd")`` -> ``[airfield.sensors][1].pd``: the leading
    tables in brackets, array elements by index from 0, then the key; ``table``: the
    whole path names a table (``[airfield.filter]``)."""
    n = next((i for i, p in enumerate(path) if isinstance(p, int)), len(path))
    if n == len(path) and n > 1 and not table:
        n -= 1
    rest = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in path[n:])
    return f"[{'.'.join(map(str, path[:n]))}]{rest}"


def _show(v: Any) -> str:
    text = repr(v) if isinstance(v, str) else toml_value(v)
    return text if len(text) <= 60 else text[:57] + "..."


def toml_value(v: Any) -> str:
    """A TOML literal for a value read from TOML (or a default written like one)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list | tuple):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{ " + ", ".join(f"{k} = {toml_value(x)}" for k, x in v.items()) + " }"
    return repr(v)


_HEADER = re.compile(r"^\s*(\[\[?)\s*([^\]]+?)\s*\]")


def locate_line(text: str, path: Path) -> int | None:
    """The 1-based line of ``path`` in the TOML ``text`` (tomllib gives no positions):
    the header of the longest table prefix of ``path`` (the n-th ``[[array]]`` for an
    index), then the first ``key =`` line below it, else the header's line."""
    lines = text.splitlines()
    headers: list[tuple[int, Path]] = [(-1, ())]  # (line index, table path); -1: top level
    counts: dict[Path, int] = {}
    for n, line in enumerate(lines):
        m = _HEADER.match(line)
        if m:
            names = tuple(p.strip().strip("\"'") for p in m.group(2).split("."))
            if m.group(1) == "[[":
                counts[names] = counts.get(names, 0) + 1
                if counts[names] == 1:
                    headers.append((n, names))
                names = (*names, counts[names] - 1)
            headers.append((n, names))
    for k in range(len(path), -1, -1):
        i = next((i for i, (_, h) in enumerate(headers) if h == path[:k]), None)
        if i is None:
            continue
        first = headers[i][0]
        end = next((n for n, _ in headers[i + 1:] if n > first), len(lines))
        if k < len(path) and isinstance(path[k], str):
            key = re.compile(rf"^\s*[\"']?{re.escape(path[k])}[\"']?\s*[=.]")
            for n in range(first + 1, end):
                if key.match(lines[n]):
                    return n + 1
        return first + 1 if first >= 0 else None
    return None
