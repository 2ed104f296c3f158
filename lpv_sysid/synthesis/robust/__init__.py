"""Robust H-infinity state feedback over the whole element box (every identified element in its
interval), polynomial in size: the structured-perturbation form of seed 0 Lemma 1.

The uncertain vertex systems are the :class:`lpv_sysid.models.lpv.ElementBox`

    [A_i(delta), B(delta)] = [A_c,i, B_c] + L_i Delta R~_i,   Delta = diag(delta_l), |delta_l| <=
    1,

with L_i = [h_l e_(r_l)]_l (n x p_i) and R~_i = [e_(c_l)^T]_l (p_i x (n + m)). For a fixed
Lyapunov-type matrix the LMI of the frozen closed loop is affine in (A, B), so the uncertain part
enters as He(cal_L Delta cal_R) and is removed with the S-procedure for diagonal (D-scaling)
multipliers T_i = diag(t_l) > 0 (Petersen's lemma with scalings: for every diagonal Delta with
|delta_l| <= 1, He(cal_L Delta cal_R) <= cal_L T cal_L^T + cal_R^T T^-1 cal_R; Petersen 1987,
Syst. Control Lett. 8:351; Khargonekar, Petersen & Zhou 1990, IEEE TAC 35:356; Boyd, El Ghaoui,
Feron & Balakrishnan 1994, *LMIs in System and Control Theory*, Sec. 5.1 and 6.3.2 (the
"scaled small-gain" / diagonal norm-bound LDI)). Three Lyapunov structures (``lyapunov``):

``common``  one X for every scheduling point and every delta: the dual bounded-real LMI with
            Y_i = K_i X (Boyd et al. Sec. 7.5),

                [A_c X + B_c Y_i + (.)^T + L T L^T   B_c R   X C^T    G^T]
                [R^T B_c^T                          -I      0        G_w^T]  < 0,
                [C X                                 0      -g I     0 ]
                [G                                   G_w     0       -T ]

            G = R~ [X; Y_i], G_w = R~ [0; R]. Because X is common, V = x^T X^-1 x is a
            Lyapunov function of every closed loop in the set, so the u_e -> z bound holds for
            any variation of v_d (and of delta) in the set; the reference-driven terms (d/dt
            x0(v_d), feedforward error) are not in it (docs/certificate.md 3b). K_i = Y_i X^-1.
``vertex``  seed 0 Eq. (30) (Rotondo Thm. 2, common H, X_i per scheduling vertex) with the same
            S-procedure on U = A H + B S_i and B_e = B R: frozen v_d (the seed's claim).
``rate``    Eq. (30) with X(v_d) = sum_i alpha_i X_i and the term -dX/dt in the (1,1) block
            (the projection of Eq. 30 onto the null space of [A^T, I, 0, C^T] is the dual BRL
            plus that term, i.e. V = x^T X(v_d)^-1 x with dV/dt including d(X^-1)/dt). With the
            multilinear alpha, dX/dt = sum_k (dv_d,k/dt) D_k X and D_k X at vertex i is
            (X_(k+) - X_(k-)) / (v_max,k - v_min,k) (constant along axis k, multilinear in the
            others), so with |dv_d,k/dt| <= rho_k it suffices that at every vertex
            Psi_i + sum_k W_ik < 0 with W_ik >= +-rho_k D_k X (Apkarian & Adams 1998, IEEE TCST
            6:21, for parameter-dependent Lyapunov functions with bounded rates). Covers v_d(t)
            whose rates stay within rho (the design envelope's ``reference_rate``).

The LMIs are affine in (A, B) for fixed decision variables, so they hold at every frozen
v_d = sum alpha_i v_i (Eq. 21) with A = sum alpha_i A_i(delta_i) and B(delta) common, which is
the interior argument of :mod:`lpv_sysid.models.lpv` with the element box in place of corners.

Size. Written with the Schur complement on T the blocks are (2n + n_e + n_z + p_i) square; with
~50 elements per vertex that is ~80 and dominates the solve. Since L T L^T = diag_r(sum t_l h_l^2)
and cal_R^T T^-1 cal_R = G'^T W G' with W = diag_c(sum_(l in column c) 1/t_l), the same condition
is the block [Psi + L T L^T, G'^T P^T; P G', -Omega] < 0 with Omega = diag(omega_c) and
omega_c <= 1 / sum_(l in c) 1/t_l (P selects the columns that carry elements); the harmonic-sum
bound is convex: u_l t_l >= omega_c^2, sum_(l in c) u_l <= omega_c (rotated second-order cones).
Exact (no added conservatism), and the block size no longer grows with p: 2n + n_e + n_z + n_c
(n_c <= n + m). :func:`box_margins` re-evaluates that compressed form with numpy; the verifier
checks the uncompressed one and the scaled small-gain frequency-domain condition independently.

Objective (``objective``): ``feasibility`` (the seed), ``min_gamma``, or ``min_effort``: minimise
kappa with K_i X K_i^T <= kappa I, i.e. [X, Y_i^T; Y_i, kappa I] >= 0 (``common``) or
[H + H^T - X_i, S_i^T; S_i, kappa I] >= 0 (``vertex``/``rate``: H^T X^-1 H >= H + H^T - X);
the input-amplitude bound of Boyd et al. Sec. 7.2.3 -- among the laws certified at gamma the one
with the least control effort, a well-defined answer where a feasibility solver returns an
arbitrary interior point (high-gain laws with ||K|| ~ 1e3 satisfy gamma = 1 just as well).

Parts: the box in scaled coordinates (:mod:`~lpv_sysid.synthesis.robust.data`), the cvxpy
problem (:mod:`~lpv_sysid.synthesis.robust.problem`), the numpy re-check
(:mod:`~lpv_sysid.synthesis.robust.check`); this module solves (:func:`solve_box`).
"""

from __future__ import annotations

from lpv_sysid.synthesis.robust.synthesize import solve_box

__all__ = [
    "solve_box",
]
