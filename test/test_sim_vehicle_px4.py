"""The simulated vehicle behaves like PX4 v1.16 SITL where issue 10 found the package wrong,
and is hardened as issue 12 item 7 asks. Every test runs the vehicle and a MAVLink peer
over UDP on 127.0.0.1 in lock-step on one simulated clock (no wall-clock timing).

PX4 facts reproduced (issue 10): DO_SET_MODE / arming answered twice (ACCEPTED, then the
commander's verdict); POSCTL refused without stick input; offboard loss with a stick mode
(COM_OBL_RC_ACT 0/1/2) and no RC -> "Matching flight task was not able to run" and an
uncontrolled descent at MPC_LAND_SPEED while the HEARTBEAT shows the failsafe mode, Hold
(5) holds; 1 Hz HEARTBEAT; the mode survives an auto-disarm; no ESC_STATUS on SIH but
motor outputs; ODOMETRY stamped before ATTITUDE_QUATERNION; ATTITUDE and
ATTITUDE_QUATERNION both streamed. Issue 12 item 7: loopback bind, PARAM_SET validation,
signing honoured, all-interface URLs warned about.
"""

from __future__ import annotations

import ast
import logging
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lpv_sysid.errors import ConfigError, LpvSysidError
from lpv_sysid.mavlink import codec, px4
from lpv_sysid.mavlink.bridge import BridgeConfig, BridgeCore
from lpv_sysid.mavlink.link import LinkConfig, MavlinkLink, free_udp_port
from lpv_sysid.mavlink.offboard import OffboardConfig, State, StatusEvent
from lpv_sysid.sim.px4_vehicle import DEFAULT_RATES, PARAMS, SimVehicle, SimVehicleConfig

DT = 0.004
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MOD = codec.dialect_module()
#: only LOCAL_POSITION_NED besides the HEARTBEAT: the flight tests look at the vehicle's truth
QUIET = {n: 0.0 for n in DEFAULT_RATES if n != "LOCAL_POSITION_NED"}
OFFBOARD_CMD = (1.0, 6.0, 0.0)


class Gcs:
    """A MAVLink peer (udpin on 127.0.0.1) and the vehicle (udpout to it), lock-step."""

    def __init__(self, gcs_key: str | None = None, sysid: int = 255, **veh_kw) -> None:
        port = free_udp_port()
        self.link = MavlinkLink(
            LinkConfig(
                url=f"udpin:127.0.0.1:{port}",
                source_system=sysid,
                source_component=190,
                streams=(),
                signing_key_file=gcs_key,
                mav_type=6,
            )
        )
        self.veh = SimVehicle(SimVehicleConfig(url=f"udpout:127.0.0.1:{port}", **veh_kw))
        self.link.open(0.0)
        self.veh.open()
        self.t = 0.0
        self.msgs: list = []
        self.sp: tuple | None = None
        self.next_sp = 0.0
        self.trace: list = []
        self.outputs: dict[int, tuple] = {}

    def run(self, t_end: float, record: bool = False, outputs: bool = False) -> None:
        n = 0
        while self.t < t_end - 1e-9:
            n += 1
            assert n < 100000
            self.t = round(self.t + DT, 9)
            if self.sp is not None and self.t >= self.next_sp:  # 20 Hz setpoint stream
                self.next_sp = self.t + 0.05
                self.link.send(
                    self.link.codec.set_position_target_local_ned_encode(
                        int(self.t * 1000), 1, 1, 1, 0x0FC7, 0, 0, 0, *self.sp, 0, 0, 0, 0, 0
                    )
                )
            self.veh.step(self.t)
            if outputs:
                self.outputs[int(self.veh.t * 1e6)] = self.veh.motor_outputs()
            for m in self.link.poll(self.t):
                self.msgs.append((self.t, m))
            self.link.step(self.t)
            if record:
                self.trace.append((self.t, self.veh.x.copy()))

    def of(self, mtype: str, since: float = -1.0) -> list:
        return [m for t, m in self.msgs if t > since and m.get_type() == mtype]

    def acks(self, command: int, since: float = -1.0) -> list[int]:
        return [m.result for m in self.of("COMMAND_ACK", since) if m.command == command]

    def hb_mode(self, since: float = -1.0) -> tuple[px4.Px4Mode, bool]:
        """Mode and arming of the newest HEARTBEAT (what any MAVLink client sees)."""
        hb = self.of("HEARTBEAT", since)[-1]
        return px4.decode_custom_mode(hb.custom_mode), bool(
            hb.base_mode & px4.MAV_MODE_FLAG_SAFETY_ARMED
        )

    def param_set(self, name: str, value: float, ptype: int) -> None:
        self.link.send(
            self.link.codec.param_set_encode(
                1, 1, name.encode("ascii"), px4.param_to_wire(value, ptype), ptype
            )
        )

    def close(self) -> None:
        self.link.close()
        self.veh.close()


@pytest.fixture
def gcs():
    made: list[Gcs] = []

    def make(**kw) -> Gcs:
        g = Gcs(**kw)
        made.append(g)
        return g

    yield make
    for g in made:
        g.close()


