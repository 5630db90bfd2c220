"""Plan exports, each read back by a reader that is not ours.

* ``.plan``: a reader written here from QGroundControl's loader (PlanMasterController / MissionController /
  MissionItem ``load``: the keys and types it requires), and MAVSDK's own C++ importer
  (``MissionRaw.import_qgroundcontrol_mission``) against the sim.
* ``.waypoints``: pymavlink's ``mavwp.MAVWPLoader`` (what MAVProxy's ``wp load`` uses) and MAVSDK's importer.
* ``.geojson``: the ``geojson`` package's validator, plus RFC 7946's rules (longitude first) checked here.
* ``.kml``: parsed as XML and checked against KML 2.2's structure.

Positions are checked against lat/lon computed here with a local WGS84 formula (not ``skyroute.frames``), on a
hand-made plan whose waypoints are spelled out.
"""

from __future__ import annotations

import asyncio
import json
import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from pymavlink import mavwp
from pymavlink.dialects.v20 import common as mavlink

from skyroute.frames import Geodetic
from skyroute.view import export
from skyroute.view.export import ExportError, FlightRecord, write_export
from tests.geodesy import distance_m, ned_to_latlon

LAT0, LON0 = 37.792480, -122.397450

#: A hand-made plan: start at home, north 100 m, then east 50 m while climbing to 8 m.
WAYPOINTS = np.array([[0.0, 0.0, 5.0, 0.0], [100.0, 0.0, 5.0, 0.0], [100.0, 50.0, 8.0, 1.5708]])
#: A flown track: [time_s, north_m, east_m, altitude_m].
TRACK = np.array([[0.0, 0.0, 0.0, 0.0], [2.0, 0.0, 0.0, 5.0], [12.0, 100.0, 0.2, 5.0], [20.0, 100.0, 50.0, 8.0],
                  [25.0, 100.1, 50.0, 0.0]])


def to_latlon(north_m: float, east_m: float) -> tuple[float, float]:
    """``(lat, lon)`` of a point north/east of the map origin (:mod:`tests.geodesy`, independent of ``frames``)."""
    return ned_to_latlon(north_m, east_m, LAT0, LON0)


def close_m(lat_a: float, lon_a: float, lat_b: float, lon_b: float, tolerance_m: float = 0.05) -> bool:
    return distance_m(lat_a, lon_a, lat_b, lon_b) <= tolerance_m


# (lat, lon, alt above home) expected for each mission item: takeoff over the start, the two waypoints after
# the start, land at the goal.
EXPECTED_ITEMS = [
    (mavlink.MAV_CMD_NAV_TAKEOFF, *to_latlon(0, 0), 5.0),
    (mavlink.MAV_CMD_NAV_WAYPOINT, *to_latlon(100, 0), 5.0),
    (mavlink.MAV_CMD_NAV_WAYPOINT, *to_latlon(100, 50), 8.0),
    (mavlink.MAV_CMD_NAV_LAND, *to_latlon(100, 50), 0.0),
]


@pytest.fixture
def record() -> FlightRecord:
    return FlightRecord(Geodetic(LAT0, LON0, 0.0), WAYPOINTS, track=TRACK)


def test_named_mavlink_numbers_are_pymavlinks():
    assert export.MAV_CMD_NAV_WAYPOINT == mavlink.MAV_CMD_NAV_WAYPOINT
    assert export.MAV_CMD_NAV_TAKEOFF == mavlink.MAV_CMD_NAV_TAKEOFF
    assert export.MAV_CMD_NAV_LAND == mavlink.MAV_CMD_NAV_LAND
    assert export.MAV_FRAME_GLOBAL == mavlink.MAV_FRAME_GLOBAL
    assert export.MAV_FRAME_GLOBAL_RELATIVE_ALT == mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT
    assert export.MAV_AUTOPILOT_GENERIC == mavlink.MAV_AUTOPILOT_GENERIC
    assert export.MAV_TYPE_QUADROTOR == mavlink.MAV_TYPE_QUADROTOR


