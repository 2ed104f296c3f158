"""Scheduling box and multilinear weights of seed 0 Eqs. (20), (21).

Vertex order (fixed, documented, identical to the ``vertices`` list of ``vertex_models.yaml``
and ``gains.yaml``): ``itertools.product(*[(min_k, max_k) for k in axes])``, first axis
slowest. For the quadrotor box ``v_d = (u_d, v_d, w_d)`` vertex 0 is (min, min, min),
vertex 1 is (min, min, max), ..., vertex 7 is (max, max, max).

Multilinear weights (seed 0 Eq. 21): with ``t_k = (v_k - min_k) / (max_k - min_k)`` and the
1-D barycentric pair ``(1 - t_k, t_k)``, ``alpha_i = prod_k w_k(bit_ik)``, where bit_ik = 0 for
min and 1 for max. They are non-negative, sum to 1, and reproduce every affine (indeed every
multilinear) function of ``v_d`` exactly from its vertex values. Outside the box ``v_d`` is
clamped to the box and a flag is returned (the caller raises the safety event).
"""

from __future__ import annotations

import itertools

import numpy as np
from numpy.typing import ArrayLike

from lpv_sysid.errors import ConfigError


# --------------------------------------------------------------------------- box and weights
def box_vertices(vmin: ArrayLike, vmax: ArrayLike) -> np.ndarray:
    """Corners of the box [vmin, vmax] (seed 0 Eq. 20), shape (2**p, p), first axis slowest."""
    lo, hi = check_box(vmin, vmax)
    return np.array(list(itertools.product(*zip(lo, hi))), dtype=float)


def check_box(vmin: ArrayLike, vmax: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    lo = np.asarray(vmin, dtype=float).ravel()
    hi = np.asarray(vmax, dtype=float).ravel()
    if lo.shape != hi.shape or lo.size == 0:
        raise ConfigError(
            f"scheduling box: min {lo.shape} and max {hi.shape} must be equal, non-empty"
        )
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ConfigError("scheduling box: min/max must be finite")
    if np.any(hi <= lo):
        raise ConfigError(
            f"scheduling box: need max > min on every axis, got min={lo.tolist()} "
            f"max={hi.tolist()}"
        )
    return lo, hi


def multilinear_weights(v: ArrayLike, vmin: ArrayLike, vmax: ArrayLike) -> tuple[np.ndarray, bool]:
    """alpha_i(v) of seed 0 Eq. (21) for the vertex order of :func:`box_vertices`.

    Returns (alpha (2**p,), clamped). ``clamped`` is True when v was outside the box and was
    projected onto it before the weights were computed. NaN in ``v`` raises ConfigError.
    """
    lo, hi = check_box(vmin, vmax)
    v = np.asarray(v, dtype=float).ravel()
    if v.shape != lo.shape:
        raise ConfigError(f"scheduling point has {v.size} entries, the box has {lo.size} axes")
    if not np.all(np.isfinite(v)):
        raise ConfigError(f"scheduling point contains NaN/inf: {v.tolist()}")
    t = (v - lo) / (hi - lo)
    clamped = bool(np.any(t < 0.0) or np.any(t > 1.0))
    t = np.clip(t, 0.0, 1.0)
    alpha = np.ones(1)
    for tk in t:
        alpha = np.kron(alpha, np.array([1.0 - tk, tk]))  # kron: first factor slowest
    return alpha, clamped


def multilinear_weight_gradient(v: ArrayLike, vmin: ArrayLike, vmax: ArrayLike) -> np.ndarray:
    """d alpha_i / d v_k, shape (2**p, p), at a point clamped into the box (used by Eq. 34).

    Outside the box the clamped coordinate has zero derivative (the clamped model is flat).
    """
    lo, hi = check_box(vmin, vmax)
    v = np.asarray(v, dtype=float).ravel()
    if not np.all(np.isfinite(v)):
        raise ConfigError(f"scheduling point contains NaN/inf: {v.tolist()}")
    t_raw = (v - lo) / (hi - lo)
    t = np.clip(t_raw, 0.0, 1.0)
    inside = (t_raw >= 0.0) & (t_raw <= 1.0)
    p = lo.size
    grad = np.empty((2**p, p))
    for k in range(p):
        g = np.ones(1)
        for l_ in range(p):
            if l_ == k:
                d = np.array([-1.0, 1.0]) / (hi[k] - lo[k]) if inside[k] else np.zeros(2)
                g = np.kron(g, d)
            else:
                g = np.kron(g, np.array([1.0 - t[l_], t[l_]]))
        grad[:, k] = g
    return grad


def interpolate_gain(K: np.ndarray, v_d, vmin, vmax) -> np.ndarray:
    """K(v_d) = sum_i alpha_i(v_d) K_i, seed 0 Eq. (31) (K: (N, m, n))."""
    alpha, _ = multilinear_weights(v_d, vmin, vmax)
    return np.tensordot(alpha, np.asarray(K, dtype=float), axes=1)