def _offboard_armed(g: Gcs) -> None:
    g.sp = (0.0, 0.0, 0.0)
    g.run(g.t + 1.3)
    g.link.command_long(176, *OFFBOARD_CMD)
    g.run(g.t + 0.1)
    g.link.command_long(400, 1.0)
    g.run(g.t + 0.1)
    assert g.veh.mode == px4.OFFBOARD and g.veh.armed


def _fly_to_5m_at_1ms(g: Gcs) -> None:
    """Climb 2.5 s at 2 m/s, then 3 s forward at 1 m/s (OFFBOARD)."""
    _offboard_armed(g)
    g.sp = (0.0, 0.0, -2.0)
    g.run(g.t + 2.5)
    g.sp = (1.0, 0.0, 0.0)
    g.run(g.t + 3.0)
    assert -5.3 < g.veh.x[2] < -4.7 and abs(g.veh.x[6] - 1.0) < 0.05


# ------------------------------------------------------------ 1. double ACK
def test_double_ack_accepted_then_verdict_posctl_rejected_without_rc_while_armed(gcs):
    """Measured on PX4 v1.16.0 SIH: DO_SET_MODE POSCTL in flight without RC is answered
    ACCEPTED, then TEMPORARILY_REJECTED; the mode stays OFFBOARD."""
    g = gcs(stream_rates=QUIET)
    _offboard_armed(g)
    g.sp = (0.0, 0.0, -1.0)
    g.run(g.t + 2.0)
    t0 = g.t
    g.link.command_long(176, 1.0, 3.0, 0.0)  # POSCTL
    g.run(g.t + 1.2)
    assert g.acks(176, t0) == [0, 1]  # ACCEPTED, TEMPORARILY_REJECTED
    (t_acc, _, r0), (t_verdict, _, r1) = [
        a for a in g.veh.acks_sent if a[1] == 176 and a[0] >= t0 - DT
    ]
    # the verdict follows verdict_delay_s (10 ms) of simulated time later, at physics resolution
    assert (r0, r1) == (0, 1) and 0.01 - 1e-9 <= t_verdict - t_acc <= 0.01 + 2 * DT
    assert g.veh.mode == px4.OFFBOARD and g.hb_mode(t0 + 0.05) == (px4.OFFBOARD, True)  # unchanged
    assert (t_verdict, "Switching to POSCTL is currently not possible") in g.veh.px4_log
    for mode in (px4.ALTCTL, px4.STABILIZED, px4.MANUAL, px4.ACRO):  # every stick mode
        t1 = g.t
        g.link.command_long(176, 1.0, float(mode.main), float(mode.sub))
        g.run(g.t + 0.1)
        assert g.acks(176, t1) == [0, 1], mode.name
    t1 = g.t
    g.link.command_long(176, 1.0, 4.0, 3.0)  # HOLD: needs no sticks
    g.run(g.t + 1.2)
    assert g.acks(176, t1) == [0, 0] and g.hb_mode(t1 + 0.05) == (px4.HOLD, True)
    g.sp = None  # stream dead for > 1 s
    g.run(g.t + 1.2)
    t1 = g.t
    g.link.command_long(176, *OFFBOARD_CMD)  # OFFBOARD cannot run: refused
    g.run(g.t + 0.1)
    assert g.acks(176, t1) == [0, 1] and g.veh.mode == px4.HOLD


def test_disarmed_every_mode_is_accepted_and_arming_decides(gcs):
    """PX4 v1.16 allows any mode change while disarmed (measured: POSCTL and OFFBOARD
    without a stream ACCEPTED twice); arming in a mode that cannot run is refused once."""
    g = gcs(stream_rates=QUIET)
    g.run(0.5)
    g.link.command_long(176, 1.0, 3.0, 0.0)
    g.run(1.2)
    assert g.acks(176) == [0, 0] and g.hb_mode(0.6) == (px4.POSCTL, False)
    t0 = g.t
    g.link.command_long(400, 1.0)  # no sticks: POSCTL cannot run
    g.run(g.t + DT)
    assert g.acks(400, t0) == [] and not g.veh.armed  # the commander has not decided yet
    g.run(g.t + 0.1)
    assert g.acks(400, t0) == [px4.MAV_RESULT_TEMPORARILY_REJECTED] and not g.veh.armed
    assert any(
        m.startswith("Arming denied: Resolve system health failures first")
        for _, m in g.veh.px4_log
    )
    t0 = g.t
    g.link.command_long(176, *OFFBOARD_CMD)  # no setpoint stream at all
    g.run(g.t + 1.2)
    assert g.acks(176, t0) == [0, 0] and g.hb_mode(t0 + 0.05) == (px4.OFFBOARD, False)
    t0 = g.t
    g.link.command_long(400, 1.0)
    g.run(g.t + 0.1)
    assert g.acks(400, t0) == [px4.MAV_RESULT_TEMPORARILY_REJECTED] and not g.veh.armed
    g.sp = (0.0, 0.0, 0.0)  # with a stream: armed, one ACK
    g.run(g.t + 0.5)
    t0 = g.t
    g.link.command_long(400, 1.0)
    g.run(g.t + 1.2)
    assert g.acks(400, t0) == [0] and g.veh.armed and g.hb_mode(t0 + 0.05) == (px4.OFFBOARD, True)


