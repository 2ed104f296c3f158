"""transport mavros (mavros_msgs) against a real MAVROS 2 connected to PX4 SITL (SIH).

Needs a sourced ROS 2 Jazzy with the ``mavros`` package (``ros_real.find_ros``, then
``ros2 pkg prefix mavros``) and ``PX4_SITL_DIR``; each missing peer skips with one line.
PX4 instance 7 sends its offboard link from UDP 14587 to 127.0.0.1:14547; MAVROS takes
``fcu_url:=udp://:14547@127.0.0.1:14587`` and ``tgt_system:=8`` (SITL MAV_SYS_ID is
1 + instance), with the package's ``config/mavros_px4.yaml`` (setpoint_raw thrust_scaling).

The flight (a driver script under ROS's python talking to the bridge node like an
operator): stream zero velocity references, call ``start``: refused by the preflight
through MAVROS (PX4 SITL's default COM_OBL_RC_ACT 0, Position, without stick input is
NO-GO); set COM_OBL_RC_ACT 5 (Hold) through MAVROS's param node, ``start`` again; the
bridge switches to OFFBOARD and arms through ``/mavros/set_mode`` and
``/mavros/cmd/arming``, confirmed by ``/mavros/state``; phase 1 climbs on velocity
setpoints (``/mavros/setpoint_raw/local``) for a few seconds; ``abort`` hands back with
the chain POSCTL, HOLD, LAND. Without RC PX4 refuses POSCTL (the commander's verdict is
not visible through MAVROS's SET_MODE, whose service answers ``mode_sent`` at once):
``/mavros/state`` never shows it, the bridge moves on after ``mode_confirm_timeout`` and
ends DONE only once the state shows HOLD.
Oracles: PX4's own mode reports on ``/mavros/state`` recorded by the driver, the altitude
of ``/lpv_sysid/state``. Timeouts are generous and bounded (2 cores, load ~10).
"""

from __future__ import annotations

import json
import shlex
import subprocess
from pathlib import Path

import pytest
from px4_sitl import Px4Sitl, find_px4
from ros_real import DomainId, RosEnv, build_package, find_ros

ROOT = Path(__file__).resolve().parents[1]
INSTANCE = 7


