"""MAVSDK (python mavsdk 3.10 with its bundled mavsdk_server) as an independent MAVLink
client of the simulated PX4 vehicle: connect, telemetry, arm, offboard start/stop.

The vehicle runs in real time in a thread (MAVSDK has its own clock); every wait is
bounded by asyncio timeouts and the vehicle thread by a duration.
"""

from __future__ import annotations

import asyncio
import socket
import threading

import pytest

from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.link import free_udp_port
from lpv_sysid.sim.px4_vehicle import SimVehicle, SimVehicleConfig

mavsdk = pytest.importorskip("mavsdk")


def _free_tcp_port() -> int:
    s = socket.socket()
    try:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
    finally:
        s.close()


async def _first(gen, timeout: float):
    async def take():
        async for x in gen:
            return x

    return await asyncio.wait_for(take(), timeout)


async def _until(gen, pred, timeout: float):
    async def take():
        async for x in gen:
            if pred(x):
                return x

    return await asyncio.wait_for(take(), timeout)


def test_mavsdk_connects_reads_telemetry_arms_and_starts_offboard():
    from mavsdk import System
    from mavsdk.offboard import VelocityBodyYawspeed
    from mavsdk.telemetry import FlightMode

    port = free_udp_port()
    veh = SimVehicle(
        SimVehicleConfig(url=f"udpout:127.0.0.1:{port}", params={"COM_OBL_RC_ACT": 5})
    )
    veh.open()
    stop = threading.Event()
    th = threading.Thread(
        target=veh.run_realtime, kwargs={"duration": 20.0, "stop": stop.is_set}, daemon=True
    )
    th.start()
    result: dict = {}

    async def client():
        drone = System(port=_free_tcp_port())
        try:
            await drone.connect(system_address=f"udpin://127.0.0.1:{port}")
            await _until(drone.core.connection_state(), lambda s: s.is_connected, 10.0)
            q = await _first(drone.telemetry.attitude_quaternion(), 5.0)
            result["q"] = (q.w, q.x, q.y, q.z)
            result["mode0"] = await _first(drone.telemetry.flight_mode(), 5.0)
            # parameters and firmware version decoded by MAVSDK's own PX4 conventions
            result["obl"] = await asyncio.wait_for(
                drone.param.get_param_int("COM_OBL_RC_ACT"), 5.0
            )
            result["loss_t"] = await asyncio.wait_for(
                drone.param.get_param_float("COM_OF_LOSS_T"), 5.0
            )
            v = await asyncio.wait_for(drone.info.get_version(), 5.0)
            result["version"] = (v.flight_sw_major, v.flight_sw_minor, v.flight_sw_patch)
            await asyncio.wait_for(drone.action.arm(), 5.0)
            result["armed"] = await _until(drone.telemetry.armed(), bool, 5.0)
            await drone.offboard.set_velocity_body(VelocityBodyYawspeed(0.0, 0.0, -1.0, 0.0))
            await asyncio.sleep(0.3)  # let the setpoint stream establish
            await asyncio.wait_for(drone.offboard.start(), 5.0)
            result["mode1"] = await _until(
                drone.telemetry.flight_mode(), lambda m: m == FlightMode.OFFBOARD, 5.0
            )
            pv = await _until(
                drone.telemetry.position_velocity_ned(), lambda p: p.position.down_m < -0.5, 5.0
            )
            result["climb"] = (pv.position.down_m, pv.velocity.down_m_s)
            await asyncio.wait_for(drone.offboard.stop(), 5.0)
            result["mode2"] = await _until(
                drone.telemetry.flight_mode(), lambda m: m != FlightMode.OFFBOARD, 5.0
            )
        finally:
            drone._stop_mavsdk_server()

    try:
        asyncio.run(asyncio.wait_for(client(), 30.0))
    finally:
        stop.set()
        th.join(timeout=5.0)
        veh.close()
    assert result["q"] == pytest.approx((1.0, 0.0, 0.0, 0.0), abs=1e-6)  # level on the ground
    assert result["mode0"] == FlightMode.HOLD
    assert result["obl"] == 5 and result["loss_t"] == pytest.approx(1.0)  # INT32 byte-wise, REAL32
    assert result["version"] == (1, 16, 0)
    assert result["armed"] is True and veh.armed
    assert result["mode1"] == FlightMode.OFFBOARD
    down, vdown = result["climb"]
    assert down < -0.5 and -1.3 < vdown < -0.5  # climbing at ~1 m/s as commanded
    assert result["mode2"] == FlightMode.HOLD and veh.mode == px4.HOLD
    modes = [m for _, m, _ in veh.mode_log]
    assert modes[:2] == ["OFFBOARD", "HOLD"]
    assert veh.setpoints_received > 10 and veh.link.stats.bad_data == 0
