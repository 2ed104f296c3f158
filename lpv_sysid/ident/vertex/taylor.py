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
from dataclasses import dataclass

import numpy as np

from lpv_sysid.ident import nonlinear as nl

#: rows of the 12-state (DESIGN.md order) fitted in Taylor mode and the Eq. (6) axes entering them
ROWS = (2, 3, 4, 5, 6, 7)
FORCE_AXES = ("X", "Y", "Z")
MOMENT_AXES = ("L", "M", "N")


def known_rigid_body(states: np.ndarray, params, Ii: np.ndarray | None = None) -> np.ndarray:
    """Known part of ``[u', v', w', p', q', r']`` (Eq. 3c-3d with F = M = 0), (N, 6), at
    ``states`` (N, 12) in STATE_NAMES order; ``Ii``: the inverse inertia when already at hand."""
    states = np.atleast_2d(states)
    inertia = np.asarray(params.inertia, dtype=float)
    Ii = np.linalg.inv(inertia) if Ii is None else Ii
    v, w = states[:, 2:5], states[:, 5:8]
    vd = np.cross(v, w) + nl.gravity_body(states[:, 0], states[:, 1], params.g)
    wd = np.cross(w @ inertia.T, w) @ Ii.T
    return np.concatenate([vd, wd], axis=1)


def known_model(params):
    """The model with all K = 0 and J_z = 0: its linearisation is the known part's."""
    from lpv_sysid.models.quadrotor import Quadrotor

    return Quadrotor(dataclasses.replace(params, K={k: 0.0 for k in params.K}, j_rotor=0.0))


def known_linear(x0: np.ndarray, params, model=None) -> tuple[np.ndarray, np.ndarray]:
    """Linearisation of the known part (model with all K = 0 and J_z = 0) at ``x0``
    (``model``: :func:`known_model` of ``params`` when already at hand)."""
    return (model or known_model(params)).linearize(np.asarray(x0, dtype=float))


def _phi(
    states: np.ndarray, params, mix: np.ndarray, mix_inv: np.ndarray
) -> dict[str, np.ndarray]:
    return nl.regressors(
        states[:, 2:5], states[:, 5:8], states[:, 8:12] @ mix_inv.T, None, params.arm_length, mix
    )


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


def nuisance_index(
    rem: dict[str, np.ndarray], params, tol: float = 1e-9
) -> dict[int, list[tuple[str, int]]]:
    """Per fitted row, the ``(axis, column)`` of the non-vanishing remainders of the axes that
    act on it: force rows take their own axis, moment rows every moment axis with a nonzero
    entry in the corresponding row of ``I^-1`` (one axis for a diagonal inertia)."""
    Ii = np.linalg.inv(np.asarray(params.inertia, dtype=float))
    out = {}
    for n, row in enumerate(ROWS):
        axes = (
            [FORCE_AXES[n]]
            if n < 3
            else [MOMENT_AXES[j] for j in range(3) if abs(Ii[n - 3, j]) > 0]
        )
        cols = [(a, c) for a in axes for c in range(rem[a].shape[1])]
        norms = np.array([np.linalg.norm(rem[a][:, c]) for a, c in cols])
        big = float(np.max(norms)) if norms.size else 1.0
        out[row] = [ac for ac, nm in zip(cols, norms) if nm > tol * max(1.0, big)]
    return out


def select_nuisance(
    rem: dict[str, np.ndarray], params, tol: float = 1e-9
) -> dict[int, np.ndarray]:
    """Per fitted row, the non-vanishing remainders of the axes that act on it (the columns of
    :func:`nuisance_index`), (N, k) per row."""
    idx = nuisance_index(rem, params, tol)
    n = next(iter(rem.values())).shape[0]
    return {
        row: (np.stack([rem[a][:, c] for a, c in cols], axis=1) if cols else np.zeros((n, 0)))
        for row, cols in idx.items()
    }


def nuisance_regressors(
    x0: np.ndarray, dx: np.ndarray, params, tol: float = 1e-9
) -> dict[int, np.ndarray]:
    """:func:`select_nuisance` of :func:`remainders` (unsmoothed data)."""
    return select_nuisance(remainders(x0, dx, params), params, tol)


