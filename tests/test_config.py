"""The config file is validated when it loads, for every command: types, ranges, unknown
and missing keys and sections, each problem with its key path and line, all at once
(pipeline/configspec.py); ``surveil config check`` prints it resolved."""

from __future__ import annotations

import dataclasses
import math
import pickle
import subprocess
import sys
import typing
from pathlib import Path

import pytest

from jobs.cli import main
from pipeline.config import AisConfig, Config, ConfigError
from pipeline.configspec import Document, locate_line, render_path, setting
from pipeline.families import FAMILIES, load_config
from pipeline.maritime.config import AssociationConfig
from pipeline.resources import resource_path

SHIPPED = resource_path("config") / "surveil.toml"
TEXT = SHIPPED.read_text(encoding="utf-8")
GOLDEN = Path(__file__).parent / "data" / "shipped_config.repr"
REPO = Path(__file__).resolve().parents[1]


def surveil(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
            *args: str) -> tuple[int, str, str]:
    """Run the console entry point (``jobs.cli:main``) in-process: (exit code, out, err)."""
    monkeypatch.setattr(sys, "argv", ["surveil", *args])
    try:
        main()
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    out, err = capsys.readouterr()
    return code, out, err


def edited(tmp_path: Path, old: str, new: str, count: int = 1) -> tuple[Path, str]:
    """The shipped config with ``old`` replaced by ``new`` (the first ``count`` times)."""
    assert old in TEXT, old
    text = TEXT.replace(old, new, count)
    path = tmp_path / "surveil.toml"
    path.write_text(text, encoding="utf-8")
    return path, text


def line_of(text: str, needle: str, nth: int = 1) -> int:
    """1-based line of the ``nth`` line starting with ``needle``."""
    hits = [i + 1 for i, line in enumerate(text.splitlines()) if line.startswith(needle)]
    return hits[nth - 1]


# --- the shipped config parses to exactly the objects it gave before ----------------------


def _reprs(cfg: Config) -> str:
    """The core config and the sensor families' configs (the sections no family owns,
    [requirements] and [reports], came later: tests/sql/test_requirements_and_params.py)."""
    from pipeline.families import FAMILIES

    families = {name: v for name, v in cfg.families.items() if name in {f.name for f in FAMILIES}}
    return (repr(cfg).replace(repr(cfg.source), "'<source>'") + "\n" + repr(families) + "\n")


def test_shipped_config_parses_to_the_same_objects_as_before():
    """tests/data/shipped_config.repr was recorded from the hand-written parsers (9392eae),
    when the demo's fault schedules were in the site config: the demo site with its
    scenario files (config/scenarios/) on top parses to exactly those objects (since
    2026-12-04 with ``range_gain=0.0`` in every ChannelFault, ``prior_range_gain=0.01``
    in RadarBiasConfig and the stated-accuracy check's two settings in
    RegistrationConfig: the fields were added, nothing else moved)."""
    from pipeline.simulate.scenarios import with_scenario

    world = with_scenario(load_config(), ["channel", "airfield", "ownship"])
    assert _reprs(world) == GOLDEN.read_text()


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


def _declared(cls: type, seen: set[type]) -> list[tuple[str, object, typing.Any]]:
    """(class.field, spec, type) of every file value reachable from ``cls``."""
    if cls in seen:
        return []
    seen.add(cls)
    out = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        spec = f.metadata.get("setting")
        if spec is None:
            continue
        tp = hints[f.name]
        inner = [a for a in typing.get_args(tp) if a is not Ellipsis]
        nested = [t for t in (tp, *inner) if dataclasses.is_dataclass(t)]
        if nested:
            out += _declared(nested[0], seen)
        else:
            out.append((f"{cls.__name__}.{f.name}", spec, tp))
    return out


def test_every_value_declares_its_valid_range():
    """Numbers: a bound; strings: choices or a check (non-empty); the rest: a check or
    a converter that validates (the AR models)."""
    import pipeline.airfield.config as a
    import pipeline.gaps.config as g
    import pipeline.maritime.config as m
    import pipeline.nav.config as n

    classes = (Config, m.MaritimeConfig, a.AirfieldConfig, g.GapsConfig, n.NavSettings,
               n.OwnshipScenarioConfig, n._FilterKeys, n._GyroKeys, n._RollKeys)
    seen: set[type] = set()
    values = [v for c in classes for v in _declared(c, seen)]
    assert len(values) > 150
    loose = []
    for where, spec, tp in values:
        bounded = any(b is not None for b in (spec.gt, spec.ge, spec.lt, spec.le))
        if tp is bool:
            continue
        if tp in (int, float) or "float" in str(tp):
            ok = bounded or spec.check is not None
        elif tp is str:
            ok = spec.choices is not None or spec.check is not None or spec.unique
        else:
            ok = spec.check is not None or spec.convert is not None
        if not ok:
            loose.append(where)
    assert loose == []


