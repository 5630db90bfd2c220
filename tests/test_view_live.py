"""The live view without a browser: the hub's channels, the server over real loopback sockets, the feed.

The server is checked with aiohttp's own client and with a raw socket that never reads (a stalled browser); the
feed with a fake mission and vehicle whose positions and expected answers are spelled out here.
"""

from __future__ import annotations

import asyncio
import enum
import hashlib
import json
import math
import re
import socket
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from skyroute.frames import Geodetic, LocalNED
from skyroute.view.feed import FlightFeed, distance_to_go_m
from skyroute.view.live import LiveView, ViewError, ViewHub, _Cursor, static_dir

aiohttp = pytest.importorskip("aiohttp")


# ------------------------------------------------------------------------------------------------- hub
def test_a_latest_value_channel_sends_only_its_newest_value_and_only_when_it_changed():
    hub, cursor = ViewHub({"boxes": []}), _Cursor()
    for k in range(5):
        hub.set("state", {"k": k})
    message = hub.update_for(cursor)
    assert message["state"] == {"k": 4} and message["seq"] == 1
    assert hub.update_for(cursor) is None
    hub.set("state", {"k": 5})
    assert hub.update_for(cursor)["state"] == {"k": 5}


def test_an_append_only_channel_sends_every_item_once_in_order_with_its_index():
    hub, cursor = ViewHub(), _Cursor()
    hub.extend("track", [[0, 1, 2, 3], [1, 2, 3, 4]])
    assert hub.update_for(cursor)["track"] == {"from": 0, "items": [[0, 1, 2, 3], [1, 2, 3, 4]]}
    hub.extend("track", [[2, 3, 4, 5]])
    other = _Cursor()  # a page that connects late gets everything from the start
    assert hub.update_for(cursor)["track"] == {"from": 2, "items": [[2, 3, 4, 5]]}
    assert hub.update_for(other)["track"]["items"] == [[0, 1, 2, 3], [1, 2, 3, 4], [2, 3, 4, 5]]


def test_nan_and_numpy_values_become_json():
    hub, cursor = ViewHub(), _Cursor()
    hub.set("state", {"speed_mps": float("nan"), "where": np.array([1.5, 2.5]), "n": np.int64(3)})
    text = json.dumps(hub.update_for(cursor), allow_nan=False)
    assert json.loads(text)["state"] == {"speed_mps": None, "where": [1.5, 2.5], "n": 3}


def test_a_channel_keeps_its_kind():
    hub = ViewHub()
    hub.set("state", {})
    with pytest.raises(ValueError, match="latest-value"):
        hub.extend("state", [1])
    with pytest.raises(ValueError, match="append-only"):
        hub.set("track", [1])


# ---------------------------------------------------------------------------------------------- server
@pytest.fixture
def served():
    hub = ViewHub({"boxes": [[10.0, 20.0, 5.0, 2.0, 3.0, 5.0]], "goal": [50.0, 60.0]})
    view = LiveView(hub, 0).start()
    yield hub, view
    view.close()


async def _receive(url: str, count: int, timeout_s: float = 10.0) -> list[dict]:
    async with aiohttp.ClientSession() as session, session.ws_connect(url) as ws:
        out = []
        while len(out) < count:
            msg = await asyncio.wait_for(ws.receive(), timeout_s)
            assert msg.type == aiohttp.WSMsgType.TEXT, msg
            out.append(json.loads(msg.data))
        return out


def test_a_page_gets_the_scene_then_updates(served):
    hub, view = served
    hub.set("state", {"mission_state": "WAYPOINT"})
    hub.extend("track", [[0.0, 1.0, 2.0, 3.0]])
    scene, update = asyncio.run(_receive(view.url + "ws", 2))
    assert scene["type"] == "scene" and scene["protocol"] == 1
    assert scene["boxes"] == [[10.0, 20.0, 5.0, 2.0, 3.0, 5.0]] and scene["goal"] == [50.0, 60.0]
    assert update["type"] == "update"
    assert update["state"] == {"mission_state": "WAYPOINT"}
    assert update["track"] == {"from": 0, "items": [[0.0, 1.0, 2.0, 3.0]]}


