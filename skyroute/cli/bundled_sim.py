"""The bundled simulator (``python -m sim``) as a child process, for ``--sim``."""

from __future__ import annotations

import json
import logging
import math
import sys
from collections.abc import Sequence
from pathlib import Path

from skyroute.cli.exits import UserError
from skyroute.frames import Geodetic

log = logging.getLogger("motion_planning")

#: A checkout's root (the ``sim`` package lies beside ``skyroute``); an installed package finds ``sim`` anywhere.
PROJECT_ROOT = Path(__file__).resolve().parents[2]


#: Above this speed-up the bundled sim multiplies its link-loss timeouts by it (``--scale-timeouts``): the client
#: paces heartbeats (1 Hz) and setpoints on the wall clock, the autopilot times them on its own, and past 5x a
#: busy machine's pause of a fraction of a second is over COM_OF_LOSS_T (1 s) of simulated time. Up to 5x the stock
#: values stay, so the flight is the one the real parameters give.
SCALE_TIMEOUTS_ABOVE = 5.0


class BundledSim:
    """The project's simulator (``python -m sim``) as a child process on a free loopback port.

    Used as a context manager: starts the sim, waits until it accepts connections, and on exit stops it with
    SIGINT (it writes its report) and kills it if it does not stop. The sim's status lines go to ``log_path``.
    """

    def __init__(self, map_path: str | Path, *, speedup: float, start: Geodetic | None, report_path: Path,
                 log_path: Path, startup_timeout_s: float = 30.0):
        self.map_path = Path(map_path).resolve()
        self.speedup, self.start, self.report_path = speedup, start, Path(report_path).resolve()
        self.log_path, self.startup_timeout_s = Path(log_path), startup_timeout_s
        self.port = 0
        self._proc = None

    def __enter__(self) -> BundledSim:
        import socket
        import subprocess
        import time

        with socket.socket() as probe:  # a free port; the sim binds it a moment later
            probe.bind(("127.0.0.1", 0))
            self.port = probe.getsockname()[1]
        cmd = [sys.executable, "-m", "sim", "--map", str(self.map_path), "--port", str(self.port),
               "--speedup", f"{self.speedup:g}", "--strict", "--origin", "boot", "--report", str(self.report_path)]
        if self.speedup > SCALE_TIMEOUTS_ABOVE:  # as PX4 SITL's startup script does for PX4_SIM_SPEED_FACTOR
            cmd.append("--scale-timeouts")
        if self.start is not None:
            cmd += ["--start", f"{self.start.lat_deg:.8f},{self.start.lon_deg:.8f}"]
        log.info("starting the sim: %s", " ".join(cmd))
        self._log = open(self.log_path, "w", encoding="utf-8")  # noqa: SIM115 (closed in __exit__)
        # A session of its own: a terminal's Ctrl-C goes to the whole foreground process group, and the sim must
        # keep flying while we land; __exit__ stops it once we are done.
        self._proc = subprocess.Popen(cmd, cwd=PROJECT_ROOT, stdout=self._log,
                                      stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True)
        deadline = time.monotonic() + self.startup_timeout_s
        while time.monotonic() < deadline:
            if self._proc.poll() is not None:
                self.__exit__(None, None, None)
                raise UserError(f"the bundled sim exited at start (code {self._proc.returncode}); see {self.log_path}")
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.5).close()
                return self
            except OSError:
                time.sleep(0.1)
        self.__exit__(None, None, None)
        raise UserError(f"the bundled sim did not start within {self.startup_timeout_s:g} s; see {self.log_path}")

    def __exit__(self, *exc_info) -> None:
        import signal
        import subprocess

        if self._proc is not None and self._proc.poll() is None:
            self._proc.send_signal(signal.SIGINT)
            try:
                self._proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        self._log.close()

    @property
    def connection(self) -> str:
        return f"tcp:127.0.0.1:{self.port}"

    def report(self) -> dict | None:
        try:
            return json.loads(self.report_path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None


def sim_report_summary(report: dict, goal_ne: Sequence[float]) -> str:
    """One line from the sim's truth: where it landed, collisions, clearance, distance, airborne time."""
    landed = report.get("landed")
    where = "not landed"
    if landed:
        error_m = math.hypot(landed["north_m"] - goal_ne[0], landed["east_m"] - goal_ne[1])
        where = f"landed at N {landed['north_m']:.1f} m, E {landed['east_m']:.1f} m ({error_m:.2f} m from the goal)"
    clearance = report.get("min_clearance_m")
    clearance_text = "n/a" if clearance is None else f"{clearance:.1f} m"
    return (
        f"sim report: {where}, {len(report.get('collisions', []))} collisions, "
        f"min clearance {clearance_text}, flown {report.get('distance_flown_m', 0):.1f} m, "
        f"airborne {report.get('airborne_time_s', 0):.1f} s (sim time)"
    )
