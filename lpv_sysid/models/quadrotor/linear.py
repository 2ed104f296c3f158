"""Analytic linearisation of the seed 0 quadrotor's 12-state controller model (seed 0
Eqs. 10-16) and the structure of its unknown elements (seed 0 Appendix A)."""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from lpv_sysid.models.quadrotor.params import K_NAMES
from lpv_sysid.models.quadrotor.protocol import QuadrotorModel
from lpv_sysid.models.quadrotor.trim import Trim


def _skew(a) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def aero_jacobians(
    model: QuadrotorModel, K: Mapping[str, float], j_rotor: float, controller_state
):
    """Partial derivatives of F and M (Eq. 6) w.r.t. nu = (v, omega) and delta.

    Returns dF/dnu (3x6), dF/ddelta (3x4), dM/dnu (3x6), dM/ddelta (3x4), dMz/du_r.
    delta^2 = Mix Omega^2 = Mix (Mix^-1 delta)^2, so d delta^2 / d delta
    = Mix diag(2 Omega) Mix^-1 (Eq. 7). The rotor reaction torque J_z delta_r-dot with
    delta-dot = -a delta + b u (unsaturated Eq. 8) adds -a J_z to dMz/d delta_r and
    b J_z to dMz/du_r.
    """
    ell = model.params.arm_length
    l2 = ell * ell
    a, b = model.params.a_omega, model.params.b_omega
    u, v, w, p, q, r = (float(t) for t in controller_state[2:8])
    dt, da, de, dr = (float(t) for t in controller_state[8:12])
    Om = model.mix_inv @ np.asarray(controller_state[8:12], dtype=float)
    D2 = model.mix @ np.diag(2.0 * Om) @ model.mix_inv  # d(delta^2)/d(delta)
    k = K
    dF_nu = np.zeros((3, 6))
    dF_d = np.zeros((3, 4))
    dF_d2 = np.zeros((3, 4))
    dM_nu = np.zeros((3, 6))
    dM_d = np.zeros((3, 4))
    dM_d2 = np.zeros((3, 4))
    # Fx = u (K_x,mu0 + K_x,muw w + K_x,muh dt)           Eq. (6a)
    dF_nu[0, 0] = k["x_mu0"] + k["x_muw"] * w + k["x_muh"] * dt
    dF_nu[0, 2] = k["x_muw"] * u
    dF_d[0, 0] = k["x_muh"] * u
    # Fy                                                    Eq. (6b)
    dF_nu[1, 1] = k["y_mu0"] + k["y_muw"] * w + k["y_muh"] * dt
    dF_nu[1, 2] = k["y_muw"] * v
    dF_d[1, 0] = k["y_muh"] * v
    # Fz                                                    Eq. (6c)
    dF_nu[2, 0] = 2.0 * k["z_mu"] * u
    dF_nu[2, 1] = 2.0 * k["z_mu"] * v
    dF_nu[2, 2] = 4.0 * k["z_muw"] * dt
    dF_nu[2, 3] = -k["z_muw"] * da
    dF_nu[2, 4] = -k["z_muw"] * de
    dF_d[2, 0] = k["z_mu0"] + 4.0 * k["z_muw"] * w
    dF_d[2, 1] = -k["z_muw"] * p
    dF_d[2, 2] = -k["z_muw"] * q
    dF_d2[2, 0] = k["z_T0"]
    # Mx                                                    Eq. (6d)
    dM_nu[0, 0] = k["l_dr"] * dr
    dM_nu[0, 1] = k["l_muh"] * dt + k["l_muh_mu0"] + k["l_muh_muw"] * w
    dM_nu[0, 2] = k["l_muw"] * da + k["l_muh_muw"] * v
    dM_nu[0, 3] = -2.0 * l2 * k["l_muw"] * dt
    dM_nu[0, 4] = -0.5 * l2 * k["l_muw"] * dr
    dM_d[0, 0] = -2.0 * l2 * k["l_muw"] * p + k["l_muh"] * v
    dM_d[0, 1] = k["l_mu0"] + k["l_muw"] * w
    dM_d[0, 3] = -0.5 * l2 * k["l_muw"] * q + k["l_dr"] * u
    dM_d2[0, 1] = k["l_T0"]
    # My                                                    Eq. (6e)
    dM_nu[1, 0] = k["m_muh"] * dt + k["m_muh_mu0"] + k["m_muh_muw"] * w
    dM_nu[1, 1] = k["m_dr"] * dr
    dM_nu[1, 2] = k["m_muw"] * de + k["m_muh_muw"] * u
    dM_nu[1, 3] = -0.5 * l2 * k["m_muw"] * dr
    dM_nu[1, 4] = -2.0 * l2 * k["m_muw"] * dt
    dM_d[1, 0] = -2.0 * l2 * k["m_muw"] * q + k["m_muh"] * u
    dM_d[1, 2] = k["m_mu0"] + k["m_muw"] * w
    dM_d[1, 3] = -0.5 * l2 * k["m_muw"] * p + k["m_dr"] * v
    dM_d2[1, 2] = k["m_T0"]
    # Mz                                                    Eq. (6f)
    dM_nu[2, 0] = k["n_muh"] * da + k["n_muh_muw"] * p
    dM_nu[2, 1] = k["n_muh"] * de + k["n_muh_muw"] * q
    dM_nu[2, 2] = k["n_muw"] * dr
    dM_nu[2, 3] = k["n_muw"] * de + k["n_muw2"] * q + k["n_muh_muw"] * u
    dM_nu[2, 4] = k["n_muw"] * da + k["n_muw2"] * p + k["n_muh_muw"] * v
    dM_d[2, 1] = k["n_muw"] * q + k["n_muh"] * u
    dM_d[2, 2] = k["n_muw"] * p + k["n_muh"] * v
    dM_d[2, 3] = k["n_mu0"] + k["n_muw"] * w - a * j_rotor
    dM_d2[2, 3] = k["n_Q0"]
    dMz_dur = b * j_rotor
    return dF_nu, dF_d + dF_d2 @ D2, dM_nu, dM_d + dM_d2 @ D2, dMz_dur


