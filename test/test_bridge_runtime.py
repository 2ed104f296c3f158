"""flight/bridge/runtime.py and flight/bridge/settings.py directly: no rclpy, no stand-in.

The message-level behaviour of mavlink_bridge_node (transport selection, MAVROS
republishing and setpoint stream, stale-input stop, status content, hand-back bound) on
rosbags messages and explicit clock values; oracles: the rotation body FRD -> local ENU
worked by hand, the configured timeouts, the hand-back rule of mavlink/offboard/machine.py.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys

import numpy as np
import pytest

from lpv_sysid.flight.bridge import PARSERS, SPECS, BridgeRuntime
from lpv_sysid.io import messages
from lpv_sysid.mavlink.link import LinkEvent
from lpv_sysid.mavlink.offboard import StatusEvent

F = messages.MsgFactory.rosbags()
NAME = "/lpv_sysid/mavlink_bridge"
DEFAULTS = {n: d for n, (d, _) in SPECS.items()}
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def runtime(sigterm_timeout_s=15.0, teardown_margin_s=3.0, **overrides):
    return BridgeRuntime({**DEFAULTS, **overrides}, F, NAME, sigterm_timeout_s, teardown_margin_s)


def status_of(out):
    """The one ``status`` array of ``out`` -> its DiagnosticStatus (StatusSample)."""
    (msg,) = [m for k, m in out if k == "status"]
    _, (st,) = messages.status_from_diagnostic_array(msg)
    return st


def odom(t, yaw, frame_id="map"):
    pos, zero = [1.0, 2.0, -3.0], [0.0, 0.0, 0.0]
    return messages.odometry_from_state(
        F, round(t * 1e9), pos, [0.0, 0.0, yaw], zero, zero, frame_id=frame_id
    )


def reference(rt, t, v, r):
    """A ``velocity_reference`` through the parser the shell uses, received at ``t``."""
    msg = messages.twist_reference_msg(F, round(t * 1e9), v, r)
    return rt.on_sample("velocity_reference", PARSERS["velocity_reference"](msg), t)


def test_the_runtime_modules_never_import_rclpy():
    code = (
        "import sys; import lpv_sysid.flight.bridge.runtime, lpv_sysid.flight.campaign.runtime; "
        "print(sorted(m for m in sys.modules if m.split('.')[0] in "
        "('rclpy', 'diagnostic_msgs', 'nav_msgs', 'std_srvs')))"
    )
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_transport_selects_the_endpoints_and_the_timer():
    rt = runtime(transport="mavros")
    assert [(e.key, e.topic, e.qos) for e in rt.publishers] == [
        ("state", "state", ""),
        ("imu", "imu", ""),
        ("cmd_vel", "/mavros/setpoint_velocity/cmd_vel", "reliable"),
    ]
    subs = [(e.key, e.topic, e.qos) for e in rt.subscriptions]
    assert subs[:3] == [
        ("velocity_reference", "velocity_reference", ""),
        ("mavros_odom", "/mavros/local_position/odom", "sensor"),
        ("mavros_imu", "/mavros/imu/data", "sensor"),
    ]
    diagnostics = [("mavros_diagnostics", "/diagnostics", "sensor")]
    assert subs[3:] == (diagnostics if DEFAULTS["mavros.use_diagnostics"] else [])
    # twice the setpoint rate; the shell's default shutdown bound (MAVROS owns no chain)
    assert rt.timer_period_s == 0.5 / DEFAULTS["offboard.setpoint_rate_hz"]
    assert rt.shutdown_timeout_s is None and rt.link is None
    rt = runtime(transport="mavlink", poll_rate_hz=200.0)
    # rate_setpoint: PX4's ATTITUDE_TARGET echo (the data logger records it); vehicle_record:
    # the vehicle record (transient local: the logger's experiment.yaml)
    assert [(e.key, e.qos) for e in rt.publishers] == [
        ("state", ""),
        ("imu", ""),
        ("rotor_speeds", ""),
        ("vehicle_record", "record"),
        ("rate_setpoint", ""),
    ]
    assert [e.key for e in rt.subscriptions] == ["velocity_reference", "actuator_command"]
    assert rt.timer_period_s == 1.0 / 200.0 and rt.mavros is None


def test_handback_bound_and_the_launch_budget_warning():
    chain = {
        "offboard.handback_chain": ["HOLD", "LAND"],
        "offboard.handback_mode": "",
        "offboard.max_retries": 3,
        "offboard.ack_timeout": 0.5,
        "offboard.mode_confirm_timeout": 2.0,
    }
    # two modes x (4 attempts x 0.5 s + 2 s confirmation) + 1 s slack
    rt = runtime(15.0, 3.0, **chain)
    assert rt.shutdown_timeout_s == 9.0
    ((level, text),) = rt.take_log()
    assert level == "info" and text.endswith("hand-back chain ['HOLD', 'LAND'] within 9 s")
    assert rt.take_log() == []
    rt = runtime(10.0, 3.0, **chain)  # 7 s left before SIGTERM < 9 s
    (_, (level, text)) = rt.take_log()
    assert level == "warn" and "more than the 7 s" in text and "sigterm_timeout:=12" in text


def test_status_level_and_message_follow_the_last_warn_or_error_event():
    rt = runtime()
    rt.take_log()
    st = status_of(rt.status(2.5))
    assert (st.level, st.name, st.message) == (0, NAME, "IDLE")
    assert st.values["state"] == "IDLE" and st.values["link_up"] == "False"
    events = [
        LinkEvent(1.0, "link_up", "system 1"),
        StatusEvent(1.1, "IDLE", "PRESTREAM", "start requested", "info"),
        StatusEvent(1.2, "PRESTREAM", "FAILED", "no ACK", "error"),
        LinkEvent(1.3, "link_lost", "no HEARTBEAT for 1.5 s"),
        StatusEvent(1.4, "FAILED", "FAILED", "still failed", "info"),
    ]
    out = rt.status(2.5, events)
    st = status_of(out)
    # the message of the last warn/error event; ERROR stays once reached
    assert (st.level, st.message) == (2, "link_lost: no HEARTBEAT for 1.5 s")
    stamp = [m for k, m in out if k == "status"][0].header.stamp
    assert stamp.sec == 2 and stamp.nanosec == 500_000_000
    assert rt.take_log() == [
        ("info", "link_up: system 1"),
        ("info", "start requested"),
        ("error", "no ACK"),
        ("warn", "link_lost: no HEARTBEAT for 1.5 s"),
        ("info", "still failed"),
    ]
    st = status_of(rt.status(2.5, events[3:4]))
    assert (st.level, st.message) == (1, "link_lost: no HEARTBEAT for 1.5 s")


def test_mavros_reference_is_rotated_to_local_enu_and_a_stale_input_stops_the_stream():
    rt = runtime(transport="mavros")
    timeout = DEFAULTS["offboard.input_timeout"]
    assert rt.on_message("mavros_odom", odom(9.99, math.pi / 2), 9.99)[0][0] == "state"
    ok, message, out = rt.start(10.0)
    assert (
        ok and message == "offboard: PRESTREAM" and status_of(out).values["state"] == "PRESTREAM"
    )
    out = reference(rt, 10.02, [1.0, 0.5, -0.2], 0.1)
    (cmd,) = [m for k, m in out if k == "cmd_vel"]
    # yaw +90 deg: body forward = east, body right = south; ENU up = -down; yaw rate flips
    lin, ang = cmd.twist.linear, cmd.twist.angular
    np.testing.assert_allclose([lin.x, lin.y, lin.z], [1.0, -0.5, 0.2], atol=1e-12)
    assert ang.z == pytest.approx(-0.1, abs=1e-12) and cmd.header.frame_id == "map"
    assert rt.core.state.value == "STREAMING"
    t = 10.02
    while t < 10.02 + timeout - 0.02:  # attitude kept fresh, no new reference
        t = round(t + 0.02, 6)
        rt.on_message("mavros_odom", odom(t, math.pi / 2), t)
        rt.on_timer(t)
    assert rt.core.state.value == "STREAMING"
    stop = round(10.02 + timeout + 0.01, 6)
    rt.on_message("mavros_odom", odom(stop, math.pi / 2), stop)
    out = rt.on_timer(stop)
    st = status_of(out)
    assert rt.core.state.value == "FAILED" and [k for k, _ in out] == ["status"]
    assert st.level == 1 and st.message.startswith(
        f"stale input: no velocity_reference for {stop - 10.02:.3f} s (> {timeout} s)"
    )
    assert rt.on_timer(stop + 0.1) == []  # stopped: no setpoint follows
    assert rt.shutdown_complete()


def test_mavros_bad_odometry_is_counted_and_reported_on_the_next_step():
    rt = runtime(transport="mavros")
    assert rt.on_message("mavros_odom", odom(1.0, 0.0, frame_id="odom"), 1.0) == []
    assert rt.core.rejected_inputs == 1
    st = status_of(rt.on_timer(1.01))
    assert st.level == 2 and st.message.startswith("/mavros/local_position/odom rejected")
    assert "expected frame_id 'map'" in st.message


def test_shutdown_hands_back_once():
    rt = runtime(transport="mavros")
    rt.on_message("mavros_odom", odom(0.9, 0.0), 0.9)
    rt.start(1.0)
    out = rt.shutdown(1.5)
    st = status_of(out)
    assert st.values["state"] == "DONE" and "shutdown" in st.values["reason"]
    assert rt.shutdown_complete() and rt.shutdown_state(1.5).startswith("hand-back DONE: ")
    assert rt.shutdown(1.6) == []  # begin_shutdown then destroy_node: one hand-back


def test_abort_service_stops_the_stream_and_answers_with_the_state():
    rt = runtime(transport="mavros")
    rt.on_message("mavros_odom", odom(0.9, 0.0), 0.9)
    rt.start(1.0)
    ok, message, out = rt.abort(1.1)
    st = status_of(out)
    assert ok and message == "handing control back to PX4: DONE"
    assert st.values["state"] == "DONE" and st.values["reason"].startswith("abort service")
    assert rt.on_timer(1.2) == []  # no setpoint after the abort
