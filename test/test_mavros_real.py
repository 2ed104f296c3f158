"""transport mavros (mavros_msgs) against a real MAVROS 2 connected to PX4 SITL (SIH).

Needs a sourced ROS 2 Jazzy with the ``mavros`` package (``ros_real.find_ros``, then
``ros2 pkg prefix mavros``) and ``PX4_SITL_DIR``; each missing peer skips with one line.
PX4 instance 16 listens on UDP 14596 for its offboard link (it sends to 127.0.0.1:14549,
the port of every instance > 9, until a peer talks to it; MAVROS sends first); MAVROS takes
``fcu_url:=udp://:14556@127.0.0.1:14596`` and ``tgt_system:=17`` (SITL MAV_SYS_ID is
1 + instance), with the package's ``config/mavros_px4.yaml`` (setpoint_raw thrust_scaling).
One PX4 SITL serves the module; the tests run in file order and each starts where the
previous one left the vehicle (the first takes off, the others take it airborne in HOLD).

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
import os
import re
import shlex
import subprocess
from pathlib import Path

import pytest
from px4_sitl import Px4Sitl, find_px4
from ros_real import DomainId, RosEnv, build_package, find_ros
from test_chain_px4 import design  # noqa: F401  (module fixture: rate-plant gains)

ROOT = Path(__file__).resolve().parents[1]
#: the PX4 SITL instance (LPV_SYSID_PX4_INSTANCE: another one when parallel runs share a host)
INSTANCE = int(os.environ.get("LPV_SYSID_PX4_INSTANCE", "16"))


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
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from std_msgs.msg import String
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
def on_record(m):
    res["records"] = res.get("records", 0) + 1
    res["vehicle"] = json.loads(m.data)["vehicle"]
latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
n.create_subscription(String, "/lpv_sysid/vehicle_record", on_record, latched)
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
vz[0] = 2.0                      # phase 1: climb on velocity setpoints (~10 m: the
spin(5.0)                        # launches below fly from there)
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
    """The package built into a colcon workspace, a ROS domain, and one PX4 SITL (instance
    :data:`INSTANCE`) for the whole module."""
    base = tmp_path_factory.mktemp("mavros_real")
    ws = build_package(SETUP, base / "ws")
    share = ws / "install" / "lpv_sysid" / "share" / "lpv_sysid" / "config"
    dom = DomainId(start=55)
    env = RosEnv(SETUP, ws, dom.value)
    try:
        with Px4Sitl(PX4_DIR, instance=INSTANCE, boot_timeout=240.0) as px4:
            yield {"env": env, "share": share, "dir": base, "px4": px4, "airborne": False}
    finally:
        dom.release()


def test_phase1_offboard_and_rejected_posctl_handback_through_real_mavros(stack):
    env, share, d, px4 = stack["env"], stack["share"], stack["dir"], stack["px4"]
    procs = []
    try:
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
            # the group, as a terminal's Ctrl-C: `ros2 run` does not pass a SIGINT of its own
            # on to the node it started, which then waited out the 60 s below and was killed
            p.sigint(group=True)
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
    stack["airborne"] = res["modes"][-1] == ["AUTO.LOITER", True]
    # the vehicle record through MAVROS (vehicle_info_get, param pull/list/get, home):
    # PX4 SITL's own parameters, the one set during the run, its firmware; no boot time
    v = res.get("vehicle")
    assert v is not None, logs
    params = v["px4_parameters"]
    MEASURED_RECORD = {"records": res["records"], "parameters": len(params), "kind": v["kind"]}
    print("MAVROS vehicle record:", json.dumps(MEASURED_RECORD))
    assert v["kind"] == "SITL" and len(params) > 500 and params["SYS_AUTOSTART"] > 0, v["kind"]
    assert params["COM_OBL_RC_ACT"] == 5  # set through MAVROS after the snapshot
    assert v["firmware"]["flight_sw_version"].startswith("v1.1"), v["firmware"]
    assert v["px4_clock"]["boot_ns"] is None and "MAVROS" in v["px4_clock"]["note"]
    assert res["records"] < 30, res["records"]  # on change, not at the 250 Hz poll rate


#: ROS-side driver of a phase launch (``auto_start:=false``): wait until MAVROS is connected
#: and has PX4's parameters (the bridge's preflight reads them through it), call the
#: sequencer's ``start``, watch every node's ``status`` until the excitation has played its
#: signal (or a node gave up), call the sequencer's ``abort`` (the hand-back), wait for the
#: bridge to end DONE or FAILED; PX4's modes as ``/mavros/state`` showed them. One JSON line.
LAUNCH_DRIVER = r"""
import json, sys, time
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from mavros_msgs.msg import State
from mavros_msgs.srv import VehicleInfoGet
from rcl_interfaces.srv import GetParameters
from rclpy.qos import qos_profile_sensor_data
from std_srvs.srv import Trigger

