"""Identification benchmark (issue 4 target: 8 vertices from 40 s logs at 100 Hz in < 2 s).

    .venv/bin/python -m bench.bench_ident

Data: per vertex, the analytic linearisation of ``models.quadrotor`` at the vertex trim under
an LQR baseline with orthogonal multisine excitation and sensor noise (``ident.synthetic``),
40 s at 100 Hz (10 s trim + 30 s excitation) - the arrays that ``ident.dataprep`` hands to
``ident.vertex.identify_vertex``.  Timed: the whole per-vertex pipeline (trim averaging,
global Fourier smoothing/differentiation, equation error with coloured-residual covariance,
intervals, influence ranking, uncertain vertex systems), for all 8 vertices; median of 5.
"""

from __future__ import annotations

import statistics
import sys
import time

import numpy as np


def _datasets():
    from lpv_sysid.ident import synthetic as syn
    from lpv_sysid.ident import vertex as vx
    from lpv_sysid.models.lpv import box_vertices
    from lpv_sysid.models.quadrotor import Quadrotor

    q = Quadrotor()
    rng = np.random.default_rng(0)
    noise = np.array([2e-3, 2e-3, 0.02, 0.02, 0.02, 5e-3, 5e-3, 5e-3, 2.0, 0.02, 0.02, 2.0])
    Qw = np.diag([10, 10, 1, 1, 1, 1, 1, 1, 1e-6, 1e-4, 1e-4, 1e-6])
    Rw = np.diag([1e2, 1e4, 1e4, 1e2])
    t = np.arange(0, 40, 0.01)
    on = t >= 10
    out = []
    for c in box_vertices([-5] * 3, [5] * 3):
        tr = q.trim(c)
        A, B = q.linearize(tr)
        e = np.zeros((t.size, 4))
        e[on] = syn.multisine(t[on], 4, (0.2, 3.0), 1.0, rng) * np.array([0.03, 0.002, 0.002, 0.03])
        d, _ = syn.closed_loop(A, B, t, e, Qw, Rw)
        x = tr.x0 + d.x + noise * rng.normal(size=d.x.shape)
        out.append(vx.VertexData(t, x, tr.u0 + d.u, c, (0.0, 10.0), (10.0, 40.0), str(c)))
    return out


def _time(fn, repeat=5):
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts), min(ts)


def main() -> int:
    from lpv_sysid.ident import equation_error as ee
    from lpv_sysid.ident import vertex as vx

    data = _datasets()
    rows = []
    for model in ("taylor2", "appendix_b"):
        cfg = vx.IdentificationConfig(model=model)
        med, best = _time(lambda: [vx.identify_vertex(d, cfg) for d in data])
        rows.append((f"8 vertices, model={model}, 40 s @ 100 Hz", med, best))
    # the equation-error core alone (one vertex, 43 parameters in 6 rows)
    cfg = vx.IdentificationConfig(model="appendix_b")
    known = vx.known_from_quadrotor(data[0].x[:1000].mean(axis=0))
    _, xdot, dx, du = vx.prepare(data[0], cfg, data[0].x[:1000].mean(axis=0), data[0].u[:1000].mean(axis=0))
    med, best = _time(lambda: ee.fit(xdot, dx, du, known.A, known.B, known.maskA, known.maskB), 20)
    rows.append(("ee.fit one vertex (with coloured covariance)", med, best))
    med, best = _time(lambda: ee.fit(xdot, dx, du, known.A, known.B, known.maskA, known.maskB, max_lag=0), 20)
    rows.append(("ee.fit one vertex (white covariance only)", med, best))
    print("| what | median | best |")
    print("|---|---|---|")
    for name, med, best in rows:
        print(f"| {name} | {med * 1e3:.1f} ms | {best * 1e3:.1f} ms |")
    target = rows[0][1]
    print(f"\ntarget 8 vertices < 2 s: {'met' if target < 2.0 else 'NOT met'} ({target:.3f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
