"""Timing of the phase-2 simulations: Eq. (33) right-hand side and runs, nonlinear run, report.

Run: ``.venv/bin/python -m bench.bench_phase2`` (prints medians). Uses a 12-state, 8-vertex
LPV model of the simulated quadrotor (vertex trims + analytic linearisation, LQR vertex
gains) over the box [-2, 2]^3 m/s; the signals are 10 s at 50 Hz.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.linalg import solve_continuous_are

from lpv_sysid.models.lpv import PolytopicModel, ScheduledLpv, box_vertices
from lpv_sysid.models.quadrotor import Quadrotor
from lpv_sysid.sim.lpv_closed_loop import (
    ClosedLoopConfig,
    LastPointCache,
    ReferenceSignals,
    eq33_rhs,
    linear_lpv_law,
    simulate_eq33,
)
from lpv_sysid.sim.phase2 import Phase2Config, Phase2Problem, run
from lpv_sysid.sim.vehicle import SensorConfig

R = np.diag([0.02, 0.002, 0.002, 0.02])
Q = 5.0 * np.eye(3)


def _median(fn, repeat: int = 3) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _setup(box: float = 2.0):
    quad = Quadrotor()
    A, B, X0, U0, K = [], [], [], [], []
    Qw = np.diag([1, 1, 20, 20, 20, 0.1, 0.1, 0.1, 1e-6, 1e-4, 1e-4, 1e-6])
    Rw = np.diag([10.0, 100.0, 100.0, 10.0])
    for v in box_vertices([-box] * 3, [box] * 3):
        tr = quad.trim(v)
        a, b = quad.linearize(tr)
        P = solve_continuous_are(a, b, Qw, Rw)
        A.append(a); B.append(b); X0.append(tr.x0); U0.append(tr.u0)
        K.append(-np.linalg.solve(Rw, b.T @ P))
    pm = PolytopicModel(vmin=[-box] * 3, vmax=[box] * 3, A=np.array(A), B=np.array(B),
                        x0=np.array(X0), u0=np.array(U0))
    return quad, ScheduledLpv(pm, np.array(K))


def _signals(T: float = 10.0, dt: float = 0.02) -> ReferenceSignals:
    t = np.arange(0.0, T + dt / 2, dt)
    vd = np.column_stack([1.5 * np.sin(2 * np.pi * 0.2 * t), np.sin(2 * np.pi * 0.15 * t),
                          0.5 * np.sin(2 * np.pi * 0.1 * t)])
    ue = np.column_stack([np.sin(2 * np.pi * f * t) for f in (1.1, 1.7, 2.3, 2.9)])
    return ReferenceSignals(t, vd, ue)


def main() -> None:
    quad, sched = _setup()
    sig = _signals()
    law = linear_lpv_law(sched, R)
    x = sched.x0(sig.v_d[0])
    n = 300
    ts = np.linspace(0.1, 9.9, n)

    def rhs_uncached():
        for tk in ts:
            eq33_rhs(tk, x, sched, sig, law, 1.0)

    cached = LastPointCache(sched)
    claw = linear_lpv_law(cached, R)

    def rhs_cached_new_point():
        for tk in ts:
            eq33_rhs(tk, x, cached, sig, claw, 1.0)

    print(f"Eq. (33) rhs, ScheduledLpv (12 states, 8 vertices)  : {_median(rhs_uncached) / n * 1e6:8.1f} us/eval")
    print(f"Eq. (33) rhs, LastPointCache, new v_d every call    : {_median(rhs_cached_new_point) / n * 1e6:8.1f} us/eval")
    for method in ("rk4", "RK45"):
        cfg = ClosedLoopConfig(method=method)
        sec = _median(lambda: simulate_eq33(sched, sig, R, Q, 1.0, cfg), repeat=1 if method == "RK45" else 3)
        res = simulate_eq33(sched, sig, R, Q, 1.0, cfg)
        print(f"Eq. (33) run 10 s @ 50 Hz, {method:4s}                   : {sec:8.2f} s wall "
              f"({res.n_steps} rhs evals)")
    pm = sched.model
    problem = Phase2Problem(vmin=pm.vmin, vmax=pm.vmax, K=sched.Kv, x0=pm.x0, u0=pm.u0, R=R, Q=Q,
                            gamma=1.0, A=pm.A, B=pm.B)
    for bag in (False, True):
        def nonlinear():
            with tempfile.TemporaryDirectory() as d:
                run(problem, sig, Phase2Config(run_eq33=False, record_bag=bag), quad.params, SensorConfig(),
                    Path(d) / "p2")
        sec = _median(nonlinear, repeat=3)
        print(f"nonlinear run 10 s (500 Hz physics, 100 Hz law){' + bag' if bag else '      '}: {sec:8.2f} s wall "
              f"(real-time factor {10.0 / sec:5.1f}x, incl. summary/plots)")


if __name__ == "__main__":
    main()