# ------------------------------------------------------------------------------------------------ .plan
def _require(obj: dict, key: str, kinds: tuple[type, ...], where: str):
    """QGroundControl's JsonHelper::validateKeys: the key is there and of the JSON type asked for."""
    assert key in obj, f"{where}: QGroundControl requires {key!r}"
    value = obj[key]
    ok = isinstance(value, bool) if bool in kinds else isinstance(value, kinds) and not isinstance(value, bool)
    assert ok, f"{where}: {key!r} must be {kinds}, got {value!r}"
    return value


def read_qgc_plan(text: str) -> tuple[list[float], list[dict]]:
    """What QGroundControl checks when it opens a ``.plan`` (its loaders' required keys and types, in order):
    returns ``(plannedHomePosition, items)``."""
    doc = json.loads(text)
    number = (int, float)
    assert _require(doc, "fileType", (str,), "plan") == "Plan"
    assert _require(doc, "version", number, "plan") == 1  # kPlanFileVersion, min = max
    _require(doc, "groundStation", (str,), "plan")
    mission = _require(doc, "mission", (dict,), "plan")
    fence = _require(doc, "geoFence", (dict,), "plan")
    rally = _require(doc, "rallyPoints", (dict,), "plan")
    assert _require(mission, "version", number, "mission") == 2
    home = _require(mission, "plannedHomePosition", (list,), "mission")
    assert len(home) == 3 and all(isinstance(v, number) for v in home), "home needs lat, lon and altitude"
    items = _require(mission, "items", (list,), "mission")
    _require(mission, "firmwareType", number, "mission")
    for optional in ("vehicleType", "cruiseSpeed", "hoverSpeed", "globalPlanAltitudeMode"):
        if optional in mission:
            _require(mission, optional, number, "mission")
    assert items, "a plan must contain at least one mission item"
    for k, item in enumerate(items):
        where = f"item {k}"
        assert _require(item, "type", (str,), where) == "SimpleItem"
        _require(item, "frame", number, where)
        _require(item, "command", number, where)
        _require(item, "autoContinue", (bool,), where)
        params = _require(item, "params", (list,), where)
        assert len(params) == 7, f"{where}: params must contain 7 values"
        assert all(p is None or isinstance(p, number) for p in params), f"{where}: params are numbers or null"
        if "doJumpId" in item:
            _require(item, "doJumpId", number, where)
    assert _require(fence, "version", number, "geoFence") == 2
    _require(fence, "circles", (list,), "geoFence")
    _require(fence, "polygons", (list,), "geoFence")
    assert _require(rally, "version", number, "rallyPoints") == 2
    _require(rally, "points", (list,), "rallyPoints")
    return home, items


def test_plan_loads_in_a_qgroundcontrol_style_reader_with_takeoff_waypoints_and_land(tmp_path, record):
    path = write_export(tmp_path / "mission.plan", record)
    home, items = read_qgc_plan(path.read_text())
    assert close_m(home[0], home[1], LAT0, LON0) and home[2] == 0.0
    assert [(i["command"], i["frame"]) for i in items] == [
        (cmd, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT) for cmd, *_ in EXPECTED_ITEMS]
    for item, (_, lat, lon, alt) in zip(items, EXPECTED_ITEMS):
        p = item["params"]
        assert close_m(p[4], p[5], lat, lon), (item, lat, lon)
        assert p[6] == pytest.approx(alt) and item["Altitude"] == pytest.approx(alt)
        assert item["AltitudeMode"] == 1  # relative to launch
        assert item["autoContinue"] is True


