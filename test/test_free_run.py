"""Output-error (free-run) validation (issue 23 item 3), against a linear system whose
response the test computes exactly (ZOH): the true model reproduces the measured states,
a model with one wrong derivative does not, and the restart horizon is honoured."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.linalg import expm

from lpv_sysid.ident import vertex as vx
from lpv_sysid.models.lpv import box_vertices


def _system(rng):
    A = 0.3 * rng.normal(size=(12, 12))
    A -= (np.max(np.linalg.eigvals(A).real) + 1.0) * np.eye(12)  # stable, slowest -1 1/s
    return A, rng.normal(size=(12, 4))


def _data(A, B, fs=100.0, T=40.0):
    t = np.arange(int(T * fs)) / fs
    f = np.array([0.2, 0.35, 0.5, 0.8, 1.1, 1.7, 2.3])
    u = np.column_stack(
        [sum(np.sin(2 * np.pi * fk * t + (j + 1) * k) for k, fk in enumerate(f)) for j in range(4)]
    )
    M = np.zeros((16, 16))
    M[:12, :12], M[:12, 12:] = A, B
    E = expm(M / fs)
    x = np.zeros((t.size, 12))
    for k in range(1, t.size):
        x[k] = E[:12, :12] @ x[k - 1] + E[:12, 12:] @ u[k - 1]
    return vx.VertexData(t, x, u, np.zeros(3), (0.0, 4.0), (4.0, T), "synthetic")


def _results(A, B, cfg):
    return [
        SimpleNamespace(
            scheduling=c, fit=SimpleNamespace(A=A, B=B), x0=np.zeros(12), u0=np.zeros(4)
        )
        for c in box_vertices(cfg.vmin, cfg.vmax)
    ]


def test_free_run_reproduces_the_true_system_and_exposes_a_wrong_one():
    rng = np.random.default_rng(4)
    A, B = _system(rng)
    cfg = vx.IdentificationConfig()
    data = _data(A, B)
    good = vx.free_run(_results(A, B, cfg), data, cfg, horizon_s=2.0)
    assert good["horizon_s"] == pytest.approx(2.0)
    assert max(good["nrmse"].values()) < 1e-4  # smoothing commutes with the LTI system
    A_bad = A.copy()
    A_bad[2, 2] -= 1.5  # one wrong damping derivative (u row)
    bad = vx.free_run(_results(A_bad, B, cfg), data, cfg, horizon_s=2.0)
    assert bad["nrmse"]["u"] > 10 * good["nrmse"]["u"]
    # restarts: every 200th sample is the measured state itself
    k = np.arange(0, bad["t"].size, 200)
    np.testing.assert_array_equal(bad["x_sim"][k], bad["x_meas"][k])
    with pytest.raises(Exception, match="horizon_s"):
        vx.free_run(_results(A, B, cfg), data, cfg, horizon_s=0.0)
