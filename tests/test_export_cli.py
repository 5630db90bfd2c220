"""``--export`` and ``--view`` on the real command line (``motion_planning.main``): plan-only, a flight against the
in-process sim, and bad input as one-line errors before any work."""

from __future__ import annotations

import json
import socket
import threading

import pytest

import motion_planning as mp
from sim import SimConfig, Simulator
from tests.geodesy import distance_m, ned_to_latlon

LAT0, LON0 = 37.792480, -122.397450
GOAL_SHORT = (99.5, 50.5)  # ~120 m from home on the project map, free at 5 m with a 5 m margin


def to_latlon(north_m: float, east_m: float) -> tuple[float, float]:
    """``(lat, lon)`` of a point north/east of the map origin (:mod:`tests.geodesy`, independent of ``frames``)."""
    return ned_to_latlon(north_m, east_m, LAT0, LON0)


def goal_args(north_m: float, east_m: float) -> list[str]:
    lat, lon = to_latlon(north_m, east_m)
    return ["--goal_lat", f"{lat:.9f}", "--goal_lon", f"{lon:.9f}"]


def test_plan_only_exports_every_format_with_the_printed_plans_waypoints(tmp_path, capsys):
    files = [tmp_path / f"mission{ext}" for ext in (".plan", ".waypoints", ".geojson", ".kml")]
    code = mp.main(["--plan-only", "--json", *goal_args(*GOAL_SHORT),
                    *[arg for f in files for arg in ("--export", str(f))]])
    assert code == 0
    printed = json.loads(capsys.readouterr().out)  # --json keeps stdout one JSON object
    waypoints = printed["waypoints"]
    plan = json.loads(files[0].read_text())
    items = plan["mission"]["items"]
    assert [i["command"] for i in items] == [22] + [16] * (len(waypoints) - 1) + [21]
    for item, (n, e, alt, _) in zip(items[1:], waypoints[1:]):
        assert distance_m(item["params"][4], item["params"][5], *to_latlon(n, e)) < 0.05
        assert item["params"][6] == pytest.approx(alt)
    goal = json.loads(files[2].read_text())["features"][2]
    lon, lat = goal["geometry"]["coordinates"]
    assert distance_m(lat, lon, *to_latlon(*GOAL_SHORT)) < 1.0  # the goal cell's centre
    assert files[1].read_text().startswith("QGC WPL 110\n") and files[3].read_text().startswith("<?xml")


@pytest.mark.parametrize(("args", "message"), [
    (["--plan-only", "--export", "plan.gpx"], "unknown extension '.gpx'"),
    (["--plan-only", "--export", "nowhere/plan.plan"], "is not a directory"),
    (["--plan-only", "--view"], "--view shows a flight"),
    (["--sim", "--view", "70000"], "--view port must be 0..65535"),
])
def test_bad_view_or_export_options_are_one_line_errors_before_any_work(args, message, tmp_path, capsys,
                                                                        monkeypatch):
    monkeypatch.chdir(tmp_path)
    code = mp.main([*goal_args(*GOAL_SHORT), "--map", str(mp.DEFAULT_MAP), *args])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and message in err and "Traceback" not in err
    assert not (tmp_path / "logs").exists()  # refused before logging, let alone connecting


@pytest.fixture
def sim(tmp_path):
    simulator = Simulator(SimConfig(map_path=mp.DEFAULT_MAP, port=0, speedup=20.0, strict=True)).start()
    yield simulator
    simulator.stop()
    assert simulator.error is None, simulator.error


@pytest.mark.flight
def test_a_flight_with_view_and_exports_writes_the_flown_track_and_closes_the_view(sim, tmp_path, capsys):
    geojson, kml, plan = tmp_path / "flight.geojson", tmp_path / "flight.kml", tmp_path / "flight.plan"
    code = mp.main([*goal_args(*GOAL_SHORT), "--connection", f"tcp:127.0.0.1:{sim.port}", "--timeout", "5",
                    "--log-dir", str(tmp_path / "logs"), "--view", "0",
                    "--export", str(geojson), "--export", str(kml), "--export", str(plan)])
    out = capsys.readouterr().out
    assert code == 0, out
    (url_line,) = [line for line in out.splitlines() if line.startswith("live view at ")]
    port = int(url_line.split()[3].rsplit(":", 1)[1].strip("/"))
    with pytest.raises(OSError):  # the view closed with the flight
        socket.create_connection(("127.0.0.1", port), timeout=2).close()
    assert not {t.name for t in threading.enumerate()} & {"live-view", "view-feed"}
    assert f"plan and flown track exported to {geojson}" in out and f"plan exported to {plan}" in out

    final = sim.report()["final"]["position"]  # the sim's truth
    features = {f["properties"]["name"]: f for f in json.loads(geojson.read_text())["features"]}
    flown = features["flown track"]["geometry"]["coordinates"]
    altitudes = features["flown track"]["properties"]["altitudes_m_above_home"]
    assert len(flown) >= 5 and max(altitudes) == pytest.approx(5.0, abs=0.6)  # sampled every 0.2 s, 20x speed
    lon, lat = flown[-1]  # the track ends where the sim says the vehicle landed
    assert distance_m(lat, lon, final["lat_deg"], final["lon_deg"]) < 0.5
    assert distance_m(lat, lon, *to_latlon(*GOAL_SHORT)) < 1.5
    assert kml.read_text().count("<Placemark>") == 4
