"""Timing of the quadrotor model, baseline controller and a phase-1 run.

Run: ``.venv/bin/python -m bench.bench_model`` (prints medians).
"""

from __future__ import annotations

import statistics
import tempfile
import time
from dataclasses import replace

from lpv_sysid.control.baseline import BaselineController, BaselineGains
from lpv_sysid.models.quadrotor import Quadrotor
from lpv_sysid.sim import phase1
from lpv_sysid.sim.vehicle import SensorConfig, SimVehicle


def _median_us(fn, n: int, repeat: int = 5) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        times.append((time.perf_counter() - t0) / n * 1e6)
    return statistics.median(times)


def main() -> None:
    q = Quadrotor()
    tr = q.trim([5.0, -5.0, 5.0])
    x16, u = tr.full_state, tr.u0
    xl, ul = x16.tolist(), u.tolist()
    print(f"derivatives() numpy API      : {_median_us(lambda: q.derivatives(x16, u), 5000):8.2f} us/call (median of 5)")
    print(f"derivatives_list() hot path  : {_median_us(lambda: q.derivatives_list(xl, ul), 5000):8.2f} us/call")
    veh = SimVehicle(q, SensorConfig(), x16)
    print(f"SimVehicle.step (RK4, 4 eval): {_median_us(lambda: veh.step(ul), 2000):8.2f} us/step")
    c = BaselineController(BaselineGains())
    c.warm_start(tr.x0, tr.u0, [5, -5, 5])
    print(f"BaselineController.step      : {_median_us(lambda: c.step(0.0, tr.x0, (5, -5, 5), 0.0), 2000):8.2f} us/call")
    print(f"linearize() analytic A, B    : {_median_us(lambda: q.linearize(tr), 200):8.2f} us/call")
    print(f"trim() least squares         : {_median_us(lambda: q.trim([5.0, -5.0, 5.0]), 5, 3) / 1e3:8.2f} ms/call")
    cfg = replace(phase1.Phase1Config(), hover_validation=False)
    runs = []
    for _ in range(3):
        t0 = time.perf_counter()
        rec = phase1.run_phase1(q, BaselineGains(), SensorConfig(), cfg, [8])[0]
        runs.append(time.perf_counter() - t0)
    print(f"phase-1 run, 40 s at 500 Hz  : {statistics.median(runs):8.2f} s (median of 3; x9 runs "
          f"~{9 * statistics.median(runs):.0f} s without bag writing)")
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        phase1.write_run_bag(rec, f"{tmp}/run")
        print(f"write_run_bag (40 s, mcap)   : {time.perf_counter() - t0:8.2f} s (single run)")


if __name__ == "__main__":
    main()
