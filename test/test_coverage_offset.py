"""Issue 20 (round 2): the steady offset ``v - v_d`` the flown law settles at on a true plant at
constant v_d (``studies.coverage.steady_offset``), against its defining equation.

Oracle: at the offset state x_ss = x_e + dx the true linearised dynamics are at rest,
``A (x_ss - x_e) + B (u0 + K (x_ss - x0) - u_e) = 0`` with x0, u0, K the multilinear
interpolation (seed 0 Eq. 21) of the vertex values; a law whose equilibrium is the true one
settles with no offset."""

import itertools
from types import SimpleNamespace

import numpy as np

from lpv_sysid.models.lpv import box_vertices
from lpv_sysid.studies.coverage import steady_offset


def _setup(seed=0):
    rng = np.random.default_rng(seed)
    corners = np.array(list(itertools.product((-5.0, 5.0), repeat=3)))
    order = rng.permutation(8)  # results in another order than the box's
    results = [
        SimpleNamespace(scheduling=corners[i], x0=rng.normal(size=12), u0=rng.normal(size=4))
        for i in order
    ]
    K = 0.1 * rng.normal(size=(8, 4, 12))  # box order (box_vertices)
    A = -2.0 * np.eye(12) + 0.1 * rng.normal(size=(12, 12))
    B = rng.normal(size=(12, 4))
    return results, K, A, B, rng


def test_offset_solves_the_rest_equation_at_an_interior_v_d():
    results, K, A, B, rng = _setup()
    v = np.array([1.0, -2.0, 3.0])
    x_e, u_e = rng.normal(size=12), rng.normal(size=4)
    off = steady_offset(results, K, v, A, B, x_e, u_e)
    # multilinear interpolation written out: weights of the box corners
    V = box_vertices(-5 * np.ones(3), 5 * np.ones(3))
    t = (v + 5.0) / 10.0
    w = np.array([np.prod(np.where(c > 0, t, 1 - t)) for c in V])
    by = {tuple(r.scheduling): r for r in results}
    x0 = sum(wi * by[tuple(c)].x0 for wi, c in zip(w, V))
    u0 = sum(wi * by[tuple(c)].u0 for wi, c in zip(w, V))
    Ka = np.tensordot(w, K, axes=1)
    # reconstruct the full offset state from the rest equation and compare its velocity rows
    dx = np.linalg.lstsq(A + B @ Ka, -B @ (u0 - u_e + Ka @ (x_e - x0)), rcond=None)[0]
    x_ss = x_e + dx
    rest = A @ (x_ss - x_e) + B @ (u0 + Ka @ (x_ss - x0) - u_e)
    assert np.max(np.abs(rest)) < 1e-10
    assert np.allclose(off, dx[2:5], atol=1e-12)
    assert np.max(np.abs(off)) > 1e-3  # a wrong equilibrium does cost an offset


def test_no_offset_when_the_law_equilibrium_is_the_true_one():
    results, K, A, B, _ = _setup(1)
    r = results[3]
    off = steady_offset(results, K, r.scheduling, A, B, r.x0, r.u0)
    assert np.max(np.abs(off)) < 1e-12
