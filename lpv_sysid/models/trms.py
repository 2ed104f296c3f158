"""Twin Rotor MIMO System (TRMS) of seed 2 (Rotondo, Nejjari & Puig 2013), Eqs. (1)-(27),
(41)-(69).

State (seed 2 Sec. 2): ``x = [omega_h, Omega_h, theta_h, omega_v, Omega_v, theta_v]`` (tail rotor
speed [V, the paper's calibrated unit, Table 7 note 4], yaw rate [rad/s], yaw [rad], main rotor
speed [V], pitch rate [rad/s], pitch [rad]); input ``u = [u_h, u_v]`` (tail / main motor voltage).
The quasi-LPV form (Eq. 41) is written in the shifted state ``x~ = x - theta_v^0 e_6``.

Parameters: Table 5 (manufacturer) and Table 6 (identified). ``theta_v^0`` ("equilibrium pitch
for u_v = 0", Table 4) has no printed value; it is *derived* from the model: with u_v = 0 the
main rotor stops (Eq. 4), f5 = 0 and Eq. (5) at rest gives (K_A - K_B) cos th - K_C sin th = 0, so
``theta_v^0 = atan2(K_A - K_B, K_C)`` (= -0.6194 rad with the table values).

Deviations from the converted seed text (docs/trms.md):
* Eq. (27) prints ``m_cb l_cb`` (kg m, dimensionally inconsistent with the other kg m^2 terms);
  read as ``m_cb l_cb^2`` (Rahideh & Shaheed 2007's H).
* The armature inductance L_a (Table 5) is unused: electrical dynamics are neglected (Sec. 2).
* The removable singularities of Eqs. (43)-(54) (f_i(w)/w at w = 0, f_3/theta_h at 0, the gravity
  term of Eq. 54 at theta_v^0) are evaluated by their limits, so the embedding is exact everywhere
  and the gaps of Eq. (69) are not needed. Eq. (54) is evaluated as
  ``-g rho sinc(theta_v - theta_v^0) / J_v`` with ``rho = hypot(K_A - K_B, K_C)``, an identity.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any, Mapping, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike

from lpv_sysid.errors import ConfigError
from lpv_sysid.config_fields import check_keys, is_finite_number

STATE_NAMES = ("omega_h", "Omega_h", "theta_h", "omega_v", "Omega_v", "theta_v")
STATE_UNITS = ("V", "rad/s", "rad", "V", "rad/s", "rad")
INPUT_NAMES = ("u_h", "u_v")
INPUT_UNITS = ("V", "V")
#: p of Eq. (41): the system variables the scheduling parameters depend on.
P_NAMES = ("theta_h", "theta_v", "omega_h", "omega_v", "Omega_h")
#: psi of Eq. (41): matrix element (row, col) of A (0-based) for psi_1..psi_11.
PSI_NAMES = ("a11", "a21", "a22", "a23", "a24", "a25", "a26", "a44", "a52", "a54", "a56")
PSI_INDEX = (
    (0, 0),
    (1, 0),
    (1, 1),
    (1, 2),
    (1, 3),
    (1, 4),
    (1, 5),
    (3, 3),
    (4, 1),
    (4, 3),
    (4, 5),
)
#: Reduced scheduling vector of Sec. 6.3 (N~ = 8): the others are frozen at constants.
REDUCED_PSI = ("a11", "a21", "a22", "a23", "a26", "a44", "a54", "a56")
#: Table 7 operating ranges: (min, max) of the p variables; theta_v is given as theta_v -
#: theta_v^0.
TABLE7_RANGES = {
    "omega_h": (-2.9, 2.9),
    "omega_v": (-1.6, 1.6),
    "Omega_h": (-1.0, 1.0),
    "Omega_v": (-0.6, 0.6),
    "theta_h": (-1.7, 1.2),
    "dtheta_v": (-0.5, 1.0),
    "u_h": (-2.5, 2.5),
    "u_v": (-2.0, 2.0),
}
TS_PAPER = 0.1  # Sec. 6.2, Euler sample time


@dataclass(frozen=True)
class TrmsParams:
    """TRMS constants, seed 2 Tables 5 (manufacturer) and 6 (identified). SI units, rotor speeds
    in V."""

    # Table 5 (known)
    k_g: float = 0.2
    l_t: float = 0.282
    l_m: float = 0.246
    l_b: float = 0.290
    l_cb: float = 0.276
    r_ts: float = 0.1
    r_ms: float = 0.155
    m_cb: float = 0.068
    m_b: float = 0.022
    m_m: float = 0.014
    m_mr: float = 0.236
    m_ms: float = 0.219
    m_t: float = 0.015
    m_tr: float = 0.221
    m_ts: float = 0.119
    k_a: float = 0.0202
    R_a: float = 8.0
    k_1: float = 6.5
    k_2: float = 8.5
    # Table 6 (identified)
    B_tr: float = 0.0086
    B_mr: float = 0.0026
    k_thp: float = 0.0027
    k_thn: float = 0.0028
    J_tr: float = 0.0059
    J_mr: float = 0.0254
    k_t: float = 0.0
    k_m: float = 0.0017
    k_tvp: float = 0.0168
    k_tvn: float = 0.0155
    k_oh: float = 0.0185
    k_ov: float = 0.1026
    k_fhp: float = 0.0566
    k_fhn: float = 0.0660
    k_fvp: float = 0.3819
    k_fvn: float = 0.2197
    k_chp: float = 0.0158
    k_chn: float = 0.0111
    k_cvp: float = 0.0623
    k_cvn: float = 0.0563
    g: float = 9.81

    _POSITIVE = (
        "l_t",
        "l_m",
        "l_b",
        "l_cb",
        "r_ts",
        "r_ms",
        "m_cb",
        "m_b",
        "m_m",
        "m_mr",
        "m_ms",
        "m_t",
        "m_tr",
        "m_ts",
        "k_a",
        "R_a",
        "J_tr",
        "J_mr",
        "g",
    )

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not is_finite_number(v):
                raise ConfigError(f"trms.{f.name}: must be a finite number, got {v!r}")
            if v < 0 or (f.name in self._POSITIVE and v == 0):
                raise ConfigError(
                    f"trms.{f.name}: must be {'> 0' if f.name in self._POSITIVE else '>= 0'}, got "
                    f"{v}"
                )

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "TrmsParams":
        check_keys(d, [f.name for f in fields(cls)], "trms", list_allowed=True)
        return cls(**dict(d))

    def to_dict(self) -> dict:
        return asdict(self)

    # derived constants, Eqs. (7)-(14), (21)-(27)
    @property
    def J_v(self) -> float:
        """J_v = sum of J_v1..J_v8, Eqs. (7)-(14)."""
        return (
            self.m_mr * self.l_m**2
            + self.m_m * self.l_m**2 / 3
            + self.m_cb * self.l_cb**2
            + self.m_b * self.l_b**2 / 3
            + self.m_tr * self.l_t**2
            + self.m_t * self.l_t**2 / 3
            + self.m_ms * self.r_ms**2 / 2
            + self.m_ms * self.l_m**2
            + self.m_ts * self.r_ts**2 / 2
            + self.m_ts * self.l_t**2
        )

    @property
    def K_A(self) -> float:  # Eq. (21)
        return (self.m_t / 2 + self.m_tr + self.m_ts) * self.l_t

    @property
    def K_B(self) -> float:  # Eq. (22)
        return (self.m_m / 2 + self.m_mr + self.m_ms) * self.l_m

    @property
    def K_C(self) -> float:  # Eq. (23)
        return self.m_b * self.l_b / 2 + self.m_cb * self.l_cb

    @property
    def K_D(self) -> float:  # Eq. (24)
        return (self.m_m / 3 + self.m_mr + self.m_ms) * self.l_m**2 + (
            self.m_t / 3 + self.m_tr + self.m_ts
        ) * self.l_t**2

    @property
    def K_E(self) -> float:  # Eq. (25)
        return self.m_b * self.l_b**2 / 3 + self.m_cb * self.l_cb**2

    @property
    def K_F(self) -> float:  # Eq. (26)
        return self.m_ms * self.r_ms**2 + self.m_ts * self.r_ts**2 / 2

    @property
    def K_H(self) -> float:
        """Eq. (27), read with m_cb l_cb^2 (the printed m_cb l_cb is not a moment of inertia)."""
        return (
            self.K_A * self.l_t
            + self.K_B * self.l_m
            + self.m_b * self.l_b**2 / 2
            + self.m_cb * self.l_cb**2
        )

    @property
    def theta_v0(self) -> float:
        """Pitch equilibrium for u_v = 0 (Table 4): the root of
        (K_A - K_B) cos th - K_C sin th (Eq. 5)."""
        return math.atan2(self.K_A - self.K_B, self.K_C)


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


# --------------------------------------------------------------------------- bounding box, Sec.
# 3.4-3.5
#: which p variables each psi_j depends on (indices into P_NAMES); used to grid only those.
PSI_DEPENDS = ((2,), (1, 2), (1,), (0, 1), (1, 3), (1, 3), (1,), (3,), (1, 3, 4), (3,), (1,))


def p_box(
    params: TrmsParams, ranges: Optional[Mapping[str, tuple]] = None
) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) of p = (theta_h, theta_v, omega_h, omega_v, Omega_h) from Table 7 (theta_v
    absolute)."""
    r = dict(TABLE7_RANGES)
    r.update(ranges or {})
    tv0 = params.theta_v0
    lo = np.array(
        [
            r["theta_h"][0],
            r["dtheta_v"][0] + tv0,
            r["omega_h"][0],
            r["omega_v"][0],
            r["Omega_h"][0],
        ]
    )
    hi = np.array(
        [
            r["theta_h"][1],
            r["dtheta_v"][1] + tv0,
            r["omega_h"][1],
            r["omega_v"][1],
            r["Omega_h"][1],
        ]
    )
    if np.any(hi <= lo):
        raise ConfigError(f"trms p box: need max > min, got {lo.tolist()} / {hi.tolist()}")
    return lo, hi