def test_updates_stream_at_the_servers_rate_while_the_state_changes(served):
    hub, view = served
    stop = threading.Event()

    def publish():
        k = 0
        while not stop.is_set():
            hub.set("state", {"k": k})
            k += 1
            time.sleep(0.005)

    publisher = threading.Thread(target=publish)
    publisher.start()
    try:
        messages = asyncio.run(_receive(view.url + "ws", 12))
    finally:
        stop.set()
        publisher.join()
    ks = [m["state"]["k"] for m in messages[1:]]
    assert ks == sorted(ks) and len(set(ks)) == len(ks)  # each update newer than the last, none repeated


def test_a_browser_that_never_reads_does_not_hold_up_publishing_nor_other_browsers(served):
    hub, view = served
    hub.set("state", {"k": -1})
    stalled = socket.create_connection(("127.0.0.1", view.port))
    stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    stalled.sendall(b"GET /ws HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                    b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n")
    try:
        big = [[float(i), 1.0, 2.0, 3.0] for i in range(200)]
        done = threading.Event()

        def publish():  # ~3 MB of track the stalled page will never read, plus 2000 states
            for k in range(2000):
                hub.set("state", {"k": k})
                if k % 10 == 0:
                    hub.extend("track", big)
            done.set()

        publisher = threading.Thread(target=publish)
        publisher.start()
        assert done.wait(60), "publishing blocked behind a page that does not read"
        publisher.join()
        scene, update = asyncio.run(_receive(view.url + "ws", 2))
        assert update["state"] == {"k": 1999}  # the latest, not a queue of stale ones
        assert len(update["track"]["items"]) == 200 * 200
    finally:
        stalled.close()


def test_the_server_listens_on_loopback_only(served):
    _, view = served
    assert view.host == "127.0.0.1"
    assert [host for host, *_ in view.addresses] == ["127.0.0.1"]


def test_a_port_in_use_is_a_view_error_naming_it():
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        with pytest.raises(ViewError, match=f"127.0.0.1:{port}"):
            LiveView(ViewHub(), port).start()


async def _get(url: str) -> tuple[int, bytes, str]:
    async with aiohttp.ClientSession() as session, session.get(url) as response:
        return response.status, await response.read(), response.headers.get("Content-Type", "")


def test_the_page_and_the_vendored_three_js_are_served_from_the_package(served):
    _, view = served
    status, body, kind = asyncio.run(_get(view.url))
    assert status == 200 and kind.startswith("text/html") and b'id="scene"' in body
    for path in ("static/view.js", "static/vendor/three/three.module.js", "static/vendor/three/three.core.js",
                 "static/vendor/three/OrbitControls.js", "static/vendor/three/LICENSE"):
        status, body, _ = asyncio.run(_get(view.url + path))
        assert status == 200 and body == (static_dir() / path.removeprefix("static/")).read_bytes()
    status, _, _ = asyncio.run(_get(view.url + "static/../live.py"))
    assert status in (403, 404)


# ---------------------------------------------------------------------------------------- vendored code
THREE_SHA256 = {  # as listed in static/vendor/three/README.md, from npm's three@0.187.0
    "three.module.js": "104f56145899722094556490d787aae0617cc2fc3382f31df02d724ea1aee341",
    "three.core.js": "613e370f76638fdef83926642bf256dc9615684922de1ce1f63a8583e5d78578",
    "OrbitControls.js": "e7fca2fe9e7670a828af9b28084669a5909445b7f36f1f26cee9bf8f2961c32c",
    "LICENSE": "8b378ebe60e2fe500158cb0ac71cb5e8b7d92953c2abcc63a0eb90499653b5bc",
}


def test_the_vendored_three_js_is_the_pinned_npm_release_with_its_licence():
    vendor = static_dir() / "vendor" / "three"
    for name, digest in THREE_SHA256.items():
        assert hashlib.sha256((vendor / name).read_bytes()).hexdigest() == digest, name
    assert "REVISION = '187'" in (vendor / "three.core.js").read_text()
    assert "MIT License" in (vendor / "LICENSE").read_text()
    assert "0.187.0" in (vendor / "README.md").read_text()


