"""``python -m sim``: serve the mock autopilot over TCP until SIGINT/SIGTERM.

Every bad option or map is one line on stderr and exit code 2; no traceback, no hang.
"""

from __future__ import annotations

import argparse
import logging
import math
import signal
import sys
import threading
from pathlib import Path

from .boot import PRESETS, parse_boot
from .config import SimConfig, default_map_path
from .faults import FaultConfig, command_id
from .params import ARDUPILOT_PARAMS, PX4_PARAMS
from .sensors import SensorConfig
from .targets import read_targets
from .world import CityMap


class _Parser(argparse.ArgumentParser):
    """argparse that reports a bad option in one line (no usage block)."""

    def error(self, message: str):
        self.exit(2, f"error: {message}\n")


def _finite(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def _ranged(low: float, high: float, *, low_open: bool = False):
    def parse(text: str) -> float:
        value = _finite(text)
        if value < low or value > high or (low_open and value == low):
            bracket = "(" if low_open else "["
            raise argparse.ArgumentTypeError(f"must be in {bracket}{low:g}, {high:g}], got {text}")
        return value
    return parse


def _count(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return value


def _port(text: str) -> int:
    value = _count(text)
    if value > 65535:
        raise argparse.ArgumentTypeError(f"must be in [0, 65535], got {text}")
    return value


def _numbers(count: tuple[int, ...], what: str):
    def parse(text: str) -> tuple[float, ...]:
        parts = text.split(",")
        if len(parts) not in count:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return tuple(_finite(p) for p in parts)
    return parse


def _command(text: str) -> str:
    try:
        command_id(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def _boot(text: str) -> str:
    try:
        parse_boot(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def _param(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if not sep or not name.strip():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    return name.strip(), _finite(value)


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="python -m sim",
        description="Mock PX4/ArduCopter autopilot: flies a point-mass quadcopter through the colliders.csv "
        "city, speaks MAVLink 2 over TCP (system 1, component 1) and reports collisions. Prints one status "
        "line per event; SIGINT/SIGTERM shut it down cleanly and write --report. Everything the autopilot "
        "times (boot, streams, heartbeats, failsafe timeouts, link faults) runs in simulated time.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    g = p.add_argument_group("server")
    g.add_argument("--map", type=Path, default=None,
                   help=f"obstacle map (colliders.csv); None = the project's own, {default_map_path()}")
    g.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (loopback unless told otherwise)")
    g.add_argument("--port", type=_port, default=5760, help="TCP port (0 = pick a free one)")
    g.add_argument("--speedup", type=_ranged(0, 1000, low_open=True), default=1.0,
                   help="simulated seconds per wall-clock second, in (0, 1000]")
    g.add_argument("--report", type=Path, default=None, help="write the JSON flight report here on exit")
    g.add_argument("--tlog", type=Path, default=None, help="write a MAVLink telemetry log (.tlog) here")
    g.add_argument("--duration", type=_ranged(0, 1e7, low_open=True), default=None,
                   help="exit by itself after this many wall-clock seconds (None = run until signalled)")
    g.add_argument("--signing-key", default=None, metavar="KEY",
                   help="MAVLink 2 signing: 64 hex characters = the 32-byte secret key, any other text = its "
                   "SHA-256 (as MAVProxy's 'signing setup'); the sim then signs what it sends and drops unsigned "
                   "or wrongly signed frames (counted in the report)")
    g.add_argument("-q", "--quiet", action="store_true", help="no status lines")
    g = p.add_argument_group("vehicle")
    g.add_argument("--autopilot", choices=("px4", "ardupilot"), default="px4",
                   help="personality: PX4 custom modes, or ArduCopter mode numbers (GUIDED 4, LAND 9, RTL 6)")
    g.add_argument("--strict", action="store_true",
                   help="PX4 as the real one: NED z only, arming in OFFBOARD needs a setpoint stream, and without "
                   "setpoints for COM_OF_LOSS_T (1 s simulated) the COM_OBL_RC_ACT failsafe acts")
    g.add_argument("--boot", type=_boot, default="fast", metavar="PRESET",
                   help=f"boot timeline: {', '.join(PRESETS)} (measured on the real autopilots), or "
                   "key=seconds pairs, e.g. gps_fix=1,origin=2,home=2,local_position=5,armable=5")
    g.add_argument("--param", type=_param, action="append", default=[], metavar="NAME=VALUE",
                   help="set a parameter at boot (repeatable); px4: " + ", ".join(PX4_PARAMS)
                   + "; ardupilot: " + ", ".join(ARDUPILOT_PARAMS))
    g.add_argument("--scale-timeouts", action="store_true",
                   help="multiply the link-loss timeouts (COM_OF_LOSS_T, COM_DL_LOSS_T, FS_GCS_TIMEOUT) by the "
                   "speedup, as PX4's SITL startup does, for clients that pace their streams in wall-clock time")
    g.add_argument("--start", type=_numbers((2, 3), "LAT,LON or LAT,LON,ALT"), default=None, metavar="LAT,LON[,ALT]",
                   help="boot position (deg), on the surface at or below ALT (m above the map datum, default 0: "
                   "the ground; a roof's height to start on it); must be on the map and not inside a building; "
                   "default: the map's home")
    g.add_argument("--origin", choices=("home", "boot"), default="home",
                   help="local NED origin: the current home position (it moves at arming), or where the vehicle "
                   "booted (the EKF origin, as on the real autopilots)")
    g.add_argument("--radius", type=_ranged(0, 100), default=0.3, help="vehicle sphere radius for collisions (m)")
    g.add_argument("--wind", type=_numbers((2,), "N,E"), default=(0.0, 0.0), metavar="N,E",
                   help="mean wind velocity north,east (m/s, direction the air moves towards)")
    g.add_argument("--gust", type=_ranged(0, 100), default=0.0, help="wind gust standard deviation (m/s)")
    g.add_argument("--gps-noise", type=_ranged(0, 1000), default=0.0,
                   help="position-estimate error standard deviation (m): reported, and flown (the vehicle "
                        "is off its commands by it); collisions use the truth")
    g.add_argument("--gps-correlation", type=_ranged(1, 3600), default=60.0, metavar="S",
                   help="the position-estimate error's correlation time (s): a Gauss-Markov drift, PX4 SITL's "
                        "GPS model by default; shorter is harsher")
    g.add_argument("--seed", type=int, default=0, help="seed for wind, GPS noise and packet loss")
    g.add_argument("--physics-dt", type=_ranged(0, 0.1, low_open=True), default=0.02,
                   help="fixed physics step (simulated s)")
    g = p.add_argument_group("obstacle sensors (sim/sensors.py; cast against the true boxes of --map)")
    g.add_argument("--targets", type=Path, default=None, metavar="FILE",
                   help="ground targets, CSV rows north_m,east_m (map frame): the downward camera reports each "
                        "in view as LANDING_TARGET; the report says when each was first seen and visited")
    g.add_argument("--no-sensor", action="store_true",
                   help="no obstacle sensors (default: px4 streams OBSTACLE_DISTANCE, 72 x 5 deg north-aligned "
                   "sectors, and a downward DISTANCE_SENSOR; ardupilot sends DISTANCE_SENSOR per 45 deg proximity "
                   "sector and the downward one when asked, e.g. in the EXTRA3 group)")
    g.add_argument("--sensor-range", type=_ranged(0.5, 600), default=30.0, metavar="M",
                   help="horizontal sensor's maximum range (m)")
    g.add_argument("--sensor-rate", type=_ranged(0, 50, low_open=True), default=10.0, metavar="HZ",
                   help="samples per simulated second (and PX4's stream rate)")
    g.add_argument("--sensor-noise", type=_ranged(0, 10), default=0.0, metavar="M",
                   help="range noise standard deviation (m)")
    g.add_argument("--sensor-dropout", type=_ranged(0, 100), default=0.0, metavar="PCT",
                   help="percentage of sectors lost in each scan (PX4: UINT16_MAX; ArduPilot: not sent)")
    g = p.add_argument_group("faults (all off by default; link faults are per client and in simulated time)")
    g.add_argument("--packet-loss", type=_ranged(0, 100), default=0.0, metavar="PCT",
                   help="drop this percentage of packets in each direction")
    g.add_argument("--latency", type=_ranged(0, 60000), default=0.0, metavar="MS",
                   help="delay every packet by this many simulated milliseconds in each direction")
    g.add_argument("--outage", type=_numbers((2,), "T,D"), default=None, metavar="T,D",
                   help="drop all packets from T to T+D simulated seconds after start (socket stays open)")
    g.add_argument("--deny-arm", type=_count, default=0, metavar="N",
                   help="answer the first N arm requests TEMPORARILY_REJECTED")
    g.add_argument("--deny-command", type=_command, action="append", default=[], metavar="NAME",
                   help="answer this MAV_CMD DENIED, e.g. NAV_TAKEOFF or MAV_CMD_NAV_LAND or 22 (repeatable)")
    g.add_argument("--battery-low", type=_ranged(0, 1e6), default=None, metavar="T",
                   help="the battery reads low T simulated seconds after start; the low-battery failsafe acts as "
                        "its parameter says (ardupilot BATT_FS_LOW_ACT, default 0: warn only; px4 warns, as at "
                        "its low level)")
    g.add_argument("--gps-loss", type=_numbers((1, 2), "T[,D]"), default=None, metavar="T[,D]",
                   help="the GPS has no fix from T simulated seconds after start (for D seconds; default: for good); "
                        "the estimate dead-reckons, and after the estimator's timeout the position-loss failsafe "
                        "acts (px4: Failsafe, blind descent in Altitude mode; ardupilot: EKF failsafe, LAND)")
    return p


def config_from_args(args: argparse.Namespace) -> SimConfig:
    """The :class:`SimConfig` of parsed arguments.

    Raises
    ------
    ValueError
        For values out of range (one line, naming the option's meaning).
    """
    faults = FaultConfig(
        packet_loss_pct=args.packet_loss,
        latency_ms=args.latency,
        outage_start_s=None if args.outage is None else args.outage[0],
        outage_duration_s=0.0 if args.outage is None else args.outage[1],
        deny_arm_count=args.deny_arm,
        deny_commands=tuple(args.deny_command),
        battery_low_s=args.battery_low,
        gps_loss_start_s=None if args.gps_loss is None else args.gps_loss[0],
        gps_loss_duration_s=math.inf if args.gps_loss is None or len(args.gps_loss) < 2 else args.gps_loss[1],
    )
    return SimConfig(
        map_path=args.map, host=args.host, port=args.port, speedup=args.speedup, start=args.start,
        report_path=args.report, tlog_path=args.tlog, autopilot=args.autopilot, strict=args.strict,
        origin=args.origin, radius_m=args.radius, wind_m_s=args.wind, gust_m_s=args.gust,
        gps_noise_m=args.gps_noise, gps_correlation_s=args.gps_correlation, seed=args.seed,
        physics_dt_s=args.physics_dt, faults=faults,
        boot=args.boot, params=dict(args.param), signing_key=args.signing_key, scale_timeouts=args.scale_timeouts,
        sensor=SensorConfig(enabled=not args.no_sensor, range_m=args.sensor_range, rate_hz=args.sensor_rate,
                            noise_m=args.sensor_noise, dropout_pct=args.sensor_dropout),
        targets=() if args.targets is None else read_targets(args.targets),
    )


def main(argv: list[str] | None = None) -> int:
    """Run the simulator until SIGINT/SIGTERM (or ``--duration``); return the exit code."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    from .simulator import Simulator  # heavy imports after argument parsing

    try:
        config = config_from_args(args)
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    map_path = config.resolved_map_path()
    if not map_path.exists():
        print(f"error: map {map_path} not found (pass --map)", file=sys.stderr)
        return 2
    try:
        city = CityMap.from_csv(map_path)
    except ValueError as exc:  # MapFormatError: "<file>:<line>: <why>"
        print(f"error: map {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"error: cannot read map {map_path}: {exc.strerror or exc}", file=sys.stderr)
        return 2

    def show(line: str) -> None:
        if not args.quiet:
            print(line, flush=True)

    stop = threading.Event()

    def on_signal(signum, _frame) -> None:
        show(f"received {signal.Signals(signum).name}, shutting down")
        stop.set()

    try:
        sim = Simulator(config, on_event=show, city=city)
    except ValueError as exc:  # a start off the map or inside a building
        print(f"error: {exc}", file=sys.stderr)
        return 2
    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            sim.start()
        except OSError as exc:
            print(f"error: cannot listen on {config.host}:{config.port}: {exc.strerror or exc}", file=sys.stderr)
            return 1
        try:
            stop.wait(args.duration)
        finally:
            report = sim.stop()
        if sim.error is not None:
            print(f"error: simulation failed: {sim.error!r}", file=sys.stderr)
            return 1
        collided = len(report["collisions"])
        rejected = report["signing"]["rejected_frames"]
        extra = f", {rejected} frame(s) dropped for their signature" if report["signing"]["enabled"] else ""
        show(f"done: {report['sim_time_s']:.1f} s simulated, {collided} collision(s){extra}")
        return 0
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)


if __name__ == "__main__":
    sys.exit(main())
