"""Fault injection for reliability tests. Everything is off by default.

Link faults act on whole MAVLink packets, per TCP client, in **simulated** time, so that a run at
``--speedup 5`` meets the same link as one at ``--speedup 1`` (a client sees them shrunk by the
speedup on its own wall clock):

* ``packet_loss_pct``: each packet, in each direction, is dropped with this probability (seeded).
* ``latency_ms``: each packet is delayed by this many simulated milliseconds in each direction (round
  trip +2x), with the physics step (20 ms) as resolution.
* ``outage_start_s`` / ``outage_duration_s``: from ``start`` simulated seconds after the sim starts, for
  ``duration`` simulated seconds, every packet in both directions is dropped (the TCP socket stays
  open).

Command faults:

* ``deny_arm_count``: the first N arm requests are answered TEMPORARILY_REJECTED.
* ``deny_commands``: named MAV_CMDs (``MAV_CMD_NAV_TAKEOFF``, ``NAV_TAKEOFF`` or ``22``) are answered
  DENIED.

Vehicle faults:

* ``battery_low_s``: this many simulated seconds after start the battery reads low; the autopilot's low-battery
  failsafe acts as its parameters say (:mod:`sim.failsafes`; ArduCopter's default and PX4 only warn).
* ``gps_loss_start_s`` / ``gps_loss_duration_s``: from ``start`` simulated seconds after the sim starts, for
  ``duration`` (default: for good), the GPS has no fix; the estimate dead-reckons, and once it has had no GPS for
  the estimator's timeout the autopilot's position-loss failsafe acts (:mod:`sim.failsafes`).
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink


@dataclass(frozen=True)
class FaultConfig:
    """Fault settings (see module docstring for semantics and units)."""

    packet_loss_pct: float = 0.0
    latency_ms: float = 0.0
    outage_start_s: float | None = None
    outage_duration_s: float = 0.0
    deny_arm_count: int = 0
    deny_commands: tuple[str, ...] = ()
    battery_low_s: float | None = None
    gps_loss_start_s: float | None = None
    gps_loss_duration_s: float = math.inf

    def __post_init__(self) -> None:
        if not 0.0 <= self.packet_loss_pct <= 100.0:  # also refuses NaN
            raise ValueError(f"packet loss must be in [0, 100] %, not {self.packet_loss_pct}")
        if not 0.0 <= self.latency_ms <= 60_000.0:
            raise ValueError(f"latency must be in [0, 60000] ms, not {self.latency_ms}")
        if self.outage_start_s is not None and not 0.0 <= self.outage_start_s <= 1e6:
            raise ValueError(f"outage start must be in [0, 1e6] s, not {self.outage_start_s}")
        if not 0.0 <= self.outage_duration_s <= 1e6:
            raise ValueError(f"outage duration must be in [0, 1e6] s, not {self.outage_duration_s}")
        if int(self.deny_arm_count) != self.deny_arm_count or self.deny_arm_count < 0:
            raise ValueError(f"deny-arm count must be a whole number >= 0, not {self.deny_arm_count}")
        for name in self.deny_commands:
            command_id(name)
        if self.battery_low_s is not None and not 0.0 <= self.battery_low_s <= 1e6:
            raise ValueError(f"battery-low time must be in [0, 1e6] s, not {self.battery_low_s}")
        if self.gps_loss_start_s is not None and not 0.0 <= self.gps_loss_start_s <= 1e6:
            raise ValueError(f"GPS loss start must be in [0, 1e6] s, not {self.gps_loss_start_s}")
        if not self.gps_loss_duration_s > 0.0:  # also refuses NaN; inf: for good
            raise ValueError(f"GPS loss duration must be > 0 s, not {self.gps_loss_duration_s}")

    def active(self) -> list[str]:
        """Human-readable list of the faults that are on."""
        out = []
        if self.packet_loss_pct > 0:
            out.append(f"packet loss {self.packet_loss_pct:g}%")
        if self.latency_ms > 0:
            out.append(f"latency {self.latency_ms:g} ms")
        if self.outage_start_s is not None and self.outage_duration_s > 0:
            out.append(f"outage at {self.outage_start_s:g} s for {self.outage_duration_s:g} s")
        if self.deny_arm_count > 0:
            out.append(f"deny first {self.deny_arm_count} arm(s)")
        if self.deny_commands:
            out.append("deny " + ",".join(self.deny_commands))
        if self.battery_low_s is not None:
            out.append(f"battery low at {self.battery_low_s:g} s")
        if self.gps_loss_start_s is not None:
            lasting = "" if math.isinf(self.gps_loss_duration_s) else f" for {self.gps_loss_duration_s:g} s"
            out.append(f"GPS lost at {self.gps_loss_start_s:g} s{lasting}")
        return out

    def gps_lost(self, sim_time_s: float) -> bool:
        """Whether the GPS has no fix at ``sim_time_s`` (simulated s)."""
        start = self.gps_loss_start_s
        return start is not None and start <= sim_time_s < start + self.gps_loss_duration_s


def command_id(name: str) -> int:
    """MAV_CMD number from ``"MAV_CMD_NAV_TAKEOFF"``, ``"NAV_TAKEOFF"`` or ``"22"``.

    Raises
    ------
    ValueError
        If the name is not a MAV_CMD of the common dialect.

    >>> command_id("NAV_TAKEOFF"), command_id("mav_cmd_nav_land"), command_id("400")
    (22, 21, 400)
    """
    text = name.strip()
    if text.isdigit():
        return int(text)
    key = text.upper()
    if not key.startswith("MAV_CMD_"):
        key = "MAV_CMD_" + key
    for number, entry in mavlink.enums["MAV_CMD"].items():
        if entry.name == key:
            return number
    raise ValueError(f"unknown MAVLink command {name!r}")


def command_name(number: int) -> str:
    """``MAV_CMD_*`` name of a command number, or ``"MAV_CMD_<n>"`` if unknown."""
    entry = mavlink.enums["MAV_CMD"].get(int(number))
    return entry.name if entry is not None else f"MAV_CMD_{int(number)}"


class LinkFaults:
    """Per-link packet faults; one instance per TCP client."""

    def __init__(self, config: FaultConfig, seed: int, link_id: int) -> None:
        self.config = config
        self._rng_in = random.Random(f"{seed}/{link_id}/in")
        self._rng_out = random.Random(f"{seed}/{link_id}/out")
        self.dropped_in = 0
        self.dropped_out = 0

    @property
    def delay_s(self) -> float:
        """One-way latency (simulated s)."""
        return self.config.latency_ms / 1000.0

    def in_outage(self, sim_time_s: float) -> bool:
        start = self.config.outage_start_s
        return start is not None and start <= sim_time_s < start + self.config.outage_duration_s

    def drop_in(self, sim_time_s: float) -> bool:
        """Whether the next incoming packet is lost."""
        lost = self.in_outage(sim_time_s) or self._rng_in.random() * 100.0 < self.config.packet_loss_pct
        self.dropped_in += lost
        return lost

    def drop_out(self, sim_time_s: float) -> bool:
        """Whether the next outgoing packet is lost."""
        lost = self.in_outage(sim_time_s) or self._rng_out.random() * 100.0 < self.config.packet_loss_pct
        self.dropped_out += lost
        return lost


class CommandFaults:
    """Arm and command denials, shared by all links."""

    def __init__(self, config: FaultConfig) -> None:
        self.config = config
        self._deny_ids = {command_id(n) for n in config.deny_commands}
        self.arms_denied = 0

    def deny_command(self, command: int) -> bool:
        return int(command) in self._deny_ids

    def deny_arm(self) -> bool:
        """Call once per arm request; True while the first N are being denied."""
        if self.arms_denied < self.config.deny_arm_count:
            self.arms_denied += 1
            return True
        return False