def remainder_hessians(x0: np.ndarray, params) -> dict[str, np.ndarray]:
    """Hessians of the quadratic remainders: ``r_k(dx) = dx^T H_k dx / 2`` exactly (the Eq. 6
    regressors are polynomials of degree <= 2), per axis an array (n_axis, 12, 12), from
    ``H_jj = 2 r(e_j)``, ``H_jk = r(e_j + e_k) - r(e_j) - r(e_k)`` (exact for a quadratic)."""
    n = np.asarray(x0).size
    pairs = [(j, k) for j in range(n) for k in range(j + 1, n)]
    E = np.eye(n)
    D = np.concatenate([E, np.array([E[j] + E[k] for j, k in pairs]).reshape(-1, n)], axis=0)
    rem = remainders(x0, D, params)
    out = {}
    for a, r in rem.items():
        H = np.zeros((r.shape[1], n, n))
        single = r[:n]
        H[:, np.arange(n), np.arange(n)] = 2.0 * single.T
        for m, (j, k) in enumerate(pairs):
            h = r[n + m] - single[j] - single[k]
            H[:, j, k] = H[:, k, j] = h
        out[a] = H
    return out


# ----------------------------------------------------------------------------- equilibrium
@dataclass(frozen=True)
class Reexpansion:
    """The identified second-order model re-expanded about its own equilibrium."""

    x_e: np.ndarray  # equilibrium state (v fixed at the flown mean, yaw rate psi_dot)
    u_e: np.ndarray
    A: np.ndarray  # Jacobians of the identified model at (x_e, u_e)
    B: np.ndarray
    std_A: np.ndarray  # delta-method standard errors (joint covariance), 0 if not identified
    std_B: np.ndarray
    cov: np.ndarray  # covariance of the identified elements (Fit.elements order)
    xdot_flown: np.ndarray  # (12,) identified model's derivative at the flown mean attitude,
    # velocity, rotor speeds and input (body rates: pure yaw rate)
    iterations: int
    # elements with a standard error: the identified ones and, with ``fixed``, the known
    # (gravity / kinematic / rigid-body) ones that move with the identified equilibrium
    maskA: np.ndarray | None = None
    maskB: np.ndarray | None = None
    cov_w: np.ndarray | None = None  # (10, 10) covariance of (phi, theta, delta_1..4, u_1..4)


def _x_of(w: np.ndarray, v0: np.ndarray, psi_dot: float) -> np.ndarray:
    phi, th = w[0], w[1]
    om = psi_dot * np.array([-np.sin(th), np.sin(phi) * np.cos(th), np.cos(phi) * np.cos(th)])
    return np.concatenate([w[:2], v0, om, w[2:6]])


MOTOR_LABELS = ("a", "b")


