"""Second-order-consistent equation error for the quadrotor vertex models.

Why: phase-1 maneuvers are large (body rates of 1-2 rad/s, rotor-speed swings of 50-150
rad/s), and the dynamics of seed 0 Eqs. (3) and (6) are not linear over that range.  Fitting
the linear perturbation model of Appendix B to such data estimates a *secant* model, whose
difference from the true Jacobian (the linearisation of Eqs. 15-16 the robust design needs)
is larger than the statistical standard errors - on the simulator, 12-14 % of the elements
fall outside 3 sigma even with perfect states and derivatives.

How (exact for the hypothesised model structure):

* the known rigid-body part of rows ``u, v, w, p, q, r`` (Eq. 3c-3d without F, M:
  ``v x omega + g R^T e3`` and ``I^-1 (I omega x omega)``) is a known *nonlinear* function; it
  is subtracted in full from the measured derivative instead of its linearisation (the
  generalisation of Eq. 41);
* every regressor ``phi_k`` of the aerodynamic model Eq. (6) is a polynomial of degree <= 2
  in ``(v, omega, delta)`` (``delta^2 = Mix (Mix^-1 delta)^2``, Eq. 7), so
  ``phi_k(x0 + dx) = phi_k(x0) + grad phi_k dx + r_k(dx)`` with the exact quadratic remainder
  ``r_k(dx) = (phi_k(x0 + dx) + phi_k(x0 - dx)) / 2 - phi_k(x0)``;
* hence ``F_a(x) / m = c + J dx + sum_k (K_k / m) r_k(dx)``: regressing on the unknown
  columns of ``dx, du`` (Eq. 40) *plus* the remainders ``r_k`` of that axis (nuisance
  regressors with unknown coefficients) and an intercept ``c`` estimates the Jacobian ``J``
  without the second-order bias (third-order terms do not exist in Eq. 6);
* the identified element is then ``A_ij = A0_ij + J_ij`` with ``A0`` the linearisation of the
  known part at the measured trim (zero aerodynamic parameters), so known and unknown
  elements combine exactly as in Eq. (15).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from lpv_sysid.ident import nonlinear as nl

#: rows of the 12-state (DESIGN.md order) fitted in Taylor mode and the Eq. (6) axes entering them
ROWS = (2, 3, 4, 5, 6, 7)
FORCE_AXES = ("X", "Y", "Z")
MOMENT_AXES = ("L", "M", "N")


def known_rigid_body(x12: np.ndarray, params) -> np.ndarray:
    """Known part of ``[u', v', w', p', q', r']`` (Eq. 3c-3d with F = M = 0), (N, 6)."""
    x12 = np.atleast_2d(x12)
    I = np.asarray(params.inertia, dtype=float)
    Ii = np.linalg.inv(I)
    v, w = x12[:, 2:5], x12[:, 5:8]
    vd = np.cross(v, w) + nl._gravity_body(x12[:, 0], x12[:, 1], params.g)
    wd = np.cross(w @ I.T, w) @ Ii.T
    return np.concatenate([vd, wd], axis=1)


def known_linear(x0: np.ndarray, params) -> tuple[np.ndarray, np.ndarray]:
    """Linearisation of the known part (model with all K = 0 and J_z = 0) at ``x0``."""
    from lpv_sysid.models.quadrotor import Quadrotor

    p0 = dataclasses.replace(params, K={k: 0.0 for k in params.K}, j_rotor=0.0)
    return Quadrotor(p0).linearize(np.asarray(x0, dtype=float))


def _phi(x12: np.ndarray, params, mix: np.ndarray, mix_inv: np.ndarray) -> dict[str, np.ndarray]:
    return nl.regressors(x12[:, 2:5], x12[:, 5:8], x12[:, 8:12] @ mix_inv.T, None, params.arm_length, mix)


def remainders(x0: np.ndarray, dx: np.ndarray, params) -> dict[str, np.ndarray]:
    """Quadratic remainders ``r_k(dx)`` of the Eq. (6) regressors per axis, (N, n_axis)."""
    from lpv_sysid.models.quadrotor import mixer

    mix = mixer(params.arm_length)
    mix_inv = np.linalg.inv(mix)
    x0 = np.asarray(x0, dtype=float)[None, :]
    rp = _phi(x0 + dx, params, mix, mix_inv)
    rm = _phi(x0 - dx, params, mix, mix_inv)
    r0 = _phi(x0, params, mix, mix_inv)
    return {a: 0.5 * (rp[a] + rm[a]) - r0[a] for a in rp}


def select_nuisance(rem: dict[str, np.ndarray], params, tol: float = 1e-9) -> dict[int, np.ndarray]:
    """Per fitted row, the non-vanishing remainders of the axes that act on it.

    Force rows take their own axis; moment rows every moment axis with a nonzero entry in
    the corresponding row of ``I^-1`` (one axis for a diagonal inertia).
    """
    Ii = np.linalg.inv(np.asarray(params.inertia, dtype=float))
    out = {}
    for n, row in enumerate(ROWS):
        if n < 3:
            cols = [rem[FORCE_AXES[n]]]
        else:
            cols = [rem[MOMENT_AXES[j]] for j in range(3) if abs(Ii[n - 3, j]) > 0]
        R = np.concatenate(cols, axis=1)
        norms = np.linalg.norm(R, axis=0)
        keep = norms > tol * max(1.0, float(np.max(norms)) if norms.size else 1.0)
        out[row] = R[:, keep]
    return out


def nuisance_regressors(x0: np.ndarray, dx: np.ndarray, params, tol: float = 1e-9) -> dict[int, np.ndarray]:
    """:func:`select_nuisance` of :func:`remainders` (unsmoothed data)."""
    return select_nuisance(remainders(x0, dx, params), params, tol)
