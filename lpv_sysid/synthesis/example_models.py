"""Small reference plants for tests and benchmarks of the synthesis code.

``quadrotor_like_polytope`` is a 12-state, 4-input polytopic LPV model with the structure of
seed 0 Eq. (15) in the state order of DESIGN.md (phi, theta, u, v, w, p, q, r, dt, da, de, dr):
Euler kinematics, gravity coupling -g theta / +g phi in the u / v rows, aerodynamic damping that
is affine in the scheduling velocity (Eq. 12), a positive speed-stability derivative M_u (the
unstable pitch-speed mode of a hovering multirotor), rotor-speed rows ``-a I`` / ``b I`` with the
seed's a = 12.31 1/s and b = 1.399e4 rad/s (per unit ESC command), and control derivatives of
FlameWheel-450 magnitude. It is an *illustrative* model with realistic numerical scaling, not
an identified one; the product uses the identified ``vertex_models.yaml``.

``first_order_plant`` is x' = a x + b u + b_e w, z = c x, whose optimal state-feedback
H-infinity bound is known analytically (see :func:`first_order_gamma_inf`).
"""

from __future__ import annotations

import numpy as np

from lpv_sysid.models.lpv import (
    PolytopicModel,
    UncertainElement,
    box_vertices,
    uncertainty_vertices,
)

A_OMEGA = 12.31
B_OMEGA = 1.399e4
G = 9.80665

#: (matrix, row, col) of the elements made uncertain by ``quadrotor_like_polytope`` (in order).
UNCERTAIN_SLOTS = (("A", 6, 2), ("A", 5, 3), ("A", 2, 2), ("A", 4, 4), ("A", 3, 3), ("A", 7, 7))


