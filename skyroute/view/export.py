"""Plan (and flown track) exports for the tools drone people use: QGroundControl, MAVProxy, geojson.io, Google Earth.

One writer per format, picked by the file's extension (:data:`FORMATS`):

``.plan``
    QGroundControl's JSON plan (file version 1, mission version 2): planned home, TAKEOFF, one WAYPOINT per
    planned waypoint after the start, LAND at the goal. Opens in QGroundControl; uploaded to PX4 or ArduPilot it
    flies in mission (AUTO) mode.
``.waypoints``
    The plain-text ``QGC WPL 110`` mission that MAVProxy (``wp load``), Mission Planner and QGroundControl read:
    item 0 is home, then the same items as the ``.plan``.
``.geojson``
    An RFC 7946 FeatureCollection: the planned path as a LineString, start and goal as Points and, after a flight,
    the flown track as a LineString (geojson.io, QGIS).
``.kml``
    A KML 2.2 document with the same features, altitudes drawn above the ground (Google Earth).

Frames and altitudes (the same in every format):

* Horizontal positions are the planned map-frame points (NED metres from the map's home ``lat0, lon0``) converted
  to WGS84 latitude/longitude with :func:`skyroute.frames.ned_to_geodetic`.
* Mission altitudes (``.plan``, ``.waypoints``) are metres **above home** (MAV_FRAME_GLOBAL_RELATIVE_ALT, QGC's
  "relative" altitude mode): the autopilot adds its own home altitude, so the file flies the planned heights
  wherever the vehicle's home altitude really is. Only the planned-home entry (item 0 of a ``.waypoints``, the
  ``plannedHomePosition`` of a ``.plan``) is absolute (MAV_FRAME_GLOBAL, metres AMSL): ``home_amsl_m``, which
  defaults to 0 because ``colliders.csv`` gives no home altitude; autopilots replace it with their real home.
* KML altitudes are ``relativeToGround``: the map's ground is flat at home altitude (every building stands on
  altitude 0), so above ground is above home.
* GeoJSON positions are ``[longitude, latitude]`` (RFC 7946 order) without a third value, because RFC 7946's
  third value is height above the WGS84 ellipsoid, which we do not know; the heights above home are in each
  feature's ``properties`` (``altitudes_m_above_home``, one per position).

MAVLink numbers are named below; the tests check each against pymavlink's generated enums (this module does not
import pymavlink: ``skyroute.vehicle`` owns it).
"""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skyroute.frames import Geodetic, LocalNED, ned_to_geodetic

# MAV_CMD / MAV_FRAME / MAV_AUTOPILOT / MAV_TYPE values from the MAVLink common dialect (checked in the tests).
MAV_CMD_NAV_WAYPOINT = 16
MAV_CMD_NAV_LAND = 21
MAV_CMD_NAV_TAKEOFF = 22
MAV_FRAME_GLOBAL = 0  # altitude AMSL
MAV_FRAME_GLOBAL_RELATIVE_ALT = 3  # altitude above home
MAV_AUTOPILOT_GENERIC = 0  # QGC: "any firmware"; the items use only commands PX4 and ArduPilot share
MAV_TYPE_QUADROTOR = 2
QGC_ALTITUDE_MODE_RELATIVE = 1  # QGroundControl's AltitudeMode / globalPlanAltitudeMode "relative to launch"

#: Speeds QGroundControl shows for time estimates (m/s); the autopilot's own parameters decide the real ones.
CRUISE_MPS, HOVER_MPS = 10.0, 5.0


class ExportError(ValueError):
    """An export that cannot be written: unknown extension, empty plan, or a file that cannot be created."""