def test_stick_input_from_rc_or_joystick_per_com_rc_in_mode(gcs):
    g = gcs(
        rc_present=True,
        params={"COM_RC_IN_MODE": 0},
        stream_rates={**QUIET, "SYS_STATUS": 5.0, "RC_CHANNELS": 20.0},
    )
    g.run(0.5)
    g.link.command_long(176, 1.0, 3.0, 0.0)
    g.run(0.7)
    g.link.command_long(400, 1.0)
    g.run(1.0)
    assert (
        g.acks(176) == [0, 0] and g.acks(400) == [0] and g.veh.armed and g.veh.mode == px4.POSCTL
    )
    assert g.of("RC_CHANNELS")[-1].chancount == 8 and g.of("RC_CHANNELS")[-1].rssi > 0
    assert g.of("SYS_STATUS")[-1].onboard_control_sensors_present & 0x10000  # RC_RECEIVER
    # an RC, but stick input disabled (COM_RC_IN_MODE 4): no stick input, arming in POSCTL refused
    g2 = gcs(
        rc_present=True, params={"COM_RC_IN_MODE": 4}, stream_rates={**QUIET, "SYS_STATUS": 5.0}
    )
    g2.run(0.5)
    g2.link.command_long(176, 1.0, 3.0, 0.0)
    g2.run(0.7)
    g2.link.command_long(400, 1.0)
    g2.run(1.0)
    assert g2.acks(400) == [1] and not g2.veh.armed
    assert not g2.of("SYS_STATUS")[-1].onboard_control_sensors_present & 0x10000
    # a MAVLink joystick (MANUAL_CONTROL) with COM_RC_IN_MODE 1 (PX4 SIH's default) counts
    g3 = gcs(stream_rates={**QUIET, "SYS_STATUS": 5.0})
    assert g3.veh.param("COM_RC_IN_MODE") == 1
    g3.run(0.3)
    g3.link.command_long(176, 1.0, 3.0, 0.0)
    for _ in range(10):
        g3.link.send(g3.link.codec.manual_control_encode(1, 0, 0, 500, 0, 0))
        g3.run(g3.t + 0.05)
    g3.link.command_long(400, 1.0)
    g3.run(g3.t + 0.05)
    assert g3.acks(400) == [0] and g3.veh.armed and g3.veh.mode == px4.POSCTL
    assert g3.of("SYS_STATUS")[-1].onboard_control_sensors_present & 0x10000
    assert not g3.of("RC_CHANNELS")  # no RC: no RC_CHANNELS stream


# ---------------------------------------------- bridge: truthful hand-back over UDP
class BridgeFlight:
    def __init__(self, offboard: OffboardConfig, **veh_kw) -> None:
        port = free_udp_port()
        self.veh = SimVehicle(SimVehicleConfig(url=f"udpout:127.0.0.1:{port}", **veh_kw))
        self.bridge = BridgeCore(
            BridgeConfig(link=LinkConfig(url=f"udpin:127.0.0.1:{port}"), offboard=offboard)
        )
        self.bridge.open(0.0)
        self.veh.open()
        self.t = 0.0
        self.events: list = []

    def run(self, t_end: float, ref=None) -> None:
        n = 0
        while self.t < t_end - 1e-9:
            n += 1
            assert n < 100000
            self.t = round(self.t + DT, 9)
            if ref is not None and int(round(self.t / DT)) % 5 == 0:
                self.bridge.on_velocity_reference(self.t, ref, 0.0)
            self.veh.step(self.t)
            self.events += self.bridge.poll(self.t).events

    def close(self) -> None:
        self.bridge.close()
        self.veh.close()


@pytest.mark.parametrize(
    "chain, final", [(("POSCTL", "HOLD", "LAND"), "DONE"), (("POSCTL",), "FAILED")]
)
def test_bridge_posctl_handback_without_rc_never_reports_done_posctl(chain, final):
    """Issue 10 finding 1 end to end: POSCTL is accepted, then rejected by the vehicle.
    With a fallback the bridge ends DONE in a confirmed HOLD, and the neutral stream kept
    the vehicle out of the offboard-loss failsafe (altitude held). Without a fallback it ends
    FAILED ("NOT confirmed") while the vehicle's failsafe shows POSCTL and descends."""
    f = BridgeFlight(OffboardConfig(arm=True, handback_chain=chain), stream_rates=QUIET)
    try:
        climb = (0.0, 0.0, -2.0)
        f.run(0.3)
        f.events += f.bridge.start(f.t)
        f.run(5.0, climb)
        f.run(6.0, (0.0, 0.0, 0.0))
        assert f.bridge.state == State.OFFBOARD_ACTIVE and f.veh.x[2] < -4.0
        z_abort = f.veh.x[2]
        f.events += f.bridge.abort(f.t, "end of run")
        f.run(12.0)
        st = [e for e in f.events if isinstance(e, StatusEvent) and e.previous != e.state]
        assert not any(e.state == "DONE" and "vehicle in POSCTL" in e.reason for e in st)
        results = [r for t, c, r in f.veh.acks_sent if c == 176 and t >= st[-2].t - DT]
        assert results[:2] == [0, 1]  # POSCTL: accepted, then rejected
        assert st[-1].state == final
        if final == "DONE":
            assert f.bridge.machine.confirmed_mode == px4.HOLD and f.veh.mode == px4.HOLD
            assert (
                "POSCTL (command 176) accepted, then rejected: TEMPORARILY_REJECTED"
                in st[-1].reason
            )
            assert results[2:4] == [0, 0]  # HOLD: accepted twice
            assert abs(f.veh.x[2] - z_abort) < 0.3 and not f.veh.failsafe_reason  # no failsafe
        else:
            assert st[-1].level == "error" and st[-1].reason.startswith(
                "hand-back NOT confirmed: POSCTL"
            )
            assert f.bridge.machine.confirmed_mode is None
            # what fooled the old bridge: the HEARTBEAT shows POSCTL, but it is PX4's failsafe
            assert f.bridge.machine.vehicle_mode == px4.POSCTL and f.veh.descending
            assert f.veh.x[2] > z_abort + 1.5  # descending at MPC_LAND_SPEED
    finally:
        f.close()