def test_the_page_loads_nothing_from_outside_the_server():
    for name in ("index.html", "view.js", "view.css"):
        text = (static_dir() / name).read_text()
        urls = re.findall(r"""(?:src|href)\s*=\s*["']([^"']+)|from\s+["']([^"']+)|url\(([^)]+)\)""", text)
        for url in (u for group in urls for u in group if u):
            assert url.startswith(("/", "data:")) or url == "three", f"{name} loads {url}"
        assert not re.search(r"https?://", text.replace("http://localhost", "")), name


# ---------------------------------------------------------------------------------------------- feed
class State(enum.Enum):
    MANUAL = "manual"
    WAYPOINT = "waypoint"


@dataclass
class FakeTelemetry:
    armed: bool = True
    mode: str = "OFFBOARD"
    north_m: float = 0.0
    east_m: float = 0.0
    down_m: float = 0.0
    local_v_north_mps: float = 3.0
    local_v_east_mps: float = 4.0
    local_v_down_mps: float = -1.0
    heading_rad: float = 0.5
    has_global: bool = True
    has_local: bool = True


@dataclass
class FakeResult:
    waypoints: np.ndarray = field(default_factory=lambda: np.empty((0, 4)))
    history: list = field(default_factory=list)


class FakeVehicle:
    link_ok = True

    def __init__(self, offset: LocalNED):
        self.telemetry = FakeTelemetry()
        self.offset = offset

    def map_offset(self, map_origin: Geodetic) -> LocalNED:
        return self.offset


class FakeMission:
    def __init__(self):
        self.state = State.MANUAL
        self.result = FakeResult()


def test_the_feed_publishes_map_positions_speeds_plan_distance_and_events():
    hub, cursor = ViewHub(), _Cursor()
    vehicle, mission = FakeVehicle(LocalNED(10.0, -5.0, 2.0)), FakeMission()
    feed = FlightFeed(hub, mission, vehicle, Geodetic(37.0, -122.0), clock=iter(range(100)).__next__)
    vehicle.telemetry.north_m, vehicle.telemetry.east_m, vehicle.telemetry.down_m = 20.0, 5.0, -7.0
    mission.state = State.WAYPOINT
    mission.result.waypoints = np.array([[0.0, 0.0, 5.0, 0.0], [30.0, 0.0, 5.0, 0.0], [30.0, 40.0, 5.0, 0.0]])
    mission.result.history.append((State.MANUAL, enum.Enum("E", "START").START, State.WAYPOINT))
    feed.poll()
    message = hub.update_for(cursor)
    s = message["state"]
    # map = local + offset: (20 + 10, 5 - 5, -(-7 + 2)) = N 30, E 0, 5 m up, i.e. the second waypoint
    assert s["vehicle"] == {"north_m": 30.0, "east_m": 0.0, "altitude_m": 5.0, "heading_rad": 0.5}
    assert s["speed_mps"] == 5.0 and s["climb_mps"] == 1.0
    assert s["mission_state"] == "WAYPOINT" and s["armed"] is True
    assert s["distance_to_go_m"] == pytest.approx(40.0 + 5.0)  # the last leg, then the descent
    assert message["plan"] == {"id": 1, "waypoints": [[0.0, 0.0, 5.0], [30.0, 0.0, 5.0], [30.0, 40.0, 5.0]]}
    assert message["events"]["items"][0]["text"] == "start: MANUAL -> WAYPOINT"
    assert message["track"]["items"] == [[1.0, 30.0, 0.0, 5.0]]


def test_the_feed_shows_the_vehicle_where_the_missions_scan_matching_puts_it():
    """With the estimate's drift corrected, the vehicle is drawn where the mission flies it, not at the raw
    estimate (else it would sit beside the route and its obstacles by the correction)."""
    hub, cursor = ViewHub(), _Cursor()
    vehicle, mission = FakeVehicle(LocalNED(10.0, -5.0, 2.0)), FakeMission()
    mission.sensing = SimpleNamespace(correction_ne=(1.5, -2.0))
    feed = FlightFeed(hub, mission, vehicle, Geodetic(37.0, -122.0))
    vehicle.telemetry.north_m, vehicle.telemetry.east_m, vehicle.telemetry.down_m = 20.0, 5.0, -7.0
    feed.poll()
    v = hub.update_for(cursor)["state"]["vehicle"]
    assert (v["north_m"], v["east_m"], v["altitude_m"]) == (31.5, -2.0, 5.0)


