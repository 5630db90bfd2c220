"""The ``--view`` and ``--export`` options: the live browser view around a flight, and plan files after planning.

The view's server (aiohttp) and the export writers are imported only when asked for, so a plain plan or flight
loads neither.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from skyroute.cli.exits import UserError
from skyroute.cli.setting import Setting
from skyroute.planning.plan import Plan


# ------------------------------------------------------------------------------------------------- checks
def check_view_export(view_port: int | None, exports: Sequence[str] | None, *, plan_only: bool) -> None:
    """Refuse a bad ``--view`` port, ``--view`` without a flight, and unusable ``--export`` files, before any work."""
    if view_port is not None:
        if plan_only:
            raise UserError("--view shows a flight; it does not go with --plan-only (use --plot or --export)")
        if not 0 <= view_port <= 65535:
            raise UserError(f"--view port must be 0..65535 (0: any free port), got {view_port}")
    if exports:
        from skyroute.view.export import ExportError, check_export_path

        for path in exports:
            try:
                check_export_path(path)
            except ExportError as exc:
                raise UserError(str(exc)) from None


# --------------------------------------------------------------------------------------------------- view
class ViewSession:
    """The live view of one flight: the hub, its server, and (once there is a mission) the feed."""

    def __init__(self, setting: Setting, goal_ne: Sequence[float], port: int, out) -> None:
        from skyroute.view.feed import scene_from_map
        from skyroute.view.live import LiveView, ViewError, ViewHub

        self.setting = setting
        self.hub = ViewHub(scene_from_map(setting.city.obstacles, setting.home, altitude_m=setting.altitude_m,
                                          safety_m=setting.safety_m, goal_ne=goal_ne))
        try:
            self.server = LiveView(self.hub, port).start()
        except ViewError as exc:
            raise UserError(f"--view: {exc}") from None
        self.feed = None
        print(f"live view at {self.server.url} (open it in a browser)", file=out, flush=True)

    def follow(self, mission, vehicle) -> None:
        """Start publishing ``mission`` flown by ``vehicle`` (polled in a thread of the view's own)."""
        from skyroute.view.feed import FlightFeed

        self.feed = FlightFeed(self.hub, mission, vehicle, self.setting.home).start()

    def close(self) -> None:
        if self.feed is not None:
            self.feed.stop()
        self.server.close()


def open_view(view_port: int | None, setting: Setting, goal_ne: Sequence[float], out) -> ViewSession | None:
    """A started :class:`ViewSession` when ``--view`` was given, else ``None``."""
    return None if view_port is None else ViewSession(setting, goal_ne, view_port, out)


# ------------------------------------------------------------------------------------------------ exports
def write_exports(exports: Sequence[str] | None, setting: Setting, plan: Plan, track=None, out=None) -> None:
    """Write ``plan`` (and the flown ``track`` ``(T, 4)`` ``[time_s, north_m, east_m, altitude_m]``, if any) to
    each ``--export`` file; a file that cannot be written is a :class:`UserError`."""
    if not exports:
        return
    from skyroute.view.export import ExportError, FlightRecord, write_export

    waypoints = np.array(plan.waypoints, dtype=float)
    waypoints[~np.isfinite(waypoints[:, 2]), 2] = setting.altitude_m  # the mission flies NaN at the altitude
    has_track = track is not None and len(track) >= 2
    record = FlightRecord(setting.home, waypoints, track=track if has_track else None,
                          name=f"skyroute {plan.planner} plan, {setting.altitude_m:g} m, "
                               f"{setting.safety_m:g} m margin")
    for path in exports:
        try:
            write_export(path, record)
        except ExportError as exc:
            raise UserError(str(exc)) from None
        if out is not None:
            what = "plan and flown track" if has_track and Path(path).suffix.lower() in (".geojson", ".kml") else "plan"
            print(f"{what} exported to {path}", file=out)
