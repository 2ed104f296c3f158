"""lpv_controller_node through a real ROS 2 (rclpy) beside a trivial echo node (issue 27 item 1).

    source /opt/ros/jazzy/setup.bash
    PYTHONPATH=$PWD python3 -m bench.bench_node_rclpy [--seconds 20] [--runs 3]
    PYTHONPATH=$PWD python3 -m bench.bench_node_rclpy --choices [--seconds 10] [--runs 2]

``--choices``: the executor x state-queue-depth study (:data:`CHOICES`), written to
bench/results/node_rclpy_choices.md. ``--executor`` / ``--depth``: one choice for every target.

Without rclpy it prints one line and records "not measured". Per run, three processes on an
isolated ``ROS_DOMAIN_ID`` (localhost only): a publisher (``state`` nav_msgs/Odometry at
250 Hz holding the gains' box-centre trim, ``rotor_speeds``, ``velocity_reference`` and
``excitation`` at 100 Hz, QoS as the shells declare), the node under test, and a receiver of
``actuator_command`` that records receipt time minus header stamp. Nodes under test, in
turn within each run (interleaved, so they share the machine's load):

- ``controller (tick on state)``: the shipped config/lpv_controller.yaml with
  ``tick_source: state`` and ``auto_start`` -- one command per state sample, stamped with it,
  so receipt - stamp is the state-to-command latency;
- ``controller (vehicle: timer 250 Hz)``: the shipped configuration (timer tick): CPU only
  (its commands carry the tick time, not the state's);
- ``echo``: an rclpy node whose state callback publishes a JointState stamped with the
  state's stamp (the rclpy floor: deserialise, callback, build, publish).

Reported per node: CPU share of one core over the measurement window (``time.process_time``
of its process), latency p50 / p99 / max, and bursts: the longest run of consecutive samples
above 8 ms (its duration). Writes bench/results/node_rclpy.md / .rows.json.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from bench.harness import Page, Row, Stat, load_average, percentile, repo_root, status

NS = "/lpv_sysid"
WARMUP_S = 3.0  # discovery and the controller's start before the window opens
BURST_MS = 8.0
TIMEOUTS = ("state_timeout_s", "rotor_timeout_s", "reference_timeout_s", "excitation_timeout_s")
TARGETS = ("controller_state", "echo", "controller_timer")
LABEL = {
    "controller_state": "controller (tick on state)",
    "echo": "echo node (Odometry in, JointState out)",
    "controller_timer": "controller (vehicle: timer 250 Hz)",
}


def _rclpy_missing() -> str:
    try:
        import rclpy  # noqa: F401
        from nav_msgs.msg import Odometry  # noqa: F401
    except ImportError as exc:
        return f"no ROS 2 rclpy ({exc}); source /opt/ros/jazzy/setup.bash first"
    return ""


def _hover(gains: str):
    """(state as NED/FRD arrays, rotor speeds) of the box-centre trim of ``gains``."""
    import numpy as np

    from lpv_sysid.io.formats import GainSchedule
    from lpv_sysid.models.quadrotor import mixer

    gs = GainSchedule.load(gains, auto_layout=True)
    x0 = gs.x0.mean(axis=0)
    return x0[:8], np.linalg.solve(mixer(0.225), x0[8:])


# ------------------------------------------------------------------------------ roles
def role_publisher(gains: str, seconds: float) -> dict:
    import rclpy
    from geometry_msgs.msg import TwistStamped
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import JointState

    from lpv_sysid.io import messages
    from lpv_sysid.nodes import shell

    rclpy.init()
    node = rclpy.create_node("bench_publisher", namespace=NS)
    f = messages.MsgFactory.rclpy()
    x8, om = _hover(gains)
    pubs = {
        "state": node.create_publisher(Odometry, "state", shell.qos_for("state")),
        "rotor_speeds": node.create_publisher(
            JointState, "rotor_speeds", shell.qos_for("rotor_speeds")
        ),
        "velocity_reference": node.create_publisher(
            TwistStamped, "velocity_reference", shell.qos_for("velocity_reference")
        ),
        "excitation": node.create_publisher(JointState, "excitation", shell.qos_for("excitation")),
    }
    clock = node.get_clock()
    sent = {"state": 0, "slow": 0}

    def state():
        ns = clock.now().nanoseconds
        euler = [x8[0], x8[1], 0.0]
        pubs["state"].publish(
            messages.odometry_from_state(f, ns, [0.0, 0.0, -10.0], euler, x8[2:5], x8[5:8])
        )
        sent["state"] += 1

    def slow():
        ns = clock.now().nanoseconds
        pubs["rotor_speeds"].publish(messages.rotor_speeds_msg(f, ns, om))
        pubs["velocity_reference"].publish(messages.twist_reference_msg(f, ns, [0.0, 0.0, 0.0]))
        pubs["excitation"].publish(messages.excitation_msg(f, ns, [0.0, 0.0, 0.0, 0.0]))
        sent["slow"] += 1

    node.create_timer(1 / 250, state)
    node.create_timer(1 / 100, slow)
    end = time.monotonic() + WARMUP_S + seconds
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    node.destroy_node()
    rclpy.shutdown()
    return sent


def _cpu_window(seconds: float, out: dict) -> threading.Thread:
    """A thread that reads this process's CPU time when the window opens and closes."""

    def run():
        time.sleep(WARMUP_S)
        c0, w0 = time.process_time(), time.monotonic()
        time.sleep(seconds)
        out["cpu_s"], out["wall_s"] = time.process_time() - c0, time.monotonic() - w0

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def role_target(
    kind: str, gains: str, seconds: float, executor: str = "node", depth: int = 0
) -> dict:
    """``executor``: ``node`` (the node class's choice, ``shell.run``'s: the controller's
    LeanExecutor, SingleThreadedExecutor for the echo), ``single`` (rclpy's
    SingleThreadedExecutor) or ``lean``; ``depth`` > 0: the keep-last depth of the ``state``
    subscription instead of the declared one."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from lpv_sysid.nodes import shell
    from lpv_sysid.nodes.lean_executor import LeanExecutor

    if depth > 0:
        declared = shell.qos_for

        def qos_for(topic: str):
            q = declared(topic)
            if topic == "state":
                q.depth = depth
            return q

        shell.qos_for = qos_for  # type: ignore[assignment]
    out: dict = {}
    rclpy.init()
    if kind == "echo":
        from nav_msgs.msg import Odometry
        from sensor_msgs.msg import JointState

        node = rclpy.create_node("bench_echo", namespace=NS)
        pub = node.create_publisher(
            JointState, "actuator_command", shell.qos_for("actuator_command")
        )
        names = ["ut", "ua", "ue", "ur"]

        def echo(msg):
            cmd = JointState()
            cmd.header.stamp = msg.header.stamp
            cmd.name = names
            t = msg.twist.twist.linear
            cmd.position = [t.x, t.y, t.z, 0.0]
            pub.publish(cmd)

        node.create_subscription(Odometry, "state", echo, shell.qos_for("state"))
    else:
        from lpv_sysid.nodes.lpv_controller_node import LpvControllerNode

        tick = "state" if kind == "controller_state" else "timer"
        yaml = str(repo_root() / "config" / "lpv_controller.yaml")
        node = LpvControllerNode(
            cli_args=[
                "--ros-args",
                "--params-file",
                yaml,
                "-p",
                f"gains_file:={gains}",
                "-p",
                "auto_start:=true",
                "-p",
                f"tick_source:={tick}",
                # a load spike must not end the run: the cost per sample is measured here
                # (the shipped 50-100 ms timeouts abort under load ~5: reported separately)
                *sum((["-p", f"{k}:=0.5"] for k in TIMEOUTS), []),
            ]
        )
    choice = {"single": SingleThreadedExecutor, "lean": LeanExecutor}
    ex = choice.get(executor, getattr(node, "EXECUTOR", SingleThreadedExecutor))()
    ex.add_node(node)
    window = _cpu_window(seconds, out)
    end = time.monotonic() + WARMUP_S + seconds + 0.2  # before the publisher stops
    while time.monotonic() < end:
        ex.spin_once(timeout_sec=0.05)
    window.join()
    if kind != "echo":
        out["commands"] = node.runtime.commands
        ev = node.runtime.supervisor.event
        out["abort"] = "" if ev is None else f"{ev.reason}: {ev.detail}"
    node.destroy_node()
    rclpy.shutdown()
    return out


def role_receiver(seconds: float) -> dict:
    import rclpy
    from sensor_msgs.msg import JointState

    from lpv_sysid.nodes import shell

    rclpy.init()
    node = rclpy.create_node("bench_receiver", namespace=NS)
    clock = node.get_clock()
    lat: list = []
    t_open = time.monotonic() + WARMUP_S
    t_close = t_open + seconds

    def on_cmd(msg):
        now = time.monotonic()
        if t_open <= now < t_close:
            st = msg.header.stamp
            lat.append((clock.now().nanoseconds - (st.sec * 10**9 + st.nanosec)) * 1e-6)

    node.create_subscription(
        JointState, "actuator_command", on_cmd, shell.qos_for("actuator_command")
    )
    while time.monotonic() < t_close + 0.5:
        rclpy.spin_once(node, timeout_sec=0.05)
    node.destroy_node()
    rclpy.shutdown()
    return {"latency_ms": lat}


# ------------------------------------------------------------------------------ driver
def _spawn(role: str, args: list, env: dict, out: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "bench.bench_node_rclpy", "--role", role, "--json", str(out)]
        + args,
        cwd=repo_root(),
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


def measure(
    kind: str,
    gains: str,
    seconds: float,
    tmp: Path,
    domain: int,
    executor: str = "node",
    depth: int = 0,
) -> dict:
    env = {
        **os.environ,
        "ROS_DOMAIN_ID": str(domain),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
    }
    common = ["--gains", gains, "--seconds", str(seconds)]
    files = {r: tmp / f"{kind}_{r}.json" for r in ("receiver", "target", "publisher")}
    procs = {
        "receiver": _spawn("receiver", common, env, files["receiver"]),
        "target": _spawn(
            kind, common + ["--executor", executor, "--depth", str(depth)], env, files["target"]
        ),
    }
    time.sleep(0.5)
    procs["publisher"] = _spawn("publisher", common, env, files["publisher"])
    for name, p in procs.items():
        _, err = p.communicate(timeout=WARMUP_S + seconds + 60)
        if p.returncode != 0:
            raise SystemExit(f"{kind} {name}: exit {p.returncode}\n{err[-2000:]}")
    res = {r: json.loads(files[r].read_text()) for r in files}
    lat = res["receiver"]["latency_ms"]
    longest, run = 0.0, 0
    for x in lat:
        run = run + 1 if x > BURST_MS else 0
        longest = max(longest, run * 4.0)  # samples at 250 Hz -> ms
    tgt = res["target"]
    return {
        "cpu": tgt["cpu_s"] / tgt["wall_s"],
        "n": len(lat),
        "sent": res["publisher"]["state"],
        "p50": percentile(lat, 0.5),
        "p99": percentile(lat, 0.99),
        "max": max(lat) if lat else float("nan"),
        "burst_ms": longest,
        "abort": tgt.get("abort", ""),
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--role", default=None)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--gains", default=str(repo_root() / "msg_samples" / "gains.yaml"))
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument(
        "--executor",
        choices=("node", "single", "lean"),
        default="node",
        help="executor of the node under test (node: the node class's, as shell.run spins it)",
    )
    ap.add_argument("--depth", type=int, default=0, help="> 0: state subscription depth")
    ap.add_argument(
        "--choices",
        action="store_true",
        help="the executor x state-depth study (issue 27): controller (tick on state) under "
        "rclpy's SingleThreadedExecutor and the LeanExecutor, depth 1/5/10, beside the echo",
    )
    args = ap.parse_args(argv)
    if args.role is not None:
        if args.role == "receiver":
            res = role_receiver(args.seconds)
        elif args.role == "publisher":
            res = role_publisher(args.gains, args.seconds)
        else:
            res = role_target(args.role, args.gains, args.seconds, args.executor, args.depth)
        args.json.write_text(json.dumps(res))
        return
    load0 = load_average()
    page = Page(
        "node_rclpy",
        "lpv_controller_node through real rclpy beside an echo node (issue 27 item 1)",
        f"source /opt/ros/jazzy/setup.bash; python3 -m bench.bench_node_rclpy --seconds "
        f"{args.seconds:g} --runs {args.runs}",
    )
    why = _rclpy_missing()
    if why:
        print(f"bench_node_rclpy skipped: {why}")
        page.add(f"Not measured: {why}.")
        page.rows.append(
            Row(
                "controller node through real rclpy (CPU, state-to-command latency)",
                "27",
                "not measured (no ROS 2 on the machine of the last run)",
                target="CPU <= 1.5x echo, p99 <= 2x echo (same run)",
                status=status(None, "not measured"),
                order=41,
            )
        )
        page.write(load0)
        return
    if args.choices:
        return choices(args, load0)
    results: dict = {k: [] for k in TARGETS}
    loads = []
    with tempfile.TemporaryDirectory(prefix="bench_node_rclpy_") as tmp:
        for r in range(args.runs):
            order = TARGETS if r % 2 == 0 else TARGETS[::-1]
            for i, kind in enumerate(order):
                loads.append(load_average())
                results[kind].append(measure(kind, args.gains, args.seconds, Path(tmp), 60 + i))
    lines = []
    for kind in TARGETS:
        rs = results[kind]
        cpu = Stat([x["cpu"] for x in rs])
        lat = kind != "controller_timer"
        lines.append(
            [
                LABEL[kind],
                f"{100 * cpu.median:.1f} % [{100 * cpu.p10:.1f}-{100 * cpu.p90:.1f}]",
                *(
                    [
                        f"{Stat([x[k] for x in rs]).median:.2f} ms" + _spread(rs, k)
                        for k in ("p50", "p99", "max")
                    ]
                    if lat
                    else ["-", "-", "-"]
                ),
                f"{Stat([x['burst_ms'] for x in rs]).median:.0f} ms" if lat else "-",
                f"{sum(x['n'] for x in rs)}",
                "; ".join(sorted({x["abort"] for x in rs if x["abort"]})) or "none",
            ]
        )
    page.add(
        f"{args.runs} runs of {args.seconds:g} s per node, interleaved; load average "
        f"{min(loads):.1f}-{max(loads):.1f} at the starts. CPU: share of one core of the node's "
        "process over the window; latency: receipt - header stamp at the receiver (median over "
        f"runs [min-max]); burst: longest run of consecutive samples above {BURST_MS:g} ms. The "
        "controllers run config/lpv_controller.yaml with the four stream timeouts at 0.5 s (a "
        "load spike must not end a cost measurement; with the shipped 50-100 ms both "
        "configurations aborted stale within 10 s at load 5-7 in a first run)."
    )
    page.add()
    page.table(
        ["node", "CPU", "p50", "p99", "max", "longest burst", "commands in the windows", "aborts"],
        lines,
    )
    c = Stat([x["cpu"] for x in results["controller_state"]]).median
    e = Stat([x["cpu"] for x in results["echo"]]).median
    cp = Stat([x["p99"] for x in results["controller_state"]]).median
    ep = Stat([x["p99"] for x in results["echo"]]).median
    v = Stat([x["cpu"] for x in results["controller_timer"]]).median
    page.rows.append(
        Row(
            "controller node through real rclpy (CPU, state-to-command latency)",
            "27",
            f"vehicle config (timer 250 Hz) CPU {100 * v:.1f} % of a core; tick on state "
            f"{100 * c:.1f} %, p99 {cp:.2f} ms",
            f"echo {100 * e:.1f} %, p99 {ep:.2f} ms",
            f"CPU {v / e:.2f}x (tick on state {c / e:.2f}x), p99 {cp / ep:.2f}x",
            "CPU <= 1.5x echo (vehicle config), p99 <= 2x echo (same run)",
            status(v <= 1.5 * e and cp <= 2 * ep),
            order=41,
        )
    )
    page.write(load0)


#: the executor x depth study: (label, target kind, executor, state depth; 0: declared)
CHOICES = (
    ("echo (SingleThreadedExecutor, depth 5)", "echo", "single", 0),
    ("controller, SingleThreadedExecutor, depth 1", "controller_state", "single", 1),
    ("controller, SingleThreadedExecutor, depth 5", "controller_state", "single", 5),
    ("controller, SingleThreadedExecutor, depth 10", "controller_state", "single", 10),
    ("controller, LeanExecutor, depth 1", "controller_state", "lean", 1),
    ("controller, LeanExecutor, depth 5", "controller_state", "lean", 5),
    ("controller, LeanExecutor, depth 10", "controller_state", "lean", 10),
    (
        "controller (vehicle: timer 250 Hz), SingleThreadedExecutor",
        "controller_timer",
        "single",
        0,
    ),
    ("controller (vehicle: timer 250 Hz), LeanExecutor", "controller_timer", "lean", 0),
)


def choices(args, load0: float) -> None:
    """The ``--choices`` study: every configuration of :data:`CHOICES` per run, interleaved
    (the order reversed every other run); CPU, latency and commands per window. Writes
    bench/results/node_rclpy_choices.md."""
    page = Page(
        "node_rclpy_choices",
        "lpv_controller_node: executor and state-queue depth through real rclpy (issue 27)",
        f"source /opt/ros/jazzy/setup.bash; python3 -m bench.bench_node_rclpy --choices "
        f"--seconds {args.seconds:g} --runs {args.runs}",
    )
    results: dict = {c[0]: [] for c in CHOICES}
    loads = []
    with tempfile.TemporaryDirectory(prefix="bench_node_rclpy_") as tmp:
        for r in range(args.runs):
            for i, (label, kind, ex, depth) in enumerate(CHOICES if r % 2 == 0 else CHOICES[::-1]):
                loads.append(load_average())
                results[label].append(
                    measure(kind, args.gains, args.seconds, Path(tmp), 60 + i, ex, depth)
                )
    lines = []
    for label, kind, _, _ in CHOICES:
        rs = results[label]
        cpu = Stat([x["cpu"] for x in rs])
        lat = kind != "controller_timer"
        lines.append(
            [
                label,
                f"{100 * cpu.median:.1f} % [{100 * cpu.p10:.1f}-{100 * cpu.p90:.1f}]",
                *(
                    [
                        f"{Stat([x[k] for x in rs]).median:.2f} ms" + _spread(rs, k)
                        for k in ("p50", "p99", "max")
                    ]
                    if lat
                    else ["-", "-", "-"]
                ),
                f"{sum(x['n'] for x in rs)}" if lat else "-",
                "; ".join(sorted({x["abort"] for x in rs if x["abort"]})) or "none",
            ]
        )
    page.add(
        f"Executor and state-queue depth (issue 27): {args.runs} runs of {args.seconds:g} s per "
        f"configuration, interleaved; load average {min(loads):.1f}-{max(loads):.1f} at the "
        "starts. Jazzy's rclpy (7.1) has no EventsExecutor (rclpy.experimental is not in it); "
        "MultiThreadedExecutor adds a thread pool to the same Python wait-set rebuild. Commands "
        "received in the windows: one per state sample that reached the controller (tick on "
        "state), so fewer means samples dropped or late."
    )
    page.add()
    page.table(
        ["configuration", "CPU", "p50", "p99", "max", "commands in the windows", "aborts"], lines
    )
    page.write(load0)


def _spread(rs: list, k: str) -> str:
    v = [x[k] for x in rs]
    return f" [{min(v):.2f}-{max(v):.2f}]"


if __name__ == "__main__":
    main()