def test_resolved_config_loads_back_to_the_same_config(tmp_path):
    from jobs.config_check import resolved_config

    text = resolved_config(None)
    path = tmp_path / "resolved.toml"
    path.write_text(text, encoding="utf-8")
    assert _reprs(load_config(path)) == _reprs(load_config())
    assert "max_course_difference_deg = 30.0\n" in text  # file units
    assert "min_track_share = 0.8  # default\n" in text  # not in the shipped file


# --- each defect, through the real CLI -------------------------------------------------------

GATE_WHY = ("a gate keeps a true pairing with this probability; below 0.5 it rejects most "
            "of them")
MAX_SPEED_WHY = ("the fastest plausible target, from a harbour's 1 m/s to a landing aircraft "
                 "(350 m/s is the speed of sound)")
SCAN_WHY = ("a rotating antenna turns once per 0.5 s (120 rpm, surface movement radars) to "
            "30 s (2 rpm, long-range surveillance); VTS radars 2-4 s")

CASES = {  # name: (old, new, nth line starting with, expected message after "line N: ")
    "wrong type in [execution]": (
        "max_workers = 2", 'max_workers = "two"', ("max_workers", 1),
        "[execution].max_workers: expected an integer, got 'two'"),
    "string in [sync]": (
        "sigma_dt_s = 0.1", 'sigma_dt_s = "0.1"', ("sigma_dt_s", 1),
        "[sync].sigma_dt_s: expected a number, got '0.1'"),
    "unknown key": (
        "epoch_period_s = 4.0", "epoch_period = 4.0", ("epoch_period", 1),
        "[sync] unknown key 'epoch_period'; did you mean 'epoch_period_s'?"),
    "gate probability out of (0, 1)": (
        "gate_probability = 0.999        #", "gate_probability = 1.5        #",
        ("gate_probability", 1), f"[association].gate_probability: must be in [0.5, 1), got "
                                 f"1.5: {GATE_WHY}"),
    "negative speed limit": (
        "max_speed_mps = 40.0", "max_speed_mps = -5", ("max_speed_mps = -5", 1),
        f"[validation].max_speed_mps: must be in [1, 350], got -5: {MAX_SPEED_WHY}"),
    "unknown section": (
        "[siap]", "[siapp]", ("[siapp]", 1), "unknown section [siapp]; did you mean [siap]?"),
    "radar site sigma": (
        "sigma_range_m = 15.0\nsigma_azimuth_deg = 0.45\nsigma_speed_mps = 0.25\n"
        "sigma_course_deg = 2.0\n\n[sync]",
        "sigma_range_m = 0\nsigma_azimuth_deg = 0.45\nsigma_speed_mps = 0.25\n"
        "sigma_course_deg = 2.0\n\n[sync]",
        ("sigma_range_m", 2), "[radar_sites][1].sigma_range_m: must be in [0.1, 1000], got 0: "
                              "a tracker's range sigma is a few metres to tens of metres; 1 km "
                              "is no track"),
    "airfield sensor pd": (
        "pd = 0.98", "pd = 1.5", ("pd = 1.5", 1),
        "[airfield.sensors][1].pd: must be in (0, 1], got 1.5"),
    "duplicate site id": (
        'site_id = "R2"', 'site_id = "R1"', ("site_id", 2),
        "[radar_sites][1].site_id: duplicate 'R1' (also [radar_sites][0])"),
    "latitude": (
        "origin_lat_deg = 46.40", "origin_lat_deg = 146.40", ("origin_lat_deg", 1),
        "[region].origin_lat_deg: must be in [-90, 90], got 146.4"),
    "polygon with two vertices": (
        "polygon = [[46.255766, 30.640617], [46.256049, 30.848123], [46.453965, 30.847935], "
        "[46.453680, 30.639678]]",
        "polygon = [[46.255766, 30.640617], [46.256049, 30.848123]]", ("polygon", 1),
        "[sectors][0].polygon: a polygon needs at least 3 [lat_deg, lon_deg] vertices, got 2"),
    "unknown airfield table": (
        "[airfield.filter]", "[airfield.filtre]", ("[airfield.filtre]", 1),
        "unknown section [airfield.filtre]; did you mean [airfield.filter]?"),
    "gaps particles": (
        "particles = 2000 ", "particles = 2000.5 ", ("particles", 1),
        "[gaps].particles: expected an integer, got 2000.5"),
    "ownship step": (
        "filter_step_s = 1.0", "filter_step_s = -1.0", ("filter_step_s", 1),
        "[ownship].filter_step_s: must be in [0.01, 60], got -1: the gyro and GNSS report at "
        "1-100 Hz: the filter steps at most 100 times a second and at least once a minute"),
    # issue 40: well-typed nonsense (a radar excluded in 894 of 897 epochs, a bow-tie sector
    # losing 17 % of its samples to "outside sectors")
    "scan period of a nanosecond": (
        "scan_period_s = 3.0", "scan_period_s = 1e-9", ("scan_period_s", 1),
        f"[radar_sites][0].scan_period_s: must be in [0.5, 30], got 1e-09: {SCAN_WHY}"),
    "a radar that sees 10,000 km": (
        "max_range_m = 24000.0", "max_range_m = 1e7", ("max_range_m", 1),
        "[radar_sites][0].max_range_m: must be in [100, 250000], got 1e+07: from a surface "
        "movement radar's few hundred metres to a long-range coastal radar's 250 km (beyond "
        "it a ship is below the radar horizon of any mast)"),
    "azimuth sigma of a nano-degree": (
        "sigma_azimuth_deg = 0.45", "sigma_azimuth_deg = 1e-9", ("sigma_azimuth_deg", 1),
        "[radar_sites][0].sigma_azimuth_deg: must be in [0.001, 10], got 1e-09: an antenna's "
        "beam is 0.3-3 deg wide: its tracks' azimuth sigma is hundredths to a few degrees"),
    "epochs every microsecond": (
        "epoch_period_s = 4.0", "epoch_period_s = 1e-6", ("epoch_period_s", 1),
        "[sync].epoch_period_s: must be in [0.5, 60], got 1e-06: the synchronised epochs "
        "follow the scans: at most one per 0.5 s (the fastest antenna) and at least one a "
        "minute"),
    "a gate that keeps nothing": (
        "gate_probability = 0.999        #", "gate_probability = 1e-9        #",
        ("gate_probability", 1), f"[association].gate_probability: must be in [0.5, 1), got "
                                 f"1e-09: {GATE_WHY}"),
    "a false alarm every other check": (
        "radar_q = 0.001", "radar_q = 0.5", ("radar_q", 1),
        "[channel_integrity].radar_q: must be in (0, 0.1], got 0.5: the share of healthy "
        "checks flagged; above 0.1 a healthy channel is excluded every few epochs"),
    "a bow-tie sector": (
        "polygon = [[46.255766, 30.640617], [46.256049, 30.848123], [46.453965, 30.847935], "
        "[46.453680, 30.639678]]",
        "polygon = [[46.255766, 30.640617], [46.256049, 30.848123], [46.453680, 30.639678], "
        "[46.453965, 30.847935]]", ("polygon", 1),
        "[sectors][0].polygon: its edges cross or touch at [46.354686, 30.744089] (lat_deg, "
        "lon_deg): a polygon's boundary must not cross itself; list the vertices in order "
        "around it"),
    "a sector on a line": (
        "polygon = [[46.255766, 30.640617], [46.256049, 30.848123], [46.453965, 30.847935], "
        "[46.453680, 30.639678]]",
        "polygon = [[46.0, 30.6], [46.1, 30.7], [46.2, 30.8]]", ("polygon", 1),
        "[sectors][0].polygon: encloses no area (its vertices lie on one line)"),
}