def test_the_qgroundcontrol_reader_rejects_what_qgroundcontrol_rejects(tmp_path, record):
    doc = json.loads(export.plan_text(record))
    del doc["rallyPoints"]
    with pytest.raises(AssertionError, match="rallyPoints"):
        read_qgc_plan(json.dumps(doc))
    doc = json.loads(export.plan_text(record))
    doc["mission"]["items"][0]["params"].pop()
    with pytest.raises(AssertionError, match="7 values"):
        read_qgc_plan(json.dumps(doc))


# ------------------------------------------------------------------------------------------- .waypoints
def test_waypoints_load_in_pymavlinks_mavwp_loader_with_home_first(tmp_path, record):
    path = write_export(tmp_path / "mission.waypoints", record)
    assert path.read_text().splitlines()[0] == "QGC WPL 110"
    assert all(len(line.split("\t")) == 12 for line in path.read_text().splitlines()[1:])
    loader = mavwp.MAVWPLoader()
    assert loader.load(str(path)) == 1 + len(EXPECTED_ITEMS)
    home = loader.wp(0)
    assert (home.seq, home.current, home.frame, home.command) == (0, 1, mavlink.MAV_FRAME_GLOBAL,
                                                                 mavlink.MAV_CMD_NAV_WAYPOINT)
    assert close_m(home.x, home.y, LAT0, LON0)
    for seq, (command, lat, lon, alt) in enumerate(EXPECTED_ITEMS, start=1):
        w = loader.wp(seq)
        assert (w.seq, w.current, w.command, w.frame, w.autocontinue) == (
            seq, 0, command, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, 1)
        assert close_m(w.x, w.y, lat, lon) and w.z == pytest.approx(alt, abs=1e-3)
        assert all(math.isfinite(p) for p in (w.param1, w.param2, w.param3, w.param4))


# ---------------------------------------------------------------------------------------------- geojson
def test_geojson_is_valid_rfc7946_with_longitude_first_and_the_flown_track(tmp_path, record):
    geojson = pytest.importorskip("geojson")
    path = write_export(tmp_path / "mission.geojson", record)
    collection = geojson.loads(path.read_text())
    assert collection.is_valid, collection.errors()
    features = {f["properties"]["name"]: f for f in collection["features"]}
    assert set(features) == {"planned path", "start", "goal", "flown track"}
    planned = features["planned path"]
    assert planned["geometry"]["type"] == "LineString"
    coords = planned["geometry"]["coordinates"]
    assert len(coords) == len(WAYPOINTS)
    for (lon, lat), (n, e, _, _) in zip(coords, WAYPOINTS):
        assert -180 <= lon <= 180 and -90 <= lat <= 90
        assert close_m(lat, lon, *to_latlon(n, e))  # [lon, lat]: RFC 7946 section 3.1.1
    assert planned["properties"]["altitudes_m_above_home"] == [5.0, 5.0, 8.0]
    assert features["goal"]["geometry"]["coordinates"] == coords[-1]
    flown = features["flown track"]
    assert len(flown["geometry"]["coordinates"]) == len(TRACK)
    assert flown["properties"]["times_s"] == TRACK[:, 0].tolist()
    lon, lat = flown["geometry"]["coordinates"][2]
    assert close_m(lat, lon, *to_latlon(100.0, 0.2))


def test_geojson_before_a_flight_has_no_track(tmp_path):
    record = FlightRecord(Geodetic(LAT0, LON0, 0.0), WAYPOINTS)
    doc = json.loads(export.geojson_text(record))
    assert [f["properties"]["name"] for f in doc["features"]] == ["planned path", "start", "goal"]


# -------------------------------------------------------------------------------------------------- kml
KML = "{http://www.opengis.net/kml/2.2}"


