"""Issue 20 item 2: is the true plant between the vertices inside the interpolated certified
set, and does the measured interpolation residual cover it?

Oracle: the analytic linearisation of the simulated quadrotor (Quadrotor.linearize at its trim)
at the vertices, at hover and at interior points; vertex "models" equal to the truth at the
vertices (so the only error left is the interpolation's)."""

from types import SimpleNamespace

import numpy as np

from lpv_sysid.models.lpv import box_vertices
from lpv_sysid.models.quadrotor import Quadrotor
from lpv_sysid.studies.coverage import (
    certified_bounds,
    interior_excess,
    interior_points,
)


def _exact_vertices(q, box=5.0, rel_std=1e-3):
    """Vertex results whose models are the truth at each vertex, every A[p, *] / A[q, *] element
    listed with a tiny std (rel_std of its value)."""
    out = []
    for v in box_vertices([-box] * 3, [box] * 3):
        A, B = q.linearize(q.trim(np.asarray(v, dtype=float), 0.0))
        ivs = []
        for r in (5, 6):
            for c in range(12):
                if A[r, c] != 0:
                    s = rel_std * abs(A[r, c])
                    ivs.append(
                        SimpleNamespace(
                            matrix="A",
                            row=r,
                            col=c,
                            nominal=A[r, c],
                            std=s,
                            lower=A[r, c] - 3 * s,
                            upper=A[r, c] + 3 * s,
                        )
                    )
        fit = SimpleNamespace(A=A, B=B, dof=None)
        out.append(
            SimpleNamespace(fit=fit, uncertain=SimpleNamespace(intervals=ivs), scheduling=v)
        )
    return out


def test_interpolation_error_is_measured_and_covered_by_the_residual():
    q = Quadrotor()
    results = _exact_vertices(q)
    verts = certified_bounds(results, 0.95, 0.05)
    # at a vertex the set contains the truth (the vertex model is the truth)
    at_vertex = interior_excess(q.params, verts, [np.array([5.0, 5.0, 5.0])])
    assert at_vertex[0][0] <= 0
    pts = interior_points(verts, 12, np.random.default_rng(3))
    assert np.allclose(pts[0], 0.0) and len(pts) == 13
    exc = interior_excess(q.params, verts, pts)
    # multilinear interpolation of exact vertex models misses the truth between them
    assert max(e for e, _ in exc) > 1.0
    # the residual at each point, added to every half-width, covers exactly those points
    w = []
    for v in pts:
        S = np.array([s for s, _, _ in verts])
        t = (v - S.min(axis=0)) / (S.max(axis=0) - S.min(axis=0))
        a = np.array([np.prod(np.where(s == S.max(axis=0), t, 1 - t)) for s in S])
        interp = sum(ai * np.concatenate([r.fit.A, r.fit.B], axis=1) for ai, r in zip(a, results))
        A, B = q.linearize(q.trim(v, 0.0))
        w.append(np.abs(np.concatenate([A, B], axis=1) - interp))
    pad = np.max(w, axis=0) * (1 + 1e-9) + 1e-12
    padded = interior_excess(q.params, verts, pts, pad)
    assert all(e <= 0 for e, _ in padded)