def test_a_replan_is_a_new_plan_and_discovered_obstacles_are_appended():
    hub, cursor = ViewHub(), _Cursor()
    vehicle, mission = FakeVehicle(LocalNED(0.0, 0.0, 0.0)), FakeMission()
    feed = FlightFeed(hub, mission, vehicle, Geodetic(37.0, -122.0))
    mission.result.waypoints = np.array([[0.0, 0.0, 5.0, 0.0], [10.0, 0.0, 5.0, 0.0]])
    feed.poll()
    assert hub.update_for(cursor)["plan"]["id"] == 1
    mission.result.waypoints = np.array([[0.0, 0.0, 5.0, 0.0], [5.0, 5.0, 5.0, 0.0], [10.0, 0.0, 5.0, 0.0]])
    mission.discovered_obstacles = np.array([[5.0, 0.0, 3.0, 1.0, 1.0, 3.0]])
    feed.poll()
    message = hub.update_for(cursor)
    assert message["plan"]["id"] == 2 and len(message["plan"]["waypoints"]) == 3
    assert message["obstacles"] == {"from": 0, "items": [[5.0, 0.0, 3.0, 1.0, 1.0, 3.0]]}
    feed.poll()
    assert "obstacles" not in (hub.update_for(cursor) or {})


def test_the_track_starts_when_armed_and_keeps_points_apart():
    hub = ViewHub()
    vehicle, mission = FakeVehicle(LocalNED(0.0, 0.0, 0.0)), FakeMission()
    clock = iter(np.arange(0, 100, 0.05)).__next__
    feed = FlightFeed(hub, mission, vehicle, Geodetic(37.0, -122.0), track_spacing_m=1.0, clock=clock)
    vehicle.telemetry.armed = False
    feed.poll()
    assert hub.length("track") == 0
    vehicle.telemetry.armed = True
    for k in range(40):  # 0.1 m per poll, 4 m in all
        vehicle.telemetry.north_m = 0.1 * k
        feed.poll()
    assert hub.length("track") == 4  # at 0, 1, 2, 3 m (within float rounding of the 0.1 m steps)


def test_the_feed_thread_stops_and_survives_a_failing_poll():
    hub = ViewHub()

    class Broken:
        @property
        def telemetry(self):
            raise RuntimeError("boom")

    feed = FlightFeed(hub, FakeMission(), Broken(), Geodetic(37.0, -122.0), period_s=0.01).start()
    time.sleep(0.05)
    feed.stop()
    assert not feed._thread.is_alive()


def test_distance_to_go_on_a_hand_drawn_path():
    wp = np.array([[0.0, 0.0, 10.0], [0.0, 100.0, 10.0], [50.0, 100.0, 10.0]])
    # 3 m beside the first leg at east 40: 3 m to the leg, 60 + 50 m of legs, 10 m descent
    assert distance_to_go_m(wp, (3.0, 40.0, 10.0))[0] == pytest.approx(123.0)
    # on the ground before takeoff at the start: climb 10 m, 150 m of legs, 10 m descent
    assert distance_to_go_m(wp, (0.0, 0.0, 0.0))[0] == pytest.approx(170.0)
    # past the corner, never back on the first leg once on the second
    d, leg = distance_to_go_m(wp, (20.0, 100.0, 10.0), 1)
    assert (d, leg) == (pytest.approx(40.0), 1)
    assert math.isclose(distance_to_go_m(wp[:1], (0.0, 0.0, 10.0))[0], 10.0)


def test_the_package_data_globs_cover_every_static_file():
    # pyproject's package-data must name every file the page needs, or the wheel ships a broken view
    import tomllib

    root = Path(__file__).resolve().parents[1]
    globs = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["skyroute.view"]
    base = root / "skyroute" / "view"
    covered = {p for g in globs for p in base.glob(g)}
    assert {p for p in (base / "static").rglob("*") if p.is_file()} <= covered