def _mavros(setup) -> str:
    """'' when the sourced ROS has the mavros package, else the reason to skip."""
    r = subprocess.run(
        ["bash", "-c", f"source {shlex.quote(str(setup))} >/dev/null && ros2 pkg prefix mavros"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    return "" if r.returncode == 0 else f"MAVROS not available in {setup} (ros2 pkg prefix mavros)"


def _peers() -> tuple:
    setup, why = find_ros()
    if setup is None:
        return None, None, why
    px4_dir, why = find_px4()
    if px4_dir is None:
        return None, None, why
    why = _mavros(setup)
    return (setup, px4_dir, "") if not why else (None, None, why)


SETUP, PX4_DIR, SKIP_REASON = _peers()
pytestmark = pytest.mark.skipif(SETUP is None, reason=SKIP_REASON)

DRIVER = r'''
import json, sys, time
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistStamped
from mavros_msgs.msg import PositionTarget, State
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import Parameter, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.qos import qos_profile_sensor_data
from std_srvs.srv import Trigger

rclpy.init()
n = rclpy.create_node("mavros_real_driver")
res = {"modes": [], "states": [], "z": [], "setpoints": 0, "reasons": []}
def on_state(m):
    if not res["modes"] or res["modes"][-1] != [m.mode, m.armed]:
        res["modes"].append([m.mode, m.armed])
def on_status(m):
    for s in m.status:
        v = {kv.key: kv.value for kv in s.values}
        st = v.get("state")
        if st and (not res["states"] or res["states"][-1] != st):
            res["states"].append(st)
            res["reasons"].append(v.get("reason", ""))
n.create_subscription(State, "/mavros/state", on_state, qos_profile_sensor_data)
n.create_subscription(DiagnosticArray, "/lpv_sysid/status", on_status, 100)
n.create_subscription(
    Odometry, "/lpv_sysid/state", lambda m: res["z"].append(m.pose.pose.position.z),
    qos_profile_sensor_data)
def on_sp(m):
    res["setpoints"] += 1
    res["last_sp"] = [m.coordinate_frame, m.type_mask, m.velocity.x, m.velocity.y, m.velocity.z]
n.create_subscription(PositionTarget, "/mavros/setpoint_raw/local", on_sp, 10)
ref = n.create_publisher(TwistStamped, "/lpv_sysid/velocity_reference", 10)
vz = [0.0]
def tick():
    m = TwistStamped()
    m.header.stamp = n.get_clock().now().to_msg()
    m.header.frame_id = "base_link"
    m.twist.linear.z = vz[0]   # FLU: + is up
    ref.publish(m)
n.create_timer(0.05, tick)

def spin(seconds, until=None):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        rclpy.spin_once(n, timeout_sec=0.05)
        if until is not None and until():
            return True
    return False

def call(name):
    c = n.create_client(Trigger, "/lpv_sysid/mavlink_bridge/" + name)
    assert c.wait_for_service(timeout_sec=60.0), name
    f = c.call_async(Trigger.Request())
    spin(30.0, until=f.done)
    return [f.result().success, f.result().message] if f.done() else [False, "no answer"]

def set_px4_param(name, value):
    """Through MAVROS's param node (it sets the FCU parameter and mirrors the answer)."""
    c = n.create_client(SetParameters, "/mavros/param/set_parameters")
    assert c.wait_for_service(timeout_sec=60.0)
    v = ParameterValue(type=2, integer_value=value)
    f = c.call_async(SetParameters.Request(parameters=[Parameter(name=name, value=v)]))
    spin(60.0, until=f.done)
    return f.done() and all(r.successful for r in f.result().results)

def state():
    return res["states"][-1] if res["states"] else ""

spin(120.0, until=lambda: any(m[0] for m in res["modes"]) and len(res["z"]) > 10)
spin(20.0)                       # MAVROS pulls PX4's parameters after connecting
# PX4 SITL's default COM_OBL_RC_ACT 0 (Position) without stick input: NO-GO
res["start_nogo"] = call("start")
res["param_set"] = set_px4_param("COM_OBL_RC_ACT", 5)
spin(15.0)                       # the bridge refreshes the parameters every 10 s
res["start"] = call("start")
res["active"] = spin(90.0, until=lambda: state() in ("OFFBOARD_ACTIVE", "FAILED", "DONE"))
t_active = time.monotonic()
vz[0] = 1.0                      # phase 1: climb on velocity setpoints
spin(5.0)
vz[0] = 0.0
spin(3.0)
res["flown_s"] = time.monotonic() - t_active
res["sp_active"] = res["setpoints"]
res["abort"] = call("abort")
res["ended"] = spin(120.0, until=lambda: state() in ("DONE", "FAILED"))
spin(3.0)
print("RESULT " + json.dumps(res))
'''


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    base = tmp_path_factory.mktemp("mavros_real")
    ws = build_package(SETUP, base / "ws")
    share = ws / "install" / "lpv_sysid" / "share" / "lpv_sysid" / "config"
    dom = DomainId(start=70)
    env = RosEnv(SETUP, ws, dom.value)
    yield {"env": env, "share": share, "dir": base}
    dom.release()


def test_phase1_offboard_and_rejected_posctl_handback_through_real_mavros(stack):
    env, share, d = stack["env"], stack["share"], stack["dir"]
    procs = []
    try:
        with Px4Sitl(PX4_DIR, instance=INSTANCE, boot_timeout=180.0) as px4:
            port = 14540 + INSTANCE
            mavros = env.popen(
                "ros2 run mavros mavros_node --ros-args -r __ns:=/mavros "
                f"--params-file {share / 'mavros_px4.yaml'} "
                f"-p fcu_url:=udp://:{port}@127.0.0.1:{port + 40} -p tgt_system:={INSTANCE + 1}",
                d / "mavros.log",
            )
            procs.append(mavros)
            bridge = env.popen(
                "ros2 run lpv_sysid mavlink_bridge_node --ros-args -r __ns:=/lpv_sysid "
                f"--params-file {share / 'mavlink_bridge_node.yaml'} "
                "-p transport:=mavros -p mavros.interfaces:=mavros_msgs -p command:=velocity "
                "-p offboard.arm:=true -p offboard.mode_confirm_timeout:=5.0 "
                "-p offboard.ack_timeout:=2.0 -p offboard.input_timeout:=1.0 "
                "-p 'offboard.handback_chain:=[POSCTL, HOLD, LAND]'",
                d / "bridge.log",
            )
            procs.append(bridge)
            (d / "driver.py").write_text(DRIVER)
            r = env.run(f"python3 {d / 'driver.py'}", timeout=600.0)
            line = [x for x in r.stdout.splitlines() if x.startswith("RESULT ")]
            logs = f"{r.stderr[-2000:]}\n--- bridge\n{bridge.log()[-4000:]}\n--- mavros\n" + (
                mavros.log()[-2000:] + "\n--- px4\n" + px4.log_tail(40)
            )
            assert line, logs
            res = json.loads(line[0][len("RESULT ") :])
    finally:
        for p in procs:
            p.sigint()
        for p in procs:
            try:
                p.wait(timeout=60.0)
            except subprocess.TimeoutExpired:
                p.kill()
    print("MAVROS real:", json.dumps({k: v for k, v in res.items() if k != "z"}))
    states, modes = res["states"], [m[0] for m in res["modes"]]
    # preflight through MAVROS: NO-GO with PX4's default offboard-loss action, GO with Hold
    ok, why = res["start_nogo"]
    assert not ok and "COM_OBL_RC_ACT: 0 (POSITION)" in why, (why, logs)
    assert res["param_set"] and res["start"][0], (res["start"], logs)
    assert res["active"] and "OFFBOARD_ACTIVE" in states, logs
    # OFFBOARD and arming confirmed by /mavros/state, as PX4 reported them
    assert ["OFFBOARD", True] in res["modes"], res["modes"]
    # phase 1 flew: velocity setpoints in BODY_NED with velocity + yaw rate, and a climb
    assert res["sp_active"] > 100 and res["last_sp"][:2] == [8, 0x07C7], res
    assert max(res["z"]) - res["z"][0] > 1.0, (res["z"][0], max(res["z"]))  # ENU z: up
    # hand-back: POSCTL never shown (refused without RC), then HOLD shown and confirmed
    assert res["ended"] and states[-1] == "DONE", (states, res["reasons"])
    final = res["reasons"][-1]
    assert "hand-back confirmed: vehicle in HOLD" in final, final
    assert "POSCTL" not in modes and "after POSCTL" in final, (modes, final)
    assert modes[-1] == "AUTO.LOITER"
