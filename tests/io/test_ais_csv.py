"""AIS CSV exports of other tools, placed by header name (pipeline/convert/ais_csv.py):
generated files of each dialect, ``[import.csv]`` overrides, the error listing the
columns that could not be placed."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pipeline.config import ConfigError
from pipeline.convert.ais_csv import CsvOptions, place_columns, read_ais_csv
from pipeline.convert.config import parse_import_options
from pipeline.convert.importer import run_import
from pipeline.convert.legacy import CSV_TOPIC, detect_format, import_file
from pipeline.families import load_config
from pipeline.ingest.driver import run_ingest
from pipeline.io.mcap_read import read_mcap_batches
from pipeline.units import NS
from pipeline.warehouse.delta import read_table

T = 1_706_702_400  # 2024-01-31T12:00:00Z


def _write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / "in" / name
    p.parent.mkdir(exist_ok=True)
    p.write_text(text)
    return p


def _docs(path: Path) -> list[tuple[int, dict]]:
    out = []
    for b in read_mcap_batches(path):
        if b.topic == CSV_TOPIC:
            out += [(t, json.loads(p)) for t, p in zip(b.log_time_ns.tolist(), b.payloads,
                                                      strict=True)]  # fmt: skip
    return out


def _ingest(tmp_path: Path, mcap: Path) -> dict[str, list[dict]]:
    s = run_ingest([mcap], load_config(), tmp_path / "wh", executor="serial")
    out = {n: read_table(tmp_path / "wh", n).to_pylist()
           for n in ("ais_reports", "ais_static", "ais_other_messages", "rejects",
                     "ingest_ledger")}  # fmt: skip
    assert s.exit_code == (1 if out["rejects"] else 0), s.render()  # issue 18: rejects -> 1
    return out


WIDE = (
    '"msg_type","mmsi","timestamp","lat","lon","speed","course","heading","name",'
    '"callsign","imo","shiptype","destination","status"\n'
    '"1","244660000","20240131T120000Z","52.1","4.2","10.5","90.0","91","","","","","","0"\n'
    '"5","244660000","20240131T120001Z","","","","","","NAME, WITH COMMA","PD1234",'
    '"9123456","70","ROTTERDAM","" \n'
    '"4","2442000","20240131T120002Z","52.0","4.0","","","","","","","","",""\n'
    '"18","244000001","20240131T120003Z","52.2","4.3","3.0","181.5","511","","","","","",""\n'
)


def test_wide_message_level_export_with_quoted_cells_and_compact_times(tmp_path):
    src = _write(tmp_path, "wide.csv", WIDE)
    assert detect_format(src) == "ais_csv"
    res = import_file(src, tmp_path / "out")
    docs = _docs(Path(res.output))
    assert [t for t, _ in docs] == [(T + k) * NS for k in range(4)]
    assert docs[1][1]["shipname"] == "NAME, WITH COMMA" and docs[1][1]["msg_type"] == 5
    assert docs[0][1]["sog_kn"] == 10.5 and docs[0][1]["nav_status"] == 0
    out = _ingest(tmp_path, Path(res.output))
    assert [r["mmsi"] for r in out["ais_reports"]] == [244660000, 244000001]
    assert [r["msg_type"] for r in out["ais_reports"]] == [1, 18]
    assert [r["ais_class"] for r in out["ais_reports"]] == ["A", "B"]  # 18: class B (issue 36)
    assert {r["time_source"] for r in out["ais_reports"]} == {"csv:timestamp"}
    (static,) = out["ais_static"]  # the type 5 row: static data, no reject
    assert static["callsign"] == "PD1234" and static["imo"] == 9123456
    assert out["rejects"] == []
    (base,) = out["ais_other_messages"]  # a base station: its own table
    assert (base["mmsi"], base["msg_type"], base["ais_class"]) == (2442000, 4, "base_station")
    assert (base["lat_deg"], base["lon_deg"]) == (52.0, 4.0)
    (ledger,) = out["ingest_ledger"]
    assert json.loads(ledger["not_stored_json"] or "{}") == {}


@pytest.mark.parametrize(
    ("header", "cells", "want_ns"),
    [
        ("mmsi,time,lon,lat,cog,sog,heading,vessel_name,ship_type",  # aisdb export
         f"244660000,{T},4.2,52.1,90.0,10.5,91,NAME A,70", T * NS),
        ("MMSI;Timestamp;Latitude;Longitude;SOG;COG",  # semicolons, ISO with Z, ms
         "244660000;2024-01-31T12:00:00.250Z;52.1;4.2;10.5;90.0", T * NS + 250_000_000),
        ("UserID\tDateTime\tLat\tLong\tSpeedOverGround\tCourseOverGround",  # tabs, +01:00
         "244660000\t2024-01-31 13:00:00+01:00\t52.1\t4.2\t10.5\t90.0", T * NS),
        ("mmsi|epoch_ms|latitude|longitude", f"244660000|{T}123|52.1|4.2",
         T * NS + 123_000_000),
        ("MMSI,Date,Time of day,LAT,LON", "244660000,2024-01-31,12:00:00,52.1,4.2", T * NS),
        ("mmsi,datetime,lat,lon", "244660000,31/01/2024 12:00:00,52.1,4.2", T * NS),
        ("mmsi,datetime,lat,lon", "244660000,20240131120000,52.1,4.2", T * NS),
    ],
)
def test_dialects_place_their_columns(tmp_path, header, cells, want_ns):
    src = _write(tmp_path, "d.csv", f"{header}\n{cells}\n")
    assert detect_format(src) == "ais_csv"
    res = import_file(src, tmp_path / "out")
    ((t, doc),) = _docs(Path(res.output))
    assert t == want_ns == doc["time_ns"]
    assert (doc["mmsi"], doc["lat_deg"], doc["lon_deg"]) == (244660000, 52.1, 4.2)


def test_unplaced_columns_are_listed_and_the_file_fails_with_exit_1(tmp_path):
    src = _write(tmp_path, "de.csv", "Kennung,Zeit,Breite,Laenge\n244660000,2024-01-31 12:00:00,"
                                     "52.1,4.2\n")  # fmt: skip
    assert detect_format(src) == "unknown"  # no MMSI column known: not taken for AIS
    src = _write(tmp_path, "de2.csv", "MMSI,Zeit,Breite,Laenge\n244660000,2024-01-31 12:00:00,"
                                      "52.1,4.2\n")  # fmt: skip
    summary = run_import([src], tmp_path / "out")
    assert summary.exit_code == 1
    ((_, err),) = summary.failed
    assert "no column for time" in err and "'Zeit', 'Breite', 'Laenge'" in err


def test_config_overrides_place_other_columns(tmp_path):
    src = _write(tmp_path, "de2.csv", "MMSI;Zeit;Breite;Laenge;Fahrt\n"
                                      "244660000;31.01.2024 12:00:00;52,1;4,2;10,5\n")  # fmt: skip
    opts = parse_import_options({"import": {"csv": {
        "columns": {"zeit": "time", "Breite": "lat_deg", "LAENGE": "lon", "Fahrt": "sog"},
        "time_format": "%d.%m.%Y %H:%M:%S"}}})  # fmt: skip
    res = import_file(src, tmp_path / "out", options=opts)
    ((t, doc),) = _docs(Path(res.output))
    assert t == T * NS and (doc["lat_deg"], doc["lon_deg"], doc["sog_kn"]) == (52.1, 4.2, 10.5)


def test_config_override_to_an_unknown_field_is_a_config_error():
    with pytest.raises(ConfigError, match="'Zeit' = 'when' is not a field"):
        parse_import_options({"import": {"csv": {"columns": {"Zeit": "when"}}}})
    with pytest.raises(ConfigError, match="colums"):
        parse_import_options({"import": {"csv": {"colums": {}}}})


def test_the_sections_load_with_the_config_file(tmp_path):
    from pipeline.convert.config import import_options
    from pipeline.families import load_config
    from pipeline.resources import resource_path

    text = (resource_path("config") / "surveil.toml").read_text()
    path = tmp_path / "c.toml"
    path.write_text(text + '\n[import.csv]\ncolumns = { "Zeit" = "time" }\n'
                    '[asterix]\neditions = { "010" = "0.24" }\n')  # fmt: skip
    opts = import_options(load_config(path))
    assert opts.csv.columns == {"Zeit": "time"} and opts.asterix_editions == {10: "0.24"}
    path.write_text(text + '\n[asterix]\neditions = { "010" = "9.9" }\n')
    with pytest.raises(ConfigError, match="not one we decode"):
        load_config(path)


def test_known_dialects_keep_their_names_and_ignore_is_honoured(tmp_path):
    src = _write(tmp_path, "mc.csv", "MMSI,BaseDateTime,LAT,LON,SOG,COG,Heading,VesselName\n"
                                     "367000001,2023-01-11T00:00:00,30.0,-90.0,0.1,360.0,511,X\n")
    table = read_ais_csv(src)
    assert table.flavor == "marinecadastre" and table.time_column == "BaseDateTime"
    placed, unplaced = place_columns(["MMSI", "Extra", "Time"], {"Time": "ignore"})
    assert placed == {"mmsi": "MMSI"} and unplaced == ["Extra"]
    table = read_ais_csv(src, CsvOptions(columns={"VesselName": "ignore"}))
    assert "shipname" not in table.rows.columns


EXACTEARTH = (
    "MMSI,Message_ID,Repeat_indicator,Time,Millisecond,Region,Country,Base_station,"
    "Online_data,Group_code,Sequence_ID,Channel,Data_length,Vessel_Name,Call_sign,IMO,"
    "Ship_Type,Dimension_to_Bow,Dimension_to_stern,Dimension_to_port,Dimension_to_starboard,"
    "Draught,Destination,AIS_version,Navigational_status,ROT,SOG,Accuracy,Longitude,"
    "Latitude,COG,Heading,Regional,Maneuver,RAIM_flag,Communication_flag\n"
    "316001234,1,0,20240131_120000,250,66,CA,003669701,,,,A,168,,,,,,,,,,,,0,0,10.5,1,"
    "-63.5,44.6,90.0,91,0,0,0,0\n"
    "316001234,5,0,20240131_120001,0,66,CA,003669701,,,,B,424,SHIP ONE,VCAB2,9123456,70,"
    "100,20,10,10,7.5,HALIFAX,0,,,,,,,,,,,,\n"
    "3160001,4,0,20240131_120002,0,66,CA,003669701,,,,A,168,,,,,,,,,,,,,,,,-63.0,44.0,,,,,,\n"
)


def test_exactearth_aisdb_message_level_csv(tmp_path):
    """The wide message-level CSV aisdb reads (exactEarth): Time to the second plus a
    Millisecond column, one row per message with its Message_ID."""
    src = _write(tmp_path, "ee.csv", EXACTEARTH)
    assert detect_format(src) == "ais_csv"
    res = import_file(src, tmp_path / "out")
    docs = _docs(Path(res.output))
    assert [t for t, _ in docs] == [T * NS + 250_000_000, (T + 1) * NS, (T + 2) * NS]
    out = _ingest(tmp_path, Path(res.output))
    (rep,) = out["ais_reports"]
    assert (rep["mmsi"], rep["lat_deg"], rep["lon_deg"]) == (316001234, 44.6, -63.5)
    (static,) = out["ais_static"]
    assert (static["shipname"], static["callsign"], static["imo"]) == ("SHIP ONE", "VCAB2",
                                                                      9123456)  # fmt: skip
    assert out["rejects"] == []
    assert [(r["msg_type"], r["ais_class"]) for r in out["ais_other_messages"]] == [
        (4, "base_station")]


def test_a_bare_type_column_of_ship_type_codes_is_the_ship_type(tmp_path):
    src = _write(tmp_path, "hub.csv", "MMSI,TIME,LONGITUDE,LATITUDE,TYPE,NAME\n"
                                      "244660000,2024-01-31 12:00:00 GMT,4.2,52.1,70,X\n")
    ((t, doc),) = _docs(Path(import_file(src, tmp_path / "out").output))
    assert t == T * NS and doc["ship_type"] == 70 and doc.get("msg_type") is None
