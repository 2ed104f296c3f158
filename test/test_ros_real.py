"""The node graph under a real ROS 2 Jazzy (rclpy + Cyclone DDS), with real ROS tools.

Skips with one line when no usable ROS 2 is found (test/support/ros_real.find_ros: a sourced
setup.bash, LPV_SYSID_ROS_SETUP, or /opt/ros/jazzy). The package is colcon-built once per
session from a copy of the checkout; every node and launch runs as processes on its own
reserved ROS_DOMAIN_ID (localhost only), queried with ``ros2 node info``, ``ros2 param
dump``, ``ros2 topic list -t``, ``ros2 topic hz`` and ``ros2 service call``.

The oracles: the README's node and topic tables (what each node publishes and subscribes,
with which type, and its services), the shipped config files (every key a node's YAML sets
is a declared parameter of the running node with that value), the declarations in the node
modules (``PARAMETERS``: exactly the node's parameters), exit status 0 on SIGINT -- to the
node, to the launch, and to the whole process group as a terminal's Ctrl-C sends it (launch
then forwards a second SIGINT to every node) -- the bridge's hand-back confirmed by the
package's own simulated PX4 (``lpv-sysid sim-vehicle``), and the recording readable by
rosbags' AnyReader with ``experiment.yaml`` closed.

Issue 11, measured under Jazzy before the orderly shutdown of nodes/shell.run: Ctrl-C
of a launch killed the bridge (``RCLError: Failed to publish: publisher's context is
invalid`` in destroy_node, exit 1, hand-back unconfirmed), and a process-group SIGINT made
every node exit -2 with ``KeyboardInterrupt`` inside destroy_node (the logger's bag without
metadata.yaml, ``closed_cleanly: false``). Measured numbers (rates, shutdown times, exit
codes) are printed at the end of the module (``pytest -s``).
"""

from __future__ import annotations

import json
import math
import os
import re
import socket
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from ros_real import DomainId, Proc, RosEnv, build_package, find_ros

ROOT = Path(__file__).resolve().parents[1]
NS = "/lpv_sysid"
#: parameters every rclpy node has (not the package's)
ROS_OWN_PARAMETERS = {"use_sim_time", "start_type_description_service"}
#: launch's log line of a process that exited 0
CLEAN = re.compile(r"\[INFO\] \[([a-z_]+)-\d+\]: process has finished cleanly")
DIED = re.compile(r"\[ERROR\] \[([a-z_]+)-\d+\]: process has died .*exit code (-?\d+)")
MEASURED: dict = {}

SETUP, SKIP_REASON = find_ros()
pytestmark = pytest.mark.skipif(SETUP is None, reason=SKIP_REASON)


# ----------------------------------------------------------------------- README oracles
def readme_tables() -> tuple[dict, dict]:
    """({topic: type}, {executable: (subscribes, publishes, services)}) from README.md."""
    text = (ROOT / "README.md").read_text()
    types = {}
    for name, typ in re.findall(r"^\| `([a-z_]+)` \| ([a-z_]+/[A-Za-z]+) \|", text, re.M):
        pkg, msg = typ.split("/")
        types[name] = f"{pkg}/msg/{msg}"
    nodes = {}
    for row in re.findall(r"^\| `([a-z_]+_node)` \|(.*)$", text, re.M):
        exe, rest = row
        subs, pubs, srvs = [c.strip() for c in rest.split("|")[:3]]
        every = "every topic" in subs
        names = lambda c: [n for n in re.findall(r"`([a-z_.]+)`", c) if n in types]  # noqa: E731
        nodes[exe] = (
            sorted(types) if every else names(subs),
            names(pubs),
            re.findall(r"`([a-z_]+)`", srvs),
        )
    assert types and nodes, "README.md: node / topic tables not found"
    return types, nodes


README_TYPES, README_NODES = readme_tables()


# --------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def ros(tmp_path_factory):
    """The colcon workspace (one build per module) and test inputs (signals, gains)."""
    t0 = time.monotonic()
    ws = build_package(SETUP, tmp_path_factory.mktemp("ros_ws"))
    MEASURED["colcon_build_s"] = round(time.monotonic() - t0, 1)
    data = tmp_path_factory.mktemp("ros_data")
    from lpv_test_gains import write_gains

    from lpv_sysid.signals.store import save_npz

    t = np.arange(0.0, 20.0, 0.02)
    s = 0.5 * np.sin(2 * np.pi * 0.5 * t)
    save_npz(
        str(data / "sig1.npz"),
        t,
        np.stack([0 * t, s, 0 * t, 0.1 * s], axis=1),
        ["u_ref", "v_ref", "w_ref", "r_ref"],
    )
    cols = [0.8 * np.sin(2 * np.pi * 0.2 * t), 0 * t, 0 * t] + [
        0.5 * np.sin(2 * np.pi * f * t) for f in (1.3, 1.7, 2.3, 2.9)
    ]
    save_npz(
        str(data / "sig2.npz"),
        t,
        np.stack(cols, axis=1),
        ["u_d", "v_d", "w_d", "ue_t", "ue_a", "ue_e", "ue_r"],
    )
    gains = write_gains(data / "gains.yaml")
    prefix = ws / "install" / "lpv_sysid"
    yield {
        "ws": ws,
        "lib": prefix / "lib" / "lpv_sysid",
        "share": prefix / "share" / "lpv_sysid",
        "data": data,
        "sig1": str(data / "sig1.npz"),
        "sig2": str(data / "sig2.npz"),
        "gains": gains,
    }
    print("\nreal ROS 2 measurements:\n" + json.dumps(MEASURED, indent=1, sort_keys=True))


_domain_start = [os.getpid() % 50]


def domain() -> DomainId:
    _domain_start[0] += 7
    return DomainId(_domain_start[0])


def free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


# ---------------------------------------------------------------------------- helpers
def flatten(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flatten(v, name + "."))
        else:
            out[name] = v
    return out


def yaml_parameters(path: Path, node: str) -> dict:
    """Flattened ``ros__parameters`` of ``/**/node`` in a shipped params file."""
    doc = yaml.safe_load(path.read_text())
    return flatten(doc[f"/**/{node}"]["ros__parameters"])


def same(a, b) -> bool:
    if isinstance(a, float) or isinstance(b, float):
        return (
            isinstance(a, (int, float))
            and isinstance(b, (int, float))
            and (
                math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-12) or math.isnan(a) and math.isnan(b)
            )
        )
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    return a == b


def node_info(env: RosEnv, fqn: str, publishers=(), timeout: float = 45.0) -> dict:
    """``ros2 node info``: {section: {name: type}} once the node is in the graph with
    every topic of ``publishers`` (a node under construction has only /rosout)."""
    deadline = time.monotonic() + timeout
    while True:
        r = env.run(f"ros2 node info {fqn} --no-daemon", timeout=60)
        sections, cur = {}, None
        for line in r.stdout.splitlines():
            m = re.match(r"^  ([A-Za-z ]+):$", line)
            if m:
                cur = sections.setdefault(m.group(1), {})
            elif cur is not None and ": " in line.strip():
                name, typ = line.strip().split(": ", 1)
                cur[name] = typ
        have = sections.get("Publishers", {})
        if r.returncode == 0 and all(p in have for p in publishers) or time.monotonic() > deadline:
            assert r.returncode == 0, f"ros2 node info {fqn}: {r.stdout}\n{r.stderr}"
            return sections
        time.sleep(0.5)


