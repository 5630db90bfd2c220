"""In-process simulator: one thread runs transport, autopilot and physics in lock-step.

Example
-------
>>> from sim import SimConfig, Simulator                      # doctest: +SKIP
>>> with Simulator(SimConfig(map_path="colliders.csv", port=0, speedup=10)) as sim:  # doctest: +SKIP
...     print(sim.port)
...     report = sim.report()
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink

from . import streams
from .autopilot import Autopilot
from .config import SimConfig
from .report import FlightRecorder, write_report
from .sensors import SENSOR_MESSAGE_IDS
from .server import TcpLink, TcpServer, TlogLink
from .signing import secret_key
from .world import CityMap

log = logging.getLogger(__name__)
M = mavlink
#: What the tlog records besides every message sent and received (Hz, simulated time): the vehicle's track.
TLOG_RATES_HZ = {
    M.MAVLINK_MSG_ID_HEARTBEAT: 1.0, M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 10.0,
    M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 10.0, M.MAVLINK_MSG_ID_ATTITUDE: 10.0,
    M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 2.0, M.MAVLINK_MSG_ID_SYS_STATUS: 1.0, M.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
}

#: At most this much wall time (s) of physics is caught up per loop turn; beyond it the sim slows.
MAX_CATCHUP_WALL_S = 0.1


class SimulatorError(RuntimeError):
    """The simulation thread failed or did not start/stop in time."""


class Simulator:
    """A mock autopilot serving MAVLink over TCP.

    Parameters
    ----------
    config : SimConfig
    on_event : callable, optional
        ``on_event(line)`` for every status line (called on the simulation thread).
    city : CityMap, optional
        Preloaded map (else read from ``config.map_path``).
    """

    def __init__(self, config: SimConfig, on_event: Callable[[str], None] | None = None,
                 city: CityMap | None = None) -> None:
        self.config = config
        self.on_event = on_event
        self.city = city if city is not None else CityMap.from_csv(config.resolved_map_path())
        self.recorder = FlightRecorder(self.city, config.radius_m)
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._server: TcpServer | None = None
        self._tlog: TlogLink | None = None
        self._t0 = time.monotonic()
        self.error: BaseException | None = None
        self.behind_s = 0.0
        self._final_report: dict | None = None
        self.autopilot = Autopilot(config, self.city, self.recorder, self._send, self._emit)
        ap = self.autopilot
        self.recorder.start = self.recorder.place(*ap.quad.state.position_neu)
        self._signing_key = None if config.signing_key is None else secret_key(config.signing_key)

    # ------------------------------------------------------------------ lifecycle
    @property
    def port(self) -> int:
        """The bound TCP port (useful with ``port=0``)."""
        if self._server is None:
            raise SimulatorError("simulator not started")
        return self._server.port

    @property
    def started_wall_s(self) -> float:
        """``time.monotonic()`` when the simulator started."""
        return self._t0

    @property
    def host(self) -> str:
        return self.config.host

    def start(self) -> Simulator:
        """Bind the socket and start the simulation thread."""
        if self._thread is not None:
            raise SimulatorError("simulator already started")
        self._server = TcpServer(self.config.host, self.config.port, self.config.faults, self.config.seed,
                                 self._signing_key)
        if self.config.tlog_path is not None:
            self._tlog = TlogLink(self.config.tlog_path)
            for msg_id, hz in TLOG_RATES_HZ.items():
                self.autopilot.scheduler.set_rate(self._tlog, msg_id, hz, 0.0)
        self._t0 = time.monotonic()
        boot = self.config.boot if isinstance(self.config.boot, str) else "custom"
        self._emit("listening", f"MAVLink on tcp:{self._server.host}:{self._server.port} "
                                f"({self.config.autopilot}{', strict' if self.config.strict else ''}, "
                                f"speedup {self.config.speedup:g}, boot {boot}, {len(self.city)} boxes"
                                f"{', signed' if self._signing_key else ''})")
        for fault in self.config.faults.active():
            self._emit("fault", fault)
        self._thread = threading.Thread(target=self._run, name="sim", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 5.0) -> dict:
        """Stop the thread, close sockets and files, write the report if configured; return it.

        Idempotent: later calls return the same report.
        """
        if self._final_report is not None:
            return self._final_report
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                raise SimulatorError(f"simulation thread did not stop within {timeout_s} s")
        with self._lock:
            if self._server is not None:
                self._server.close(self.autopilot.sim_time_s)
            if self._tlog is not None:
                self._tlog.close()
            report = self.report()
            if self.config.report_path is not None:
                write_report(self.config.report_path, report)
                self._emit("report", f"report written to {self.config.report_path}")
            self._final_report = report
        return report

    def __enter__(self) -> Simulator:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # ------------------------------------------------------------------ observation
    def report(self) -> dict:
        """The flight report (see ``sim/__init__.py`` for the keys)."""
        with self._lock:
            ap = self.autopilot
            report = self.recorder.to_dict(ap.truth(), self.config.as_dict(), ap.sim_time_s,
                                           time.monotonic() - self._t0)
            links = [] if self._server is None else self._server.stats()
            report["links"] = links
            report["sensor"] = ap.sensor.report() if ap.sensor is not None else {"enabled": False}
            report["targets"] = ap.targets.report() if ap.targets is not None else []
            report["signing"] = {"enabled": self._signing_key is not None,
                                 "rejected_frames": sum(link["rejected_signature"] for link in links)}
            return report

    def truth(self) -> dict:
        """The vehicle's true state right now (map frame, see :meth:`Autopilot.truth`)."""
        with self._lock:
            return self.autopilot.truth()

    def wait_until(self, predicate: Callable[[dict], bool], timeout_s: float, poll_s: float = 0.02) -> dict:
        """Poll :meth:`truth` until ``predicate(truth)``; raise ``TimeoutError`` after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while True:
            state = self.truth()
            if predicate(state):
                return state
            if self.error is not None:
                raise SimulatorError("simulation thread failed") from self.error
            if time.monotonic() > deadline:
                raise TimeoutError(f"condition not met within {timeout_s} s; last state {state}")
            time.sleep(poll_s)

    def clients(self) -> int:
        with self._lock:
            return 0 if self._server is None else len(self._server.links)

    # ------------------------------------------------------------------ internals
    def _emit(self, kind: str, text: str) -> None:
        sim_t = self.autopilot.sim_time_s if hasattr(self, "autopilot") else 0.0
        self.recorder.add_event(sim_t, kind, text)
        line = f"[sim {sim_t:8.2f}s] {kind:<9} {text}"
        log.info(line)
        if self.on_event is not None:
            self.on_event(line)

    def _send(self, link, msg) -> None:
        if self._server is None or not hasattr(self, "autopilot"):
            return
        ap = self.autopilot
        sim_s = ap.sim_time_s
        for each in (self._server.links if link is None else [link]):
            if ap.delivers(each, msg):
                each.queue(msg, sim_s)
        if self._tlog is not None:
            self._tlog.queue(msg, sim_s)

    def _on_connect(self, link: TcpLink) -> None:
        self.autopilot.scheduler.attach(link, self.autopilot.sim_time_s)
        self._emit("client", f"link {link.link_id} connected from {link.peer}")

    def _stream(self, links) -> None:
        ap = self.autopilot
        now = ap.sim_time_s
        cache: dict = {}
        snap = None
        def ready(msg_id: int) -> bool:
            return streams.available(ap, msg_id)

        for link in links:
            for msg_id in ap.scheduler.due(link, now, ready):
                if msg_id in SENSOR_MESSAGE_IDS:  # per link (ArduPilot's ever-valid sectors), not cached
                    for msg in ap.build_messages(msg_id, link, ap.snapshot):
                        link.queue(msg, now)
                    continue
                if msg_id not in cache:
                    snap = snap or ap.snapshot()
                    cache[msg_id] = streams.build(ap, msg_id, snap)
                if cache[msg_id] is not None:
                    link.queue(cache[msg_id], now)

    def _report_link_events(self, links) -> None:
        for link in links:
            if link.junk_unreported:
                self._emit("client", f"link {link.link_id}: ignored {link.junk_unreported} byte(s) that are "
                           "not MAVLink (e.g. udacidrone send_waypoints() msgpack)")
                link.junk_unreported = 0
            rejected = link.scanner.rejected_frames
            if rejected > link.rejected_reported:
                if link.rejected_reported == 0:
                    self._emit("signing", f"link {link.link_id}: dropping unsigned or wrongly signed frames")
                link.rejected_reported = rejected

    def _run(self) -> None:
        try:
            self._loop()
        except BaseException as exc:  # reported to callers through self.error
            self.error = exc
            log.exception("simulation thread failed")
            self._emit("error", f"simulation thread failed: {exc!r}")

    def _loop(self) -> None:
        cfg = self.config
        ap = self.autopilot
        server = self._server
        dt = cfg.physics_dt_s
        wall_step = dt / cfg.speedup
        sim_origin_wall = self._t0
        timeout = 0.0
        while not self._stop.is_set():
            new_links, messages, closed = server.poll(timeout, ap.sim_time_s)
            wall = time.monotonic()
            with self._lock:
                for link in new_links:
                    self._on_connect(link)
                for link, msg in messages:
                    if self._tlog is not None:
                        self._tlog.record_incoming(msg)
                    ap.handle(link, msg)
                self._report_link_events(list(server.links) + closed)
                for link in closed:
                    self._emit("client", f"link {link.link_id} disconnected")
                target_sim = (wall - sim_origin_wall) * cfg.speedup
                steps = 0
                max_steps = max(1, int(MAX_CATCHUP_WALL_S / wall_step))
                while ap.sim_time_s + dt <= target_sim + 1e-9 and steps < max_steps:
                    ap.step(dt)
                    steps += 1
                if steps == max_steps and ap.sim_time_s + dt <= target_sim:
                    lag = (target_sim - ap.sim_time_s) / cfg.speedup
                    sim_origin_wall += lag  # fall back rather than spiral
                    self.behind_s += lag
                links = list(server.links) + ([self._tlog] if self._tlog is not None else [])
                self._stream(links)
                for link in server.links:
                    link.flush(ap.sim_time_s)
            next_step_wall = sim_origin_wall + (ap.sim_time_s + dt) / cfg.speedup
            timeout = min(0.01, max(0.0, next_step_wall - time.monotonic()))
