"""``python -m sim``: serve the mock autopilot over TCP until SIGINT/SIGTERM."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from pathlib import Path

from .config import SimConfig, default_map_path
from .faults import FaultConfig, command_id
from .world import CityMap


def _pair(text: str) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected two comma-separated numbers, got {text!r}") from None
    return a, b


def _command(text: str) -> str:
    try:
        command_id(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m sim",
        description="Mock PX4/ArduCopter autopilot: flies a point-mass quadcopter through the colliders.csv "
        "city, speaks MAVLink 2 over TCP (system 1, component 1) and reports collisions. Prints one status "
        "line per event; SIGINT/SIGTERM shut it down cleanly and write --report.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    g = p.add_argument_group("server")
    g.add_argument("--map", type=Path, default=None,
                   help=f"obstacle map (colliders.csv); None = the project's own, {default_map_path()}")
    g.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (loopback unless told otherwise)")
    g.add_argument("--port", type=int, default=5760, help="TCP port (0 = pick a free one)")
    g.add_argument("--speedup", type=float, default=1.0,
                   help="simulated seconds per wall-clock second (heartbeats stay at 1 Hz wall clock)")
    g.add_argument("--report", type=Path, default=None, help="write the JSON flight report here on exit")
    g.add_argument("--tlog", type=Path, default=None, help="write a MAVLink telemetry log (.tlog) here")
    g.add_argument("--duration", type=float, default=None,
                   help="exit by itself after this many wall-clock seconds (None = run until signalled)")
    g.add_argument("-q", "--quiet", action="store_true", help="no status lines")
    g = p.add_argument_group("vehicle")
    g.add_argument("--autopilot", choices=("px4", "ardupilot"), default="px4",
                   help="personality: PX4 custom modes, or ArduCopter mode numbers (GUIDED 4, LAND 9, RTL 6)")
    g.add_argument("--strict", action="store_true",
                   help="PX4-like: NED z only, OFFBOARD needs a setpoint stream and holds after 0.5 s "
                   "(wall clock) without one")
    g.add_argument("--start", type=_pair, default=None, metavar="LAT,LON",
                   help="boot position (deg); default: home = the map header's lat0,lon0 at altitude 0")
    g.add_argument("--origin", choices=("home", "boot"), default="home",
                   help="local NED origin: the home position, or where the vehicle booted "
                   "(as the PX4/ArduPilot EKF origin)")
    g.add_argument("--radius", type=float, default=0.3, help="vehicle sphere radius for collisions (m)")
    g.add_argument("--wind", type=_pair, default=(0.0, 0.0), metavar="N,E",
                   help="mean wind velocity north,east (m/s, direction the air moves towards)")
    g.add_argument("--gust", type=float, default=0.0, help="wind gust standard deviation (m/s)")
    g.add_argument("--gps-noise", type=float, default=0.0,
                   help="reported-position noise standard deviation (m); collisions use the truth")
    g.add_argument("--seed", type=int, default=0, help="seed for wind, GPS noise and packet loss")
    g.add_argument("--physics-dt", type=float, default=0.02, help="fixed physics step (simulated s)")
    g = p.add_argument_group("faults (all off by default; link faults are per client and wall-clock)")
    g.add_argument("--packet-loss", type=float, default=0.0, metavar="PCT",
                   help="drop this percentage of packets in each direction")
    g.add_argument("--latency", type=float, default=0.0, metavar="MS",
                   help="delay every packet by this many milliseconds in each direction")
    g.add_argument("--outage", type=_pair, default=None, metavar="T,D",
                   help="drop all packets from T to T+D wall-clock seconds after start (socket stays open)")
    g.add_argument("--deny-arm", type=int, default=0, metavar="N",
                   help="answer the first N arm requests TEMPORARILY_REJECTED")
    g.add_argument("--deny-command", type=_command, action="append", default=[], metavar="NAME",
                   help="answer this MAV_CMD DENIED, e.g. NAV_TAKEOFF or MAV_CMD_NAV_LAND or 22 (repeatable)")
    return p


def config_from_args(args: argparse.Namespace) -> SimConfig:
    faults = FaultConfig(
        packet_loss_pct=args.packet_loss,
        latency_ms=args.latency,
        outage_start_s=None if args.outage is None else args.outage[0],
        outage_duration_s=0.0 if args.outage is None else args.outage[1],
        deny_arm_count=args.deny_arm,
        deny_commands=tuple(args.deny_command),
    )
    return SimConfig(
        map_path=args.map, host=args.host, port=args.port, speedup=args.speedup, start=args.start,
        report_path=args.report, tlog_path=args.tlog, autopilot=args.autopilot, strict=args.strict,
        origin=args.origin, radius_m=args.radius, wind_m_s=args.wind, gust_m_s=args.gust,
        gps_noise_m=args.gps_noise, seed=args.seed, physics_dt_s=args.physics_dt, faults=faults,
    )


def main(argv: list[str] | None = None) -> int:
    """Run the simulator until SIGINT/SIGTERM (or ``--duration``); return the exit code."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    from .simulator import Simulator  # heavy imports after argument parsing

    try:
        config = config_from_args(args)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    map_path = config.resolved_map_path()
    if not map_path.exists():
        print(f"error: map {map_path} not found (pass --map)", file=sys.stderr)
        return 2
    try:
        city = CityMap.from_csv(map_path)
    except (OSError, ValueError) as exc:  # MapFormatError, a row numpy cannot parse, a binary file
        print(f"error: cannot read map {map_path}: {exc}", file=sys.stderr)
        return 2

    def show(line: str) -> None:
        if not args.quiet:
            print(line, flush=True)

    stop = threading.Event()

    def on_signal(signum, _frame) -> None:
        show(f"received {signal.Signals(signum).name}, shutting down")
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            sim = Simulator(config, on_event=show, city=city).start()
        except OSError as exc:
            print(f"error: cannot listen on {config.host}:{config.port}: {exc}", file=sys.stderr)
            return 1
        try:
            stop.wait(args.duration)
        finally:
            report = sim.stop()
        if sim.error is not None:
            print(f"error: simulation failed: {sim.error!r}", file=sys.stderr)
            return 1
        collided = len(report["collisions"])
        show(f"done: {report['sim_time_s']:.1f} s simulated, {collided} collision(s)")
        return 0
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)


if __name__ == "__main__":
    sys.exit(main())