# ----------------------------------------------------- 2. offboard-loss failsafe
@pytest.mark.parametrize(
    "act, shown, nav", [(0, px4.POSCTL, 2), (1, px4.ALTCTL, 1), (2, px4.STABILIZED, 15)]
)
def test_offboard_loss_stick_mode_without_rc_is_an_uncontrolled_descent(gcs, act, shown, nav):
    g = gcs(params={"COM_OBL_RC_ACT": act}, stream_rates=QUIET)
    _fly_to_5m_at_1ms(g)
    g.sp = None  # the companion dies
    t_stop, t_last_sp = g.t, g.veh.setpoint.t
    g.run(t_stop + 16.0, record=True)
    t_fs, mode, reason = next(e for e in g.veh.mode_log if e[0] > t_stop)
    assert mode == shown.name and 1.0 < t_fs - t_last_sp <= 1.0 + 2 * DT  # COM_OF_LOSS_T
    assert (t_fs, f"Matching flight task was not able to run, Nav state: {nav}") in g.veh.px4_log
    # HEARTBEAT: the failsafe mode, critical, until the landing's auto-disarm ends the failsafe
    (t_dis,) = [t for t, m, _ in g.veh.mode_log if m == "DISARMED"]
    hbs = [m for t, m in g.msgs if m.get_type() == "HEARTBEAT" and t_fs < t < t_dis]
    assert len(hbs) >= 9 and {px4.decode_custom_mode(h.custom_mode) for h in hbs} == {shown}
    assert {h.system_status for h in hbs} == {5}  # MAV_STATE_CRITICAL
    tr = [(t, x) for t, x in g.trace if t > t_fs]
    z = np.array([x[2] for _, x in tr])
    vz = np.diff(z) / DT
    mid = (z[1:] < -1.0) & (z[1:] > -3.5)
    assert (
        abs(float(np.mean(vz[mid])) - PARAMS["MPC_LAND_SPEED"].default) < 0.05
    )  # FlightTaskDescend
    tilt = max(float(np.max(np.abs(x[3:5]))) for t, x in tr if t > t_fs + 1.0 and x[2] < -0.2)
    assert math.degrees(tilt) < 2.0  # level attitude
    p0 = tr[0][1][0:2]
    x_land = next(x for t, x in tr if x[2] >= 0.0)
    assert np.linalg.norm(x_land[0:2] - p0) > 3.0  # nothing held the position
    assert t_dis - g.veh.t_landed == pytest.approx(2.0, abs=2 * DT)  # COM_DISARM_LAND
    # measured on PX4 v1.16 SIH: "Disarmed by landing", then the HEARTBEAT shows OFFBOARD again
    assert g.veh.landed and not g.veh.armed and g.veh.mode == px4.OFFBOARD
    assert g.hb_mode(t_dis + 0.01) == (px4.OFFBOARD, False)


def test_offboard_loss_hold_holds_altitude_and_land_lands(gcs):
    g = gcs(params={"COM_OBL_RC_ACT": 5}, stream_rates=QUIET)
    _fly_to_5m_at_1ms(g)
    z0 = g.veh.x[2]
    g.sp = None
    t_stop = g.t
    g.run(t_stop + 12.0, record=True)
    assert [m for t, m, _ in g.veh.mode_log if t > t_stop] == ["HOLD"]
    assert not any("Matching flight task" in m for _, m in g.veh.px4_log)
    z = np.array([x[2] for _, x in g.trace])
    assert float(np.max(np.abs(z - z0))) < 0.5  # altitude held within 0.5 m
    assert np.linalg.norm(g.trace[-1][1][6:9]) < 0.05 and g.hb_mode(g.t - 1.0) == (px4.HOLD, True)
    g4 = gcs(params={"COM_OBL_RC_ACT": 4}, stream_rates=QUIET)
    _fly_to_5m_at_1ms(g4)
    g4.sp = None
    t_stop = g4.t
    g4.run(t_stop + 12.0)
    assert [m for t, m, _ in g4.veh.mode_log if t > t_stop] == ["LAND", "DISARMED", "OFFBOARD"]
    assert g4.veh.landed and not g4.veh.armed
    assert px4.LAND in {
        px4.decode_custom_mode(h.custom_mode) for h in g4.of("HEARTBEAT", t_stop + 1.5)
    }


