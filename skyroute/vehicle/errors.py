"""The vehicle link's typed errors: each says what was asked and what came back.

Part of the ``vehicle`` package; :func:`command_name` and :func:`result_name` read pymavlink's enum tables.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink


def command_name(command: int) -> str:
    """``MAV_CMD_...`` name of a command number (or the number)."""
    entry = mavlink.enums["MAV_CMD"].get(command)
    return entry.name if entry else f"command {command}"


def result_name(result: int) -> str:
    """``MAV_RESULT_...`` name of a result number (or the number)."""
    entry = mavlink.enums["MAV_RESULT"].get(result)
    return entry.name if entry else f"result {result}"


class VehicleError(Exception):
    """Base class of every error raised by the vehicle package. ``permanent``: waiting will not change it."""

    permanent = False


class BadConnection(VehicleError):
    """The connection string cannot be opened by pymavlink (unknown scheme, bad port, no such device)."""

    def __init__(self, connection: str, detail: str):
        self.connection, self.detail = connection, detail
        super().__init__(f"cannot open connection {connection!r}: {detail}")


class ConnectionTimeout(VehicleError):
    """No autopilot heartbeat arrived on ``connection`` within ``timeout_s``."""

    def __init__(self, connection: str, timeout_s: float, detail: str = ""):
        self.connection, self.timeout_s, self.detail = connection, timeout_s, detail
        msg = f"no autopilot heartbeat on {connection} within {timeout_s:g} s"
        super().__init__(f"{msg} ({detail})" if detail else msg)


class SigningRequired(VehicleError):
    """The autopilot signs its MAVLink 2 messages and we have no key: it will drop every unsigned command."""

    permanent = True

    def __init__(self, connection: str):
        self.connection = connection
        super().__init__(f"the autopilot on {connection} signs its MAVLink messages and drops unsigned ones: "
                         "give its key with --signing-key")


class CommandRejected(VehicleError):
    """The autopilot answered a command with a result other than ACCEPTED.

    ``command`` and ``result`` are the MAVLink numbers; ``reason`` is the autopilot's STATUSTEXT that came with
    the refusal, if any. ``temporary`` is True for TEMPORARILY_REJECTED (the autopilot is not ready yet).
    """

    def __init__(self, command: int, result: int, reason: str | None = None):
        self.command, self.result, self.reason = command, result, reason
        text = f"{command_name(command)} rejected: {result_name(result)}"
        super().__init__(f"{text}: {reason}" if reason else text)

    @property
    def temporary(self) -> bool:
        return self.result == mavlink.MAV_RESULT_TEMPORARILY_REJECTED

    @property
    def permanent(self) -> bool:
        """DENIED, FAILED, UNSUPPORTED: the autopilot will answer the same until something changes."""
        return not self.temporary


class CommandTimeout(VehicleError):
    """No final COMMAND_ACK for ``command`` after ``attempts`` sends of ``timeout_s`` each."""

    def __init__(self, command: int, attempts: int, timeout_s: float, detail: str = ""):
        self.command, self.attempts, self.timeout_s = command, attempts, timeout_s
        msg = f"no COMMAND_ACK for {command_name(command)} after {attempts} x {timeout_s:.2g} s"
        super().__init__(f"{msg} ({detail})" if detail else msg)


class LinkLost(VehicleError):
    """Nothing arrived from the autopilot for longer than the link timeout."""

    def __init__(self, silent_s: float, timeout_s: float | None = None):
        self.silent_s, self.timeout_s = silent_s, timeout_s
        limit = "" if timeout_s is None else f" (link timeout {timeout_s:.1f} s)"
        super().__init__(f"link lost: nothing from the autopilot for {silent_s:.1f} s{limit}")


class TelemetryTimeout(VehicleError):
    """A telemetry condition (``what``) did not hold within ``timeout_s``."""

    def __init__(self, what: str, timeout_s: float):
        self.what, self.timeout_s = what, timeout_s
        super().__init__(f"timed out after {timeout_s:g} s waiting for {what}")


class UnsupportedMode(VehicleError):
    """The mode name is not in pymavlink's table for this autopilot."""

    def __init__(self, mode: str, autopilot_name: str):
        self.mode, self.autopilot = mode, autopilot_name
        super().__init__(f"mode {mode!r} unknown for {autopilot_name}")