class IdentifiedModel:
    """``xdot_i = K_i(x) + theta_i . phi_i(x, u)`` per fitted row (``K_i`` the known rigid-body
    part of rows u..r) with ``phi_i`` built from the design labels (``x<j>``: dx_j, ``u<k>``:
    du_k, ``bias``: 1, ``aux``: rotor acceleration d(delta_r)/dt = the delta_r row itself,
    ``nuisance<c>``: the remainder ``nuis[row][c]``), and the motor rows of Eq. (8) in virtual
    actuators, ``delta_j' = theta_a d(delta_j) + theta_b du_j + (Mix c)_j``, from the fit whose
    labels start with ``a, b`` (``bias<i>``: rotor i's offset; ``delay``: the latency increment,
    whose regressor vanishes at rest); without such a fit the configured ``a_Omega, b_Omega``."""

    def __init__(self, x0, u0, fits, nuis: dict[int, list[tuple[str, int]]], params):
        from lpv_sysid.models.quadrotor import I_DR, mixer

        self.x0 = np.asarray(x0, dtype=float)
        self.u0 = np.asarray(u0, dtype=float)
        self.params = params
        self.motor = next((rf for rf in fits if rf.labels[:2] == MOTOR_LABELS), None)
        self.fits = {rf.row: rf for rf in fits if rf is not self.motor}
        self.hess = remainder_hessians(self.x0, params)
        self.mix = mixer(params.arm_length)
        self.i_dr = I_DR
        self.known = known_model(params)
        self.Ii = np.linalg.inv(np.asarray(params.inertia, dtype=float))
        self.nuis = {row: [self.hess[a][c] for a, c in cols] for row, cols in nuis.items()}

    def phi(self, row: int, dx: np.ndarray, du: np.ndarray) -> np.ndarray:
        """Regressor vector of ``row`` at a point (aux = 0: equilibrium, rotor acceleration 0)."""
        out = []
        for lab in self.fits[row].labels:
            if lab.startswith("x"):
                out.append(dx[int(lab[1:])])
            elif lab.startswith("u"):
                out.append(du[int(lab[1:])])
            elif lab == "bias":
                out.append(1.0)
            elif lab == "aux":
                out.append(0.0)
            else:
                H = self.nuis[row][int(lab[len("nuisance") :])]
                out.append(0.5 * dx @ H @ dx)
        return np.array(out)

    def motor_phi(self, j: int, dx: np.ndarray, du: np.ndarray) -> np.ndarray:
        """d(motor row j)/d(motor theta) at a point at rest (empty without a motor fit)."""
        out = []
        for lab in self.motor.labels if self.motor is not None else ():
            if lab == "a":
                out.append(dx[8 + j])
            elif lab == "b":
                out.append(du[j])
            elif lab.startswith("bias"):
                out.append(self.mix[j, int(lab[4:])])
            else:  # delay
                out.append(0.0)
        return np.array(out)

    def _ab(self, theta: np.ndarray) -> tuple[float, float]:
        if self.motor is None:
            return -self.params.a_omega, self.params.b_omega
        o = self.motor.offset
        return float(theta[o]), float(theta[o + 1])

    def residual(
        self, w: np.ndarray, theta: np.ndarray, v0: np.ndarray, psi_dot: float
    ) -> np.ndarray:
        """Identified state derivative of rows u..r and of the four motor rows at
        ``w = (phi, theta, delta_1..4, u_1..4)``."""
        x = _x_of(w[:6], v0, psi_dot)
        dx, du = x - self.x0, w[6:10] - self.u0
        kr = known_rigid_body(x[None, :], self.params, self.Ii)[0]
        out = np.zeros(10)
        for n, row in enumerate(ROWS):
            rf = self.fits.get(row)
            out[n] = kr[n] + (
                0.0
                if rf is None
                else theta[rf.offset : rf.offset + rf.theta.size] @ self.phi(row, dx, du)
            )
        for j in range(4):
            if self.motor is None:
                ta, tb = self._ab(theta)
                out[6 + j] = ta * dx[8 + j] + tb * du[j]
            else:
                o = self.motor.offset
                out[6 + j] = theta[o : o + self.motor.theta.size] @ self.motor_phi(j, dx, du)
        return out

    def jacobians(
        self, x: np.ndarray, u: np.ndarray, theta: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``A, B`` of the identified model at ``(x, u)`` where the rotor acceleration vanishes
        (the ``aux`` term then contributes ``theta_aux * d(delta_r row)/d(x, u)``)."""
        A, B = known_linear(x, self.params, self.known)
        dx = x - self.x0
        ta, tb = self._ab(theta)
        A[8:12, 8:12] = ta * np.eye(4)
        B[8:12, :] = tb * np.eye(4)
        for row, rf in self.fits.items():
            th = theta[rf.offset : rf.offset + rf.theta.size]
            for lab, c in zip(rf.labels, th):
                if lab.startswith("x"):
                    A[row, int(lab[1:])] += c
                elif lab.startswith("u"):
                    B[row, int(lab[1:])] += c
                elif lab.startswith("nuisance"):
                    A[row] += c * (self.nuis[row][int(lab[len("nuisance") :])] @ dx)
        for row, rf in self.fits.items():
            if "aux" in rf.labels:
                c = theta[rf.offset + rf.labels.index("aux")]
                A[row] += c * A[self.i_dr]
                B[row] += c * B[self.i_dr]
        return A, B


def reexpand(
    model: IdentifiedModel,
    theta: np.ndarray,
    cov: np.ndarray,
    v0: np.ndarray,
    psi_dot: float,
    maskA: np.ndarray,
    maskB: np.ndarray,
    max_iter: int = 20,
    tol: float = 1e-10,
    fixed: bool = False,
    psi_var: float = 0.0,
) -> Reexpansion:
    """Equilibrium of the identified model at the flown velocity, its Jacobians there and their
    covariance (seed 0 Eq. 13: the model is the expansion about an equilibrium).

    Newton on ``w = (phi, theta, delta, u)`` with ``v = v0`` and body rates of a pure yaw rate
    ``psi_dot``; the delta-method covariance of the elements includes the dependence of the
    equilibrium on the parameters (implicit function theorem: ``dw/dtheta = -G_w^-1 G_theta``,
    ``G_theta`` = the regressor vectors at the equilibrium).

    ``fixed`` (issue 20 item 3): the elements the identification does not estimate but that
    move with the identified equilibrium (gravity and kinematic terms at the identified
    attitude, rigid-body terms at the identified rotor speeds, remainder terms of identified
    rows) get their delta-method standard error too, from the same covariance (the trim
    uncertainty ``dw/dtheta cov dw/dtheta^T``); ``maskA``/``maskB`` of the result then mark
    every element with a standard error. ``psi_var``: variance of the equilibrium's yaw rate
    (the trim-window mean, not identified); its effect on the elements, directly and through
    the equilibrium, is added to their covariance.
    """
    from lpv_sysid.errors import SolverError

    x0, u0 = model.x0, model.u0
    w = np.concatenate([x0[:2], x0[8:12], u0])
    scale = np.concatenate(
        [
            [1e-3, 1e-3],
            np.maximum(1.0, np.abs(x0[8:12])) * 1e-4,
            np.maximum(1e-3, np.abs(u0)) * 1e-3,
        ]
    )

    def G(wv, th=theta):
        return model.residual(wv, th, v0, psi_dot)

    def G_w(wv):
        J = np.zeros((10, 10))
        for k in range(10):
            e = np.zeros(10)
            e[k] = scale[k]
            J[:, k] = (G(wv + e) - G(wv - e)) / (2 * scale[k])
        return J

    g = G(w)
    flown = g.copy()
    it = 0
    for it in range(1, max_iter + 1):
        step = np.linalg.solve(G_w(w), -g)
        w = w + step
        g = G(w)
        if np.all(np.abs(step) <= tol * np.maximum(1.0, np.abs(w))):
            break
    else:
        raise SolverError(
            f"equilibrium of the identified model not found in {max_iter} Newton steps "
            f"(|xdot| = {np.max(np.abs(g)):.3g})"
        )
    x_e = _x_of(w[:6], v0, psi_dot)
    u_e = w[6:10]
    A, B = model.jacobians(x_e, u_e, theta)
    if fixed:
        maskA, maskB = _moving_elements(
            model, w, theta, v0, psi_dot, scale, cov, maskA, maskB, psi_var > 0
        )
    # delta method: d(elements)/d(theta) = direct + d/dw * dw/dtheta
    idx = []
    for i in range(A.shape[0]):
        idx += [("A", i, int(j)) for j in np.nonzero(maskA[i])[0]]
        idx += [("B", i, int(k)) for k in np.nonzero(maskB[i])[0]]

    def elems(wv, th):
        Aw, Bw = model.jacobians(_x_of(wv[:6], v0, psi_dot), wv[6:10], th)
        return np.array([(Aw if m == "A" else Bw)[i, j] for m, i, j in idx])

    P = theta.size
    Gth = np.zeros((10, P))
    dx, du = x_e - x0, u_e - u0
    for n, row in enumerate(ROWS):
        rf = model.fits.get(row)
        if rf is not None:
            Gth[n, rf.offset : rf.offset + rf.theta.size] = model.phi(row, dx, du)
    if model.motor is not None:
        o = model.motor.offset
        for j in range(4):
            Gth[6 + j, o : o + model.motor.theta.size] = model.motor_phi(j, dx, du)
    dw = -np.linalg.solve(G_w(w), Gth)  # (10, P)
    D = np.zeros((len(idx), P))
    for k in range(10):  # d elements / d w (finite differences)
        e = np.zeros(10)
        e[k] = scale[k]
        D += np.outer((elems(w + e, theta) - elems(w - e, theta)) / (2 * scale[k]), dw[k])
    th_scale = np.maximum(np.abs(theta), 1e-12) * 1e-6
    nz = np.nonzero(np.any(cov != 0, axis=0))[0]
    for p in nz:  # d elements / d theta (linear but for aux)
        e = np.zeros(P)
        e[p] = th_scale[p]
        D[:, p] += (elems(w, theta + e) - elems(w, theta - e)) / (2 * th_scale[p])
    C = D @ cov @ D.T
    if psi_var > 0:  # the yaw rate of the equilibrium: directly and through w(psi_dot)
        e_p = 1e-4

        def at(psi: float) -> tuple[np.ndarray, np.ndarray]:
            gp = model.residual(w, theta, v0, psi)
            Aw, Bw = model.jacobians(_x_of(w[:6], v0, psi), w[6:10], theta)
            return gp, np.array([(Aw if m == "A" else Bw)[i, j] for m, i, j in idx])

        (g_hi, e_hi), (g_lo, e_lo) = at(psi_dot + e_p), at(psi_dot - e_p)
        dw_psi = -np.linalg.solve(G_w(w), (g_hi - g_lo) / (2 * e_p))
        d_psi = (e_hi - e_lo) / (2 * e_p)
        for k in range(10):
            e = np.zeros(10)
            e[k] = scale[k]
            d_psi += (elems(w + e, theta) - elems(w - e, theta)) / (2 * scale[k]) * dw_psi[k]
        C = C + psi_var * np.outer(d_psi, d_psi)
    std = np.sqrt(np.maximum(np.diag(C), 0.0))
    std_A, std_B = np.zeros_like(A), np.zeros_like(B)
    for (m, i, j), s in zip(idx, std):
        (std_A if m == "A" else std_B)[i, j] = s
    return Reexpansion(
        x_e,
        u_e,
        A,
        B,
        std_A,
        std_B,
        C,
        np.concatenate([[0.0, 0.0], flown]),
        it,
        maskA,
        maskB,
        dw @ cov @ dw.T,
    )


def _moving_elements(model, w, theta, v0, psi_dot, scale, cov, maskA, maskB, psi=False):
    """``maskA | extraA, maskB | extraB``: the elements whose value changes with the
    equilibrium ``w`` or with an uncertain parameter (finite differences; relative threshold
    1e-9), i.e. the ones that carry a standard error."""

    def ab(wv, th):
        Aw, Bw = model.jacobians(_x_of(wv[:6], v0, psi_dot), wv[6:10], th)
        return np.concatenate([Aw, Bw], axis=1)

    base = ab(w, theta)
    moved = np.zeros(base.shape, dtype=bool)
    tol = 1e-9 * np.maximum(1.0, np.abs(base))
    for k in range(w.size):
        e = np.zeros(w.size)
        e[k] = scale[k]
        moved |= np.abs(ab(w + e, theta) - ab(w - e, theta)) > tol
    th_scale = np.maximum(np.abs(theta), 1e-12) * 1e-6
    for p in np.nonzero(np.any(cov != 0, axis=0))[0]:
        e = np.zeros(theta.size)
        e[p] = th_scale[p]
        moved |= np.abs(ab(w, theta + e) - ab(w, theta - e)) > tol
    if psi:
        hi = model.jacobians(_x_of(w[:6], v0, psi_dot + 1e-4), w[6:10], theta)
        lo = model.jacobians(_x_of(w[:6], v0, psi_dot - 1e-4), w[6:10], theta)
        moved |= np.abs(np.concatenate(hi, axis=1) - np.concatenate(lo, axis=1)) > tol
    n = maskA.shape[0]
    return maskA | moved[:, :n], maskB | moved[:, n:]
