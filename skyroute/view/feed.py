"""What the live view shows, read from what the command line already has: the mission and the vehicle.

:class:`FlightFeed` polls, in a thread of its own, the mission's public ``state`` and ``result`` (``waypoints``,
``history``) and the vehicle's ``telemetry``, and publishes them to a :class:`~skyroute.view.live.ViewHub`. The
mission knows nothing of it, and nothing it does waits on a browser: the mission's setpoint stream cannot be
held up by the view.

Positions are in the map frame: the autopilot's local NED position plus the vehicle's ``map_offset`` (taken once,
as the mission does) and the mission's scan-matching correction (``sensing.correction_ne``), as the mission
flies. Sensing and exploration work that keeps ``discovered_obstacles`` (``(N, 6)`` boxes),
``known_area`` (a dict, see :mod:`skyroute.view.live`) or ``frontiers`` (``(F, 2)`` north/east points) as public
attributes of the mission gets them drawn; a replan that replaces ``result.waypoints`` shows as a new plan.
The mission keeps ``discovered_obstacles`` (the live layer's observed obstacle cells as 1 m boxes, see
``skyroute.flight.replanning``) and sets ``result.waypoints`` to each replanned route, so a sensing flight shows
both; exploration (issue 12) adds ``known_area`` and ``frontiers`` the same way.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Sequence

import numpy as np

from skyroute.frames import Geodetic, LocalNED
from skyroute.view.live import ViewHub

log = logging.getLogger(__name__)


def scene_from_map(obstacles: np.ndarray, home: Geodetic, *, altitude_m: float, safety_m: float,
                   goal_ne: Sequence[float], start_ne: Sequence[float] | None = None) -> dict:
    """The view's scene: the map's boxes (map frame, metres), home, flight altitude, margin, goal and start."""
    return {
        "home": {"lat_deg": home.lat_deg, "lon_deg": home.lon_deg},
        "boxes": np.round(np.asarray(obstacles, dtype=float), 2),
        "altitude_m": float(altitude_m),
        "safety_m": float(safety_m),
        "goal": [float(goal_ne[0]), float(goal_ne[1])],
        "start": None if start_ne is None else [float(start_ne[0]), float(start_ne[1])],
    }


def distance_to_go_m(waypoints: np.ndarray, position: Sequence[float], from_leg: int = 0) -> tuple[float, int]:
    """Distance left along the plan from ``position`` ``(north_m, east_m, altitude_m)``, and the leg it is on.

    The vehicle is projected (3D) onto the nearest leg at or after ``from_leg`` (the index of the leg's first
    waypoint; pass the previous answer so a path that crosses itself does not jump back); the distance is from
    the vehicle to that point, then the rest of the planned legs, then the descent from the last waypoint to the
    ground (the mission lands there).

    >>> wp = np.array([[0.0, 0.0, 5.0], [10.0, 0.0, 5.0], [10.0, 10.0, 5.0]])
    >>> distance_to_go_m(wp, (4.0, 0.0, 5.0))
    (21.0, 0)
    >>> distance_to_go_m(wp, (10.0, 3.0, 5.0), from_leg=0)
    (12.0, 1)
    """
    points = np.asarray(waypoints, dtype=float)[:, :3]
    p = np.asarray(position, dtype=float)
    if len(points) == 1:
        return float(np.linalg.norm(points[0] - p) + points[0, 2]), 0
    best = (math.inf, from_leg, points[from_leg])
    for i in range(min(from_leg, len(points) - 2), len(points) - 1):
        a, b = points[i], points[i + 1]
        ab = b - a
        t = float(np.clip(np.dot(p - a, ab) / max(float(np.dot(ab, ab)), 1e-12), 0.0, 1.0))
        q = a + t * ab
        d = float(np.linalg.norm(p - q))
        if d < best[0] - 1e-9:
            best = (d, i, q)
    d, leg, q = best
    rest = float(np.linalg.norm(points[leg + 1] - q)) + float(
        np.linalg.norm(np.diff(points[leg + 1:], axis=0), axis=1).sum())
    return d + rest + float(points[-1, 2]), leg


def _finite(value: float) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


class FlightFeed:
    """Publish the flight of ``mission`` with ``vehicle`` to ``hub`` every ``period_s`` until :meth:`stop`.

    ``map_origin`` is the map's home. Track points are kept ``track_spacing_m`` apart (or ``track_interval_s``
    when hovering), from the first armed sample on.
    """

    def __init__(self, hub: ViewHub, mission, vehicle, map_origin: Geodetic, *, period_s: float = 0.05,
                 track_spacing_m: float = 0.25, track_interval_s: float = 1.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.hub, self.mission, self.vehicle, self.map_origin = hub, mission, vehicle, map_origin
        self.period_s, self.track_spacing_m, self.track_interval_s = period_s, track_spacing_m, track_interval_s
        self.clock = clock
        self._offset: LocalNED | None = None
        self._t0 = clock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._plan_source = None
        self._plan_id = 0
        self._plan = None
        self._leg = 0
        self._history_sent = 0
        self._last_track: tuple[float, float, float, float] | None = None
        self._obstacles_sent = 0
        self._extras_sent: dict[str, object] = {}

    # ------------------------------------------------------------------------------------------ lifecycle
    def start(self) -> FlightFeed:
        self._thread = threading.Thread(target=self._run, name="view-feed", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Publish a last frame and stop the thread."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.poll()
            except Exception:  # noqa: BLE001 - the view must never take the flight down; say why, keep going
                log.exception("live view feed")
            self._stop.wait(self.period_s)
        try:
            self.poll()
        except Exception:  # noqa: BLE001
            log.exception("live view feed")

    # ----------------------------------------------------------------------------------------------- poll
    def _map_position(self, t) -> LocalNED | None:
        if self._offset is None and getattr(t, "has_global", False) and getattr(t, "has_local", False):
            try:
                self._offset = self.vehicle.map_offset(self.map_origin)
            except Exception as exc:  # noqa: BLE001 - e.g. a vehicle error: try again next poll
                log.debug("no map offset yet: %s", exc)
        if self._offset is None or not math.isfinite(t.north_m):
            return None
        o = self._offset
        cn, ce = getattr(getattr(self.mission, "sensing", None), "correction_ne", (0.0, 0.0))
        return LocalNED(t.north_m + o.north_m + cn, t.east_m + o.east_m + ce, t.down_m + o.down_m)

    def poll(self) -> None:
        """Read the mission and the vehicle once and publish what changed."""
        now_s = self.clock() - self._t0
        t = self.vehicle.telemetry
        p = self._map_position(t)
        self._publish_plan()
        self._publish_events(now_s)
        self._publish_extras()
        vehicle = None
        distance = None
        if p is not None:
            vehicle = {"north_m": p.north_m, "east_m": p.east_m, "altitude_m": p.altitude_m,
                       "heading_rad": _finite(t.heading_rad)}
            if self._plan is not None:
                distance, self._leg = distance_to_go_m(self._plan, (p.north_m, p.east_m, p.altitude_m), self._leg)
            self._record_track(now_s, p, bool(t.armed))
        state = self.mission.state
        self.hub.set("state", {
            "time_s": round(now_s, 3),
            "mission_state": getattr(state, "name", str(state)),
            "armed": bool(t.armed),
            "mode": str(getattr(t, "mode", "")),
            "link_ok": bool(getattr(self.vehicle, "link_ok", True)),
            "vehicle": vehicle,
            "speed_mps": _finite(math.hypot(t.local_v_north_mps, t.local_v_east_mps)),
            "climb_mps": _finite(-t.local_v_down_mps),
            "distance_to_go_m": distance,
        })

    def _publish_plan(self) -> None:
        waypoints = getattr(getattr(self.mission, "result", None), "waypoints", None)
        if waypoints is None or waypoints is self._plan_source or len(waypoints) == 0:
            return
        self._plan_source = waypoints
        plan = np.asarray(waypoints, dtype=float)[:, :3].copy()
        if self._plan is not None and plan.shape == self._plan.shape and np.allclose(plan, self._plan):
            return
        self._plan, self._leg, self._plan_id = plan, 0, self._plan_id + 1
        self.hub.set("plan", {"id": self._plan_id, "waypoints": np.round(plan, 3)})

    def _publish_events(self, now_s: float) -> None:
        history = getattr(getattr(self.mission, "result", None), "history", None) or []
        new = history[self._history_sent:]
        if new:
            self._history_sent += len(new)
            self.hub.extend("events", [
                {"time_s": round(now_s, 3),
                 "text": f"{event.name.lower().replace('_', ' ')}: {old.name} -> {state.name}"}
                for old, event, state in new])

    def _publish_extras(self) -> None:
        obstacles = getattr(self.mission, "discovered_obstacles", None)
        if obstacles is not None and len(obstacles) > self._obstacles_sent:
            boxes = np.asarray(obstacles, dtype=float).reshape(-1, 6)
            self.hub.extend("obstacles", np.round(boxes[self._obstacles_sent:], 2))
            self._obstacles_sent = len(boxes)
        for channel in ("known_area", "frontiers"):
            value = getattr(self.mission, channel, None)
            if value is not None and value is not self._extras_sent.get(channel):  # a new object is a new value
                self._extras_sent[channel] = value
                self.hub.set(channel, value)

    def _record_track(self, now_s: float, p: LocalNED, armed: bool) -> None:
        if not armed and self._last_track is None:
            return
        point = (round(now_s, 3), round(p.north_m, 3), round(p.east_m, 3), round(p.altitude_m, 3))
        last = self._last_track
        if last is not None:
            moved = math.dist(point[1:], last[1:])
            if moved < self.track_spacing_m and point[0] - last[0] < self.track_interval_s:
                return
        self._last_track = point
        self.hub.extend("track", [point])
