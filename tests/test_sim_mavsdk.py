"""MAVSDK-Python (an independent client, with its own C++ core) flies the sim in both modes."""

from __future__ import annotations

import asyncio
import time

import pytest

mavsdk = pytest.importorskip("mavsdk.asyncio")
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk  # noqa: E402
from mavsdk.asyncio.plugins.action import ActionAsync  # noqa: E402
from mavsdk.asyncio.plugins.offboard import OffboardAsync  # noqa: E402
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync  # noqa: E402
from mavsdk.plugins.offboard import PositionNedYaw  # noqa: E402


async def _until(check, timeout_s: float, what: str, poll_s: float = 0.05):
    deadline = time.monotonic() + timeout_s
    while True:
        value = await check()
        if value:
            return value
        if time.monotonic() > deadline:
            raise TimeoutError(f"MAVSDK: {what} not within {timeout_s} s")
        await asyncio.sleep(poll_s)


async def _mission(port: int, log: list) -> None:
    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(config) as sdk:
        await sdk.add_any_connection(f"tcpout://127.0.0.1:{port}")
        drone = await sdk.first_autopilot(timeout_s=10.0)
        assert drone is not None, "no autopilot discovered"
        tel, act, off = TelemetryAsync(drone), ActionAsync(drone), OffboardAsync(drone)

        async def healthy():
            h = await tel.health()
            return h.is_global_position_ok and h.is_local_position_ok and h.is_home_position_ok and h.is_armable

        await _until(healthy, 10, "health ok")
        log.append("health")
        await act.arm()
        await _until(tel.armed, 5, "armed")
        await act.set_takeoff_altitude(5.0)
        await act.takeoff()

        async def at_altitude():
            return (await tel.position()).relative_altitude_m > 4.8

        await _until(at_altitude, 10, "takeoff altitude")
        await _until(tel.in_air, 5, "in air")
        log.append("takeoff")
        await off.set_position_ned(PositionNedYaw(10.0, 5.0, -5.0, 90.0))
        await off.start()

        async def arrived():
            p = (await tel.position_velocity_ned()).position
            return abs(p.north_m - 10.0) < 0.2 and abs(p.east_m - 5.0) < 0.2 and abs(p.down_m + 5.0) < 0.2

        await _until(arrived, 15, "offboard position")
        log.append("offboard")
        await off.stop()
        await act.land()

        async def on_ground():
            return not await tel.in_air()

        await _until(on_ground, 20, "landed")
        log.append("landed")
        await act.disarm()

        async def disarmed():
            return not await tel.armed()

        await _until(disarmed, 5, "disarmed")
        log.append("disarmed")


@pytest.mark.flight
@pytest.mark.parametrize("strict", [False, True], ids=["default", "strict"])
def test_mavsdk_flies_takeoff_offboard_land(sim_start, strict):
    sim = sim_start(strict=strict, speedup=15.0)
    log: list = []
    asyncio.run(asyncio.wait_for(_mission(sim.port, log), timeout=60))
    assert log == ["health", "takeoff", "offboard", "landed", "disarmed"]
    report = sim.report()
    assert report["collisions"] == []
    assert report["landed"]["north_m"] == pytest.approx(10.0, abs=0.3)
    assert report["landed"]["east_m"] == pytest.approx(5.0, abs=0.3)
    names = [c["name"] for c in report["commands"]]
    for needed in ("MAV_CMD_COMPONENT_ARM_DISARM", "MAV_CMD_NAV_TAKEOFF", "MAV_CMD_DO_SET_MODE", "MAV_CMD_NAV_LAND"):
        assert needed in names
    assert all(c["result"] is not None for c in report["commands"])
    assert not any(e["kind"] == "dialect" for e in report["events"])  # MAVSDK is never taken for classic
    assert sim.truth()["yaw_deg"] == pytest.approx(90.0, abs=2.0)