# --------------------------------------------------- 3. 1 Hz HEARTBEAT, streams
def test_heartbeat_1hz_attitude_both_and_odometry_stamped_before_attitude(gcs):
    g = gcs()
    g.run(10.0)
    hbs = [t for t, m in g.msgs if m.get_type() == "HEARTBEAT"]
    assert len(hbs) in (10, 11) and np.allclose(np.diff(hbs), 1.0, atol=2 * DT)
    counts = {
        n: len(g.of(n, 5.0))
        for n in ("ATTITUDE", "ATTITUDE_QUATERNION", "ODOMETRY", "LOCAL_POSITION_NED")
    }
    # PX4 v1.16 onboard-link rates over 5 s: ATTITUDE 100 Hz and ATTITUDE_QUATERNION 50 Hz both
    assert abs(counts["ATTITUDE"] - 500) <= 5 and abs(counts["ATTITUDE_QUATERNION"] - 250) <= 3
    assert abs(counts["ODOMETRY"] - 150) <= 3 and abs(counts["LOCAL_POSITION_NED"] - 150) <= 3
    # ODOMETRY: EKF2 frame conventions; its stamp lags the attitude stamp of the same state
    last_aq = None
    behind = 0
    for _, m in g.msgs:
        if m.get_type() == "ATTITUDE_QUATERNION":
            last_aq = m.time_boot_ms * 1e-3
        elif m.get_type() == "ODOMETRY" and last_aq is not None:
            assert m.frame_id == 1 and m.child_frame_id == 1 and m.estimator_type == 8
            behind += m.time_usec * 1e-6 < last_aq
    assert behind > 0.3 * counts["ODOMETRY"]  # a naive decoder sees disorder
    # sent in the same vehicle step: ODOMETRY stamped odometry_lag_s (4 ms) before the attitude
    by_step: dict = {}
    for t, m in g.msgs:
        by_step.setdefault(t, {})[m.get_type()] = m
    pairs = [
        (d["ATTITUDE_QUATERNION"].time_boot_ms * 1e-3, d["ODOMETRY"].time_usec * 1e-6)
        for d in by_step.values()
        if "ATTITUDE_QUATERNION" in d and "ODOMETRY" in d
    ]
    assert len(pairs) > 10
    assert all(abs(t_aq - t_odo - 0.004) <= 1e-3 + 1e-6 for t_aq, t_odo in pairs)  # ms truncation


def test_odometry_content_matches_the_state(gcs):
    g = gcs(stream_rates={"ODOMETRY": 30.0})
    _offboard_armed(g)
    g.sp = (0.0, 0.0, -1.0)
    g.run(g.t + 2.0)
    odo = g.of("ODOMETRY")[-1]
    # sent in the last step: same state as the vehicle's (within one physics step)
    x = g.veh.x
    v_ned = g.veh._R(x) @ x[6:9]
    np.testing.assert_allclose([odo.x, odo.y, odo.z], x[0:3], atol=2 * DT * 1.1)
    np.testing.assert_allclose([odo.vx, odo.vy, odo.vz], v_ned, atol=0.02)


# ---------------------------------------------------- 4. mode survives auto-disarm
def test_auto_disarm_keeps_offboard_in_the_heartbeat(gcs):
    g = gcs(params={"COM_DISARM_PRFLT": 2.0}, stream_rates=QUIET)
    _offboard_armed(g)  # on the ground, no takeoff
    t_arm = g.veh.t_armed
    g.run(t_arm + 2.5)
    dis = [t for t, m, _ in g.veh.mode_log if m == "DISARMED"]
    assert len(dis) == 1 and 2.0 < dis[0] - t_arm <= 2.0 + 2 * DT and not g.veh.armed
    g.sp = None  # the stream stops too
    g.run(g.t + 5.0)
    assert g.veh.mode == px4.OFFBOARD and g.hb_mode(g.t - 1.1) == (px4.OFFBOARD, False)
    assert not g.veh.failsafe_reason  # no failsafe while disarmed
    t0 = g.t
    g.link.command_long(176, 1.0, 4.0, 3.0)  # someone changes the mode
    g.run(g.t + 1.2)
    assert g.acks(176, t0) == [0, 0] and g.hb_mode(t0 + 0.1)[0] == px4.HOLD