def param_dump(env: RosEnv, fqn: str) -> dict:
    r = env.run(f"ros2 param dump {fqn} --no-daemon", timeout=60, check=True)
    ((key, body),) = yaml.safe_load(r.stdout).items()
    assert key == fqn
    return flatten(body["ros__parameters"])


def param_list(env: RosEnv, fqn: str) -> set:
    r = env.run(f"ros2 param list {fqn} --no-daemon", timeout=60, check=True)
    return {line.strip() for line in r.stdout.splitlines() if line.strip()}


def trigger(env: RosEnv, service: str, launched: Proc | None = None) -> tuple[bool, str]:
    """``ros2 service call <service> std_srvs/srv/Trigger``: (success, message); with
    ``launched`` (a ros2 launch), first that none of its processes has died (the call
    would wait for a server that is gone)."""
    if launched is not None:
        assert not DIED.findall(launched.log()), launched.log()[-5000:]
    r = env.run(f"ros2 service call {service} std_srvs/srv/Trigger", timeout=60)
    m = re.search(r"Trigger_Response\(success=(True|False), message='(.*)'\)", r.stdout)
    assert m, f"{service}: no response\n{r.stdout}\n{r.stderr}"
    return m.group(1) == "True", m.group(2)


def topic_hz(env: RosEnv, topic: str, seconds: float = 6.0, start_timeout: float = 120.0) -> float:
    """Last ``average rate`` of ``ros2 topic hz`` after ``seconds`` of reports.

    The window starts at its first report, not at the command: the CLI's own start and
    discovery took longer than a fixed 6 s budget at load 27 on 2 cores (no report at all,
    five nodes' probes failed in one run), which says nothing about the node's rate. ``ros2
    topic hz`` ignores SIGTERM: KILL after."""
    with tempfile.TemporaryDirectory(prefix="topic_hz_") as d:
        p = env.popen(f"ros2 topic hz {topic} --window 200", Path(d) / "hz.log")
        try:
            first = p.wait_for("average rate", start_timeout)
            if first:
                time.sleep(seconds)
            out = p.log()
        finally:
            p.kill()
    rates = re.findall(r"average rate: ([0-9.]+)", out)
    assert rates, f"ros2 topic hz {topic}: no report within {start_timeout:g} s\n{out}"
    return float(rates[-1])


def sigint_and_wait(proc: Proc, group: bool, timeout: float = 30.0) -> tuple[int, float]:
    """SIGINT (to the process or its whole group); (exit status, seconds to exit). For a
    ``ros2 launch``, the seconds from the SIGINT to each node's "finished cleanly" line
    go to MEASURED["launch_node_exit_s"]."""
    t0 = time.monotonic()
    proc.sigint(group=group)
    exits: dict = {}
    while proc.p.poll() is None and time.monotonic() - t0 < timeout:
        for name in CLEAN.findall(proc.log()):
            exits.setdefault(name, round(time.monotonic() - t0, 2))
        time.sleep(0.05)
    if proc.p.poll() is None:
        proc.kill()
        raise AssertionError(
            f"{proc.log_path.name}: still running {timeout} s after SIGINT:\n{proc.log()[-3000:]}"
        )
    rc = proc.wait(1.0)
    if exits:
        MEASURED.setdefault("launch_node_exit_s", {})[proc.log_path.parent.name] = exits
    return rc, round(time.monotonic() - t0, 2)


def handback_latency(text: str) -> float:
    """Node-clock seconds from the bridge's "shutdown" line to "hand-back confirmed"."""
    stamp = r"\[(\d+\.\d+)\] \[lpv_sysid\.mavlink_bridge\]: "
    t0 = re.search(stamp + "shutdown", text)
    t1 = re.search(stamp + "hand-back confirmed", text)
    assert t0 and t1, text[-3000:]
    return round(float(t1.group(1)) - float(t0.group(1)), 3)


def assert_no_traceback(text: str, what: str) -> None:
    for bad in ("Traceback", "KeyboardInterrupt", "RCLError", "context is invalid"):
        assert bad not in text, f"{what}: {bad!r} in the output:\n{text[-4000:]}"