@pytest.mark.parametrize("case", CASES, ids=list(CASES))
def test_bad_value_is_exit_2_naming_key_path_and_line(case, tmp_path, monkeypatch, capsys):
    old, new, (needle, nth), message = CASES[case]
    path, text = edited(tmp_path, old, new)
    for args in (("--config", str(path), "--warehouse", str(tmp_path / "wh"), "batch",
                  "--from", "2026-01-15T00:00:00Z", "--to", "2026-01-15T00:01:00Z"),
                 ("config", "check", str(path))):
        code, out, err = surveil(monkeypatch, capsys, *args)
        assert code == 2, (args, out, err)
        assert err == f"error: {path} line {line_of(text, needle, nth)}: {message}\n"
        assert not (tmp_path / "wh").exists()


def test_every_problem_is_reported_at_once(tmp_path, monkeypatch, capsys):
    text = TEXT
    applied = set()  # (cases editing the same line: the first)
    for k, (old, new, *_) in CASES.items():
        if old in text and "[siap]" not in old:  # (one unknown section is enough)
            text = text.replace(old, new, 1)
            applied.add(k)
    path = tmp_path / "many.toml"
    path.write_text(text, encoding="utf-8")
    code, _, err = surveil(monkeypatch, capsys, "--config", str(path), "report", "--list")
    assert code == 2
    lines = err.removeprefix("error: ").splitlines()
    found = {line.split(": ", 1)[1] for line in lines}
    expected = {m for k, (*_, m) in CASES.items() if k in applied}
    assert expected <= found, expected - found
    numbers = [int(line.split(" line ")[1].split(":")[0]) for line in lines]
    assert numbers == sorted(numbers)  # in file order