# --------------------------------------------------- 5. no ESC telemetry: outputs
@pytest.mark.parametrize("scale", ["pwm", "normalized"])
def test_no_esc_telemetry_motor_outputs_instead(gcs, scale):
    g = gcs(esc_telemetry=False, actuator_output_scale=scale)
    g.run(1.0)
    assert g.of("SERVO_OUTPUT_RAW") and not g.of("ACTUATOR_OUTPUT_STATUS")  # PX4: off by default
    assert all(m.servo1_raw == m.servo4_raw == 900 for m in g.of("SERVO_OUTPUT_RAW"))  # disarmed
    for name, rate in (("ACTUATOR_OUTPUT_STATUS", 50.0), ("ESC_STATUS", 50.0)):
        g.link.command_long(511, float(getattr(MOD, f"MAVLINK_MSG_ID_{name}", 291)), 1e6 / rate)
    g.link.command_long(512, 291.0)  # REQUEST_MESSAGE ESC_STATUS
    _offboard_armed(g)
    g.sp = (0.0, 0.0, -1.0)
    g.run(g.t + 2.0)
    g.sp = (0.0, 0.0, 0.0)
    g.run(g.t + 3.0, outputs=True)
    assert g.acks(511) == [0, 0] and g.acks(512) == [px4.MAV_RESULT_FAILED]
    assert not g.of("ESC_STATUS")  # configured, never sent
    aos = [m for m in g.of("ACTUATOR_OUTPUT_STATUS") if m.time_usec in g.outputs]
    srs = [m for m in g.of("SERVO_OUTPUT_RAW") if m.time_usec in g.outputs]
    assert len(aos) > 100 and len(srs) > 20
    for m in aos:
        u_esc, pwm = g.outputs[m.time_usec]
        want = pwm if scale == "pwm" else u_esc
        assert m.active == 16  # as PX4 v1.16 SIH reports
        np.testing.assert_allclose(m.actuator[:4], want, rtol=1e-6, atol=1e-4)
        assert (
            m.actuator[4:16] == [900.0 if scale == "pwm" else 0.0] * 12
            and m.actuator[16:] == [0.0] * 16
        )
    for m in srs:
        u_esc, _ = g.outputs[m.time_usec]
        raw = [getattr(m, f"servo{i}_raw") for i in range(1, 17)]
        np.testing.assert_allclose(raw[:4], 1000.0 + 1000.0 * u_esc, atol=0.5)  # PWM 1000..2000 us
        assert raw[4:] == [900] * 12  # unused outputs idle
    # hovering: the rotor speeds sit at the Eq. (8) steady state b/a * u_ESC of the outputs
    u_esc, _ = g.veh.motor_outputs()
    p = g.veh.model.params
    np.testing.assert_allclose(g.veh.x[12:16], p.b_omega / p.a_omega * u_esc, rtol=0.01)
    assert 0.3 < float(np.mean(u_esc)) < 0.8


def test_esc_telemetry_default_reports_rotor_speeds(gcs):
    g = gcs()
    g.run(0.5)
    esc = g.of("ESC_STATUS")
    assert len(esc) in (4, 5, 6) and esc[-1].rpm == [0, 0, 0, 0]  # 10 Hz, motors off


# ---------------------------------------------------- issue 12 item 7: hardening
def test_param_set_validation_refuses_nan_inf_and_out_of_range(gcs):
    g = gcs()
    g.run(0.3)
    R32, I32 = px4.MAV_PARAM_TYPE_REAL32, px4.MAV_PARAM_TYPE_INT32
    bad = [
        ("COM_OF_LOSS_T", float("nan"), R32),
        ("COM_OF_LOSS_T", float("inf"), R32),
        ("COM_OF_LOSS_T", -1.0, R32),
        ("COM_OF_LOSS_T", 61.0, R32),
        ("COM_OBL_RC_ACT", 8, I32),
        ("COM_OBL_RC_ACT", -1, I32),
        ("COM_RC_IN_MODE", 5, I32),
        ("NAV_DLL_ACT", 4, I32),
    ]
    for name, value, ptype in bad:
        before = g.veh.param(name)
        t0 = g.t
        g.param_set(name, value, ptype)
        g.run(g.t + 0.05)
        (pv,) = [m for m in g.of("PARAM_VALUE", t0) if px4.param_id_str(m.param_id) == name]
        assert px4.param_from_wire(pv.param_value, pv.param_type) == before == g.veh.param(name), (
            name,
            value,
        )
    assert len(g.veh.param_rejections) == len(bad)
    assert "not a finite number" in g.veh.param_rejections[0][1]
    assert "outside [0, 60]" in g.veh.param_rejections[3][1]
    # an INT32 sent as a plain float (not PX4's byte-wise encoding) is refused, not misread
    t0 = g.t
    g.link.send(g.link.codec.param_set_encode(1, 1, b"COM_OBL_RC_ACT", 5.0, I32))
    g.run(g.t + 0.05)
    assert g.veh.param("COM_OBL_RC_ACT") == 0
    # valid values are taken
    g.param_set("COM_OF_LOSS_T", 0.5, R32)
    g.param_set("COM_OBL_RC_ACT", 5, I32)
    g.run(g.t + 0.05)
    assert g.veh.param("COM_OF_LOSS_T") == 0.5 and g.veh.param("COM_OBL_RC_ACT") == 5
    # the same rules for the configuration
    for params, match in (
        ({"COM_OF_LOSS_T": float("nan")}, "finite"),
        ({"COM_OBL_RC_ACT": 9}, "not one of"),
        ({"COM_OBL_RC_ACT": 2.5}, "integer"),
        ({"COM_OF_LOSS_T": 100.0}, "outside"),
    ):
        with pytest.raises(ConfigError, match=match):
            SimVehicleConfig(params=params).validate()


