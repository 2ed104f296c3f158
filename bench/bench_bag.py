"""Throughput of rosbag2 writing and reading (io/bag.py) and of message building.

Run: ``.venv/bin/python -m bench.bench_bag`` (prints medians of 3 runs).

A 500 Hz phase-1 experiment publishes about 500 (state) + 500 (rotor_speeds) + 500 (imu)
+ 50 (reference/excitation/command) messages per second, so the logger must sustain
~2000 msgs/s with margin.
"""

from __future__ import annotations

import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from lpv_sysid.io import bag as bg
from lpv_sysid.io import messages as m

N = 6000      # messages per run: 3000 Odometry + 3000 JointState


def _messages(f):
    rng = np.random.default_rng(0)
    out = []
    for i in range(N // 2):
        ns = 1_700_000_000_000_000_000 + i * 2_000_000
        out.append(("/state", ns, m.odometry_from_state(f, ns, *rng.normal(size=(4, 3)) * 0.3)))
        out.append(("/rotor_speeds", ns, m.rotor_speeds_msg(f, ns, rng.uniform(300, 900, 4))))
    return out


def _run(storage: str, msgs, root: Path, k: int) -> tuple[float, float, int]:
    path = root / f"{storage}_{k}"
    t0 = time.perf_counter()
    with bg.BagWriter(path, storage=storage) as b:
        b.add_topic("/state", "nav_msgs/msg/Odometry")
        b.add_topic("/rotor_speeds", "sensor_msgs/msg/JointState")
        for topic, ns, msg in msgs:
            b.write(topic, ns, msg)
    t1 = time.perf_counter()
    data = bg.read_bag(path)
    t2 = time.perf_counter()
    n = sum(len(v) for v in data.values())
    assert n == len(msgs), (n, len(msgs))
    size = sum(p.stat().st_size for p in path.iterdir())
    return len(msgs) / (t1 - t0), len(msgs) / (t2 - t1), size


def main() -> None:
    f = m.MsgFactory.rosbags()
    t0 = time.perf_counter()
    msgs = _messages(f)
    build = len(msgs) / (time.perf_counter() - t0)
    print(f"message building (Odometry+JointState, rosbags) : {build:9.0f} msgs/s")
    t0 = time.perf_counter()
    for topic, _, msg in msgs[:2000]:
        if topic == "/state":
            m.state_from_odometry(msg)
        else:
            m.rotor_speeds_from_joint_state(msg)
    print(f"message parsing (state_from_odometry, ...)      : {2000 / (time.perf_counter() - t0):9.0f} msgs/s")
    odom = [msg for topic, _, msg in msgs if topic == "/state"]
    t0 = time.perf_counter()
    m.states_from_odometry(odom)
    print(f"batch parsing (states_from_odometry)            : {len(odom) / (time.perf_counter() - t0):9.0f} msgs/s")
    root = Path(tempfile.mkdtemp(prefix="bench_bag_"))
    try:
        for storage in ("mcap", "sqlite3"):
            runs = [_run(storage, msgs, root, k) for k in range(3)]
            w = statistics.median(r[0] for r in runs)
            r = statistics.median(r[1] for r in runs)
            size = runs[0][2]
            print(f"{storage:7s} write {N} msgs (serialise + store)    : {w:9.0f} msgs/s "
                  f"(median of 3, {size / N:.0f} B/msg on disk)")
            print(f"{storage:7s} read_bag (read + deserialise)         : {r:9.0f} msgs/s (median of 3)")
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