def test_missing_required_section(tmp_path, monkeypatch, capsys):
    start = TEXT.index("[region]")
    end = TEXT.index("# Each radar")
    path = tmp_path / "surveil.toml"
    path.write_text(TEXT[:start] + TEXT[end:], encoding="utf-8")
    code, _, err = surveil(monkeypatch, capsys, "--config", str(path), "report", "--list")
    assert (code, err) == (2, f"error: {path}: missing required section [region]\n")


def test_a_file_with_only_region_passes_config_check(tmp_path, monkeypatch, capsys):
    """Issue 35: `config check` of a file with only [region] exited 2 ([[radar_sites]]
    was required): an AIS-only site could not be declared. Every family is optional."""
    path = tmp_path / "ais_only.toml"
    path.write_text('[region]\nname = "solent"\norigin_lat_deg = 50.75\n'
                    'origin_lon_deg = -1.30\n', encoding="utf-8")
    code, out, err = surveil(monkeypatch, capsys, "config", "check", str(path))
    assert (code, err) == (0, "")
    cfg = load_config(path)
    assert cfg.radar_sites == () and cfg.family("airfield") is None
    assert "[[radar_sites]]" not in out


def test_an_old_config_with_simulator_settings_says_where_they_moved(tmp_path, monkeypatch,
                                                                     capsys):
    """Issue 35: the demo config mixed the site with the simulator's fault schedules; they
    moved to config/scenarios/*.toml, and a site config still holding one is told so
    (exit 2, its line), not silently ignored."""
    path, text = edited(tmp_path, "[[airfield.sectors]]\nname = \"runway\"",
                        '[[airfield.faults]]\nkind = "jam"\nsensor_id = "SMR1"\nstart_s = 1.0\n'
                        'duration_s = 1.0\n\n[[airfield.sectors]]\nname = "runway"')
    text += ('\n[[channel_faults]]\nkind = "radar_outage"\nsite_id = "R1"\nstart_s = 1.0\n'
             'duration_s = 1.0\n\n[radar_bias.simulate]\nR1 = { range_bias_m = 5.0 }\n'
             '\n[ownship.scenario]\naccel_mps2 = 0.1\n')
    path.write_text(text, encoding="utf-8")
    code, _, err = surveil(monkeypatch, capsys, "config", "check", str(path))
    assert code == 2
    lines = err.removeprefix("error: ").splitlines()
    assert len(lines) == 4
    for what, scenario in (("[[airfield.faults]]", "airfield"), ("[[channel_faults]]", "channel"),
                           ("[radar_bias.simulate]", "channel"),
                           ("[ownship.scenario]", "ownship")):
        (line,) = [x for x in lines if f": {what} is a simulator setting" in x]
        assert f"config/scenarios/{scenario}.toml" in line and " line " in line