def linearize(model: QuadrotorModel, trim_or_x, u0=None):
    """Analytic Jacobians A (12x12), B (12x4) of the 12-state model (seed 0 Eqs. 10-16).

    Accepts a ``Trim`` or a 12-state operating point ``x`` (then ``u0`` is unused: the
    Jacobians assume unsaturated motors, delta-dot = -a_Omega delta + b_Omega u).
    """
    x = np.asarray(trim_or_x.x0 if isinstance(trim_or_x, Trim) else trim_or_x, dtype=float)
    if x.shape != (12,):
        raise ValueError(f"linearize: expected a Trim or a 12-state, got shape {x.shape}")
    p = model.params
    g, m = p.g, p.mass
    phi, th = x[0], x[1]
    v = x[2:5]
    om = x[5:8]
    sf, cf, st, ct = math.sin(phi), math.cos(phi), math.sin(th), math.cos(th)
    tt = st / ct
    pp, qq, rr = om
    A = np.zeros((12, 12))
    B = np.zeros((12, 4))
    # Eq. (2) kinematics rows
    A[0, 0] = cf * tt * qq - sf * tt * rr
    A[0, 1] = (sf * qq + cf * rr) / (ct * ct)
    A[0, 5:8] = [1.0, sf * tt, cf * tt]
    A[1, 0] = -sf * qq - cf * rr
    A[1, 5:8] = [0.0, cf, -sf]
    # Eq. (3c): gravity, Coriolis v x omega, aerodynamics
    A[2:5, 0] = g * np.array([0.0, cf * ct, -sf * ct])
    A[2:5, 1] = g * np.array([-ct, -sf * st, -cf * st])
    A[2:5, 2:5] = -_skew(om)
    A[2:5, 5:8] = _skew(v)
    dF_nu, dF_d, dM_nu, dM_d, dMz_dur = aero_jacobians(model, p.K, p.j_rotor, x)
    A[2:5, 2:8] += dF_nu / m
    A[2:5, 8:12] = dF_d / m
    # Eq. (3d): d/d omega of I^-1 (I omega x omega) = I^-1 ([I omega x] - [omega x] I)
    J, Ii = model.inertia, model.inertia_inv
    A[5:8, 5:8] = Ii @ (_skew(J @ om) - _skew(om) @ J)
    A[5:8, 2:8] += Ii @ dM_nu
    A[5:8, 8:12] = Ii @ dM_d
    B[5:8, 3] = Ii[:, 2] * dMz_dur
    # Eq. (15): actuator rows, d(delta)/dt = -a_Omega delta + b_Omega u
    A[8:12, 8:12] = -p.a_omega * np.eye(4)
    B[8:12, :] = p.b_omega * np.eye(4)
    return A, B


def unknown_masks(model: QuadrotorModel):
    """Structural masks of the A, B elements that depend on the aero parameters.

    Seed 0 Appendix A: an element is unknown when d f_a / d(x, u) (Eq. 6) is
    structurally nonzero anywhere in the flight domain; evaluated analytically with
    generic (all nonzero, non-commensurate) parameters at a generic state so that no
    element vanishes by coincidence. Known elements: kinematics (Eq. 2), gravity,
    v x omega, I omega x omega, and the motor rows (-a_Omega I, b_Omega I). The rotor
    inertia J_z (it multiplies delta_r-dot in M_z) is treated as unknown like the K.
    """
    rng = np.random.default_rng(12345)
    Kg = {k: float(rng.uniform(0.5, 1.5)) for k in K_NAMES}
    xg = np.r_[0.1, -0.07, rng.uniform(-3, 3, 6), 600.0, 13.0, -11.0, 57.0]
    dF_nu, dF_d, dM_nu, dM_d, dMz = aero_jacobians(model, Kg, 0.7, xg)
    maskA = np.zeros((12, 12), dtype=bool)
    maskB = np.zeros((12, 4), dtype=bool)
    maskA[2:5, 2:8] = dF_nu != 0
    maskA[2:5, 8:12] = dF_d != 0
    Ii = np.abs(model.inertia_inv) > 0
    maskA[5:8, 2:8] = (Ii.astype(int) @ (dM_nu != 0).astype(int)) > 0
    maskA[5:8, 8:12] = (Ii.astype(int) @ (dM_d != 0).astype(int)) > 0
    maskB[5:8, 3] = Ii[:, 2] & (dMz != 0)
    return maskA, maskB