@dataclass(frozen=True)
class FlightRecord:
    """What an export is made of, all in the map frame (NED metres from ``home``; altitude metres above home).

    ``waypoints`` ``(K, 4)`` ``[north_m, east_m, altitude_m, heading_rad]``, the first at the start (as every
    planner returns them); ``track`` ``(T, 4)`` ``[time_s, north_m, east_m, altitude_m]`` as flown (a
    :class:`~skyroute.flight.mission.MissionResult`'s ``track``), or ``None`` before a flight.
    """

    home: Geodetic
    waypoints: np.ndarray
    track: np.ndarray | None = None
    home_amsl_m: float = 0.0
    name: str = "skyroute plan"

    def __post_init__(self) -> None:
        wp = np.asarray(self.waypoints, dtype=float)
        if wp.ndim != 2 or wp.shape[1] < 3 or len(wp) == 0:
            raise ExportError(f"an export needs (K >= 1, 4) waypoints, got shape {wp.shape}")
        if not np.isfinite(wp[:, :3]).all():
            raise ExportError("an export needs finite waypoint positions and altitudes")
        object.__setattr__(self, "waypoints", wp)
        if self.track is not None:
            track = np.asarray(self.track, dtype=float).reshape(-1, 4)
            object.__setattr__(self, "track", track if len(track) else None)

    def geodetic(self, north_m: float, east_m: float) -> Geodetic:
        """WGS84 position of a map point (altitude 0 = home)."""
        return ned_to_geodetic(LocalNED(float(north_m), float(east_m), 0.0), self.home)

    def waypoint_geodetics(self) -> list[tuple[float, float, float]]:
        """``(lat_deg, lon_deg, altitude_m_above_home)`` of every planned waypoint."""
        return [(*self.geodetic(n, e)[:2], float(a)) for n, e, a in self.waypoints[:, :3]]

    def track_geodetics(self) -> list[tuple[float, float, float]]:
        """``(lat_deg, lon_deg, altitude_m_above_home)`` of every flown track sample (empty before a flight)."""
        if self.track is None:
            return []
        return [(*self.geodetic(n, e)[:2], float(a)) for _, n, e, a in self.track]


# ------------------------------------------------------------------------------------------ mission items
@dataclass(frozen=True)
class MissionItem:
    """One MAVLink mission item as files store it: params 1-4, then latitude, longitude, altitude (params 5-7)."""

    command: int
    frame: int
    params: tuple[float, float, float, float]
    lat_deg: float
    lon_deg: float
    altitude_m: float


def mission_items(record: FlightRecord) -> list[MissionItem]:
    """TAKEOFF above the start, WAYPOINT at each planned waypoint after the start, LAND at the goal.

    Altitudes above home (``MAV_FRAME_GLOBAL_RELATIVE_ALT``). The takeoff climbs to the first waypoint's
    altitude at the start; the first waypoint *is* the start, so it is not repeated as a WAYPOINT. Yaw (param 4)
    is NaN: "keep the autopilot's heading behaviour" (PX4 faces along the leg; ArduPilot ignores it).
    """
    points = record.waypoint_geodetics()
    nan = math.nan
    lat0, lon0, alt0 = points[0]
    items = [MissionItem(MAV_CMD_NAV_TAKEOFF, MAV_FRAME_GLOBAL_RELATIVE_ALT, (0.0, 0.0, 0.0, nan), lat0, lon0, alt0)]
    items += [MissionItem(MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT, (0.0, 0.0, 0.0, nan), lat, lon, alt)
              for lat, lon, alt in points[1:]]
    lat_goal, lon_goal, _ = points[-1]
    items.append(MissionItem(MAV_CMD_NAV_LAND, MAV_FRAME_GLOBAL_RELATIVE_ALT, (0.0, 0.0, 0.0, nan),
                             lat_goal, lon_goal, 0.0))
    return items


# ------------------------------------------------------------------------------------------------ writers
def _json_number(value: float) -> float | None:
    """QGroundControl writes NaN params as JSON ``null``; JSON has no NaN."""
    return None if math.isnan(value) else round(float(value), 9)


