"""Runtime LPV law step time (issue 5 target: < 20 us median).

One LpvController.step = input check + multilinear weights + interpolation of K, x0, u0 +
feedback + mixer saturation + bound monitor, for the 12-state / 4-input / 8-vertex schedule.

    .venv/bin/python -m bench.bench_lpv_law
"""

from __future__ import annotations

import time

import numpy as np


def _schedule(feedforward: bool = False):
    """Random 8-vertex schedule of the quadrotor's size; with ``feedforward`` also F_ff (10x3:
    phi, theta, dt..dr, then the 4 inputs) and F_jerk (13x3: + p, q, r) per vertex, the shapes
    synthesize writes."""
    from types import SimpleNamespace

    rng = np.random.default_rng(0)
    s = SimpleNamespace(K=rng.normal(size=(8, 4, 12)) * 1e-3, x0=rng.normal(size=(8, 12)),
                        u0=0.4 + 0.01 * rng.normal(size=(8, 4)), R=np.eye(4) * 0.7, Q=np.eye(3) * 86.6,
                        gamma=1.0, vmin=-5 * np.ones(3), vmax=5 * np.ones(3))
    if feedforward:
        s.feedforward = {"free_states": ["phi", "theta", "dt", "da", "de", "dr"], "rate_states": ["p", "q", "r"]}
        s.F_ff = rng.normal(size=(8, 10, 3)) * 1e-2
        s.F_jerk = rng.normal(size=(8, 13, 3)) * 1e-3
    return s


def main() -> None:
    from lpv_sysid.control.lpv_controller import LpvController, LpvControllerConfig
    from lpv_sysid.models.quadrotor import mixer

    cases = (("law only (no mixer, no rate limit)", LpvControllerConfig(), None, False),
             ("law + mixer saturation", LpvControllerConfig(), mixer(0.225), False),
             ("law + mixer + rate limit", LpvControllerConfig(rate_limit=(5.0,) * 4), mixer(0.225), False),
             ("law + feedforward (filtered a, j) + mixer", LpvControllerConfig(), mixer(0.225), True))
    for label, cfg, mix, ff in cases:
        ctl = LpvController(_schedule(ff), cfg, mix=mix)
        rng = np.random.default_rng(1)
        n = 20000
        xs = rng.normal(size=(n, 12)) * 0.1
        vds = rng.uniform(-6, 6, size=(n, 3))
        ues = rng.normal(size=(n, 4)) * 0.1
        times = np.empty(n)
        step = ctl.step
        pc = time.perf_counter_ns
        for k in range(n):
            x, vd, ue = xs[k], vds[k], ues[k]
            t0 = pc()
            step(0.01 * k, x, vd, ue)
            times[k] = pc() - t0
        times = times[1000:] / 1000.0
        print(f"{label:<42} median {np.median(times):6.2f} us   p90 {np.percentile(times, 90):6.2f} us   "
              f"p99 {np.percentile(times, 99):6.2f} us  (n={times.size})")


if __name__ == "__main__":
    main()