def test_kml_is_a_kml22_document_with_lon_lat_alt_above_ground(tmp_path, record):
    path = write_export(tmp_path / "mission.kml", record)
    root = ET.parse(path).getroot()
    assert root.tag == f"{KML}kml"
    (document,) = root.findall(f"{KML}Document")
    placemarks = {p.findtext(f"{KML}name"): p for p in document.findall(f"{KML}Placemark")}
    assert set(placemarks) == {"planned path", "start", "goal", "flown track"}
    for name, geometry in (("planned path", "LineString"), ("flown track", "LineString"), ("start", "Point"),
                           ("goal", "Point")):
        (g,) = placemarks[name].findall(f"{KML}{geometry}")
        children = [c.tag.removeprefix(KML) for c in g]
        assert children == ["altitudeMode", "coordinates"]  # the schema's order
        assert g.findtext(f"{KML}altitudeMode") == "relativeToGround"
    style_ids = {s.get("id") for s in document.findall(f"{KML}Style")}
    for name in ("planned path", "flown track"):
        assert placemarks[name].findtext(f"{KML}styleUrl").lstrip("#") in style_ids
    tuples = placemarks["planned path"].find(f"{KML}LineString").findtext(f"{KML}coordinates").split()
    assert len(tuples) == len(WAYPOINTS)
    for text, (n, e, alt, _) in zip(tuples, WAYPOINTS):
        lon, lat, z = map(float, text.split(","))  # KML: lon,lat[,alt] with no spaces inside a tuple
        assert close_m(lat, lon, *to_latlon(n, e)) and z == pytest.approx(alt)
    flown = placemarks["flown track"].find(f"{KML}LineString").findtext(f"{KML}coordinates").split()
    assert len(flown) == len(TRACK)


# ------------------------------------------------------------------------------------------------ errors
def test_an_unknown_extension_names_the_formats(tmp_path, record):
    with pytest.raises(ExportError, match=r"\.plan, \.waypoints, \.geojson, \.kml"):
        write_export(tmp_path / "mission.gpx", record)


def test_a_missing_directory_is_refused_before_writing(tmp_path):
    with pytest.raises(ExportError, match="not a directory"):
        export.check_export_path(tmp_path / "nowhere" / "mission.plan")


def test_an_empty_plan_is_refused():
    with pytest.raises(ExportError, match="waypoints"):
        FlightRecord(Geodetic(LAT0, LON0, 0.0), np.empty((0, 4)))


# ---------------------------------------------------------------------------------------- MAVSDK reads
@pytest.mark.flight
def test_mavsdks_importers_read_the_plan_and_the_waypoints(tmp_path, record, sim_start):
    """MAVSDK's own C++ importers (QGroundControl JSON and Mission Planner text) read both files the same way."""
    sdk_mod = pytest.importorskip("mavsdk.asyncio")
    from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync

    plan = write_export(tmp_path / "mission.plan", record)
    waypoints = write_export(tmp_path / "mission.waypoints", record)
    sim = sim_start(speedup=1.0)

    async def import_both():
        config = sdk_mod.Configuration.create_with_component_type(sdk_mod.ComponentType.GROUND_STATION)
        async with sdk_mod.Mavsdk(config) as sdk:
            await sdk.add_any_connection(f"tcpout://127.0.0.1:{sim.port}")
            drone = await sdk.first_autopilot(timeout_s=10.0)
            assert drone is not None
            raw = MissionRawAsync(drone)
            return (await raw.import_qgroundcontrol_mission(str(plan)),
                    await raw.import_mission_planner_mission(str(waypoints)))

    from_plan, from_waypoints = asyncio.run(asyncio.wait_for(import_both(), 60))
    for imported in (from_plan, from_waypoints):
        items = [i for i in imported.mission_items if i.command in {c for c, *_ in EXPECTED_ITEMS}]
        assert [i.command for i in items][-len(EXPECTED_ITEMS):] == [c for c, *_ in EXPECTED_ITEMS]
        for item, (_, lat, lon, alt) in zip(items[-len(EXPECTED_ITEMS):], EXPECTED_ITEMS):
            assert item.frame == mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT
            assert close_m(item.x * 1e-7, item.y * 1e-7, lat, lon, 0.05)
            assert item.z == pytest.approx(alt, abs=1e-3)