def psi_bounds(
    model: Trms,
    plo,
    phi,
    n_grid: int = 201,
    gaps: Optional[Mapping[str, tuple]] = None,
    max_points: int = 200_000,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bounding box of psi over the p box (Eq. 62): (min (11,), max (11,), least-squares constant
    (11,)).

    Seed 2 Sec. 3.5 takes the extremes "by numerical optimization"; here each psi_j is gridded
    over only the p variables it depends on (PSI_DEPENDS, <= 3 of them; at most ``max_points``
    points per psi), with the box edges, 0 and the sign switches of Eqs. (15)-(20) added to the
    grid. ``gaps`` = {name: (minus, plus)} removes the open interval (minus, plus) of a p variable
    (Eq. 69; names of P_NAMES, theta_v given as the offset from theta_v^0) and adds its edges.
    The third output is the grid mean, the least-squares constant used for frozen parameters (Sec.
    6.3).
    """
    plo = np.asarray(plo, dtype=float)
    phi = np.asarray(phi, dtype=float)
    gaps = dict(gaps or {})
    bad = sorted(set(gaps) - set(P_NAMES))
    if bad:
        raise ConfigError(f"trms gaps: unknown variable(s) {bad}; known: {list(P_NAMES)}")
    mid = 0.5 * (plo + phi)
    lo = np.empty(11)
    hi = np.empty(11)
    mean = np.empty(11)
    for j, dep in enumerate(PSI_DEPENDS):
        per_axis = max(11, min(n_grid, int(max_points ** (1.0 / len(dep)))))
        axes = []
        for k in dep:
            g = np.linspace(plo[k], phi[k], per_axis)
            extra = [0.0, model.p.theta_v0] if k == 1 else [0.0]
            if P_NAMES[k] in gaps:
                off = model.p.theta_v0 if k == 1 else 0.0
                gm, gp = (float(v) + off for v in gaps[P_NAMES[k]])
                g = g[(g <= gm) | (g >= gp)]
                extra = [e for e in extra if not gm < e < gp] + [gm, gp]
            extra = [e for e in extra if plo[k] <= e <= phi[k]]
            axes.append(np.unique(np.concatenate([g, extra])))
        grids = np.meshgrid(*axes, indexing="ij")
        P = np.broadcast_to(mid, grids[0].shape + (5,)).copy()
        for k, gk in zip(dep, grids):
            P[..., k] = gk
        v = model.psi(P)[..., j]
        lo[j], hi[j], mean[j] = v.min(), v.max(), v.mean()
    return lo, hi, mean


def euler_discrete(A: np.ndarray, B: np.ndarray, ts: float) -> tuple[np.ndarray, np.ndarray]:
    """A_d = I + Ts A, B_d = Ts B (Euler, Eqs. 59-61)."""
    n = A.shape[-1]
    return np.eye(n) + ts * A, ts * B


@dataclass
class TrmsPolytope:
    """Bounding-box polytope of the (reduced) scheduling vector, Eqs. (62)-(65), discrete or
    continuous.

    ``names`` the scheduled psi (a subset of PSI_NAMES), ``lo``/``hi`` their box, ``frozen`` the
    constants used for the other psi and for b22 (Sec. 6.3 and footnote 1), ``A`` (2**q, 6, 6) the
    vertex matrices in the order of :func:`lpv_sysid.models.lpv.box_vertices` (first psi slowest),
    ``B`` the common input matrix, ``ts`` None (continuous) or the Euler sample time.
    """

    model: Trms
    names: tuple
    lo: np.ndarray
    hi: np.ndarray
    frozen: dict
    A: np.ndarray
    B: np.ndarray
    ts: Optional[float]

    @property
    def index(self) -> list[int]:
        return [PSI_NAMES.index(n) for n in self.names]

    def psi_full(self, x) -> np.ndarray:
        """All 11 psi at state x with the frozen ones replaced by their constants."""
        v = self.model.psi(self.model.p_of_x(x))
        for k, name in enumerate(PSI_NAMES):
            if name in self.frozen:
                v[..., k] = self.frozen[name]
        return v

    def scheduled(self, x) -> np.ndarray:
        """The scheduled psi at x (for the multilinear weights)."""
        return self.model.psi(self.model.p_of_x(x))[..., self.index]

    def weights(self, x) -> tuple[np.ndarray, bool]:
        """pi_i(psi(x)) of Eq. (65) (multilinear, seed 0 Eq. 21); True when psi left the box."""
        from lpv_sysid.models.lpv import multilinear_weights

        return multilinear_weights(self.scheduled(x), self.lo, self.hi)

    def A_at(self, x) -> np.ndarray:
        """sum_i pi_i A_i; equals the reduced A(psi(x)) (Euler-discretised if ts) inside the
        box."""
        alpha, _ = self.weights(x)
        return np.tensordot(alpha, self.A, axes=1)

    def contains(self, x, tol: float = 1e-12) -> bool:
        v = self.scheduled(x)
        return bool(np.all(v >= self.lo - tol) and np.all(v <= self.hi + tol))


def bounding_box_polytope(
    model: Trms,
    names: Sequence[str] = REDUCED_PSI,
    ts: Optional[float] = TS_PAPER,
    ranges: Optional[Mapping[str, tuple]] = None,
    gaps: Optional[Mapping[str, tuple]] = None,
    n_grid: int = 201,
) -> TrmsPolytope:
    """Polytopic quasi-LPV model of Sec. 3.5 / 6.2 (bounding box over Table 7), vertices per Eq.
    (65).

    psi not in ``names`` are frozen at their least-squares constant over the box (Sec. 6.3), and so
    is b22 (footnote 1 of Eq. 41). With ``ts`` the vertices are the Euler A_d of Eq. (60).
    """
    from lpv_sysid.models.lpv import box_vertices

    bad = [n for n in names if n not in PSI_NAMES]
    if bad or len(set(names)) != len(names) or not names:
        raise ConfigError(
            f"trms polytope: scheduled parameters must be distinct names from {PSI_NAMES}, got "
            f"{list(names)}"
        )
    plo, phi = p_box(model.p, ranges)
    lo, hi, mean = psi_bounds(model, plo, phi, n_grid, gaps)
    idx = [PSI_NAMES.index(n) for n in names]
    frozen = {PSI_NAMES[k]: float(mean[k]) for k in range(11) if k not in idx}
    tv = np.linspace(plo[1], phi[1], n_grid)
    frozen["b22"] = float(np.mean(model.b22(tv)))
    base = mean.copy()
    verts = box_vertices(lo[idx], hi[idx])
    vertex_A = []
    for v in verts:
        psi = base.copy()
        psi[idx] = v
        vertex_A.append(model.A_of_psi(psi))
    A = np.array(vertex_A)
    B = model.B_of(model.p.theta_v0)
    B[1, 1] = frozen["b22"]
    if ts is not None:
        A, B = euler_discrete(A, B, ts)
    return TrmsPolytope(
        model=model, names=tuple(names), lo=lo[idx], hi=hi[idx], frozen=frozen, A=A, B=B, ts=ts
    )


__all__ = [
    "INPUT_NAMES",
    "P_NAMES",
    "PSI_NAMES",
    "REDUCED_PSI",
    "STATE_NAMES",
    "TABLE7_RANGES",
    "TS_PAPER",
    "Trms",
    "TrmsParams",
    "TrmsPolytope",
    "bounding_box_polytope",
    "euler_discrete",
    "p_box",
    "psi_bounds",
]
