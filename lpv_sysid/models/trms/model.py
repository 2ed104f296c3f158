"""The TRMS model (seed 2 Eqs. 1-6), its quasi-LPV embedding (Eqs. 41-58) and reference
equilibria (Sec. 5.1); conventions and deviations from the seed: :mod:`lpv_sysid.models.trms`."""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
from numpy.typing import ArrayLike

from lpv_sysid.errors import ConfigError
from lpv_sysid.models.trms.params import P_NAMES, PSI_INDEX, TrmsParams


# --------------------------------------------------------------------------- nonlinear functions
def _pn(w, kp: float, kn: float):
    """kp where w >= 0, kn where w < 0 (the sign switch of Eqs. 15-20)."""
    return np.where(np.asarray(w) >= 0, kp, kn)


class Trms:
    """Nonlinear TRMS model (seed 2 Eqs. 1-6) and its quasi-LPV embedding (Eqs. 41-58)."""

    def __init__(self, params: Optional[TrmsParams] = None) -> None:
        self.p = params or TrmsParams()

    # Eqs. (15)-(20)
    def f1(self, wh):
        return _pn(wh, self.p.k_thp, -self.p.k_thn) * np.square(wh)

    def f2(self, wh):
        return _pn(wh, self.p.k_fhp, -self.p.k_fhn) * np.square(wh)

    def f3(self, th):
        return _pn(th, self.p.k_chp, self.p.k_chn) * np.asarray(th)

    def f4(self, wv):
        return _pn(wv, self.p.k_tvp, -self.p.k_tvn) * np.square(wv)

    def f5(self, wv):
        return _pn(wv, self.p.k_fvp, -self.p.k_fvn) * np.square(wv)

    def f6(self, tv):
        d = np.asarray(tv) - self.p.theta_v0
        return _pn(d, self.p.k_cvp, self.p.k_cvn) * np.square(d)

    def den(self, tv):
        """K_D cos^2 + K_E sin^2 + K_F (denominator of Eq. 2)."""
        c, s = np.cos(tv), np.sin(tv)
        return self.p.K_D * c**2 + self.p.K_E * s**2 + self.p.K_F

    def derivatives(self, x: ArrayLike, u: ArrayLike) -> np.ndarray:
        """dx/dt of seed 2 Eqs. (1)-(6). ``x`` (6,), ``u`` (2,) in the order of
        STATE_NAMES/INPUT_NAMES."""
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        if x.shape != (6,) or u.shape != (2,):
            raise ConfigError(
                f"trms.derivatives: need x (6,) and u (2,), got {x.shape}, {u.shape}"
            )
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(u))):
            raise ConfigError(f"trms.derivatives: NaN/inf in x={x.tolist()} or u={u.tolist()}")
        p = self.p
        wh, Wh, th, wv, Wv, tv = x
        uh, uv = u
        c, s = math.cos(tv), math.sin(tv)
        D = float(self.den(tv))
        ka2 = p.k_a**2 / p.R_a
        tail = p.k_a * p.k_1 / p.R_a * uh - (p.B_tr + ka2) * wh - float(self.f1(wh))  # J_tr dwh/dt
        main = p.k_a * p.k_2 / p.R_a * uv - (p.B_mr + ka2) * wv - float(self.f4(wv))  # J_mr dwv/dt
        f5 = float(self.f5(wv))
        d_wh = tail / p.J_tr  # Eq. (1)
        d_Wh = (
            (
                p.l_t * float(self.f2(wh)) * c
                - p.k_oh * Wh
                - float(self.f3(th))
                + float(self.f6(tv))
            )
            / D
            + p.k_m * wv * s * Wv * (p.K_D * c**2 - p.K_E * s**2 - p.K_F - 2 * p.K_E * c**2) / D**2
            + p.k_m * c * main / (p.J_mr * D)
        )  # Eq. (2)
        d_wv = main / p.J_mr  # Eq. (4)
        d_Wv = (
            (p.l_m * f5 + p.k_g * Wh * f5 * c - p.k_ov * Wv) / p.J_v
            + (p.g * ((p.K_A - p.K_B) * c - p.K_C * s) - Wh**2 * p.K_H * s * c) / p.J_v
            + p.k_t * tail / (p.J_v * p.J_tr)
        )  # Eq. (5)
        return np.array([d_wh, d_Wh, Wh, d_wv, d_Wv, Wv])  # Eqs. (3), (6)

    # --------------------------------------------------------------- quasi-LPV form, Eqs.
    # (41)-(58)
    def shift(self, x) -> np.ndarray:
        """x~ = x - theta_v^0 e_6, the state of Eq. (41)."""
        xs = np.array(x, dtype=float)
        xs[..., 5] -= self.p.theta_v0
        return xs

    def psi(self, P) -> np.ndarray:
        """psi_1..psi_11 of Eqs. (43)-(54) at p = (theta_h, theta_v, omega_h, omega_v, Omega_h)
        (Eq. 41).

        Vectorised: ``P`` (..., 5) -> (..., 11). Removable singularities take their limits.
        """
        P = np.asarray(P, dtype=float)
        if P.shape[-1] != 5:
            raise ConfigError(f"trms.psi: p must have 5 entries {P_NAMES}, got shape {P.shape}")
        pr = self.p
        th, tv, wh, wv, Wh = (P[..., k] for k in range(5))
        c, s = np.cos(tv), np.sin(tv)
        D = self.den(tv)
        ka2 = pr.k_a**2 / pr.R_a
        f1_w = _pn(wh, pr.k_thp, -pr.k_thn) * wh  # f1(wh)/wh (limit 0 at wh = 0)
        f2_w = _pn(wh, pr.k_fhp, -pr.k_fhn) * wh
        f4_w = _pn(wv, pr.k_tvp, -pr.k_tvn) * wv
        f5_w = _pn(wv, pr.k_fvp, -pr.k_fvn) * wv
        f3_t = _pn(th, pr.k_chp, pr.k_chn)  # f3(th)/th
        dv = tv - pr.theta_v0
        f6_t = _pn(dv, pr.k_cvp, pr.k_cvn) * dv  # f6/(tv - tv0)
        rho = math.hypot(pr.K_A - pr.K_B, pr.K_C)
        out = np.empty(P.shape[:-1] + (11,))
        out[..., 0] = -(ka2 + pr.B_tr + f1_w) / pr.J_tr  # (43)
        out[..., 1] = pr.l_t * c * f2_w / D  # (44)
        out[..., 2] = -pr.k_oh / D  # (45)
        out[..., 3] = -f3_t / D  # (46)
        out[..., 4] = -pr.k_m * (ka2 + pr.B_mr + f4_w) * c / (D * pr.J_mr)  # (47)
        out[..., 5] = (
            pr.k_m * wv * s * (pr.K_D * c**2 - pr.K_E * s**2 - pr.K_F - 2 * pr.K_E * c**2) / D**2
        )  # (48)
        out[..., 6] = f6_t / D  # (49)
        out[..., 7] = -(ka2 + pr.B_mr + f4_w) / pr.J_mr  # (50)
        out[..., 8] = (pr.k_g * c * f5_w * wv - Wh * pr.K_H * s * c) / pr.J_v  # (51)
        out[..., 9] = pr.l_m * f5_w / pr.J_v  # (52)
        # (54): g((K_A - K_B) cos tv - K_C sin tv) = -g rho sin(tv - tv0); np.sinc(x) = sin(pi
        # x)/(pi x)
        out[..., 10] = -pr.g * rho * np.sinc(dv / np.pi) / pr.J_v
        return out

    def p_of_x(self, x) -> np.ndarray:
        """p(x) of Eq. (41): (theta_h, theta_v, omega_h, omega_v, Omega_h)."""
        x = np.asarray(x, dtype=float)
        return np.stack([x[..., 2], x[..., 5], x[..., 0], x[..., 3], x[..., 1]], axis=-1)

    def A_of_psi(self, psi) -> np.ndarray:
        """A(psi) of Eq. (42) (continuous time); affine in psi."""
        psi = np.asarray(psi, dtype=float)
        A = np.zeros(psi.shape[:-1] + (6, 6))
        for k, (r, c) in enumerate(PSI_INDEX):
            A[..., r, c] = psi[..., k]
        A[..., 2, 1] = 1.0
        A[..., 5, 4] = 1.0
        A[..., 4, 0] = self.p.k_t / self.p.J_v * psi[..., 0]
        A[..., 4, 4] = -self.p.k_ov / self.p.J_v  # (53)
        return A

    def b22(self, theta_v):
        """Eq. (56)."""
        pr = self.p
        return pr.k_m * np.cos(theta_v) * pr.k_a * pr.k_2 / (self.den(theta_v) * pr.R_a * pr.J_mr)

    def B_of(self, theta_v) -> np.ndarray:
        """B(p) of Eq. (41) with b11, b22(theta_v), b42, b51 of Eqs. (55)-(58)."""
        pr = self.p
        B = np.zeros((6, 2))
        B[0, 0] = pr.k_a * pr.k_1 / (pr.J_tr * pr.R_a)
        B[1, 1] = float(self.b22(theta_v))
        B[3, 1] = pr.k_a * pr.k_2 / (pr.J_mr * pr.R_a)
        B[4, 0] = pr.k_a * pr.k_1 * pr.k_t / (pr.J_v * pr.J_tr * pr.R_a)
        return B

    def lpv_matrices(self, x) -> tuple[np.ndarray, np.ndarray]:
        """(A(psi(x)), B(p(x))) such that A x~ + B u = derivatives(x, u) (Eq. 41), exactly."""
        x = np.asarray(x, dtype=float)
        return self.A_of_psi(self.psi(self.p_of_x(x))), self.B_of(x[5])

    # --------------------------------------------------------------- equilibria, Sec. 5.1
    def reference_equilibrium(
        self, theta_h_r: float, theta_v_r: float, Omega_h_r: float = 0.0, Omega_v_r: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """State reference x_r and feedforward u_r of Eqs. (107)-(112) (x_r in the unshifted
        state)."""
        pr = self.p
        c, s = math.cos(theta_v_r), math.sin(theta_v_r)
        D = float(self.den(theta_v_r))
        f5r = (
            pr.g * (pr.K_C * s + (pr.K_B - pr.K_A) * c)
            + pr.k_ov * Omega_v_r
            + Omega_h_r**2 * pr.K_H * s * c
        ) / (pr.l_m + pr.k_g * Omega_h_r * c)  # (107)
        wv = math.sqrt(f5r / pr.k_fvp) if f5r >= 0 else -math.sqrt(-f5r / pr.k_fvn)  # (110)
        f2r = (
            float(self.f3(theta_h_r))
            - float(self.f6(theta_v_r))
            + pr.k_oh * Omega_h_r
            - pr.k_m
            * wv
            * s
            * Omega_v_r
            * (pr.K_D * c**2 - pr.K_E * s**2 - pr.K_F - 2 * pr.K_E * c**2)
            / D
        ) / (pr.l_t * c)  # (108)
        wh = math.sqrt(f2r / pr.k_fhp) if f2r >= 0 else -math.sqrt(-f2r / pr.k_fhn)  # (109)
        uh = ((pr.B_tr * pr.R_a + pr.k_a**2) * wh + float(self.f1(wh)) * pr.R_a) / (
            pr.k_a * pr.k_1
        )  # (111)
        uv = ((pr.B_mr * pr.R_a + pr.k_a**2) * wv + float(self.f4(wv)) * pr.R_a) / (
            pr.k_a * pr.k_2
        )  # (112)
        return np.array([wh, Omega_h_r, theta_h_r, wv, Omega_v_r, theta_v_r]), np.array([uh, uv])

    def jacobian(self, x, u, h: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
        """Central-difference Jacobians of :meth:`derivatives` (the model is only piecewise
        smooth)."""
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        A = np.empty((6, 6))
        B = np.empty((6, 2))
        for k in range(6):
            e = np.zeros(6)
            e[k] = h
            A[:, k] = (self.derivatives(x + e, u) - self.derivatives(x - e, u)) / (2 * h)
        for k in range(2):
            e = np.zeros(2)
            e[k] = h
            B[:, k] = (self.derivatives(x, u + e) - self.derivatives(x, u - e)) / (2 * h)
        return A, B