def test_scenario_files_hold_simulator_settings_only_and_are_validated(tmp_path):
    from pipeline.families import with_scenario_files
    from pipeline.simulate.scenarios import with_scenario

    site = load_config()
    assert site.family("maritime").faults == () and site.family("airfield").faults == ()
    world = with_scenario(site, ["channel", "airfield"])
    assert len(world.family("maritime").faults) == 10
    assert len(world.family("airfield").faults) == 5
    bad = tmp_path / "bad.toml"
    bad.write_text('[[airfield.faults]]\nkind = "dropout"\nsensor_id = "VASN2"\n'
                   'start_s = 0.0\nduration_s = 1.0\n', encoding="utf-8")
    with pytest.raises(ConfigError, match=r"\[airfield.faults\]\[0\].sensor_id: no sensor "
                                          r"'VASN2' \(sensors: SMR1, MLAT1, VASN1\)"):
        with_scenario_files(site, [bad])
    bad.write_text("[sync]\nepoch_period_s = 2.0\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"\[sync\] is a site setting"):
        with_scenario_files(site, [bad])
    # a site of your own is simulated without the demo's faults unless a file is given
    own = tmp_path / "own.toml"
    own.write_text(TEXT, encoding="utf-8")
    assert with_scenario(load_config(own), ["channel"]).family("maritime").faults == ()


def test_missing_required_key_names_the_table(tmp_path, monkeypatch, capsys):
    path, text = edited(tmp_path, "origin_lon_deg = 30.90\n", "")
    code, _, err = surveil(monkeypatch, capsys, "--config", str(path), "report", "--list")
    assert code == 2
    assert err == (f"error: {path} line {line_of(text, '[region]')}: [region] missing "
                   "required key 'origin_lon_deg'\n")


def test_binary_file_is_not_a_utf8_toml_file(tmp_path, monkeypatch, capsys):
    path = tmp_path / "surveil.toml"
    path.write_bytes(bytes(range(256)) * 4)
    code, _, err = surveil(monkeypatch, capsys, "--config", str(path), "report", "--list")
    assert code == 2
    assert err.startswith(f"error: config file {path} is not a UTF-8 TOML file")


@pytest.mark.parametrize("args", [("report",), ("report", "--list"),
                                  ("report", "accuracy_by_sector", "--format", "csv")])
def test_report_validates_the_config_too(args, tmp_path, monkeypatch, capsys):
    path, _ = edited(tmp_path, "max_speed_mps = 40.0", "max_speed_mps = -5")
    code, out, err = surveil(monkeypatch, capsys, "--config", str(path),
                             "--warehouse", str(tmp_path), *args)
    assert code == 2 and out == ""
    assert "[validation].max_speed_mps: must be in [1, 350], got -5" in err


def test_config_check_prints_the_resolved_config(tmp_path, monkeypatch, capsys):
    path = tmp_path / "small.toml"
    path.write_text(TEXT[:TEXT.index("[sync]")], encoding="utf-8")  # region + radar sites
    code, out, err = surveil(monkeypatch, capsys, "config", "check", str(path))
    assert (code, err) == (0, "")
    assert out.startswith(f"# {path}: ok.")
    for line in ("[region]\nname = \"demo-estuary\"\n", "[sync]\nsigma_dt_s = 0.1  # default\n",
                 "max_course_difference_deg = 30.0  # default\n",
                 "[gaps]\ngap_threshold_s = 600.0  # default\n"):
        assert line in out
    assert "[airfield]" not in out  # no section: the airfield family writes nothing
    assert "[ownship.scenario]" not in out  # the simulator's, not the site's
    # --config is what `config check` checks when no FILE is given
    code, out2, _ = surveil(monkeypatch, capsys, "--config", str(path), "config", "check")
    assert (code, out2) == (0, out)


def test_installed_command_exits_2_instead_of_aborting(tmp_path):
    """Was a traceback and a C++ terminate (exit 134) in the process pool."""
    path, text = edited(tmp_path, "max_workers = 2", 'max_workers = "two"')
    exe = Path(sys.executable).with_name("surveil")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "jobs.cli"]
    res = subprocess.run([*cmd, "--config", str(path), "--warehouse", str(tmp_path / "wh"),
                          "batch", "--from", "2026-01-15T00:00:00Z", "--to",
                          "2026-01-15T00:01:00Z"], capture_output=True, text=True, cwd=REPO,
                         check=False)
    assert res.returncode == 2, res.stderr
    assert res.stderr == (f"error: {path} line {line_of(text, 'max_workers')}: "
                          "[execution].max_workers: expected an integer, got 'two'\n")


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