def plan_document(record: FlightRecord) -> dict:
    """The QGroundControl ``.plan`` as a dict (see the module docstring for frames)."""
    items = []
    for seq, item in enumerate(mission_items(record), start=1):
        items.append({
            "AMSLAltAboveTerrain": None,
            "Altitude": _json_number(item.altitude_m),
            "AltitudeMode": QGC_ALTITUDE_MODE_RELATIVE,
            "autoContinue": True,
            "command": item.command,
            "doJumpId": seq,
            "frame": item.frame,
            "params": [*map(_json_number, item.params), _json_number(item.lat_deg), _json_number(item.lon_deg),
                       _json_number(item.altitude_m)],
            "type": "SimpleItem",
        })
    return {
        "fileType": "Plan",
        "version": 1,
        "groundStation": "skyroute",
        "mission": {
            "version": 2,
            "firmwareType": MAV_AUTOPILOT_GENERIC,
            "vehicleType": MAV_TYPE_QUADROTOR,
            "globalPlanAltitudeMode": QGC_ALTITUDE_MODE_RELATIVE,
            "cruiseSpeed": CRUISE_MPS,
            "hoverSpeed": HOVER_MPS,
            "plannedHomePosition": [round(record.home.lat_deg, 9), round(record.home.lon_deg, 9),
                                    float(record.home_amsl_m)],
            "items": items,
        },
        "geoFence": {"version": 2, "circles": [], "polygons": []},
        "rallyPoints": {"version": 2, "points": []},
    }


def plan_text(record: FlightRecord) -> str:
    return json.dumps(plan_document(record), indent=2) + "\n"


def waypoints_text(record: FlightRecord) -> str:
    """``QGC WPL 110``: tab-separated ``seq current frame command p1 p2 p3 p4 lat lon alt autocontinue``.

    Item 0 is home (MAV_FRAME_GLOBAL, ``home_amsl_m`` AMSL), current; the mission items follow. NaN params are
    written as 0, which ArduPilot (the format's main reader) treats as "default".
    """
    def number(value: float, digits: int) -> str:
        return f"{0.0 if math.isnan(value) else value:.{digits}f}"

    rows = [(MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL, (0.0, 0.0, 0.0, 0.0), record.home.lat_deg, record.home.lon_deg,
             float(record.home_amsl_m))]
    rows += [(i.command, i.frame, i.params, i.lat_deg, i.lon_deg, i.altitude_m) for i in mission_items(record)]
    lines = ["QGC WPL 110"]
    for seq, (command, frame, params, lat, lon, alt) in enumerate(rows):
        fields = [str(seq), "1" if seq == 0 else "0", str(frame), str(command),
                  *(number(p, 6) for p in params), number(lat, 9), number(lon, 9), number(alt, 3), "1"]
        lines.append("\t".join(fields))
    return "\n".join(lines) + "\n"


def geojson_document(record: FlightRecord) -> dict:
    """RFC 7946 FeatureCollection: ``planned path``, ``start``, ``goal`` and, after a flight, ``flown track``."""
    def line(name: str, points: list[tuple[float, float, float]], **extra) -> dict:
        coordinates = [[round(lon, 9), round(lat, 9)] for lat, lon, _ in points]
        return {
            "type": "Feature",
            "geometry": {"type": "LineString", "coordinates": coordinates},
            "properties": {"name": name, "altitudes_m_above_home": [round(a, 3) for *_, a in points], **extra},
        }

    def point(name: str, lat: float, lon: float, alt: float) -> dict:
        return {"type": "Feature", "geometry": {"type": "Point", "coordinates": [round(lon, 9), round(lat, 9)]},
                "properties": {"name": name, "altitude_m_above_home": round(alt, 3)}}

    planned = record.waypoint_geodetics()
    if len(planned) == 1:  # a LineString needs two positions: start and goal coincide
        planned = planned * 2
    features = [line("planned path", planned, stroke="#1f77b4"), point("start", *planned[0]),
                point("goal", *planned[-1])]
    flown = record.track_geodetics()
    if len(flown) >= 2:
        times = [round(float(t), 3) for t in record.track[:, 0]]
        features.append(line("flown track", flown, stroke="#d62728", times_s=times))
    return {"type": "FeatureCollection", "features": features}