def test_default_bind_is_loopback_not_all_interfaces():
    import argparse

    from lpv_sysid.cli.vehicle import sim_vehicle as cli

    p = argparse.ArgumentParser()
    cli.add_arguments(p)
    cfg = cli.build_config(p.parse_args([]))
    assert cfg.url == "udpout:127.0.0.1:14540" and cfg.bind is None
    port = free_udp_port()
    veh = SimVehicle(SimVehicleConfig(url=f"udpout:127.0.0.1:{port}"))
    veh.open()
    try:
        assert (
            veh.local_address[0] == "127.0.0.1" and veh.local_address[1] > 0
        )  # bound before sending
        veh.step(0.01)
        assert veh.link.conn.port.getsockname() == veh.local_address
    finally:
        veh.close()
    veh = SimVehicle(
        SimVehicleConfig(url=f"udpout:127.0.0.1:{port}", bind=f"127.0.0.1:{free_udp_port()}")
    )
    veh.open()
    try:
        assert veh.local_address[0] == "127.0.0.1"
    finally:
        veh.close()
    with pytest.raises(ConfigError, match="port"):
        SimVehicleConfig(bind="127.0.0.1:notaport").validate()


def test_cli_sim_vehicle_binds_loopback_and_reports_it():
    port = free_udp_port()
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "lpv_sysid.cli",
            "sim-vehicle",
            "--udp",
            f"127.0.0.1:{port}",
            "--duration",
            "0.3",
            "--speed",
            "5",
            "--no-esc-telemetry",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "PYTHONPATH": ROOT},
    )
    assert r.returncode == 0, r.stderr
    assert "local socket 127.0.0.1:" in r.stdout and "ESC telemetry off" in r.stdout
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "lpv_sysid.cli",
            "sim-vehicle",
            "--udp",
            f"127.0.0.1:{port}",
            "--duration",
            "0.3",
            "--param",
            "COM_OF_LOSS_T=nan",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "PYTHONPATH": ROOT},
    )
    assert r.returncode == 2 and "COM_OF_LOSS_T" in r.stderr and "finite" in r.stderr


@pytest.mark.parametrize(
    "url, warns",
    [
        ("udpin:0.0.0.0:{p}", True),
        ("udp://:{p}", True),
        ("udpin://:{p}", True),
        ("udpin:127.0.0.1:{p}", False),
    ],
)
def test_all_interface_urls_are_warned_about(caplog, url, warns):
    link = MavlinkLink(LinkConfig(url=url.format(p=free_udp_port())))
    with caplog.at_level(logging.WARNING, logger="lpv_sysid.mavlink.link.url"):
        link.open(0.0)
    link.close()
    hit = [r for r in caplog.records if "ALL network interfaces" in r.getMessage()]
    assert bool(hit) is warns
    if warns:
        assert "MAVLink signing" in hit[0].getMessage() and "127.0.0.1" in hit[0].getMessage()


def test_signing_on_refuses_unsigned_param_set_commands_and_setpoints(gcs, tmp_path):
    key = tmp_path / "vehicle.key"
    key.write_bytes(os.urandom(32))
    g = gcs(signing_key_file=str(key))  # a foreign, unsigned GCS
    g.run(0.3)
    g.param_set("COM_OF_LOSS_T", float("nan"), px4.MAV_PARAM_TYPE_REAL32)
    g.param_set("COM_OBL_RC_ACT", 7, px4.MAV_PARAM_TYPE_INT32)  # valid value, but unsigned
    g.link.command_long(400, 1.0)
    g.sp = (0.0, 0.0, -1.0)
    g.run(2.0)
    assert g.veh.param("COM_OF_LOSS_T") == 1.0 and g.veh.param("COM_OBL_RC_ACT") == 0
    assert not g.veh.armed and g.veh.setpoints_received == 0 and g.veh.link.stats.rx_messages == 0
    assert g.veh.link.stats.bad_signature > 30 and not g.veh.acks_sent
    assert g.veh.param_rejections == []  # never even parsed
    # the owner signs with the vehicle's key: accepted
    own = gcs(signing_key_file=str(key), gcs_key=str(key))
    own.run(0.3)
    own.param_set("COM_OBL_RC_ACT", 5, px4.MAV_PARAM_TYPE_INT32)
    own.run(0.6)
    assert own.veh.param("COM_OBL_RC_ACT") == 5 and own.veh.link.codec.signing.goodsig_count > 0
    # allow_unsigned: the operator's explicit choice
    lax = gcs(signing_key_file=str(key), allow_unsigned=True)
    lax.run(0.3)
    lax.param_set("COM_OBL_RC_ACT", 4, px4.MAV_PARAM_TYPE_INT32)
    lax.run(0.6)
    assert lax.veh.param("COM_OBL_RC_ACT") == 4


