"""Shared fixtures: the sim fixtures (all prefixed ``sim_``) and what every test needs."""

from __future__ import annotations

import math
import socket
import threading
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sim import FaultConfig, SimConfig, Simulator, write_colliders


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """The SITL tests run one after another in one pytest-xdist worker (``--dist loadgroup``): two real autopilots
    booting side by side on 2 cores miss their real-time deadlines (PX4 SIH then refuses to arm)."""
    for item in items:
        if item.get_closest_marker("sitl") is not None:
            item.add_marker(pytest.mark.xdist_group("sitl"))


@pytest.fixture(autouse=True)
def _no_compile_notice_in_process(request, monkeypatch):
    """In-process CLI tests check stderr line by line, and which of them happens to compile a kernel first (and so
    prints the first-run 'compiling' notice) depends on the test order; the notice has tests of its own
    (marked ``compile_notice``, and a subprocess run with a fresh cache)."""
    if request.node.get_closest_marker("compile_notice") is None:
        import skyroute.cli.main

        monkeypatch.setattr(skyroute.cli.main, "announce_first_compile", lambda enabled=True: None)


#: One building: north 25..35 m, east -5..5 m, up 0..20 m (centre 30,0,10; half sizes 5,5,10).
SIM_BUILDING = (30.0, 0.0, 10.0, 5.0, 5.0, 10.0)
SIM_LAT0, SIM_LON0 = 37.792480, -122.397450