ns, limit = sys.argv[1], float(sys.argv[2])
rclpy.init()
n = rclpy.create_node("mavros_launch_driver")
res = {"modes": [], "states": [], "reasons": [], "phases": [], "armed": False, "abort": ""}
def on_state(m):
    if m.connected and (not res["modes"] or res["modes"][-1] != [m.mode, m.armed]):
        res["modes"].append([m.mode, m.armed])
def on_status(msg):
    for s in msg.status:
        v = {kv.key: kv.value for kv in s.values}
        if s.name.endswith("mavlink_bridge"):
            res["link_up"] = v.get("link_up", "").lower() == "true"
        if s.name.endswith("mavlink_bridge") and v.get("state"):
            if not res["states"] or res["states"][-1] != v["state"]:
                res["states"].append(v["state"])
                res["reasons"].append(v.get("reason", ""))
        elif s.name.endswith("excitation") and v.get("phase"):
            if not res["phases"] or res["phases"][-1] != v["phase"]:
                res["phases"].append(v["phase"])
        elif s.name.endswith("lpv_controller"):
            res["armed"] |= v.get("armed") == "true"
            if v.get("aborted") == "true" and not res["abort"]:
                res["abort"] = s.message
n.create_subscription(State, ns + "/state", on_state, qos_profile_sensor_data)
n.create_subscription(DiagnosticArray, "/lpv_sysid/status", on_status, 100)

def spin(seconds, until=None):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        rclpy.spin_once(n, timeout_sec=0.05)
        if until is not None and until():
            return True
    return False

def call(name):
    c = n.create_client(Trigger, "/lpv_sysid/sequencer/" + name)
    assert c.wait_for_service(timeout_sec=60.0), name
    f = c.call_async(Trigger.Request())
    spin(30.0, until=f.done)
    return [f.result().success, f.result().message] if f.done() else [False, "no answer"]

def have_params():
    c = n.create_client(GetParameters, ns + "/param/get_parameters")
    if not c.wait_for_service(timeout_sec=5.0):
        return False
    f = c.call_async(GetParameters.Request(names=["COM_OBL_RC_ACT"]))
    spin(10.0, until=f.done)
    return f.done() and len(f.result().values) == 1 and f.result().values[0].type == 2

def bridge():
    return res["states"][-1] if res["states"] else ""

def have_info():
    c = n.create_client(VehicleInfoGet, ns + "/vehicle_info_get")
    if not c.wait_for_service(timeout_sec=5.0):
        return False
    f = c.call_async(VehicleInfoGet.Request())
    spin(10.0, until=f.done)
    # MAVROS answers from the HEARTBEAT before it has PX4's AUTOPILOT_VERSION (firmware 0;
    # the bridge asks PX4 for it meanwhile): the preflight needs the firmware
    r = f.result() if f.done() else None
    return bool(r and r.success and r.vehicles and r.vehicles[0].flight_sw_version != 0)