def test_families_claim_their_sections():
    claimed = [s for f in FAMILIES for s in f.sections]
    assert len(claimed) == len(set(claimed))
    assert {"sync", "airfield", "gaps", "ownship"} <= set(claimed)


def test_config_sections_are_the_families_own():
    """Loading a config uses FAMILY_SECTIONS (no stage imported); the batch uses FAMILIES:
    the same sections and parsers, in the same order."""
    from pipeline.families import FAMILY_SECTIONS

    assert [(s.name, s.sections, s.parse_config) for s in FAMILY_SECTIONS] == [
        (f.name, f.sections, f.parse_config) for f in FAMILIES
    ]


def test_loading_a_config_imports_no_stage():
    code = ("import sys; from pipeline.families import load_config; load_config(); "
            "print(sorted(m for m in sys.modules if m.endswith('.stage') or m == 'scipy.stats'))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


def test_family_declarations_are_the_families_own():
    """Provenance reads FAMILY_DECLARATIONS (no stage imported): the same names, core
    config fields and output tables as FAMILIES, in the same order."""
    from pipeline.families import FAMILY_DECLARATIONS

    assert [(d.name, d.config_fields, d.outputs) for d in FAMILY_DECLARATIONS] == [
        (f.name, f.config_fields, f.outputs) for f in FAMILIES]


def test_a_report_imports_no_stage(e2e):
    """`surveil report` (with its provenance lines) imports no family's stage, nor scipy:
    ~0.8 s of every report command before (the stages pull in scipy and the batch's
    kernels), and ~0.3 s more for scipy.linalg through the airfield config's VAR model."""
    code = ("import sys; from jobs.cli import main; sys.argv = ['surveil', '--warehouse', "
            f"{str(e2e.warehouse)!r}, 'report', 'accuracy_by_sector', '--format', 'csv']\n"
            "try:\n    main()\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in sys.modules if m.endswith('.stage') or m == 'scipy'),"
            " file=sys.stderr)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=REPO)
    assert "config digest" in out.stderr and "fused" in out.stdout
    assert out.stderr.strip().splitlines()[-1] == "[]", out.stderr


def test_the_documented_template_checks(monkeypatch, capsys):
    """config/site-template.toml (every section optional, commented) is a valid site."""
    code, out, err = surveil(monkeypatch, capsys, "config", "check",
                             str(resource_path("config") / "site-template.toml"))
    assert (code, err) == (0, "") and 'name = "my-harbour"' in out


def _with_sectors(n: int) -> str:
    """The shipped config with its maritime sectors replaced by ``n`` small squares."""
    start = TEXT.index("[[sectors]]")
    end = TEXT.index("\n[", TEXT.rindex("[[sectors]]") + 1)
    squares = "".join(
        f'[[sectors]]\nname = "s{i}"\npolygon = [[{46.3 + 0.001 * i:.3f}, 30.7], '
        f"[{46.3 + 0.001 * i:.3f}, 30.701], [{46.3005 + 0.001 * i:.4f}, 30.701]]\n\n"
        for i in range(n))
    return TEXT[:start] + squares + TEXT[end + 1:]


def test_more_sectors_than_the_audit_can_draw_is_exit_2(tmp_path, monkeypatch, capsys):
    """Issue 40: 10,000 sectors loaded, and `surveil audit` was still running after 600 s
    (3.4 s with 3). At most MAX_SECTORS, refused at the first [[sectors]] line."""
    from pipeline.configspec import MAX_SECTORS

    path = tmp_path / "many.toml"
    path.write_text(_with_sectors(MAX_SECTORS), encoding="utf-8")
    code, _, err = surveil(monkeypatch, capsys, "config", "check", str(path))
    assert (code, err) == (0, "")
    text = _with_sectors(MAX_SECTORS + 1)
    path.write_text(text, encoding="utf-8")
    code, _, err = surveil(monkeypatch, capsys, "config", "check", str(path))
    assert code == 2
    assert err == (f"error: {path} line {line_of(text, '[[sectors]]')}: [sectors]: at most "
                   f"{MAX_SECTORS} entries, got {MAX_SECTORS + 1}: a site is split into a few "
                   "to a few tens of sectors; each is a row of every per-sector report and a "
                   "bar of every audit chart: merge small ones\n")
