"""Phase 2 (issue 15 row "phase 2, Eq. 33 right-hand side"): the right-hand side of seed 0
Eq. (33) as `simulate_eq33` evaluates it, against its floor, plus the Eq. (33) runs and the
nonlinear run.

    .venv/bin/python -m bench.bench_phase2

Model: 12-state, 8-vertex LPV model of the simulated quadrotor (vertex trims + analytic
linearisation, LQR vertex gains) over the box [-2, 2]^3 m/s -- the sizes of the demo's
``vertex_models.yaml`` / ``gains.yaml``; signals 10 s at 50 Hz.

* product: ``lpv_closed_loop.fused_eq33`` (what ``simulate_eq33`` uses for the shipped laws);
* floor: the same arithmetic written out in this file -- weights and their rate as plain
  floats, one ``[alpha; beta] @ W`` product, the law and ``A dx + B du + x0'`` -- nothing else;
* before: ``eq33_rhs`` through the ``ScheduledModel`` methods (``models.lpv``: ``np.kron``
  weights per call), the path every evaluation took before.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.linalg import solve_continuous_are

from bench.harness import Page, Row, interleaved, load_average, status, timed, us

R = np.diag([0.02, 0.002, 0.002, 0.02])
Q = 5.0 * np.eye(3)


def _setup(box: float = 2.0):
    from lpv_sysid.models.lpv import PolytopicModel, ScheduledLpv, box_vertices
    from lpv_sysid.models.quadrotor import Quadrotor

    quad = Quadrotor()
    A, B, X0, U0, K = [], [], [], [], []
    Qw = np.diag([1, 1, 20, 20, 20, 0.1, 0.1, 0.1, 1e-6, 1e-4, 1e-4, 1e-6])
    Rw = np.diag([10.0, 100.0, 100.0, 10.0])
    for v in box_vertices([-box] * 3, [box] * 3):
        tr = quad.trim(v)
        a, b = quad.linearize(tr)
        P = solve_continuous_are(a, b, Qw, Rw)
        A.append(a)
        B.append(b)
        X0.append(tr.x0)
        U0.append(tr.u0)
        K.append(-np.linalg.solve(Rw, b.T @ P))
    pm = PolytopicModel(
        vmin=[-box] * 3,
        vmax=[box] * 3,
        A=np.array(A),
        B=np.array(B),
        x0=np.array(X0),
        u0=np.array(U0),
    )
    return quad, ScheduledLpv(pm, np.array(K))


def _signals(T: float = 10.0, dt: float = 0.02):
    from lpv_sysid.sim.closed_loop import ReferenceSignals

    t = np.arange(0.0, T + dt / 2, dt)
    vd = np.column_stack(
        [
            1.5 * np.sin(2 * np.pi * 0.2 * t),
            np.sin(2 * np.pi * 0.15 * t),
            0.5 * np.sin(2 * np.pi * 0.1 * t),
        ]
    )
    ue = np.column_stack([np.sin(2 * np.pi * f * t) for f in (1.1, 1.7, 2.3, 2.9)])
    return ReferenceSignals(t, vd, ue)


def floor_rhs(sched, sig, kappa: float = 1.0):
    """Eq. (33) with the unsaturated Eq. (31) law, the least numpy work: plain-float FOH,
    weights and weight rates; one (2 x 8) @ (8 x C) product; five small matrix-vector ops."""
    pm = sched.model
    n, m = pm.A.shape[1], pm.B.shape[2]
    W = np.hstack(
        [pm.A.reshape(8, -1), pm.B.reshape(8, -1), sched.Kv.reshape(8, -1), pm.x0, pm.u0]
    )
    a0, a1, a2, a3 = n * n, n * n + n * m, n * n + 2 * n * m, n * n + 2 * n * m + n
    lo, sp = pm.vmin.tolist(), (pm.vmax - pm.vmin).tolist()
    T, V, U = sig.t.tolist(), sig.v_d.tolist(), sig.u_e
    KR = kappa * R

    def f(t, x, k):
        t0, t1 = T[k], T[k + 1]
        s = (t - t0) / (t1 - t0)
        r = 1.0 - s
        va, vb = V[k], V[k + 1]
        w = [min(max(((r * va[i] + s * vb[i]) - lo[i]) / sp[i], 0.0), 1.0) for i in range(3)]
        d = [(vb[i] - va[i]) / (t1 - t0) / sp[i] for i in range(3)]
        (x_, y_, z_), (dx_, dy_, dz_) = w, d
        al, be = [], []
        for a in (1.0 - x_, x_):
            for b in (1.0 - y_, y_):
                for c in (1.0 - z_, z_):
                    al.append(a * b * c)
        for sa, a in ((-1.0, 1.0 - x_), (1.0, x_)):
            for sb, b in ((-1.0, 1.0 - y_), (1.0, y_)):
                for sc, c in ((-1.0, 1.0 - z_), (1.0, z_)):
                    be.append(sa * dx_ * b * c + a * sb * dy_ * c + a * b * sc * dz_)
        P = np.array((al, be)) @ W
        row = P[0]
        dx = x - row[a2:a3]
        du = row[a1:a2].reshape(m, n) @ dx + KR @ (r * U[k] + s * U[k + 1])
        return row[:a0].reshape(n, n) @ dx + row[a0:a1].reshape(n, m) @ du + P[1, a2:a3]

    return f


def main() -> None:
    from lpv_sysid.sim.closed_loop import (
        ClosedLoopConfig,
        eq33_rhs,
        fused_eq33,
        linear_lpv_law,
        simulate_eq33,
    )
    from lpv_sysid.sim.phase2 import Phase2Config, Phase2Problem, run
    from lpv_sysid.sim.vehicle import SensorConfig

    load0 = load_average()
    page = Page(
        "phase2",
        "Phase 2: Eq. (33) right-hand side and runs (issue 15)",
        ".venv/bin/python -m bench.bench_phase2",
    )
    quad, sched = _setup()
    sig = _signals()
    law = linear_lpv_law(sched, R)
    fused = fused_eq33(sched, sig, None, R, 1.0)
    flo = floor_rhs(sched, sig)
    rng = np.random.default_rng(0)
    pts = [
        (
            float(t),
            sig.segment(float(t)),
            sched.x0(sig.v_d[sig.segment(float(t))]) + 0.1 * rng.normal(size=12),
        )
        for t in rng.uniform(0.1, 9.9, 200)
    ]
    worst = max(
        float(np.max(np.abs(fused(t, x, k) - flo(t, x, k)) / (1e-9 + np.abs(flo(t, x, k)))))
        for t, k, x in pts[:50]
    )
    gen = max(
        float(
            np.max(
                np.abs(fused(t, x, k) - eq33_rhs(t, x, sched, sig, law, 1.0, k))
                / (1e-9 + np.abs(flo(t, x, k)))
            )
        )
        for t, k, x in pts[:20]
    )
    it = iter(range(10**9))

    def call(fn):
        def go():
            t, k, x = pts[next(it) % len(pts)]
            fn(t, x, k)

        return go

    st = interleaved(
        {
            "product": call(fused),
            "floor": call(flo),
            "before": call(lambda t, x, k: eq33_rhs(t, x, sched, sig, law, 1.0, k)),
        },
        number=200,
        repeat=11,
        clock=time.process_time,
    )
    ratio = st["product"].median / st["floor"].median
    page.add("## Eq. (33) right-hand side (12 states, 8 vertices, new v_d every call; CPU time)")
    page.add()
    page.table(
        ["what", "median [p10-p90]", "vs floor"],
        [
            [
                "`fused_eq33` (what `simulate_eq33` evaluates)",
                st["product"].fmt(1e6, "us"),
                f"{ratio:.2f}x",
            ],
            [
                "floor: plain floats + one `[alpha; beta] @ W` + 5 matrix-vector products",
                st["floor"].fmt(1e6, "us"),
                "1",
            ],
            [
                "before: `eq33_rhs` through `ScheduledLpv` (np.kron weights per call)",
                st["before"].fmt(1e6, "us"),
                f"{st['before'].median / st['floor'].median:.1f}x",
            ],
        ],
    )
    page.add(
        f"Largest relative difference fused vs floor {worst:.1e}, fused vs `eq33_rhs` {gen:.1e} "
        "(summation order only)."
    )
    page.add()
    lines = []
    for method in ("rk4", "RK45"):
        cfg = ClosedLoopConfig(method=method)
        w, c, res = timed(
            lambda: simulate_eq33(sched, sig, R, Q, 1.0, cfg), repeat=3 if method == "rk4" else 1
        )
        lines.append(
            [
                f"`simulate_eq33` 10 s @ 50 Hz, {method} ({res.n_steps} rhs evaluations)",
                w.fmt(1, "s"),
                c.fmt(1, "s"),
            ]
        )
    pm = sched.model
    problem = Phase2Problem(
        vmin=pm.vmin,
        vmax=pm.vmax,
        K=sched.Kv,
        x0=pm.x0,
        u0=pm.u0,
        R=R,
        Q=Q,
        gamma=1.0,
        A=pm.A,
        B=pm.B,
    )
    for bag in (False, True):

        def nonlinear():
            with tempfile.TemporaryDirectory() as d:
                run(
                    problem,
                    sig,
                    Phase2Config(run_eq33=False, record_bag=bag),
                    quad.params,
                    SensorConfig(),
                    Path(d) / "p2",
                )

        w, c, _ = timed(nonlinear, repeat=3)
        lines.append(
            [
                f"nonlinear run 10 s (500 Hz physics, 100 Hz law){' + rosbag2' if bag else ''}, "
                "incl. summary and plots",
                w.fmt(1, "s"),
                c.fmt(1, "s"),
            ]
        )
    page.add("## Runs")
    page.add()
    page.table(["what", "wall median [p10-p90]", "CPU"], lines)
    page.rows.append(
        Row(
            "phase 2, Eq. 33 right-hand side",
            "15",
            f"{us(st['product'].median)} per call (before: {us(st['before'].median)})",
            f"plain floats + one alpha @ W: {us(st['floor'].median)}",
            f"{ratio:.2f}x",
            "<= 3x floor",
            status(ratio <= 3.0),
            order=4,
        )
    )
    page.write(load0)


if __name__ == "__main__":
    main()