res["connected"] = spin(180.0, until=lambda: bool(res["modes"]) and res.get("link_up"))
t0 = time.monotonic()
while not (have_params() and have_info()) and time.monotonic() - t0 < 180.0:
    spin(3.0)
spin(8.0, until=lambda: False)   # the bridge asks what is missing every 2 s
spin(30.0, until=lambda: res.get("link_up"))  # its /mavros/state fresh at the start
res["start"] = call("start")
spin(limit, until=lambda: (res["phases"] and res["phases"][-1] == "done")
     or bridge() in ("DONE", "FAILED") or bool(res["abort"]))
spin(1.0)
res["abort_call"] = call("abort")
res["ended"] = spin(120.0, until=lambda: bridge() in ("DONE", "FAILED"))
spin(3.0)
print("RESULT " + json.dumps(res))
"""


def _config_dir(share: Path, tmp: Path, edits: dict) -> Path:
    """A copy of the installed config directory with ``edits`` {file: {dotted: value}}
    (the launch files' ``config_dir`` argument)."""
    import shutil

    import yaml

    d = tmp / "config"
    shutil.copytree(share, d)
    for file, overrides in edits.items():
        doc = yaml.safe_load((d / file).read_text())
        (body,) = doc.values()
        for name, value in overrides.items():
            *sections, leaf = name.split(".")
            sec = body["ros__parameters"]
            for s in sections:
                sec = sec[s]
            sec[leaf] = value
        (d / file).write_text(yaml.safe_dump(doc))
    return d


#: the bridge as both launches fly it here: the hand-back chain starts with POSCTL, which
#: PX4 refuses without RC (the fallback HOLD must be shown on /mavros/state before DONE);
#: acknowledgement and confirmation times for a loaded 2-core host
BRIDGE_EDITS = {
    "offboard.handback_chain": ["POSCTL", "HOLD", "LAND"],
    "offboard.mode_confirm_timeout": 5.0,
    "offboard.ack_timeout": 2.0,
    "offboard.input_timeout": 1.0,
    "mavros.interfaces": "mavros_msgs",
}


def _fly_launch(stack, file: str, args: dict, mavros_ns: str, limit_s: float, tag: str):
    """``ros2 launch lpv_sysid <file> transport:=mavros fcu_url:=... ...`` (the launch
    starts MAVROS), the driver above, SIGINT to the launch; (result, launch log, exit)."""
    import signal as sig

    env, px4, d = stack["env"], stack["px4"], stack["dir"] / tag
    d.mkdir()
    port = 14540 + INSTANCE
    argv = {
        "transport": "mavros",
        "mavros_ns": mavros_ns,
        "fcu_url": f"udp://:{port}@127.0.0.1:{port + 40}",
        "tgt_system": str(INSTANCE + 1),
        "auto_start": "false",
        **args,
    }
    previous = sig.getsignal(sig.SIGINT)  # a background run inherits SIGINT ignored
    sig.signal(sig.SIGINT, sig.SIG_DFL)
    try:
        proc = env.popen(
            f"ros2 launch lpv_sysid {file} " + " ".join(f"{k}:={v}" for k, v in argv.items()),
            d / "launch.log",
        )
    finally:
        sig.signal(sig.SIGINT, previous)
    try:
        (d / "driver.py").write_text(LAUNCH_DRIVER)
        r = env.run(f"python3 {d / 'driver.py'} {mavros_ns} {limit_s}", timeout=limit_s + 700)
        line = [x for x in r.stdout.splitlines() if x.startswith("RESULT ")]
        logs = f"{r.stderr[-2000:]}\n--- launch\n{proc.log()[-6000:]}\n--- px4\n{px4.log_tail(30)}"
        assert line, logs
        res = json.loads(line[0][len("RESULT ") :])
        proc.sigint()
        try:
            rc = proc.wait(timeout=90.0)
        except subprocess.TimeoutExpired:
            rc = None
    finally:
        proc.kill()
    print(f"{file} through MAVROS:", json.dumps(res))
    return res, proc.log(), rc, logs


def _recorded(out_dir: Path) -> dict:
    """{topic: [(stamp_ns, msg), ...]} of every bag of a data_logger directory."""
    import yaml

    from lpv_sysid.io import bag as iobag

    meta = yaml.safe_load((out_dir / "experiment.yaml").read_text())
    assert meta["closed_cleanly"] is True, meta
    out: dict = {}
    for b in meta["bags"]:
        for topic, msgs in iobag.read_bag(str(out_dir / b["path"])).items():
            out.setdefault(topic, []).extend(msgs)
    return out


def _assert_confirmed_handback(res: dict, logs: str) -> None:
    """The sequencer flew it, the hand-back ended DONE only with HOLD shown by PX4 through
    /mavros/state after POSCTL was refused (never shown)."""
    states, modes = res["states"], [m[0] for m in res["modes"]]
    assert res["start"][0], (res["start"], logs)
    assert "OFFBOARD_ACTIVE" in states and "OFFBOARD" in modes, (states, modes, logs)
    assert res["ended"] and states[-1] == "DONE", (states, res["reasons"], logs)
    final = res["reasons"][-1]
    assert "hand-back confirmed: vehicle in HOLD" in final and "after POSCTL" in final, final
    assert "POSCTL" not in modes and modes[-1] == "AUTO.LOITER", modes
    assert res["modes"][-1][1], "still armed in the air after the hand-back"


def test_phase1_launch_through_mavros_flies_and_hands_back_confirmed(stack, tmp_path):
    """``phase1.launch.py transport:=mavros mavros_ns:=/fcu fcu_url:=... tgt_system:=17``:
    the launch starts MAVROS in /fcu, the sequencer switches the airborne vehicle to
    OFFBOARD, the excitation plays an 8 s lateral sine, ``abort`` hands back (POSCTL
    refused, HOLD confirmed); the recording holds the MAVLink transport's topics."""
    if not stack["airborne"]:
        pytest.fail("the first test did not leave the vehicle airborne in HOLD")
    import numpy as np

    from lpv_sysid.io import messages
    from lpv_sysid.signals.store import save_npz

    t = np.arange(0.0, 8.0, 0.02)
    s = 0.8 * np.sin(2 * np.pi * 0.25 * t)
    save_npz(
        str(tmp_path / "sig1.npz"),
        t,
        np.stack([0 * t, s, 0 * t, 0 * t], axis=1),
        ["u_ref", "v_ref", "w_ref", "r_ref"],
    )
    cfg = _config_dir(stack["share"], tmp_path, {"mavlink_bridge_node.yaml": BRIDGE_EDITS})
    out = tmp_path / "phase1_log"
    res, text, rc, logs = _fly_launch(
        stack,
        "phase1.launch.py",
        {"config_dir": cfg, "signals_file": tmp_path / "sig1.npz", "log_dir": out},
        "/fcu",
        120.0,
        "phase1",
    )
    _assert_confirmed_handback(res, logs)
    assert "done" in res["phases"], res["phases"]
    assert rc == 0, text[-4000:]
    rec = _recorded(out)
    ns = "/lpv_sysid/"
    for topic, least in (
        ("state", 200),
        ("imu", 200),
        ("rotor_speeds", 100),
        ("velocity_reference", 200),
        ("excitation", 200),
        ("status", 5),
    ):
        assert len(rec.get(ns + topic, [])) >= least, (topic, {k: len(v) for k, v in rec.items()})
    # the lateral sine was flown: the body v of PX4's odometry follows the reference
    v = np.array([messages.state_from_odometry(m).v_body[1] for _, m in rec[ns + "state"]])
    assert np.ptp(v) > 0.6, np.ptp(v)
    stack["airborne"] = res["modes"][-1] == ["AUTO.LOITER", True]


#: the phase-2 gains flown here: test_chain_px4's plant and signals, synthesized for less
#: closed-loop bandwidth (pole disk centre -4, radius 4: |s| <= 8 rad/s instead of the
#: shipped synthesis_chain.yaml's 14) and certified for 160 ms of loop delay (the shipped
#: design: 96.6 ms). Why: the loop delay (state stamp = MAVROS's receipt -> command) through
#: MAVROS, DDS, the bridge and the controller on this 2-core host at load 12-19 is real age
#: (Python nodes starved of CPU, the stamps are MAVROS's own), measured p50 11 / p99 106 /
#: max 172 ms in a run that flew the whole signal, 208 ms for 325 ms in one the watchdog
#: stopped. 160 ms is about the most this plant and signal set certify (performance margin
#: 165.7 ms, stable to 214.7 ms); a smaller disk is infeasible at gamma 1 (gamma_min 1.23
#: at radius 2.5), so 0.25-0.3 s is out of reach. A vehicle keeps the shipped design.
MAVROS_SYNTHESIS = {
    "hinf.region": {"disk": {"centre": -4.0, "radius": 4.0}, "half_plane": {"alpha": 0.2}},
    "loop_delay": {"bound_s": 0.16},
}


@pytest.fixture(scope="module")
def design_mavros(design, tmp_path_factory):  # noqa: F811
    """``design`` (test_chain_px4) synthesized with :data:`MAVROS_SYNTHESIS`."""
    import yaml

    from lpv_sysid.cli.main import main as cli_main

    d = tmp_path_factory.mktemp("design_mavros")
    cfg = yaml.safe_load((ROOT / "config" / "synthesis_chain.yaml").read_text())
    cfg["hinf"]["region"] = MAVROS_SYNTHESIS["hinf.region"]
    cfg["loop_delay"] = MAVROS_SYNTHESIS["loop_delay"]
    (d / "synthesis.yaml").write_text(yaml.safe_dump(cfg))
    argv = ["synthesize", "--models", str(design / "vertex_models.yaml")]
    argv += ["--config", str(d / "synthesis.yaml")]
    argv += ["--summary", str(design / "signals" / "summary.yaml"), "--out", str(d / "gains.yaml")]
    assert cli_main(argv) == 0
    cert = yaml.safe_load((d / "gains.yaml").read_text())["certificate"]["loop_delay"]
    assert cert["bound_s"] == 0.16 and cert["performance_margin_s"] >= 0.16, cert
    return d


def test_phase2_launch_through_mavros_flies_the_lpv_law_and_hands_back_confirmed(
    stack,
    design,  # noqa: F811  (test_chain_px4's rate-plant gains and phase-2 signal)
    design_mavros,
    tmp_path,
):
    """``phase2.launch.py design:=rate_plant transport:=mavros fcu_url:=...``: the LPV law
    (rate plant: test_chain_px4's plant and signal, the gains of :data:`MAVROS_SYNTHESIS`)
    commands thrust + body rates through
    ``/mavros/setpoint_raw/attitude`` while the excitation plays the phase-2 signal; the
    sequencer's abort hands back (POSCTL refused, HOLD confirmed on /mavros/state). The
    recording holds the MAVLink transport's topics, and PX4's own echo of the setpoints it
    tracks (``rate_setpoint``, from ``setpoint_raw/target_attitude``) equals the law's
    commands (``actuator_command``) that went out through MAVROS."""
    if not stack["airborne"]:
        pytest.fail("the tests before did not leave the vehicle airborne in HOLD")
    import numpy as np

    from lpv_sysid.io import messages

    cfg = _config_dir(
        stack["share"],
        tmp_path,
        {
            "mavlink_bridge_node.yaml": BRIDGE_EDITS,
            # a loaded 2-core host: state through MAVROS + DDS arrives late by > 0.2 s
            # and the loop-delay watchdog lets isolated scheduling stalls of up to 0.3 s pass
            # (a 176 ms stall at load 15 aborted the default 20 ms; the bound is the gains')
            "lpv_controller_px4.yaml": {
                **{f"{k}_timeout_s": 0.5 for k in ("state", "rotor", "reference", "excitation")},
                "loop_delay_tolerance_s": 0.3,
            },
        },
    )
    out = tmp_path / "phase2_log"
    res, text, rc, logs = _fly_launch(
        stack,
        "phase2.launch.py",
        {
            "config_dir": cfg,
            "design": "rate_plant",
            "gains_file": design_mavros / "gains.yaml",
            "signals_file": design / "signals" / "signals.npz",
            "log_dir": out,
        },
        "/mavros",
        150.0,
        "phase2",
    )
    assert res["armed"], ("the law never commanded", logs)
    # the whole signal, unless the controller's own watchdogs stopped it on this host (the
    # loop delay state stamp -> command through MAVROS + DDS + two Python nodes against
    # the certified bound, or a stale input): named, and the end still the truth
    full = "done" in res["phases"]
    # or the bridge's envelope handed back first (the vehicle, left low by the tests before,
    # descending toward the altitude floor: measured in CI, 0.39 m/s at 6.11 m, floor 5 m)
    envelope = "reaches the floor" in str(res.get("abort_call")) or any(
        "envelope" in r or "reaches the floor" in r for r in res["reasons"]
    )
    assert full or envelope or "loop_delay" in res["abort"] or "stale" in res["abort"], res
    modes = [m[0] for m in res["modes"]]
    if full or "OFFBOARD_ACTIVE" in res["states"]:
        _assert_confirmed_handback(res, logs)
    else:  # aborted while switching: never DONE unless PX4 shows the hand-back mode
        assert res["ended"] and modes[-1] != "OFFBOARD", (res, logs)
        if res["states"][-1] == "DONE" and "OFFBOARD" in modes:
            assert "hand-back confirmed: vehicle in HOLD" in res["reasons"][-1], res
            assert modes[-1] == "AUTO.LOITER", modes
    assert rc == 0, text[-4000:]
    rec = _recorded(out)
    ns = "/lpv_sysid/"
    counts = {k: len(v) for k, v in rec.items()}
    print("phase 2 through MAVROS: full signal" if full else f"aborted: {res['abort']}", counts)
    for topic, least in (
        ("state", 200),
        ("imu", 200),
        ("rotor_speeds", 100),
        ("velocity_reference", 200),
        ("excitation", 200),
        ("actuator_command", 1000 if full else 1),
        ("rate_setpoint", 100),
        ("status", 5),
    ):
        assert counts.get(ns + topic, 0) >= least, (topic, counts)
    names = ("thrust", "p_sp", "q_sp", "r_sp")
    sent = rec[ns + "actuator_command"]
    t_sent = np.array([s for s, _ in sent], dtype=np.int64)
    u_sent = np.array(
        [messages.channels_from_joint_state(m, names, field="position")[1] for _, m in sent]
    )
    echo = [
        (s, messages.channels_from_joint_state(m, names, field="position")[1])
        for s, m in rec[ns + "rate_setpoint"]
    ]
    # PX4's echo of the body rates it tracks equals one of the law's commands sent around
    # it (float32 through MAVROS and back; measured: exact to 1e-8 rad/s, the echo stamped
    # ~90 ms after the command on a loaded host); echoes of PX4's own rate setpoints
    # (before OFFBOARD, in HOLD) match none
    exact, lags = 0, []
    for s, u in echo:
        near = np.abs(t_sent - s) < 1_000_000_000
        if not near.any():
            continue
        e = np.abs(u_sent[near, 1:] - np.asarray(u[1:])).max(axis=1)
        k = int(np.argmin(e))
        if e[k] < 1e-6:
            exact += 1
            lags.append((s - t_sent[near][k]) * 1e-6)
    print(f"echo = command: {exact} of {len(echo)}; lag p50 {np.median(lags or [0]):.0f} ms")
    active = "OFFBOARD_ACTIVE" in res["states"]
    assert exact >= (500 if full else 20 if active else 0), (exact, counts)
    stack["airborne"] = res["modes"][-1] == ["AUTO.LOITER", True]


#: a companion computer that freezes mid-flight: the driver starts the bridge (phase 1,
#: velocity), waits for OFFBOARD, stops the bridge's process group (SIGSTOP) long enough
#: for PX4's offboard-loss failsafe (COM_OF_LOSS_T 1 s -> COM_OBL_RC_ACT 5, Hold), records
#: /mavros/state (mode, system_status) meanwhile, resumes it (SIGCONT) and watches what the
#: bridge concludes.
FREEZE_DRIVER = r"""
import json, os, signal, sys, time
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistStamped
from mavros_msgs.msg import State
from rclpy.qos import qos_profile_sensor_data
from std_srvs.srv import Trigger

pgid = int(sys.argv[1])
rclpy.init()
n = rclpy.create_node("mavros_freeze_driver")
res = {"modes": [], "states": [], "reasons": [], "failsafe": [], "events": []}
def on_state(m):
    row = [m.mode, m.armed, m.system_status]
    if m.connected and (not res["modes"] or res["modes"][-1] != row):
        res["modes"].append(row)
def on_status(msg):
    for s in msg.status:
        if not s.name.endswith("mavlink_bridge"):
            continue
        v = {kv.key: kv.value for kv in s.values}
        if v.get("state") and (not res["states"] or res["states"][-1] != v["state"]):
            res["states"].append(v["state"])
            res["reasons"].append(v.get("reason", ""))
        fs = v.get("px4_failsafe")
        if fs and (not res["failsafe"] or res["failsafe"][-1] != fs):
            res["failsafe"].append(fs)
        new = not res["events"] or res["events"][-1] != s.message
        if s.level not in (0, bytes([0])) and new:
            res["events"].append(s.message)
n.create_subscription(State, "/mavros/state", on_state, qos_profile_sensor_data)
n.create_subscription(DiagnosticArray, "/lpv_sysid/status", on_status, 100)
ref = n.create_publisher(TwistStamped, "/lpv_sysid/velocity_reference", 10)
def tick():
    m = TwistStamped()
    m.header.stamp = n.get_clock().now().to_msg()
    m.header.frame_id = "base_link"
    ref.publish(m)
n.create_timer(0.05, tick)
def spin(seconds, until=None):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        rclpy.spin_once(n, timeout_sec=0.05)
        if until is not None and until():
            return True
    return False
def bridge():
    return res["states"][-1] if res["states"] else ""
spin(120.0, until=lambda: bool(res["modes"]) and bool(res["states"]))
c = n.create_client(Trigger, "/lpv_sysid/mavlink_bridge/start")
assert c.wait_for_service(timeout_sec=60.0)
t0 = time.monotonic()
# until MAVROS has delivered the preflight's evidence (PX4's parameters and
# AUTOPILOT_VERSION): a refusal naming "evidence missing" is retried, a judged NO-GO is not
while True:
    spin(8.0)
    f = c.call_async(Trigger.Request())
    spin(30.0, until=f.done)
    res["start"] = [f.result().success, f.result().message] if f.done() else [False, "?"]
    missing = "evidence missing so far" in res["start"][1]
    if res["start"][0] or not missing or time.monotonic() - t0 > 120:
        break
res["active"] = spin(60.0, until=lambda: bridge() in ("OFFBOARD_ACTIVE", "FAILED", "DONE"))
spin(2.0)
os.killpg(pgid, signal.SIGSTOP)  # the companion freezes: no setpoint reaches PX4
res["frozen_at"] = len(res["modes"])
spin(8.0)
os.killpg(pgid, signal.SIGCONT)
res["ended"] = spin(90.0, until=lambda: bridge() in ("DONE", "FAILED"))
spin(3.0)
print("RESULT " + json.dumps(res))
"""


def test_a_px4_failsafe_seen_through_mavros_is_never_a_confirmed_mode(stack):
    """The bridge (``ros2 run``, phase 1 through the real MAVROS) is frozen in OFFBOARD;
    PX4's offboard-loss failsafe takes the vehicle to Hold and reports MAV_STATE_CRITICAL
    (the oracle: /mavros/state as the driver saw it). Resumed, the bridge reports the
    failsafe and confirms a mode of its hand-back chain only from a state outside the
    failsafe (system_status back to ACTIVE), never from the failsafe's own Hold."""
    if not stack["airborne"]:
        pytest.fail("the tests before did not leave the vehicle airborne in HOLD")
    env, share, d = stack["env"], stack["share"], stack["dir"] / "freeze"
    d.mkdir()
    port = 14540 + INSTANCE
    procs = []
    try:
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
            "-p offboard.mode_confirm_timeout:=5.0 -p offboard.ack_timeout:=2.0 "
            "-p offboard.input_timeout:=1.0 -p 'offboard.handback_chain:=[HOLD, LAND]'",
            d / "bridge.log",
        )
        procs.append(bridge)
        (d / "driver.py").write_text(FREEZE_DRIVER)
        r = env.run(f"python3 {d / 'driver.py'} {bridge.pid}", timeout=600.0)
        line = [x for x in r.stdout.splitlines() if x.startswith("RESULT ")]
        logs = f"{r.stderr[-2000:]}\n--- bridge\n{bridge.log()[-4000:]}"
        assert line, logs
        res = json.loads(line[0][len("RESULT ") :])
    finally:
        for p in procs:
            p.sigint(group=True)
        for p in procs:
            try:
                p.wait(timeout=60.0)
            except subprocess.TimeoutExpired:
                p.kill()
    print("failsafe through MAVROS:", json.dumps(res))
    assert res["start"][0] and res["active"] and "OFFBOARD_ACTIVE" in res["states"], logs
    # PX4's failsafe while frozen: Hold, armed, MAV_STATE_CRITICAL on /mavros/state
    frozen = res["modes"][res["frozen_at"] :]
    assert ["AUTO.LOITER", True, 5] in frozen, res["modes"]
    # the bridge saw it as a failsafe and confirmed nothing from it: a mode of its chain
    # counts only from a state outside the failsafe (measured: the failsafe's Hold, then
    # 0.09 s later the same Hold with MAV_STATE_ACTIVE once the neutral stream and the
    # HOLD request were back -- that one confirms, the run still FAILED: a fault ended it)
    assert "AUTO.LOITER (MAV_STATE_CRITICAL)" in res["failsafe"], res
    final, text = res["reasons"][-1], bridge.log()
    assert res["ended"] and res["states"][-1] in ("DONE", "FAILED"), res
    if "hand-back confirmed" in final:
        assert res["failsafe"][-1] == "false" and res["modes"][-1][2] not in (5, 6, 8), res

        # node-clock log stamps: the failsafe seen before the confirmation, whose poll also
        # logs the failsafe's end (after it: the link's events follow the core's)
        def stamp(what: str) -> float:
            return float(re.search(r"\[(\d+\.\d+)\] \[[^]]+\]: " + what, text).group(1))

        t_ok = stamp("hand-back confirmed")
        assert stamp("px4_failsafe:") < t_ok and stamp("px4_failsafe_end") <= t_ok + 0.1, text
        shown = {"HOLD": "AUTO.LOITER", "LAND": "AUTO.LAND"}[final.split("vehicle in ")[1][:4]]
        assert res["modes"][-1][:2] == [shown, True], res["modes"]
    else:
        assert "hand-back NOT confirmed" in final or "left OFFBOARD" in final, final
