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


def test_interpolation_pad_from_the_vertex_models_covers_the_grid():
    """ident.vertex.interpolation: vertex models that re-expand exactly (the truth at any v, a
    tiny std) give a pad under which the interpolated set holds the truth at every grid point;
    the gravity term A[v, phi] (not multilinear in v_d) needs one."""
    from lpv_sysid.ident.vertex.interpolation import GRID_T, interpolation_pad

    q = Quadrotor()
    results = _exact_vertices(q)

    def expander(v):
        A, B = q.linearize(q.trim(np.asarray(v, dtype=float), 0.0))
        return SimpleNamespace(A=A, B=B, std_A=1e-9 * np.abs(A), std_B=1e-9 * np.abs(B))

    for r in results:
        r.fit.expand = expander
    ip = interpolation_pad(results, 0.95)
    assert ip is not None and ip["points"] == len(GRID_T) == 27
    pad = np.concatenate([np.array(ip["pad_A"]), np.array(ip["pad_B"])], axis=1)
    assert pad[3, 0] > 0.01  # A[v, phi]
    verts = certified_bounds(results, 0.95, 0.0, pad)
    grid = [-5.0 + 10.0 * np.asarray(tg) for tg in GRID_T]
    assert all(e <= 0 for e, _ in interior_excess(q.params, verts, grid))
    # without the pad the same grid is not covered
    bare = certified_bounds(results, 0.95, 0.0)
    assert max(e for e, _ in interior_excess(q.params, bare, grid)) > 1.0


def test_synthesis_box_adds_the_interpolation_pad(tmp_path):
    import yaml
    from test_certificate_joint import _half, _models

    from lpv_sysid.synthesis.uncertainty_set import load_models

    models = _models(tmp_path / "vm.yaml")
    doc = yaml.safe_load(models.read_text())
    pad_A = [[0.01, 0.0], [0.0, 0.02]]  # A[0,0] listed (widened), A[1,1] fixed (added)
    doc["meta"]["interpolation"] = {"pad_A": pad_A, "pad_B": [[0.0], [0.0]], "points": 27}
    models.write_text(yaml.safe_dump(doc))
    cfg = {"set": "full_box", "joint_probability": None, "box_inflation": None}
    model, _ = load_models(models, cfg)
    assert abs(_half(model.box, 0, 0, 0) - (0.03 + 0.01)) < 1e-12
    assert abs(_half(model.box, 1, 1, 1) - 0.02) < 1e-12
    bare, _ = load_models(models, dict(cfg, interpolation=False))
    assert abs(_half(bare.box, 0, 0, 0) - 0.03) < 1e-12


def test_the_shipped_synthesis_config_certifies_the_padded_set(tmp_path):
    """Issue 20: the certificate the package ships is about the set that holds the identified
    dynamics between the vertices (the pad on), not seed 0's Assumption 2 alone: the shipped
    config's uncertainty section widens a half-width by the models file's pad."""
    from pathlib import Path

    import yaml
    from test_certificate_joint import _half, _models

    from lpv_sysid.synthesis.uncertainty_set import load_models

    shipped = yaml.safe_load(
        (Path(__file__).resolve().parents[1] / "config" / "synthesis.yaml").read_text()
    )["uncertainty"]
    assert shipped["interpolation"] is True
    models = _models(tmp_path / "vm.yaml")
    doc = yaml.safe_load(models.read_text())
    doc["meta"]["interpolation"] = {
        "pad_A": [[0.01, 0.0], [0.0, 0.0]],
        "pad_B": [[0.0], [0.0]],
        "points": 27,
    }
    models.write_text(yaml.safe_dump(doc))
    cfg = dict(shipped, joint_probability=None, box_inflation=None)
    model, _ = load_models(models, cfg)
    assert abs(_half(model.box, 0, 0, 0) - (0.03 + 0.01)) < 1e-12