def geojson_text(record: FlightRecord) -> str:
    return json.dumps(geojson_document(record), indent=1) + "\n"


KML_NS = "http://www.opengis.net/kml/2.2"


def kml_text(record: FlightRecord) -> str:
    """KML 2.2: a Document with the planned path, start and goal Placemarks and, after a flight, the flown track."""
    ET.register_namespace("", KML_NS)

    def sub(parent, tag: str, text: str | None = None, **attrib):
        element = ET.SubElement(parent, f"{{{KML_NS}}}{tag}", attrib)
        if text is not None:
            element.text = text
        return element

    def coordinates(points) -> str:
        return " ".join(f"{lon:.9f},{lat:.9f},{alt:.3f}" for lat, lon, alt in points)

    root = ET.Element(f"{{{KML_NS}}}kml")
    doc = sub(root, "Document")
    sub(doc, "name", record.name)
    for style_id, colour in (("planned", "ffb4771f"), ("flown", "ff2827d6")):  # aabbggrr
        style = sub(doc, "Style", id=style_id)
        line_style = sub(style, "LineStyle")
        sub(line_style, "color", colour)
        sub(line_style, "width", "3")

    def line(name: str, style: str, points) -> None:
        placemark = sub(doc, "Placemark")
        sub(placemark, "name", name)
        sub(placemark, "styleUrl", f"#{style}")
        geometry = sub(placemark, "LineString")
        sub(geometry, "altitudeMode", "relativeToGround")
        sub(geometry, "coordinates", coordinates(points))

    planned = record.waypoint_geodetics()
    line("planned path", "planned", planned if len(planned) > 1 else planned * 2)
    for name, p in (("start", planned[0]), ("goal", planned[-1])):
        placemark = sub(doc, "Placemark")
        sub(placemark, "name", name)
        geometry = sub(placemark, "Point")
        sub(geometry, "altitudeMode", "relativeToGround")
        sub(geometry, "coordinates", coordinates([p]))
    flown = record.track_geodetics()
    if len(flown) >= 2:
        line("flown track", "flown", flown)
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


#: Extension -> writer.
FORMATS: dict[str, Callable[[FlightRecord], str]] = {
    ".plan": plan_text,
    ".waypoints": waypoints_text,
    ".geojson": geojson_text,
    ".kml": kml_text,
}


def export_format(path: str | Path) -> str:
    """The format of ``path`` from its extension (lower case), or raise :class:`ExportError` naming the choices."""
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise ExportError(f"cannot export {path}: unknown extension {suffix or '(none)'!r}; "
                          f"use one of {', '.join(FORMATS)}")
    return suffix


def check_export_path(path: str | Path) -> None:
    """Raise :class:`ExportError` before any work if ``path`` has an unknown extension or no directory to go in."""
    export_format(path)
    parent = Path(path).resolve().parent
    if not parent.is_dir():
        raise ExportError(f"cannot export {path}: {parent} is not a directory")


def write_export(path: str | Path, record: FlightRecord) -> Path:
    """Write ``record`` to ``path`` in the format its extension names; returns the path.

    Raises :class:`ExportError` for an unknown extension or a file that cannot be written.
    """
    text = FORMATS[export_format(path)](record)
    try:
        Path(path).write_text(text, encoding="utf-8")
    except OSError as exc:
        raise ExportError(f"cannot write {path}: {exc.strerror or exc}") from None
    return Path(path)


def write_exports(paths: Sequence[str | Path], record: FlightRecord) -> list[Path]:
    """:func:`write_export` for each path, in order."""
    return [write_export(path, record) for path in paths]
