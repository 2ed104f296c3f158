"""CPU cost of the lpv_controller node's message path, and replay throughput.

Run: ``.venv/bin/python -m bench.bench_controller_node`` (prints medians of 3 runs).

1. Controller runtime at 250 Hz state input: one simulated second of the phase-2 sample's
   input (state 250 Hz, rotor_speeds / velocity_reference / excitation 100 Hz) plus 250
   ticks (safety supervisor + LPV law + actuator_command message) through
   :class:`lpv_sysid.nodes.controller_runtime.ControllerRuntime`; CPU share of one core =
   process time per simulated second (target < 5 %).
2. ``lpv-sysid replay`` of a 60 s, 250 Hz bag (the 5 s phase-2 sample tiled 12 times with
   shifted stamps: 15000 state + 3 x 6000 other inputs); wall time of
   :func:`lpv_sysid.cli.replay.replay_controller` including bag reading and writing
   (target < 2 s).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLE = os.path.join(ROOT, "msg_samples", "phase2_sim", "bag_0000")
GAINS = os.path.join(ROOT, "msg_samples", "gains.yaml")
NS = "/lpv_sysid"
INPUTS = ("state", "rotor_speeds", "velocity_reference", "excitation")


def _runtime():
    from lpv_sysid.io import messages as M
    from lpv_sysid.nodes.controller_runtime import ControllerRuntime, ControllerSettings

    return ControllerRuntime(ControllerSettings(gains_file=GAINS), M.MsgFactory.rosbags())


def bench_runtime(seconds: float = 4.0, ticks: list | None = None) -> float:
    """Process time per simulated second (s/s) of inputs + 250 Hz ticks; ``ticks`` collects
    the wall time of every ``tick`` (s)."""
    from lpv_sysid.io.bag import read_bag

    data = read_bag(SAMPLE, topics=[f"{NS}/{t}" for t in INPUTS])
    events = sorted((ns, t[len(NS) + 1 :], m) for t in data for ns, m in data[t])
    t0 = events[0][0]
    events = [e for e in events if e[0] - t0 < seconds * 1e9]
    rt = _runtime()
    rt.start(t0 * 1e-9)
    period = 4_000_000
    nxt = t0 + period
    c0 = time.process_time()
    pc = time.perf_counter
    for ns, topic, msg in events:
        while nxt <= ns:
            w0 = pc()
            rt.tick(nxt * 1e-9)
            if ticks is not None:
                ticks.append(pc() - w0)
            nxt += period
        rt.on_message(topic, msg, ns * 1e-9)
    cpu = time.process_time() - c0
    assert rt.supervisor.event is None and rt.commands > 200 * seconds
    return cpu / seconds


def make_60s_bag(path: str) -> int:
    """Tile the 5 s sample to 60 s (stamps shifted by 5 s per copy)."""
    from lpv_sysid.io.bag import BagWriter, read_bag

    data = read_bag(SAMPLE, topics=[f"{NS}/{t}" for t in INPUTS])
    span = 5_000_000_000
    n = 0
    with BagWriter(path) as w:
        for t in data:
            w.add_topic(t, data.types[t])
        for k in range(12):
            for t in data:
                for ns, msg in data[t]:
                    st = msg.header.stamp
                    orig = (st.sec, st.nanosec)
                    st.sec, st.nanosec = divmod(st.sec * 10**9 + st.nanosec + k * span, 10**9)
                    w.write(t, ns + k * span, msg)
                    st.sec, st.nanosec = orig
                    n += 1
    return n


def bench_replay(tmp: str) -> tuple[float, float, dict]:
    from lpv_sysid.cli.replay import replay_controller

    bag = os.path.join(tmp, "in60")
    if not os.path.exists(bag):
        make_60s_bag(bag)
    out = os.path.join(tmp, "out")
    shutil.rmtree(out, ignore_errors=True)
    w0, c0 = time.perf_counter(), time.process_time()
    s = replay_controller(bag, {"gains_file": GAINS}, out, ticks="rate")
    return time.perf_counter() - w0, time.process_time() - c0, s


def main() -> None:
    from bench.harness import Page, Row, Stat, load_average, status

    load0 = load_average()
    page = Page(
        "nodes",
        "lpv_controller node path and replay (issues 6, 15)",
        ".venv/bin/python -m bench.bench_controller_node",
    )
    ticks: list = []
    cpu = [bench_runtime(ticks=ticks) for _ in range(3)]
    tk = Stat(ticks)
    page.add(
        "## Controller runtime at 250 Hz (msg_samples/phase2_sim inputs, msg_samples/gains.yaml)"
    )
    page.add()
    page.table(
        ["what", "value"],
        [
            [
                "CPU share of one core (inputs + ticks per simulated second)",
                f"median {100 * Stat(cpu).median:.2f} % (runs {', '.join(f'{100 * c:.2f}' for c in cpu)} %)",
            ],
            [
                "one tick (supervisor + LPV law + actuator_command), wall",
                f"median {tk.median * 1e6:.1f} us, "
                f"p90 {tk.p90 * 1e6:.1f} us, p99 {tk.p99 * 1e6:.1f} us, max {max(ticks) * 1e6:.0f} us (n={len(ticks)})",
            ],
        ],
    )
    with tempfile.TemporaryDirectory() as tmp:
        times, cpus = [], []
        for _ in range(3):
            dt, dc, s = bench_replay(tmp)
            times.append(dt)
            cpus.append(dc)
    page.add(
        f"## `lpv-sysid replay` of a {s['duration_s']:.1f} s bag ({s['inputs']} input messages, "
        f"{s['commands']} commands)"
    )
    page.add()
    page.table(
        ["what", "median [p10-p90]"],
        [["wall", Stat(times).fmt(1, "s")], ["CPU", Stat(cpus).fmt(1, "s")]],
    )
    page.rows.append(
        Row(
            "controller node tick @ 250 Hz",
            "6, 15",
            f"median {tk.median * 1e6:.0f} us, p99 {tk.p99 * 1e6:.0f} us; {100 * Stat(cpu).median:.2f} % "
            "of one core",
            target="<= 30 us median; bounded tail",
            status=status(None, "measured only (nodes/ owned elsewhere)"),
            order=7,
        )
    )
    page.rows.append(
        Row(
            "replay of a 60 s 250 Hz bag",
            "6",
            f"{Stat(times).median:.2f} s wall, {Stat(cpus).median:.2f} s CPU",
            target="< 2 s",
            status=status(Stat(times).median < 2.0),
            order=21,
        )
    )
    page.write(load0)


if __name__ == "__main__":
    main()