def quadrotor_like_vertex(vd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the illustrative 12-state model at scheduling velocity vd = (u_d, v_d, w_d)."""
    ud, vd_, wd = (float(x) for x in vd)
    A = np.zeros((12, 12))
    B = np.zeros((12, 4))
    A[0, 5] = 1.0  # phi' = p
    A[1, 6] = 1.0  # theta' = q
    A[2, 1] = -G  # u' = -g theta + X_u u + X_q q
    A[2, 2] = -0.25 - 0.02 * ud
    A[3, 0] = G  # v' = g phi + Y_v v
    A[3, 3] = -0.25 - 0.02 * vd_
    A[4, 4] = -0.6 - 0.04 * wd  # w' = Z_w w + Z_dt dt
    A[4, 8] = -8.3e-3 * (1.0 + 0.02 * ud)
    A[2, 8] = -1.0e-3 * ud / 5.0  # thrust tilt with forward speed
    A[5, 3] = -0.35 - 0.03 * vd_  # p' = L_v v + L_p p + L_da da (dihedral-like)
    A[5, 5] = -0.8
    A[5, 9] = 0.66
    A[6, 2] = 0.35 + 0.03 * ud  # q' = M_u u + M_q q + M_de de  (M_u > 0: unstable mode)
    A[6, 6] = -0.8
    A[6, 10] = 0.66
    A[7, 7] = -0.3 - 0.01 * wd  # r' = N_r r + N_dr dr
    A[7, 11] = 4.5e-3
    for k in range(4):  # rotor speeds: delta' = -a delta + b u  (seed 0 Eq. 8, 15)
        A[8 + k, 8 + k] = -A_OMEGA
        B[8 + k, k] = B_OMEGA
    return A, B


def quadrotor_like_polytope(
    n_uncertain: int = 0, rel: float = 0.2, vmax: float = 5.0
) -> PolytopicModel:
    """Polytope over [-vmax, vmax]^3 with 2**n_uncertain uncertainty vertices per vertex (Eq. 23).

    The first ``n_uncertain`` entries of :data:`UNCERTAIN_SLOTS` get the interval
    nominal * (1 -/+ rel).
    """
    if not 0 <= n_uncertain <= len(UNCERTAIN_SLOTS):
        raise ValueError(f"n_uncertain must be in 0..{len(UNCERTAIN_SLOTS)}")
    lo, hi = -vmax * np.ones(3), vmax * np.ones(3)
    verts = box_vertices(lo, hi)
    As, Bs, systems = [], [], []
    for vd in verts:
        A, B = quadrotor_like_vertex(vd)
        els = []
        for mat, r, c in UNCERTAIN_SLOTS[:n_uncertain]:
            nom = (A if mat == "A" else B)[r, c]
            a, b = sorted((nom * (1 - rel), nom * (1 + rel)))
            els.append(UncertainElement(mat, r, c, a, b, nom))
        As.append(A)
        Bs.append(B)
        systems.append(uncertainty_vertices(A, B, els))
    x0 = np.zeros((8, 12))
    x0[:, 2:5] = verts
    x0[:, 0] = np.arctan(0.02 * verts[:, 1])  # small trim angles, linear in v_d (Assumption 1)
    x0[:, 1] = -np.arctan(0.02 * verts[:, 0])
    u0 = np.full((8, 4), 0.0)
    u0[:, 0] = 0.45 + 0.002 * verts[:, 2]
    return PolytopicModel(
        vmin=lo,
        vmax=hi,
        A=np.array(As),
        B=np.array(Bs),
        x0=x0,
        u0=u0,
        systems=systems,
        state_names=("phi", "theta", "u", "v", "w", "p", "q", "r", "dt", "da", "de", "dr"),
        input_names=("ut", "ua", "ue", "ur"),
        scheduling_names=("u_d", "v_d", "w_d"),
    )


def first_order_plant(a: float, b: float, be: float, vmin=(-1.0,), vmax=(1.0,)) -> PolytopicModel:
    """x' = a x + b u + b_e w on a 1-axis box with identical vertices
    (so B_e = B R, R = be / b)."""
    A = np.array([[[a]], [[a]]])
    B = np.array([[[b]], [[b]]])
    return PolytopicModel(
        vmin=np.array(vmin, float),
        vmax=np.array(vmax, float),
        A=A,
        B=B,
        x0=np.zeros((2, 1)),
        u0=np.zeros((2, 1)),
    )


def first_order_min_gain(a: float, b: float, be: float, c: float, gamma: float) -> float:
    """Smallest-|k| static gain with ||w -> z||_inf <= gamma for x' = a x + b u + b_e w, z = c x.

    Closed loop G(s) = c b_e / (s - (a + b k)); for a + b k < 0 its H-inf norm is the DC gain
    |c b_e| / |a + b k| (first-order low-pass). So ||G||_inf <= gamma iff
    a + b k <= -|c b_e| / gamma, i.e. k <= -(a + |c b_e| / gamma) / b for b > 0. The infimum of the
    norm over k is 0 (high gain), so only the feasibility direction is an oracle here.
    """
    return -(a + abs(c * be) / gamma) / b


def uncontrollable_disturbance_plant(
    a1: float, a2: float
) -> tuple[PolytopicModel, np.ndarray, np.ndarray, float]:
    """2-state plant with an analytic optimal H-inf state-feedback bound.

        x1' = -a1 x1 + w,   x2' = a2 x2 + x1 + u,   z = x1     (a1 > 0, a2 > 0: x2 unstable)

    u cannot reach x1, so the channel w -> z = 1 / (s + a1) is the same for every stabilising K:
    ||w -> z||_inf = 1 / a1 (DC gain) and gamma_min = 1 / a1 exactly; K must still stabilise x2.
    The disturbance is not matched (B_e != B R), so it is passed to the synthesis as an explicit
    ``Be``. Returns (model, Be, C, gamma_min).
    """
    A = np.array([[-a1, 0.0], [1.0, a2]])
    B = np.array([[0.0], [1.0]])
    model = PolytopicModel(
        vmin=np.array([-1.0]),
        vmax=np.array([1.0]),
        A=np.array([A, A]),
        B=np.array([B, B]),
        x0=np.zeros((2, 2)),
        u0=np.zeros((2, 1)),
    )
    return model, np.array([[1.0], [0.0]]), np.array([[1.0, 0.0]]), 1.0 / a1