def test_sim_vehicle_config_file_and_errors(tmp_path):
    cfg = SimVehicleConfig.load(os.path.join(ROOT, "config", "sim_vehicle_px4.yaml"))
    assert cfg == SimVehicleConfig()  # the file documents the defaults
    for d, match in (
        ({"actuator_output_scale": "dshot"}, "actuator_output_scale"),
        ({"stream_rates": {"NOPE": 1.0}}, "NOPE"),
        ({"stream_rates": {"ODOMETRY": -1}}, "ODOMETRY"),
        ({"rc_present": "yes"}, "rc_present"),
        ({"verdict_delay_s": 5.0}, "verdict_delay_s"),
        ({"bogus": 1}, "bogus"),
    ):
        with pytest.raises(ConfigError, match=match):
            SimVehicleConfig.from_dict(d)
    bad = tmp_path / "bad.yaml"
    bad.write_text("params: {COM_OF_LOSS_T: .nan}\n")
    with pytest.raises(ConfigError, match="bad.yaml.*COM_OF_LOSS_T"):
        SimVehicleConfig.load(str(bad))


def test_cli_config_file_and_flags(tmp_path):
    import argparse

    from lpv_sysid.cli.vehicle import sim_vehicle as cli

    p = argparse.ArgumentParser()
    cli.add_arguments(p)
    f = tmp_path / "veh.yaml"
    f.write_text(
        "url: udpout:127.0.0.1:14999\nesc_telemetry: false\nparams: {COM_OBL_RC_ACT: 5}\n"
    )
    cfg = cli.build_config(p.parse_args(["--config", str(f)]))
    assert (
        cfg.url == "udpout:127.0.0.1:14999"
        and not cfg.esc_telemetry
        and cfg.params == {"COM_OBL_RC_ACT": 5}
    )
    cfg = cli.build_config(
        p.parse_args(
            [
                "--config",
                str(f),
                "--udp",
                "127.0.0.1:15000",
                "--rc",
                "--param",
                "COM_OF_LOSS_T=0.5",
                "--bind",
                "127.0.0.1",
            ]
        )
    )
    assert cfg.url == "udpout:127.0.0.1:15000" and cfg.rc_present and cfg.bind == "127.0.0.1"
    assert cfg.params == {"COM_OBL_RC_ACT": 5, "COM_OF_LOSS_T": 0.5}  # flags add to the file
    with pytest.raises(ConfigError, match="COM_OBL_RC_ACT"):
        cli.build_config(p.parse_args(["--param", "COM_OBL_RC_ACT=5.5"]))


#: a command-line flag inside a string (``--bind``), not ``udp://`` or an en dash
CLI_FLAG = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]+")
MAVLINK_CORES = sorted(
    p
    for folder in ("sim/px4_vehicle", "mavlink/link")
    for p in (Path(ROOT) / "lpv_sysid" / folder).glob("*.py")
)


def test_vehicle_and_link_errors_name_no_command_line_flag():
    """Cores name the configuration field; the sim-vehicle command maps it to its flag."""
    raised = {
        (path.name, c.value)
        for path in MAVLINK_CORES
        for node in ast.walk(ast.parse(path.read_text()))
        if isinstance(node, ast.Raise) and node.exc is not None
        for c in ast.walk(node.exc)
        if isinstance(c, ast.Constant) and isinstance(c.value, str)
    }
    # the scan sees the wording of the no-route error (it named --bind before)
    assert any("HOST[:PORT]" in text for _, text in raised)
    assert not [(name, text) for name, text in raised if CLI_FLAG.search(text)]


def test_unroutable_destination_names_the_bind_field_and_the_cli_its_flag(tmp_path):
    import argparse

    from lpv_sysid.cli.vehicle import sim_vehicle as cli

    # a UDP connect() to the broadcast address without SO_BROADCAST is refused locally
    # (EACCES): no route to report, and not a datagram leaves the machine
    url = "udpout:255.255.255.255:14540"
    veh = SimVehicle(SimVehicleConfig(url=url))
    with pytest.raises(LpvSysidError, match=r"no local interface routes to") as ei:
        veh.open()
    assert "in the bind field (HOST[:PORT])" in str(ei.value) and "--" not in str(ei.value)
    veh.close()
    p = argparse.ArgumentParser()
    cli.add_arguments(p)
    with pytest.raises(LpvSysidError, match=r"bind field \(HOST\[:PORT\]\) \[--bind\]$"):
        cli.run(p.parse_args(["--connect", url, "--duration", "0.1"]))
    # a bad value from the flag names the flag, the same value from a file does not
    with pytest.raises(ConfigError, match=r"bind .*notaport.* \[--bind\]$"):
        cli.build_config(p.parse_args(["--bind", "127.0.0.1:notaport"]))
    f = tmp_path / "veh.yaml"
    f.write_text('bind: "127.0.0.1:notaport"\n')
    with pytest.raises(ConfigError, match="notaport") as ei:
        cli.build_config(p.parse_args(["--config", str(f)]))
    assert "--bind" not in str(ei.value)
    assert cli.with_flag("sim vehicle physics_hz must be in [50, 1000] Hz, got 1") == (
        "sim vehicle physics_hz must be in [50, 1000] Hz, got 1 [--physics-hz]"
    )
    assert cli.with_flag("sim vehicle seed must be a non-negative integer") == (
        "sim vehicle seed must be a non-negative integer"  # no flag sets seed
    )