class SimClient:
    """A minimal MAVLink 2 ground station over TCP (system 255, component 190) for tests.

    A reader thread parses everything into ``self.messages``; ``wait_for`` scans them with a timeout.
    """

    def __init__(self, port: int, system: int = 255, component: int = 190) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        self.sock.settimeout(0.2)
        self.mav = mavlink.MAVLink(None, system, component)
        self.mav.robust_parsing = True
        self.messages: list = []
        self.cond = threading.Condition()
        self._stop = threading.Event()
        self._heartbeat_stop: threading.Event | None = None
        self._send_lock = threading.Lock()
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                break
            if not data:
                break
            msgs = [m for m in (self.mav.parse_buffer(data) or []) if m.get_type() != "BAD_DATA"]
            if msgs:
                with self.cond:
                    for m in msgs:
                        m.rx_wall_s = time.monotonic()
                    self.messages.extend(msgs)
                    self.cond.notify_all()

    def send(self, msg) -> None:
        with self._send_lock:
            self.sock.sendall(msg.pack(self.mav))

    def mark(self) -> int:
        """Index to pass as ``since`` so that only later messages count."""
        with self.cond:
            return len(self.messages)

    def wait_for(self, kind: str, predicate=None, timeout_s: float = 5.0, since: int = 0):
        """First message of type ``kind`` (index >= since) satisfying ``predicate``.

        Raises
        ------
        TimeoutError
            If none arrives within ``timeout_s`` (wall clock).
        """
        deadline = time.monotonic() + timeout_s
        with self.cond:
            i = since
            while True:
                while i < len(self.messages):
                    m = self.messages[i]
                    i += 1
                    if m.get_type() == kind and (predicate is None or predicate(m)):
                        return m
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise TimeoutError(f"no {kind} within {timeout_s} s")
                self.cond.wait(remaining)

    def of_type(self, kind: str, since: int = 0) -> list:
        with self.cond:
            return [m for m in self.messages[since:] if m.get_type() == kind]

    def command(self, command: int, *params: float, timeout_s: float = 3.0, target=(1, 1)):
        """Send COMMAND_LONG and return its COMMAND_ACK."""
        p = list(params) + [0.0] * (7 - len(params))
        since = self.mark()
        self.send(mavlink.MAVLink_command_long_message(target[0], target[1], command, 0, *p))
        return self.wait_for("COMMAND_ACK", lambda m: m.command == command, timeout_s, since)

    def arm(self, timeout_s: float = 10.0):
        """Ask to arm until the autopilot accepts (it refuses while it boots); return the last COMMAND_ACK."""
        deadline = time.monotonic() + timeout_s
        while True:
            ack = self.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
            if ack.result == mavlink.MAV_RESULT_ACCEPTED or time.monotonic() > deadline:
                return ack
            time.sleep(0.05)

    def set_mode_px4(self, main: int, sub: int = 0):
        return self.command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub)

    def setpoint_local(self, north: float, east: float, z: float, type_mask: int | None = None,
                       yaw: float = math.nan) -> None:
        if type_mask is None:
            type_mask = 0b0000_1111_1111_1000 if not math.isfinite(yaw) else 0b0000_1001_1111_1000
        self.send(mavlink.MAVLink_set_position_target_local_ned_message(
            0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, type_mask, north, east, z, 0, 0, 0, 0, 0, 0,
            yaw if math.isfinite(yaw) else 0.0, 0))

    def start_heartbeats(self, hz: float, mav_type: int = mavlink.MAV_TYPE_GCS) -> None:
        """Send HEARTBEATs (as a ground station by default) at ``hz`` (wall clock) until :meth:`stop_heartbeats`."""
        self.stop_heartbeats()
        stop = self._heartbeat_stop = threading.Event()

        def run() -> None:
            while not stop.is_set():
                try:
                    self.send(mavlink.MAVLink_heartbeat_message(mav_type, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
                except OSError:  # the socket closed under us
                    return
                stop.wait(1.0 / hz)

        threading.Thread(target=run, daemon=True).start()

    def stop_heartbeats(self) -> None:
        if self._heartbeat_stop is not None:
            self._heartbeat_stop.set()
            self._heartbeat_stop = None

    def close(self) -> None:
        self.stop_heartbeats()
        self._stop.set()
        try:
            self.sock.close()
        except OSError:
            pass
        self.thread.join(2)


def wait_sim(sim, seconds: float, timeout_s: float = 20.0) -> dict:
    """Wait until ``seconds`` of simulated time have passed (however slow the machine is)."""
    until = sim.truth()["sim_time_s"] + seconds
    return sim.wait_until(lambda s: s["sim_time_s"] >= until, timeout_s)


def wait_ready(sim, timeout_s: float = 10.0) -> dict:
    """Wait until the simulated vehicle has booted far enough to arm (its pre-arm checks pass)."""
    return sim.wait_until(lambda s: s["ready"], timeout_s)


@pytest.fixture
def sim_map(tmp_path):
    """Path of a tiny map with :data:`SIM_BUILDING`."""
    return write_colliders(tmp_path / "colliders.csv", SIM_LAT0, SIM_LON0, [SIM_BUILDING])


@pytest.fixture
def sim_start(sim_map):
    """``sim_start(**config) -> Simulator`` started on an ephemeral port; all stopped at teardown."""
    sims = []

    def start(**kwargs) -> Simulator:
        kwargs.setdefault("map_path", sim_map)
        kwargs.setdefault("port", 0)
        kwargs.setdefault("speedup", 10.0)
        if "faults" in kwargs and isinstance(kwargs["faults"], dict):
            kwargs["faults"] = FaultConfig(**kwargs["faults"])
        sim = Simulator(SimConfig(**kwargs)).start()
        sims.append(sim)
        return sim

    yield start
    for sim in sims:
        sim.stop()
        assert sim.error is None, sim.error


@pytest.fixture
def sim_connect():
    """``sim_connect(sim_or_port, gcs=True) -> SimClient``; all closed at teardown.

    Given a :class:`Simulator`, the client heartbeats as a ground station once per simulated second (PX4 sends
    STATUSTEXT only to a link it has a ground station's heartbeat on); given a port, it sends none.
    """
    clients = []

    def connect(target, gcs: bool = True, **kwargs) -> SimClient:
        port = target if isinstance(target, int) else target.port
        c = SimClient(port, **kwargs)
        clients.append(c)
        if gcs and not isinstance(target, int):
            c.start_heartbeats(min(50.0, target.config.speedup))
        return c

    yield connect
    for c in clients:
        c.close()
