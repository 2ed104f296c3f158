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
    s = SimpleNamespace(
        K=rng.normal(size=(8, 4, 12)) * 1e-3,
        x0=rng.normal(size=(8, 12)),
        u0=0.4 + 0.01 * rng.normal(size=(8, 4)),
        R=np.eye(4) * 0.7,
        Q=np.eye(3) * 86.6,
        gamma=1.0,
        vmin=-5 * np.ones(3),
        vmax=5 * np.ones(3),
    )
    if feedforward:
        s.feedforward = {
            "free_states": ["phi", "theta", "dt", "da", "de", "dr"],
            "rate_states": ["p", "q", "r"],
        }
        s.F_ff = rng.normal(size=(8, 10, 3)) * 1e-2
        s.F_jerk = rng.normal(size=(8, 13, 3)) * 1e-3
    return s


def _floor(sched):
    """The numpy floor of the law: weights as floats, one alpha @ W, K dx + R u_e."""
    N, m, n = sched.K.shape
    W = np.hstack([sched.K.reshape(N, -1), sched.x0, sched.u0])
    lo, sp = sched.vmin.tolist(), (sched.vmax - sched.vmin).tolist()
    R = sched.R

    def f(x, vd, ue):
        w = [min(max((v - a) / s, 0.0), 1.0) for v, a, s in zip(vd.tolist(), lo, sp)]
        al = [1.0]
        for t in w:
            al = [a * b for a in al for b in (1.0 - t, t)]
        row = np.array(al) @ W
        return (
            row[n * m + n :] + row[: n * m].reshape(m, n) @ (x - row[n * m : n * m + n]) + R @ ue
        )

    return f


def main() -> None:
    from bench.harness import Page, Row, Stat, load_average, status
    from lpv_sysid.control.lpv_controller import LpvController, LpvControllerConfig
    from lpv_sysid.models.quadrotor import mixer

    load0 = load_average()
    page = Page(
        "lpv_law",
        "Runtime LPV law step (control/lpv_controller.py; issues 5, 15)",
        ".venv/bin/python -m bench.bench_lpv_law",
    )
    cases = (
        ("law only (no mixer, no rate limit)", LpvControllerConfig(), None, False),
        ("law + mixer saturation", LpvControllerConfig(), mixer(0.225), False),
        (
            "law + mixer + rate limit",
            LpvControllerConfig(rate_limit=(5.0,) * 4),
            mixer(0.225),
            False,
        ),
        (
            "default path: feedforward (filtered a, j) + mixer",
            LpvControllerConfig(),
            mixer(0.225),
            True,
        ),
    )
    lines = []
    stats = {}
    rng = np.random.default_rng(1)
    n = 20000
    xs = rng.normal(size=(n, 12)) * 0.1
    vds = rng.uniform(-6, 6, size=(n, 3))
    ues = rng.normal(size=(n, 4)) * 0.1
    pc = time.perf_counter_ns
    for label, cfg, mix, ff in cases:
        ctl = LpvController(_schedule(ff), cfg, mix=mix)
        times = np.empty(n)
        step = ctl.step
        for k in range(n):
            x, vd, ue = xs[k], vds[k], ues[k]
            t0 = pc()
            step(0.01 * k, x, vd, ue)
            times[k] = pc() - t0
        st = Stat((times[1000:] * 1e-9).tolist())
        stats[label] = st
        lines.append(
            [
                label,
                f"{st.median * 1e6:.2f} us",
                f"{st.p90 * 1e6:.2f} us",
                f"{st.p99 * 1e6:.2f} us",
            ]
        )
    fl = _floor(_schedule(False))
    times = np.empty(n)
    for k in range(n):
        x, vd, ue = xs[k], vds[k], ues[k]
        t0 = pc()
        fl(x, vd, ue)
        times[k] = pc() - t0
    flo = Stat((times[1000:] * 1e-9).tolist())
    lines.append(
        [
            "floor: float weights + one alpha @ W + K dx + R u_e (no checks, no feedforward)",
            f"{flo.median * 1e6:.2f} us",
            f"{flo.p90 * 1e6:.2f} us",
            f"{flo.p99 * 1e6:.2f} us",
        ]
    )
    page.add(
        f"## One `LpvController.step` (12 states, 4 inputs, 8 vertices; {n - 1000} steps after 1000 "
        "warm-up, random x, v_d partly outside the box; wall time per step)"
    )
    page.add()
    page.table(["variant", "median", "p90", "p99"], lines)
    d = stats["default path: feedforward (filtered a, j) + mixer"]
    page.rows.append(
        Row(
            "runtime LPV law step",
            "5, 15",
            f"default path (feedforward + mixer) median {d.median * 1e6:.1f} us, p99 "
            f"{d.p99 * 1e6:.1f} us; without feedforward {stats['law + mixer saturation'].median * 1e6:.1f} us",
            f"numpy floor {flo.median * 1e6:.1f} us",
            f"{d.median / flo.median:.1f}x",
            "<= 10 us on the default path",
            status(
                None,
                "measured only (control/ owned elsewhere); met"
                if d.median <= 10e-6
                else "measured only (control/ owned elsewhere); not met",
            ),
            order=6,
        )
    )
    page.write(load0)


if __name__ == "__main__":
    main()