def check_recording(out_dir: Path, min_counts: dict) -> dict:
    """experiment.yaml closed cleanly, every bag opens in rosbags' AnyReader with its
    metadata.yaml, and holds at least ``min_counts`` messages per topic; returns the
    recorded rates {topic: Hz}."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    meta = yaml.safe_load((out_dir / "experiment.yaml").read_text())
    assert meta["closed_cleanly"] is True and meta["status"] == "closed_cleanly", meta
    counts: dict = {}
    for b in meta["bags"]:
        bag = out_dir / b["path"]
        assert (bag / "metadata.yaml").is_file(), f"{bag}: no metadata.yaml"
        with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
            for conn, _, raw in reader.messages():
                if conn.topic not in counts:  # one of each topic decodes
                    reader.deserialize(raw, conn.msgtype)
                counts[conn.topic] = counts.get(conn.topic, 0) + 1
    for topic, n in min_counts.items():
        assert counts.get(NS + "/" + topic, 0) >= n, (topic, counts)
        assert meta["topics"][NS + "/" + topic]["count"] == counts[NS + "/" + topic]
    return {t.rsplit("/", 1)[-1]: round(v["rate_hz"], 1) for t, v in meta["topics"].items()}


def check_vehicle_record(experiment: Path, t_booted_after: int, t_booted_before: int) -> None:
    """``experiment.yaml``'s ``vehicle``, from the bridge's ``vehicle_record`` through the
    data logger: the mapping ``fly`` writes (VehicleRecord.summary's keys), the package's
    simulated PX4 (kind SIMULATED, its AUTOPILOT_VERSION v1.16.0, every parameter it serves
    at its default), and PX4's boot on the bag clock (epoch ns) between the simulator's
    start and the bridge's link_up."""
    from lpv_sysid.mavlink.telemetry import VehicleRecord
    from lpv_sysid.sim.px4_vehicle.config import DEFAULT_PARAMS

    meta = yaml.safe_load(experiment.read_text())
    v = meta.get("vehicle")
    assert v is not None, f"{experiment}: no vehicle record"
    assert set(v) == set(VehicleRecord().summary()), sorted(v)
    assert v["kind"] == "SIMULATED" and v["firmware"]["flight_sw_version"] == "v1.16.0"
    assert v["px4_parameters"] == pytest.approx({k: d for k, (d, _) in DEFAULT_PARAMS.items()})
    boot = v["px4_clock"]["boot_ns_min"]
    assert t_booted_after <= boot <= t_booted_before, (t_booted_after, boot, t_booted_before)
    assert v["px4_clock"]["boot_samples"] > 100 and v["px4_clock"]["knots"]
    assert meta["clock"]["kind"] == "utc" and "vehicle_record_clock" not in meta["clock"]
    MEASURED["phase1_vehicle_record"] = {
        "boot_after_sim_start_s": round((boot - t_booted_after) * 1e-9, 3),
        "knots": len(v["px4_clock"]["knots"]),
        "boot_samples": v["px4_clock"]["boot_samples"],
    }


def assert_topics_as_readme(info: dict, exe: str) -> None:
    """The node's publishers / subscribers carry the README's names and types; its status
    array is on /diagnostics too; its services are the README's (std_srvs/Trigger)."""
    subs, pubs, srvs = README_NODES[exe]
    for section, names in (("Publishers", pubs), ("Subscribers", subs)):
        got = info.get(section, {})
        for n in names:
            assert got.get(f"{NS}/{n}") == README_TYPES[n], (exe, section, n, got)
    if "status" in pubs:
        assert info["Publishers"].get("/diagnostics") == README_TYPES["status"], info
    servers = {
        k: v for k, v in info.get("Service Servers", {}).items() if v == "std_srvs/srv/Trigger"
    }
    node = exe[: -len("_node")] if exe != "mavlink_bridge_node" else "mavlink_bridge"
    assert sorted(servers) == sorted(f"{NS}/{node}/{s}" for s in srvs), (exe, servers)


# ------------------------------------------------------------ each node on its own
#: executable -> (node name, params file, extra -p overrides (by fixture key), services)
NODES = {
    "excitation_node": ("excitation", "excitation_node.yaml", {"signals_file": "sig1"}),
    "lpv_controller_node": ("lpv_controller", "lpv_controller.yaml", {"gains_file": "gains"}),
    "mavlink_bridge_node": ("mavlink_bridge", "mavlink_bridge_node.yaml", {}),
    "data_logger_node": ("data_logger", "data_logger.yaml", {}),
    "sim_vehicle_node": ("sim_vehicle", "sim_vehicle.yaml", {}),
}


def declared(exe: str) -> set:
    """The node module's declared parameter names (the one declaration)."""
    import importlib

    mod = importlib.import_module(f"lpv_sysid.nodes.{exe}")
    return {name for name, _, _ in mod.PARAMETERS}


#: a velocity reference stream for the bridge alone (ros2 topic pub stamps it "now")
REFERENCE_PUB = (
    "ros2 topic pub -r 50 /lpv_sysid/velocity_reference geometry_msgs/msg/TwistStamped "
    "'{header: {stamp: now, frame_id: base_link}}'"
)
#: the bridge's log line once PX4 (the simulated one) reports the hand-back mode
HANDBACK_DONE = re.compile(r"hand-back confirmed: vehicle in ([A-Z]+)")


def ready(node: str) -> str:
    """The log line of nodes/shell.run once ``node`` is constructed."""
    return f"[lpv_sysid.{node}]: ready"


def parallel(**calls) -> dict:
    """Run the zero-argument ``calls`` in threads; {name: result} (a ros2 call is mostly
    waiting for discovery: ~1.5 s of wall time, 0.3 s of CPU)."""
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(len(calls)) as pool:
        futures = {k: pool.submit(fn) for k, fn in calls.items()}
        return {k: f.result() for k, f in futures.items()}


#: per executable, a read-only parameter and a valid value (issue 24: ``ros2 param set
#: state_hz 5.0`` answered "successful" while the node kept publishing at 250 Hz)
READ_ONLY_PROBE = {
    "excitation_node": ("rate_hz", "50.0"),
    "lpv_controller_node": ("rate_hz", "100.0"),
    "mavlink_bridge_node": ("offboard.input_timeout", "0.3"),
    "data_logger_node": ("queue_depth", "10"),
    "sim_vehicle_node": ("state_hz", "5.0"),
    "campaign_node": ("rate_hz", "50.0"),
    "sequencer_node": ("step_timeout_s", "10.0"),
}


def param_set(env: RosEnv, fqn: str, name: str, value: str) -> str:
    r = env.run(f"ros2 param set {fqn} {name} {value} --no-daemon", timeout=60)
    return (r.stdout + r.stderr).strip()


def probe_param_set(env: RosEnv, fqn: str, exe: str, proc: Proc) -> dict:
    """``ros2 param set``: a read-only parameter is refused and keeps its value; the status
    rate set to 10 Hz takes effect (``ros2 topic hz`` of the node's own status: each node
    runs alone on its domain), a value out of range is refused."""
    name, value = READ_ONLY_PROBE[exe]
    before = param_dump(env, fqn)[name]
    out = {"read_only": param_set(env, fqn, name, value)}
    out["read_only_after"] = (before, param_dump(env, fqn)[name])
    out["out_of_range"] = param_set(env, fqn, "status_rate_hz", "1000.0")
    out["runtime"] = param_set(env, fqn, "status_rate_hz", "10.0")
    out["applied_logged"] = proc.wait_for("parameters applied: status_rate_hz=10.0", 30.0)
    out["status_hz"] = topic_hz(env, f"{NS}/status")
    return out


def probe_node(exe: str, s: dict) -> dict:
    """What the node-alone test checks, queried with the ROS tools (run for every node at
    once, in threads)."""
    node = NODES[exe][0]
    env, fqn = s["env"], f"{NS}/{node}"
    assert s["proc"].wait_for(ready(node), 90.0), s["proc"].log()[-3000:]
    out = {"ready_s": round(time.monotonic() - s["t0"], 1)}
    out.update(
        parallel(
            info=lambda: node_info(env, fqn, [f"{NS}/{t}" for t in README_NODES[exe][1]]),
            dump=lambda: param_dump(env, fqn),
        )
    )
    out["param_set"] = probe_param_set(env, fqn, exe, s["proc"])
    services = README_NODES[exe][2]
    if exe == "mavlink_bridge_node":
        # start with a reference stream: OFFBOARD, then the hand-back is SIGINT's (the
        # abort service is called in the phase-2 launch test)
        s["helpers"].append(env.popen(REFERENCE_PUB, s["logs"] / "reference_pub.log"))
        services = ["start"]
    out["services"] = {srv: trigger(env, f"{fqn}/{srv}") for srv in services}
    if exe == "mavlink_bridge_node":
        out["offboard"] = s["proc"].wait_for("OFFBOARD confirmed", 30.0)
        out["offboard_kept"] = not HANDBACK_DONE.search(s["proc"].log())
    # SIGINT to the node alone, as soon as it is probed (fewer nodes share the CPU)
    out["sigint"] = sigint_and_wait(s["proc"], group=False)
    return out


@pytest.fixture(scope="module")
def alone(ros, tmp_path_factory):
    """Every node started at once from its config file, each on its own domain (the bridge
    connected to the package's simulated PX4 over 127.0.0.1), and probed concurrently."""
    from concurrent.futures import ThreadPoolExecutor

    logs = tmp_path_factory.mktemp("alone")
    started = {}
    for exe, (node, params_file, extra) in NODES.items():
        dom = domain()
        env = RosEnv(SETUP, ros["ws"], dom.value)
        overrides = {k: ros[v] for k, v in extra.items()}
        procs = []
        if exe == "mavlink_bridge_node":
            port = free_udp_port()
            # input_timeout: see the phase-1 launch test (a 207 ms gap in ros2 topic pub's
            # 50 Hz stream handed back before the SIGINT under load ~11)
            overrides.update(
                {"link.url": f"udpin:127.0.0.1:{port}", "offboard.input_timeout": 1.0}
            )
            procs.append(
                env.popen(
                    f"{ros['lib']}/lpv-sysid sim-vehicle --udp 127.0.0.1:{port}",
                    logs / "px4_sim.log",
                )
            )
        if exe == "data_logger_node":
            overrides["out_dir"] = str(logs / "alone_log")
        args = " ".join(f"-p {k}:={v}" for k, v in overrides.items())
        cmd = (
            f"{ros['lib']}/{exe} --ros-args --params-file "
            f"{ros['share']}/config/{params_file} {args}"
        )
        started[exe] = {
            "env": env,
            "domain": dom,
            "proc": env.popen(cmd, logs / f"{exe}.log"),
            "helpers": procs,
            "overrides": overrides,
            "t0": time.monotonic(),
            "logs": logs,
        }
    try:
        with ThreadPoolExecutor(len(started)) as pool:  # all nodes at once
            futures = {exe: pool.submit(probe_node, exe, s) for exe, s in started.items()}
            for exe, fut in futures.items():
                try:
                    started[exe]["probe"] = fut.result()
                except Exception as exc:  # reported by that node's test
                    started[exe]["probe"] = exc
        yield started
    finally:
        for s in started.values():
            for p in [s["proc"], *s["helpers"]]:
                p.kill()
            s["domain"].release()


@pytest.mark.parametrize("exe", list(NODES))
def test_node_from_config_params_topics_services_sigint(ros, alone, exe):
    """Each node alone, started from its shipped config file: README topics and types
    (``ros2 node info``), every key of its YAML a declared parameter with the file's value
    and exactly the parameters of its module's one declaration (``ros2 param dump``), its
    services answer (``ros2 service call``), and SIGINT to the node gives exit status 0;
    the bridge, in OFFBOARD on the simulated PX4, hands back on SIGINT with the mode
    confirmed by PX4's HEARTBEAT."""
    node, params_file, _ = NODES[exe]
    s = alone[exe]
    proc, probe = s["proc"], s["probe"]
    if isinstance(probe, Exception):
        raise AssertionError(f"{exe}: {probe!r}\n{proc.log()[-3000:]}") from probe
    MEASURED.setdefault("node_ready_s", {})[exe] = probe["ready_s"]
    assert_topics_as_readme(probe["info"], exe)
    want = {**yaml_parameters(ros["share"] / "config" / params_file, node), **s["overrides"]}
    dump = probe["dump"]
    for name, value in want.items():
        assert name in dump, f"{exe}: {name} set by {params_file} is not declared"
        assert same(dump[name], value), (exe, name, dump[name], value)
    # the dump lists every declared parameter only when each has a value (one
    # uninitialized parameter empties rclpy's get_parameters answer)
    assert set(dump) - ROS_OWN_PARAMETERS == declared(exe), (
        exe,
        sorted((set(dump) - ROS_OWN_PARAMETERS) ^ declared(exe)),
    )
    # every service answers: abort succeeds; start succeeds or is refused with the reason
    # (the controller alone has no input streams to start on)
    for srv, (ok, message) in probe["services"].items():
        MEASURED.setdefault("services", {})[f"{node}/{srv}"] = message
        assert ok or srv == "start" and message, (exe, srv, message)
    assert all(ok for srv, (ok, _) in probe["services"].items() if srv == "abort")
    if exe != "lpv_controller_node":
        assert all(ok for ok, _ in probe["services"].values()), probe["services"]
    if exe == "mavlink_bridge_node":
        assert probe["offboard"] and probe["offboard_kept"], proc.log()[-3000:]
    ps = probe["param_set"]
    MEASURED.setdefault("param_set", {})[exe] = ps
    assert "Setting parameter failed" in ps["read_only"] and "read-only" in ps["read_only"], ps
    assert same(*ps["read_only_after"]), ps
    assert "Setting parameter failed" in ps["out_of_range"], ps
    assert "Set parameter successful" in ps["runtime"] and ps["applied_logged"], ps
    assert 8.0 <= ps["status_hz"] <= 12.0, ps  # from <= 2 Hz (the shipped files)
    rc, dt = probe["sigint"]
    MEASURED.setdefault("sigint_node_exit", {})[exe] = {"rc": rc, "s": dt}
    assert rc == 0, proc.log()[-3000:]
    assert_no_traceback(proc.log(), exe)
    if exe == "mavlink_bridge_node":
        after = proc.log().split("OFFBOARD confirmed", 1)[1]
        m = HANDBACK_DONE.search(after)
        assert m and m.group(1) == "HOLD", proc.log()[-3000:]
        MEASURED["bridge_alone_handback"] = after[m.start() :].splitlines()[0]
        MEASURED["bridge_alone_handback_confirmed_after_s"] = handback_latency(after)


# ------------------------------------------------------------------------ launch files
def launch(ros, env: RosEnv, file: str, args: dict, log: Path) -> Proc:
    """``ros2 launch lpv_sysid <file> k:=v ...`` in its own process group (the pid is
    ``ros2 launch``: ``exec``)."""
    argv = " ".join(f"{k}:={v}" for k, v in args.items())
    return env.popen(f"ros2 launch lpv_sysid {file} {argv}", log)


def wait_all(proc: Proc, patterns, timeout: float = 90.0) -> None:
    deadline = time.monotonic() + timeout
    for p in patterns:
        left = max(0.0, deadline - time.monotonic())
        assert proc.wait_for(p, left), f"{p!r} not in the output:\n{proc.log()[-4000:]}"


def topic_types(env: RosEnv) -> dict:
    r = env.run("ros2 topic list -t --no-daemon", timeout=60, check=True)
    return dict(re.findall(r"^(\S+) \[(\S+)\]$", r.stdout, re.M))


def assert_graph_topics(env: RosEnv, names) -> dict:
    """``ros2 topic list -t``: the README's topics with the README's types, /diagnostics."""
    types = topic_types(env)
    for n in names:
        assert types.get(f"{NS}/{n}") == README_TYPES[n], (n, types)
    assert types.get("/diagnostics") == README_TYPES["status"], types
    return types


def assert_launch_exit(proc: Proc, rc: int, executables) -> None:
    """The launch exited 0 and every node process exited 0 ("finished cleanly")."""
    text = proc.log()
    assert rc == 0, text[-4000:]
    assert not DIED.findall(text), DIED.findall(text)
    assert sorted(CLEAN.findall(text)) == sorted(executables), (CLEAN.findall(text), text[-4000:])
    assert_no_traceback(text, proc.log_path.name)


def config_dir_with(ros, tmp: Path, file: str, overrides: dict) -> Path:
    """A copy of the installed config directory with ``overrides`` (dotted names) set in
    ``file``'s ros__parameters: the launch files' ``config_dir`` argument."""
    import shutil

    d = tmp / "config"
    shutil.copytree(ros["share"] / "config", d)
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


@pytest.fixture
def dom():
    d = domain()
    yield d
    d.release()


#: the two nodes the README's node table leaves to the launch files: node name and the -p
#: arguments (by fixture key) they need to start alone
LAUNCH_ONLY_NODES = {
    "campaign_node": ("campaign", {"campaign_file": "campaign_yaml", "signals_file": "sig1"}),
    "sequencer_node": ("sequencer", {}),
}


@pytest.mark.parametrize("exe", list(LAUNCH_ONLY_NODES))
def test_param_set_on_the_campaign_and_sequencer_nodes(ros, dom, tmp_path, exe):
    """Issue 24 item 1 for the nodes of the launch files only (the README's five nodes:
    test_node_from_config_params_topics_services_sigint): under real Jazzy, ``ros2 param
    set`` of a read-only parameter is refused and the value kept, ``status_rate_hz`` out of
    range is refused, and ``status_rate_hz`` 10 takes effect -- the node's status, measured
    with ``ros2 topic hz`` before (the default: 2 Hz campaign, 1 Hz sequencer) and after."""
    env = RosEnv(SETUP, ros["ws"], dom.value)
    node, extra = LAUNCH_ONLY_NODES[exe]
    fixture = {**ros, "campaign_yaml": ros["share"] / "config" / "campaign.yaml"}
    args = " ".join(f"-p {k}:={fixture[v]}" for k, v in extra.items())
    proc = env.popen(f"{ros['lib']}/{exe} --ros-args {args}", tmp_path / f"{exe}.log")
    try:
        assert proc.wait_for(ready(node), 90.0), proc.log()[-3000:]
        default_hz = declared_defaults(exe)["status_rate_hz"]
        before = topic_hz(env, f"{NS}/status")
        ps = probe_param_set(env, f"{NS}/{node}", exe, proc)
        rc, _ = sigint_and_wait(proc, group=False)
    finally:
        proc.kill()
    MEASURED.setdefault("param_set", {})[exe] = {**ps, "status_hz_before": before}
    assert before == pytest.approx(default_hz, rel=0.3), (before, default_hz)
    assert "Setting parameter failed" in ps["read_only"] and "read-only" in ps["read_only"], ps
    assert same(*ps["read_only_after"]), ps
    assert "Setting parameter failed" in ps["out_of_range"], ps
    assert "Set parameter successful" in ps["runtime"] and ps["applied_logged"], ps
    assert 8.0 <= ps["status_hz"] <= 12.0, ps
    assert rc == 0, proc.log()[-3000:]
    assert_no_traceback(proc.log(), exe)


def declared_defaults(exe: str) -> dict:
    """{parameter: default} of the node module's declaration."""
    import importlib

    mod = importlib.import_module(f"lpv_sysid.nodes.{exe}")
    return {name: default for name, default, _ in mod.PARAMETERS}


def test_sim_launch_phase2_process_group_sigint(ros, dom, tmp_path):
    """sim.launch.py phase:=2 (sim_vehicle, excitation, lpv_controller, data_logger):
    topics and types, rates, start, then -- the controller commanding -- SIGINT to the
    whole process group as a terminal's Ctrl-C sends it (launch forwards a second one): the
    controller latches the abort "shutdown" on its own logger (timestamped, /rosout) and
    stops commanding, the excitation fades out, every node exits 0 and the recording opens
    in rosbags."""
    env = RosEnv(SETUP, ros["ws"], dom.value)
    out = tmp_path / "sim_log"
    proc = launch(
        ros,
        env,
        "sim.launch.py",
        {"phase": 2, "gains_file": ros["gains"], "signals_file": ros["sig2"], "log_dir": out},
        tmp_path / "launch.log",
    )
    try:
        wait_all(
            proc,
            [ready(n) for n in ("sim_vehicle", "excitation", "lpv_controller", "data_logger")],
        )

        def fly():
            ok, msg = trigger(env, f"{NS}/lpv_controller/start", proc)
            assert ok, msg
            ok, msg = trigger(env, f"{NS}/excitation/start", proc)
            assert ok, msg
            return topic_hz(env, f"{NS}/state", 5.0)

        got = parallel(topics=lambda: assert_graph_topics(env, README_TYPES), fly=fly)
        MEASURED["sim_phase2_state_hz_ros2_topic_hz"] = got["fly"]
        commanding = "safety abort" not in proc.log()
        rc, dt = sigint_and_wait(proc, group=True)
    finally:
        proc.kill()
    MEASURED["sim_phase2_group_sigint"] = {"rc": rc, "s": dt}
    assert_launch_exit(
        proc,
        rc,
        [
            "sim_vehicle_node",
            "excitation_node",
            "lpv_controller_node",
            "data_logger_node",
            "sequencer_node",
        ],
    )
    text = proc.log()
    abort = re.search(
        r"\[ERROR\] \[\d+\.\d+\] \[lpv_sysid\.lpv_controller\]: safety abort: "
        r"(.*); actuator commands stopped",
        text,
    )
    assert abort, text[-4000:]
    MEASURED["sim_phase2_controller_abort"] = abort.group(1)
    if commanding:  # no other abort came first: it is the shutdown's
        assert abort.group(1) == "external: shutdown", abort.group(1)
    # the excitation's final status: faded out, or its (sim-time) clock stopped with the sim
    assert re.search(
        r"\[lpv_sysid\.excitation\]: excitation (faded out|node clock stopped "
        r"at [0-9.]+ s before the fade ended): shutdown",
        text,
    ), text[-4000:]
    rates = check_recording(
        out,
        {
            "state": 100,
            "imu": 100,
            "rotor_speeds": 40,
            "velocity_reference": 40,
            "excitation": 40,
            "actuator_command": 1,
            "status": 2,
        },
    )
    MEASURED["sim_phase2_recorded_rates_hz"] = rates
    # on sim time (lock-step) the simulated sensors keep their configured rates exactly,
    # however loaded the machine (10 %: re-sent unanswered state samples count twice)
    sim = yaml_parameters(ros["share"] / "config" / "sim_vehicle.yaml", "sim_vehicle")
    for topic, key in (("state", "state_hz"), ("imu", "imu_hz"), ("rotor_speeds", "rotor_hz")):
        assert rates[topic] == pytest.approx(sim[key], rel=0.1), (topic, rates)


def test_phase1_launch_px4_sim_handback_on_process_group_sigint(ros, dom, tmp_path):
    """phase1.launch.py (excitation, mavlink_bridge, data_logger) against the package's
    simulated PX4 (``lpv-sysid sim-vehicle``, MAVLink over 127.0.0.1): OFFBOARD active,
    excitation running, then the terminal's Ctrl-C (SIGINT to the process group, launch
    forwards a second one): the bridge hands back and PX4's HEARTBEAT confirms HOLD before
    it exits 0, every node exits 0, the bag opens in rosbags (issue 11: exit 1 with
    "publisher's context is invalid", exit -2 with KeyboardInterrupt, no metadata.yaml)."""
    env = RosEnv(SETUP, ros["ws"], dom.value)
    port = free_udp_port()
    # input_timeout: the shipped 0.2 s of reference silence before a hand-back was exceeded
    # here (223 ms between two 100 Hz references, load ~10 on 2 cores from other processes);
    # this test is about the Ctrl-C, so a stale-input hand-back must not come first
    cfg = config_dir_with(
        ros,
        tmp_path,
        "mavlink_bridge_node.yaml",
        {"link.url": f"udpin:127.0.0.1:{port}", "offboard.input_timeout": 1.0},
    )
    t_px4_started = time.time_ns()  # the simulated PX4 boots after this (epoch ns)
    px4 = env.popen(
        f"{ros['lib']}/lpv-sysid sim-vehicle --udp 127.0.0.1:{port}", tmp_path / "px4_sim.log"
    )
    out = tmp_path / "phase1_log"
    proc = launch(
        ros,
        env,
        "phase1.launch.py",
        {
            "config_dir": cfg,  # its link.url is the link: no link_url argument (empty)
            "signals_file": ros["sig1"],
            "log_dir": out,
            "vertex": '"[1.0, 0.0, 0.0]"',
        },
        tmp_path / "launch.log",
    )
    try:
        wait_all(
            proc,
            [ready(n) for n in ("excitation", "mavlink_bridge", "data_logger")]
            + ["[lpv_sysid.mavlink_bridge]: link_up"],
        )
        t_link_up = time.time_ns()  # the simulated PX4 had booted by then
        assert (
            f"MAVLink udpin:127.0.0.1:{port} (from the link.url of the parameter file)"
            in proc.log()
        ), proc.log()[-4000:]
        got = parallel(
            topics=lambda: assert_graph_topics(
                env, ["velocity_reference", "excitation", "state", "imu", "rotor_speeds", "status"]
            ),
            start=lambda: trigger(env, f"{NS}/mavlink_bridge/start", proc),
        )
        assert got["start"][0], got["start"]
        assert proc.wait_for("OFFBOARD confirmed", 30.0), proc.log()[-4000:]
        ok, msg = trigger(env, f"{NS}/excitation/start", proc)
        assert ok, (msg, proc.log()[-6000:], px4.log()[-2000:])
        MEASURED["phase1_state_hz_ros2_topic_hz"] = topic_hz(env, f"{NS}/state", 5.0)
        assert "OFFBOARD" in proc.log().rsplit("OFFBOARD confirmed", 1)[
            1
        ] or not HANDBACK_DONE.search(proc.log()), "left OFFBOARD before the Ctrl-C"
        rc, dt = sigint_and_wait(proc, group=True)
    finally:
        proc.kill()
        px4_rc, _ = sigint_and_wait(px4, group=False)
    MEASURED["phase1_group_sigint"] = {"rc": rc, "s": dt}
    assert_launch_exit(
        proc,
        rc,
        ["excitation_node", "mavlink_bridge_node", "data_logger_node", "sequencer_node"],
    )
    assert "[lpv_sysid.excitation]: excitation faded out: shutdown" in proc.log()
    after = proc.log().rsplit("OFFBOARD confirmed", 1)[1]
    m = HANDBACK_DONE.search(after)
    assert m and m.group(1) == "HOLD", proc.log()[-4000:]
    MEASURED["phase1_handback"] = after[m.start() :].splitlines()[0]
    MEASURED["phase1_handback_confirmed_after_s"] = handback_latency(after)
    # the simulated PX4's own account: OFFBOARD, then HOLD commanded by the bridge
    assert px4_rc == 0
    modes = re.findall(r"t=\s*[0-9.]+ s\s+([A-Z_]+)", px4.log())
    assert "OFFBOARD" in modes and modes[-1] == "HOLD", px4.log()
    rates = check_recording(
        out, {"state": 50, "imu": 50, "velocity_reference": 50, "excitation": 50, "status": 2}
    )
    MEASURED["phase1_recorded_rates_hz"] = rates
    check_vehicle_record(out / "experiment.yaml", t_px4_started, t_link_up)
    # wall-clock streams at their configured rates: PX4's (the bridge's stream requests)
    # and the excitation's timer (30 %: the other processes of a loaded machine)
    bridge = yaml_parameters(cfg / "mavlink_bridge_node.yaml", "mavlink_bridge")
    exc = yaml_parameters(cfg / "excitation_node.yaml", "excitation")
    for topic, want in (
        ("imu", bridge["link.streams.HIGHRES_IMU"]),
        ("rotor_speeds", bridge["link.streams.ESC_STATUS"]),
        ("velocity_reference", exc["rate_hz"]),
        ("excitation", exc["rate_hz"]),
    ):
        assert rates[topic] == pytest.approx(want, rel=0.3), (topic, rates)


def test_phase2_launch_px4_sim_services_and_launch_sigint(ros, dom, tmp_path):
    """phase2.launch.py (excitation, lpv_controller, mavlink_bridge in attitude_rate,
    data_logger) against the simulated PX4: topics and types, every start / abort service
    answers (the bridge's abort hands back), then SIGINT to the launch process alone (it
    signals each node once): every node exits 0, the recording opens in rosbags."""
    env = RosEnv(SETUP, ros["ws"], dom.value)
    port = free_udp_port()
    unused = next(u for u in iter(free_udp_port, None) if u != port)
    # link.url of config_dir names a port no PX4 serves: the link_url argument wins over it
    cfg = config_dir_with(
        ros, tmp_path, "mavlink_bridge_node.yaml", {"link.url": f"udpin:127.0.0.1:{unused}"}
    )
    px4 = env.popen(
        f"{ros['lib']}/lpv-sysid sim-vehicle --udp 127.0.0.1:{port}", tmp_path / "px4_sim.log"
    )
    out = tmp_path / "phase2_log"
    proc = launch(
        ros,
        env,
        "phase2.launch.py",
        {
            "config_dir": cfg,
            "link_url": f"udpin:127.0.0.1:{port}",  # the launch argument wins over link.url
            "gains_file": ros["gains"],
            "signals_file": ros["sig2"],
            "log_dir": out,
        },
        tmp_path / "launch.log",
    )
    answers = {}
    try:
        wait_all(
            proc,
            [ready(n) for n in ("excitation", "lpv_controller", "mavlink_bridge", "data_logger")]
            + ["[lpv_sysid.mavlink_bridge]: link_up"],
        )
        assert (
            f"MAVLink udpin:127.0.0.1:{port} (from the link_url launch argument" in proc.log()
        ), proc.log()[-4000:]
        calls = {
            srv: (lambda srv=srv: trigger(env, f"{NS}/{srv}", proc))
            for srv in ("mavlink_bridge/start", "lpv_controller/start", "excitation/start")
        }
        answers.update(parallel(topics=lambda: assert_graph_topics(env, README_TYPES), **calls))
        answers.pop("topics")
        answers.update(
            parallel(
                **{
                    srv: (lambda srv=srv: trigger(env, f"{NS}/{srv}", proc))
                    for srv in ("excitation/abort", "lpv_controller/abort", "mavlink_bridge/abort")
                }
            )
        )
        rc, dt = sigint_and_wait(proc, group=False)
    finally:
        proc.kill()
        sigint_and_wait(px4, group=False)
    MEASURED["phase2_launch_sigint"] = {"rc": rc, "s": dt}
    MEASURED["phase2_services"] = {k: v[1] for k, v in answers.items()}
    # every service answers; a start may be refused naming a latched abort (under load the
    # bridged state can go stale for the controller: its abort then fades the excitation)
    for srv, (ok, msg) in answers.items():
        assert ok or srv.endswith("/start") and msg.startswith("aborted ("), (srv, msg)
    assert answers["mavlink_bridge/start"][0], answers
    assert answers["mavlink_bridge/abort"][1].startswith("handing control back to PX4"), answers
    assert_launch_exit(
        proc,
        rc,
        [
            "excitation_node",
            "lpv_controller_node",
            "mavlink_bridge_node",
            "data_logger_node",
            "sequencer_node",
        ],
    )
    check_recording(out, {"state": 20, "velocity_reference": 20, "excitation": 20, "status": 2})


@pytest.mark.xfail(
    reason="known defect (issue 27): through real rclpy the shipped 50-60 ms state/rotor "
    "timeouts can trip at the controller's start (state 57 ms old on a quiet 2-core machine; "
    "at load 15-19 the bridge's polls stamp a backlog of MAVLink states with one time, 10+ "
    "states per stamp up to 250 ms late, and rotor_speeds arrived 80 ms old); open",
    strict=False,
)
def test_phase2_launch_sequencer_starts_the_nodes_in_the_safe_order(ros, dom, tmp_path):
    """Issue 24 item 4: phase2.launch.py with ``link_url`` (no copied config directory) and
    ``auto_start:=true`` against the simulated PX4: the sequencer waits for the link, starts
    the controller, then the bridge (OFFBOARD confirmed), then the excitation, each after the
    previous one confirmed on its status; SIGINT ends everything with exit 0."""
    env = RosEnv(SETUP, ros["ws"], dom.value)
    port = free_udp_port()
    px4 = env.popen(
        f"{ros['lib']}/lpv-sysid sim-vehicle --udp 127.0.0.1:{port}", tmp_path / "px4_sim.log"
    )
    proc = launch(
        ros,
        env,
        "phase2.launch.py",
        {
            "link_url": f"udpin:127.0.0.1:{port}",
            "gains_file": ros["gains"],
            "signals_file": ros["sig2"],
            "log_dir": tmp_path / "phase2_log",
            "auto_start": "true",
        },
        tmp_path / "launch.log",
    )
    try:
        ok = proc.wait_for("sequence complete: every node started in order", 150.0)
        text = proc.log()
        steps = re.findall(r"\[lpv_sysid\.sequencer\]: (step \d/4: .*)", text)
        MEASURED["phase2_sequence"] = steps
        assert ok, text[-5000:]
        order = [m for m in steps if "confirmed" in m or ": start " in m]
        assert [o.split(": ", 1)[1].split(" (")[0] for o in order] == [
            "mavlink_bridge:ready confirmed",
            "start lpv_controller",
            "lpv_controller confirmed",
            "start mavlink_bridge",
            "mavlink_bridge confirmed",
            "start excitation",
            "excitation confirmed",
        ], steps
        rc, _ = sigint_and_wait(proc, group=False)
    finally:
        proc.kill()
        sigint_and_wait(px4, group=False)
    assert rc == 0, proc.log()[-4000:]


def test_campaign_launch_px4_sim_start_abort_process_group_sigint(ros, dom, tmp_path):
    """campaign.launch.py (mavlink_bridge arming, campaign, data_logger) against the
    simulated PX4: topics and types, the campaign's start (pre-stream, OFFBOARD, arm, take
    off) and abort (hand-back) services, then the terminal's Ctrl-C: every node exits 0
    and the whole-flight recording opens in rosbags. (It was an expected failure while
    campaign_node logged several severities from one call site -- real rclpy: "Logger
    severity cannot be changed between calls"; the nodes log through shell.log_lines, one
    call site per severity, and the stand-in enforces the rule: rclpy_probe.py.)"""
    env = RosEnv(SETUP, ros["ws"], dom.value)
    port = free_udp_port()
    cfg = config_dir_with(
        ros, tmp_path, "mavlink_bridge_node.yaml", {"link.url": f"udpin:127.0.0.1:{port}"}
    )
    px4 = env.popen(
        f"{ros['lib']}/lpv-sysid sim-vehicle --udp 127.0.0.1:{port} --param COM_OBL_RC_ACT=5",
        tmp_path / "px4_sim.log",
    )
    out = tmp_path / "campaign_log"
    proc = launch(
        ros,
        env,
        "campaign.launch.py",
        {
            "config_dir": cfg,
            "link_url": f"udpin:127.0.0.1:{port}",  # the launch argument sets the link
            "signals_file": ros["sig1"],
            "log_dir": out,
            "runs_dir": tmp_path / "runs",
        },
        tmp_path / "launch.log",
    )
    try:
        wait_all(
            proc,
            [ready(n) for n in ("mavlink_bridge", "campaign", "data_logger")]
            + ["[lpv_sysid.mavlink_bridge]: link_up"],
        )
        assert_graph_topics(
            env, ["velocity_reference", "excitation", "state", "imu", "rotor_speeds", "status"]
        )
        ok, msg = trigger(env, f"{NS}/campaign/start", proc)
        MEASURED["campaign_start"] = msg
        assert ok, msg
        assert proc.wait_for("OFFBOARD confirmed", 30.0), proc.log()[-4000:]
        ok, msg = trigger(env, f"{NS}/campaign/abort", proc)
        MEASURED["campaign_abort"] = msg
        assert ok, msg
        assert proc.wait_for("hand-back confirmed", 30.0), proc.log()[-4000:]
        rc, dt = sigint_and_wait(proc, group=True)
        MEASURED["campaign_group_sigint"] = {"rc": rc, "s": dt}
        assert_launch_exit(proc, rc, ["mavlink_bridge_node", "campaign_node", "data_logger_node"])
    finally:
        proc.kill()
        sigint_and_wait(px4, group=False)
    check_recording(out, {"state": 20, "velocity_reference": 20, "status": 2})


# ------------------------------------------------------- the stand-in against rclpy
#: the late status echo as README.md / docs/field_manual.md give it (the ``--qos-*`` options:
#: without them ``ros2 topic echo`` asks for transient local only when it has discovered the
#: publishers within its 0.5 s spin time)
LATE_STATUS_ECHO = (
    "ros2 topic echo --once /lpv_sysid/status "
    "--qos-durability transient_local --qos-reliability reliable"
)


def test_two_namespaced_vehicles_late_status_and_tf(ros, dom, tmp_path):
    """Issue 24 item 3 under real Jazzy: two simulated vehicles in ``uav1`` / ``uav2`` on
    one domain keep to their namespaces (``ros2 topic list``; a state subscriber of one
    sees only its own vehicle), a ``ros2 topic echo`` started long after a status was
    published still receives it (transient local: the stamp is older than the echo), and
    ``publish_tf`` puts odom -> base_link on /tf.

    The echo is the documented command (README, field manual). Measured before each node
    published its first status at start: the echo, 2 s after the node was ready, printed
    the status the 0.1 Hz timer published 5.7 s after the echo started (the first one)."""
    for doc in ("README.md", "docs/field_manual.md"):
        assert LATE_STATUS_ECHO in " ".join((ROOT / doc).read_text().split()), doc
    env = RosEnv(SETUP, ros["ws"], dom.value)
    # a partial ROS build may lack tf2_msgs (ros_base has it): then no TF part
    have_tf = env.run("python3 -c 'import tf2_msgs.msg'").returncode == 0
    MEASURED["tf2_msgs_available"] = have_tf
    procs = []
    try:
        for ns, extra in (("uav1", "-p publish_tf:=true" if have_tf else ""), ("uav2", "")):
            procs.append(
                env.popen(
                    f"{ros['lib']}/sim_vehicle_node --ros-args -r __ns:=/{ns} "
                    f"--params-file {ros['share']}/config/sim_vehicle.yaml "
                    f"-p status_rate_hz:=0.1 -p initial_velocity_frd:='[1.0, 0.0, 0.0]' {extra}",
                    tmp_path / f"{ns}.log",
                )
            )
        for p, ns in zip(procs, ("uav1", "uav2")):
            assert p.wait_for(f"[{ns}.sim_vehicle]: ready", 90.0), p.log()[-3000:]
        types = topic_types(env)
        for ns in ("uav1", "uav2"):
            for t in ("state", "imu", "rotor_speeds", "status"):
                assert types.get(f"/{ns}/{t}") == README_TYPES[t], (ns, t, types)
        assert not any(n.startswith(NS + "/") for n in types), types
        time.sleep(2.0)  # the first status (at start) is now seconds old; the next in ~8 s
        t_echo = time.time()
        echo = LATE_STATUS_ECHO.replace("/lpv_sysid/", "/uav2/")
        r = env.run(f"timeout 60 {echo} --no-daemon", timeout=90)  # CLI start at load: seconds
        assert "/uav2/sim_vehicle" in r.stdout and "/uav1/" not in r.stdout, r.stdout
        m = re.search(r"stamp:\s+sec: (\d+)\s+nanosec: (\d+)", r.stdout)
        stamp = int(m.group(1)) + int(m.group(2)) * 1e-9
        MEASURED["late_status_age_s"] = round(t_echo - stamp, 1)
        assert stamp < t_echo  # published before the subscriber existed: transient local
        if have_tf:
            r = env.run("timeout 60 ros2 topic echo --once /tf --no-daemon", timeout=90)
            assert "frame_id: odom" in r.stdout and "child_frame_id: base_link" in r.stdout
    finally:
        for p in procs:
            p.kill()


def test_standin_is_no_kinder_than_rclpy(ros, dom, tmp_path):
    """test/support/rclpy_probe.py under real rclpy and under the stand-in gives the same
    outcome in every case: the logger's one-severity-per-call-site rule and its keyword
    check, parameter typing from files (an integer for a double, [] and null in a file, a
    plain [] typed BYTE_ARRAY, an uninitialized parameter), publishing after shutdown or
    destruction, a spin on a shut-down context, message field checks, re-init."""
    probe = ROOT / "test" / "support" / "rclpy_probe.py"
    env = RosEnv(SETUP, ros["ws"], dom.value)
    (tmp_path / "real").mkdir()
    (tmp_path / "standin").mkdir()
    r = env.run(f"python3 {probe} {tmp_path / 'real'}", timeout=120, check=True)
    real = json.loads(r.stdout[r.stdout.index("{") :])
    support = str(ROOT / "test" / "support")
    path = os.pathsep.join([support, str(ROOT), os.environ.get("PYTHONPATH", "")])
    import sys

    s = subprocess.run(
        [sys.executable, str(probe), str(tmp_path / "standin")],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": path},
    )
    assert s.returncode == 0, s.stderr
    standin = json.loads(s.stdout[s.stdout.index("{") :])
    assert len(real) >= 30
    diff = {
        k: (real.get(k), standin.get(k))
        for k in set(real) | set(standin)
        if real.get(k) != standin.get(k)
    }
    assert diff == {}, diff


@pytest.mark.parametrize(
    "exe, typo",
    [
        ("mavlink_bridge_node", "telemetry_max_agee"),
        ("lpv_controller_node", "box_margn"),
        ("data_logger_node", "flush_intervall_s"),
    ],
)
def test_a_misspelt_parameter_is_refused_under_real_rclpy(ros, dom, tmp_path, exe, typo):
    """Issue 25 item 5 under real Jazzy rclpy: a ``-p`` key no declaration takes (rclpy keeps
    it in the node's overrides) ends the node at start, exit 2, naming the key -- the node
    does not run on its defaults."""
    env = RosEnv(SETUP, ros["ws"], dom.value)
    node, params_file, _ = NODES[exe]
    extra = f" -p gains_file:={ros['gains']}" if exe == "lpv_controller_node" else ""
    r = env.run(
        f"timeout -s KILL 60 {ros['lib']}/{exe} --ros-args --params-file "
        f"{ros['share']}/config/{params_file}{extra} -p {typo}:=1.0",
        timeout=90,
    )
    out = r.stdout + r.stderr
    assert r.returncode == 2, out[-3000:]
    assert typo in out and "unknown" in out.lower(), out[-3000:]


def test_an_out_of_range_parameter_is_one_fatal_line_under_real_rclpy(ros, dom, tmp_path):
    """Under real Jazzy rclpy a ``-p`` value outside the declared range ends the node at
    start with exit 2 and one FATAL line naming the parameter, not rclpy's traceback."""
    env = RosEnv(SETUP, ros["ws"], dom.value)
    r = env.run(
        f"timeout -s KILL 60 {ros['lib']}/lpv_controller_node --ros-args --params-file "
        f"{ros['share']}/config/lpv_controller.yaml -p gains_file:={ros['gains']} "
        "-p status_rate_hz:=0.05",
        timeout=90,
    )
    out = r.stdout + r.stderr
    assert r.returncode == 2, out[-3000:]
    assert "parameter 'status_rate_hz'" in out and "Traceback" not in out, out[-3000:]
