"""Nonlinear quadrotor model of seed 0 (Hopwood & Woolsey), Eqs. (2), (3), (6), (7), (8).

Frames: NED world frame F_I, FRD body frame F_B (seed 0 Sec. II). Euler angles follow
R_IB = exp([e3x] psi) exp([e2x] theta) exp([e1x] phi) and the kinematics of Eq. (2).

Full state (16, ``FULL_STATE_NAMES``): position NED, Euler angles, body velocity, body
rates, rotor speeds Omega_1..4 (PX4 quad-X numbering: 1 front-right CCW, 2 rear-left CCW,
3 front-left CW, 4 rear-right CW). Controller state (12, ``STATE_NAMES``, seed 0 Eq. 14
without position and yaw) replaces Omega by the virtual actuators delta = Mix Omega.

Input: the virtual actuator command u = Mix u_ESC (seed 0 Eq. 8); per motor
u_ESC = clip(Mix^-1 u, 0, 1) and dOmega/dt = -a_Omega Omega + b_Omega u_ESC, with the rotor
speed held inside [omega_min, omega_max].

Aerodynamic model (seed 0 Eq. 6, "Model 3" of its Ref. [11]); the lumped parameters
K_(.) are named entries of ``QuadrotorParams.K`` (key -> seed symbol -> regressor):

==============  =====================  ==========================================
key             seed 0 symbol          regressor
==============  =====================  ==========================================
x_mu0           K_{x,mu0}              u                         (F_x, Eq. 6a)
x_muw           K_{x,muw}              u w
x_muh           K_{x,muk} (H-force)    u delta_t
y_mu0, y_muw,   K_{y,...}              v, v w, v delta_t          (F_y, Eq. 6b)
y_muh
z_T0            K_{z,T0}               delta_t^2                  (F_z, Eq. 6c)
z_mu0           K_{z,mu0}              delta_t
z_mu            K_{z,mu}               u^2 + v^2
z_muw           K_{z,muw}              4 w delta_t - p delta_a - q delta_e
l_T0, l_mu0     K_{l,T0}, K_{l,mu0}    delta_a^2, delta_a         (M_x, Eq. 6d)
l_muw           K_{l,muw}              w delta_a - 2 l^2 p delta_t - l^2 q delta_r / 2
l_muh           K_{l,muh}              v delta_t
l_muh_mu0       K_{l,muh,mu0}          v
l_muh_muw       K_{l,muh,muw}          v w
l_dr            K_{l,dr}               u delta_r
m_T0 ... m_dr   K_{m,...}              mirror of the l_ terms     (M_y, Eq. 6e)
                                       (e, q, u instead of a, p, v; cross term
                                       -l^2 p delta_r / 2, m_dr: v delta_r)
n_Q0, n_mu0     K_{n,Q0}, K_{n,mu0}    delta_r^2, delta_r         (M_z, Eq. 6f)
n_muw           K_{n,muw}              w delta_r + p delta_e + q delta_a
n_muw2          K_{n,muw^2}            p q
n_muh           K_{n,muh}              u delta_a + v delta_e
n_muh_muw       K_{n,muh,muw}          u p + v q
==============  =====================  ==========================================

plus J_z d(delta_r)/dt in M_z with J_z = ``j_rotor`` (rotor spin-up reaction torque). The
seed prints this term as "J_z p delta_r-dot"; that product is not a moment (N m rad/s), so
it is read as J_z delta_r-dot, which is the physical reaction torque of the rotors.

The squared virtual actuators are delta^2 = Mix Omega^2 (Eq. 7, not the square of delta).
The first row of Mix is 1/4 [1 1 1 1] (the seed's pdf shows a fifth entry, a typo).
"""

from __future__ import annotations

import ast
import functools
import logging
import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np
from scipy import optimize

from lpv_sysid.errors import ConfigError, SolverError

log = logging.getLogger(__name__)

STATE_NAMES = ("phi", "theta", "u", "v", "w", "p", "q", "r", "dt", "da", "de", "dr")
STATE_UNITS = (
    "rad",
    "rad",
    "m/s",
    "m/s",
    "m/s",
    "rad/s",
    "rad/s",
    "rad/s",
    "rad/s",
    "m*rad/s",
    "m*rad/s",
    "rad/s",
)
INPUT_NAMES = ("ut", "ua", "ue", "ur")
INPUT_UNITS = ("1", "m", "m", "1")
FULL_STATE_NAMES = (
    "x",
    "y",
    "z",
    "phi",
    "theta",
    "psi",
    "u",
    "v",
    "w",
    "p",
    "q",
    "r",
    "Omega1",
    "Omega2",
    "Omega3",
    "Omega4",
)
SCHEDULING_NAMES = ("u_d", "v_d", "w_d")
EXCITATION_NAMES = ("ue_t", "ue_a", "ue_e", "ue_r")

K_NAMES = (
    "x_mu0",
    "x_muw",
    "x_muh",
    "y_mu0",
    "y_muw",
    "y_muh",
    "z_T0",
    "z_mu0",
    "z_mu",
    "z_muw",
    "l_T0",
    "l_mu0",
    "l_muw",
    "l_muh",
    "l_muh_mu0",
    "l_muh_muw",
    "l_dr",
    "m_T0",
    "m_mu0",
    "m_muw",
    "m_muh",
    "m_muh_mu0",
    "m_muh_muw",
    "m_dr",
    "n_Q0",
    "n_mu0",
    "n_muw",
    "n_muw2",
    "n_muh",
    "n_muh_muw",
)

# FlameWheel-450-like lumped parameters (SI, Omega in rad/s). Calibrated so that the trims
# at the vertices of the [-5, 5]^3 m/s box resemble seed 0 Table 1; see docs/quadrotor_model.md.
DEFAULT_K = {
    "x_mu0": -0.1323,
    "x_muw": 0.02062,
    "x_muh": -3.359e-4,
    "y_mu0": -0.1589,
    "y_muw": 0.02155,
    "y_muh": -3.62e-4,
    "z_T0": -4.17e-5,
    "z_mu0": 0.0,
    "z_mu": -0.00594,
    "z_muw": -3.22e-4,
    "l_T0": 1.09e-5,
    "l_mu0": 0.0,
    "l_muw": 1.2e-4,
    "l_muh": -7.77e-5,
    "l_muh_mu0": -0.004,
    "l_muh_muw": -0.00259,
    "l_dr": 1.5e-5,
    "m_T0": 1.09e-5,
    "m_mu0": 0.0,
    "m_muw": 1.2e-4,
    "m_muh": 7.09e-5,
    "m_muh_mu0": 0.004,
    "m_muh_muw": 0.00194,
    "m_dr": -1.5e-5,
    "n_Q0": 1.75e-7,
    "n_mu0": 0.0,
    "n_muw": 2.0e-6,
    "n_muw2": -5.0e-4,
    "n_muh": 1.4e-4,
    "n_muh_muw": -2.0e-4,
}

_SQ2 = math.sqrt(2.0) / 2.0
# Index slices of the 12-state controller model.
I_PHI, I_THETA, I_U, I_V, I_W, I_P, I_Q, I_R, I_DT, I_DA, I_DE, I_DR = range(12)


def _as_finite(name: str, value: Any, shape: tuple[int, ...] | None = None) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{name}: not numeric ({exc})") from None
    if shape is not None and arr.shape != shape:
        raise ConfigError(f"{name}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name}: contains NaN or inf")
    return arr


@dataclass(frozen=True)
class QuadrotorParams:
    """Physical parameters of the quadrotor (FlameWheel-450-like defaults).

    ``K`` holds the lumped aerodynamic parameters of seed 0 Eq. (6) keyed by ``K_NAMES``.
    ``hub_height`` (h in seed 0 Fig. 2) enters Eq. (6) only through the lumped K (blade
    flapping moments); it is kept for documentation and for the inertia bookkeeping.
    """

    mass: float = 1.6
    inertia: tuple = ((0.0205, 0.0, 0.0), (0.0, 0.0215, 0.0), (0.0, 0.0, 0.0385))
    arm_length: float = 0.225
    hub_height: float = 0.045
    a_omega: float = 12.31
    b_omega: float = 1.399e4
    j_rotor: float = 2.5e-5
    K: Mapping[str, float] = field(default_factory=lambda: dict(DEFAULT_K))
    omega_min: float = 120.0
    omega_max: float = 1100.0
    g: float = 9.80665

    def __post_init__(self) -> None:
        for name in ("mass", "arm_length", "a_omega", "b_omega", "g", "omega_max"):
            val = getattr(self, name)
            if not (isinstance(val, (int, float)) and math.isfinite(val) and val > 0):
                raise ConfigError(
                    f"quadrotor.{name}: must be a positive finite number, got {val!r}"
                )
        for name in ("hub_height", "j_rotor", "omega_min"):
            val = getattr(self, name)
            if not (isinstance(val, (int, float)) and math.isfinite(val) and val >= 0):
                raise ConfigError(f"quadrotor.{name}: must be a finite number >= 0, got {val!r}")
        if self.omega_min >= self.omega_max:
            raise ConfigError("quadrotor.omega_min: must be below omega_max")
        inertia = _as_finite("quadrotor.inertia", self.inertia, (3, 3))
        if not np.allclose(inertia, inertia.T):
            raise ConfigError("quadrotor.inertia: must be symmetric")
        if np.any(np.linalg.eigvalsh(inertia) <= 0):
            raise ConfigError("quadrotor.inertia: must be positive definite")
        object.__setattr__(self, "inertia", tuple(tuple(float(v) for v in row) for row in inertia))
        missing = [k for k in K_NAMES if k not in self.K]
        unknown = [k for k in self.K if k not in K_NAMES]
        if missing:
            raise ConfigError(f"quadrotor.K: missing parameter(s) {missing}")
        if unknown:
            raise ConfigError(
                f"quadrotor.K: unknown parameter(s) {unknown}; known: {list(K_NAMES)}"
            )
        K = {}
        for k in K_NAMES:
            v = self.K[k]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"quadrotor.K.{k}: must be a finite number, got {v!r}")
            K[k] = float(v)
        object.__setattr__(self, "K", K)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "QuadrotorParams":
        if not isinstance(d, Mapping):
            raise ConfigError(f"quadrotor: expected a mapping, got {type(d).__name__}")
        allowed = {
            "mass",
            "inertia",
            "arm_length",
            "hub_height",
            "a_omega",
            "b_omega",
            "j_rotor",
            "K",
            "omega_min",
            "omega_max",
            "g",
        }
        bad = sorted(set(d) - allowed)
        if bad:
            raise ConfigError(f"quadrotor: unknown key(s) {bad}; allowed: {sorted(allowed)}")
        kw = dict(d)
        if "K" in kw:
            if not isinstance(kw["K"], Mapping):
                raise ConfigError("quadrotor.K: expected a mapping of name -> value")
            merged = dict(DEFAULT_K)
            merged.update(kw["K"])
            unknown = [k for k in kw["K"] if k not in K_NAMES]
            if unknown:
                raise ConfigError(
                    f"quadrotor.K: unknown parameter(s) {unknown}; known: {list(K_NAMES)}"
                )
            kw["K"] = merged
        for key in (
            "mass",
            "arm_length",
            "hub_height",
            "a_omega",
            "b_omega",
            "j_rotor",
            "omega_min",
            "omega_max",
            "g",
        ):
            if key in kw:
                v = kw[key]
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    raise ConfigError(f"quadrotor.{key}: must be a number, got {v!r}")
                kw[key] = float(v)
        return cls(**kw)

    def to_dict(self) -> dict:
        return {
            "mass": self.mass,
            "inertia": [list(r) for r in self.inertia],
            "arm_length": self.arm_length,
            "hub_height": self.hub_height,
            "a_omega": self.a_omega,
            "b_omega": self.b_omega,
            "j_rotor": self.j_rotor,
            "K": dict(self.K),
            "omega_min": self.omega_min,
            "omega_max": self.omega_max,
            "g": self.g,
        }


@dataclass(frozen=True)
class Trim:
    """Equilibrium of seed 0 Sec. III: v = v_d, constant Euler angles, Omega = Omega_0."""

    v_d: np.ndarray  # (3,) commanded body velocity, FRD, m/s
    yaw_rate: float  # psi-dot, rad/s
    x0: np.ndarray  # (12,) STATE_NAMES
    u0: np.ndarray  # (4,) INPUT_NAMES
    full_state: np.ndarray  # (16,) FULL_STATE_NAMES (position 0, psi 0)
    residual: float  # max |xdot| of phi, theta, v, omega, Omega at the solution


def mixer(arm_length: float) -> np.ndarray:
    """Mix of seed 0 Eq. (7) for the PX4 quad-X rotor numbering."""
    s = arm_length * _SQ2
    return np.array(
        [[0.25, 0.25, 0.25, 0.25], [-s, s, s, -s], [s, -s, s, -s], [1.0, 1.0, -1.0, -1.0]]
    )


def reduced_state(x16: np.ndarray, arm_length: float = QuadrotorParams.arm_length) -> np.ndarray:
    """x16 (FULL_STATE_NAMES) -> x12 (STATE_NAMES), delta = Mix Omega (Eq. 7)."""
    x16 = np.asarray(x16, dtype=float)
    if x16.shape[-1] != 16:
        raise ValueError(f"reduced_state: expected 16 states, got shape {x16.shape}")
    delta = x16[..., 12:16] @ mixer(arm_length).T
    return np.concatenate([x16[..., 3:5], x16[..., 6:12], delta], axis=-1)


def full_state(
    x12: np.ndarray, pos_ned=0.0, psi: float = 0.0, arm_length: float = QuadrotorParams.arm_length
) -> np.ndarray:
    """x12 (STATE_NAMES) -> x16 with the given NED position and yaw; Omega = Mix^-1 delta."""
    x12 = np.asarray(x12, dtype=float)
    if x12.shape != (12,):
        raise ValueError(f"full_state: expected 12 states, got shape {x12.shape}")
    out = np.zeros(16)
    out[0:3] = np.broadcast_to(np.asarray(pos_ned, dtype=float), (3,))
    out[3:5] = x12[0:2]
    out[5] = psi
    out[6:12] = x12[2:8]
    out[12:16] = np.linalg.solve(mixer(arm_length), x12[8:12])
    return out


def _skew(a) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


# ---------------------------------------------------------------- hot-path equations
# The equations of the simulation's hot path, written once as source text and compiled per
# model (every parameter a closure constant, every state a plain-float local): the rotor
# model of Eq. (8), the aerodynamic forces and moments of Eq. (6) and the rigid-body
# equations of Eq. (3). From them the model builds ``_fm`` (F, M), ``_rotor_rates``
# (Omega-dot), ``derivatives_list`` (the 16-state derivative) and ``rk4_step`` (one classical
# Runge-Kutta step with the command held, the four derivative evaluations inlined: no
# calls, lists or attribute lookups between the stages). CPython executes the same float
# operations in the same order in all four, so they agree bit for bit.
# Names: body velocity u, v, w; rates p, q, r; rotor speeds O1..O4; command c0..c3.

_SRC_ESC = """
e1 = mi00 * c0 + mi01 * c1 + mi02 * c2 + mi03 * c3
e1 = 0.0 if e1 < 0.0 else (1.0 if e1 > 1.0 else e1)
e2 = mi10 * c0 + mi11 * c1 + mi12 * c2 + mi13 * c3
e2 = 0.0 if e2 < 0.0 else (1.0 if e2 > 1.0 else e2)
e3 = mi20 * c0 + mi21 * c1 + mi22 * c2 + mi23 * c3
e3 = 0.0 if e3 < 0.0 else (1.0 if e3 > 1.0 else e3)
e4 = mi30 * c0 + mi31 * c1 + mi32 * c2 + mi33 * c3
e4 = 0.0 if e4 < 0.0 else (1.0 if e4 > 1.0 else e4)
be1 = b_om * e1
be2 = b_om * e2
be3 = b_om * e3
be4 = b_om * e4
"""
# Eq. (8): u_ESC = clip(Mix^-1 u, 0, 1) (e1..e4 above, be = b_Omega u_ESC: computed once per
# held command); Omega-dot held at 0 beyond the limits
_SRC_ROTOR = """
D1 = -a_om * O1 + be1
if (O1 >= om_hi and D1 > 0.0) or (O1 <= om_lo and D1 < 0.0):
    D1 = 0.0
D2 = -a_om * O2 + be2
if (O2 >= om_hi and D2 > 0.0) or (O2 <= om_lo and D2 < 0.0):
    D2 = 0.0
D3 = -a_om * O3 + be3
if (O3 >= om_hi and D3 > 0.0) or (O3 <= om_lo and D3 < 0.0):
    D3 = 0.0
D4 = -a_om * O4 + be4
if (O4 >= om_hi and D4 > 0.0) or (O4 <= om_lo and D4 < 0.0):
    D4 = 0.0
"""
# Eq. (6) with delta = Mix Omega and delta^2 = Mix Omega^2 (Eq. 7), J_z delta_r-dot in M_z
_SRC_FM = """
dt = 0.25 * (O1 + O2 + O3 + O4)
da = s_arm * (-O1 + O2 + O3 - O4)
de = s_arm * (O1 - O2 + O3 - O4)
dr = O1 + O2 - O3 - O4
S1 = O1 * O1
S2 = O2 * O2
S3 = O3 * O3
S4 = O4 * O4
dt2 = 0.25 * (S1 + S2 + S3 + S4)
da2 = s_arm * (-S1 + S2 + S3 - S4)
de2 = s_arm * (S1 - S2 + S3 - S4)
dr2 = S1 + S2 - S3 - S4
ddr = D1 + D2 - D3 - D4
Fx = u * (x_mu0 + x_muw * w + x_muh * dt)
Fy = v * (y_mu0 + y_muw * w + y_muh * dt)
Fz = (z_T0 * dt2 + z_mu0 * dt + z_mu * (u * u + v * v)
      + z_muw * (4.0 * w * dt - p * da - q * de))
Mx = (l_T0 * da2 + l_mu0 * da + l_muw * (w * da - 2.0 * l2 * p * dt - 0.5 * l2 * q * dr)
      + l_muh * v * dt + l_muh_mu0 * v + l_muh_muw * v * w + l_dr * u * dr)
My = (m_T0 * de2 + m_mu0 * de + m_muw * (w * de - 2.0 * l2 * q * dt - 0.5 * l2 * p * dr)
      + m_muh * u * dt + m_muh_mu0 * u + m_muh_muw * u * w + m_dr * v * dr)
Mz = (n_Q0 * dr2 + n_mu0 * dr + n_muw * (w * dr + p * de + q * da) + n_muw2 * p * q
      + n_muh * (u * da + v * de) + n_muh_muw * (u * p + v * q) + j_rot * ddr)
"""
# Eq. (3): position (3a, ZYX Euler R_IB of Eq. 2), Euler angles (2/3b), body velocity
# (3c: v x omega + g R^T e3 + F / m) and rates (3d: I^-1 (I omega x omega + M)); the rotor
# rows are D1..D4
_SRC_EQ3 = """
sf = sin(phi)
cf = cos(phi)
st = sin(th)
ct = cos(th)
sp = sin(psi)
cp = cos(psi)
sfst = sf * st
cfst = cf * st
d0 = ct * cp * u + (sfst * cp - cf * sp) * v + (cfst * cp + sf * sp) * w
d1 = ct * sp * u + (sfst * sp + cf * cp) * v + (cfst * sp - sf * cp) * w
d2 = -st * u + sf * ct * v + cf * ct * w
tt = st / ct
d3 = p + sf * tt * q + cf * tt * r
d4 = cf * q - sf * r
d5 = (sf * q + cf * r) / ct
d6 = v * r - w * q - g * st + Fx / m
d7 = w * p - u * r + g * sf * ct + Fy / m
d8 = u * q - v * p + g * cf * ct + Fz / m
h0 = I00 * p + I01 * q + I02 * r
h1 = I10 * p + I11 * q + I12 * r
h2 = I20 * p + I21 * q + I22 * r
t0 = h1 * r - h2 * q + Mx
t1 = h2 * p - h0 * r + My
t2 = h0 * q - h1 * p + Mz
d9 = Ii00 * t0 + Ii01 * t1 + Ii02 * t2
d10 = Ii10 * t0 + Ii11 * t1 + Ii12 * t2
d11 = Ii20 * t0 + Ii21 * t1 + Ii22 * t2
d12 = D1
d13 = D2
d14 = D3
d15 = D4
"""
_X16 = ("X", "Y", "Z", "phi", "th", "psi", "u", "v", "w", "p", "q", "r", "O1", "O2", "O3", "O4")


def _indent(src: str, n: int = 4) -> str:
    return "".join(" " * n + line + "\n" for line in src.strip("\n").splitlines())


def _hot_path_source() -> str:
    """Source of the factory that compiles the hot-path functions of one model."""
    fm = (
        "def _fm(u, v, w, p, q, r, O1, O2, O3, O4, D1, D2, D3, D4):\n"
        + _indent(_SRC_FM)
        + "    return (Fx, Fy, Fz), (Mx, My, Mz)\n"
    )
    rates = (
        "def _rotor_rates(O, c):\n    O1, O2, O3, O4 = O\n    c0, c1, c2, c3 = c\n"
        + _indent(_SRC_ESC)
        + _indent(_SRC_ROTOR)
        + "    return [D1, D2, D3, D4]\n"
    )
    deriv = (
        "def derivatives_list(x, c):\n    "
        + ", ".join(_X16)
        + " = x\n    c0, c1, c2, c3 = c\n"
        + _indent(_SRC_ESC)
        + _indent(_SRC_ROTOR)
        + _indent(_SRC_FM)
        + _indent(_SRC_EQ3)
        + "    return ["
        + ", ".join(f"d{i}" for i in range(16))
        + "]\n"
    )
    # rk4_step: the command is held, so Eq. (8)'s u_ESC is computed once; stage k evaluates
    # the derivative at x + a_k h k_(k-1) (positions are not needed by any derivative)
    body = "def rk4_step(x, c, h):\n    " + ", ".join(n + "_0" for n in _X16) + " = x\n"
    body += "    c0, c1, c2, c3 = c\n" + _indent(_SRC_ESC) + "    hh = 0.5 * h\n"
    for k, coef in ((1, None), (2, "hh"), (3, "hh"), (4, "h")):
        for i, n in enumerate(_X16[3:], start=3):
            body += (
                f"    {n} = {n}_0\n"
                if coef is None
                else f"    {n} = {n}_0 + {coef} * k{k - 1}_{i}\n"
            )
        stage = _SRC_ROTOR + _SRC_FM + _SRC_EQ3
        for i in range(16):
            stage = stage.replace(f"d{i} = ", f"k{k}_{i} = ")
        body += _indent(stage)
    body += (
        "    h6 = h / 6.0\n    return ["
        + ", ".join(
            f"{n}_0 + h6 * (k1_{i} + 2.0 * k2_{i} + 2.0 * k3_{i} + k4_{i})"
            for i, n in enumerate(_X16)
        )
        + "]\n"
    )
    consts = (
        list(K_NAMES)
        + ["s_arm", "l2", "j_rot", "a_om", "b_om", "om_lo", "om_hi", "g", "m"]
        + [f"{n}{i}{j}" for n in ("I", "Ii") for i in range(3) for j in range(3)]
        + [f"mi{i}{j}" for i in range(4) for j in range(4)]
    )
    return (
        "def _factory("
        + ", ".join(consts)
        + "):\n    from math import sin, cos\n"
        + _indent(fm)
        + _indent(rates)
        + _indent(deriv)
        + _indent(body)
        + "    return _fm, _rotor_rates, derivatives_list, rk4_step\n"
    )


_HOT_PATH_SOURCE = _hot_path_source()


class _Specialise(ast.NodeTransformer):
    """The hot path of one model: every parameter name becomes its value (a literal instead
    of a closure cell), then the arithmetic that the values settle is done once here:
    literal-only operations are folded (``2.0 * l2`` in ``2.0 * l2 * p * dt``: the same IEEE
    operation the interpreter would repeat every stage, so the same bits), products with a
    literal 0.0 are dropped from sums (off-diagonal inertia, zero aerodynamic coefficients:
    ``x + 0.0 * y`` is ``x`` for finite y) and products with 1.0 are bypassed. The default
    model loses ~24 % of its float operations this way; the order of every operation that
    remains is unchanged, so results agree bit for bit with the unspecialised source (up to
    the sign of a zero)."""

    def __init__(self, consts: Mapping[str, float]) -> None:
        self.consts = consts

    def visit_Name(self, node: ast.Name) -> ast.AST:
        if isinstance(node.ctx, ast.Load) and node.id in self.consts:
            return ast.copy_location(ast.Constant(float(self.consts[node.id])), node)
        return node

    def visit_UnaryOp(self, node: ast.UnaryOp) -> ast.AST:
        self.generic_visit(node)
        v = _num(node.operand)
        if isinstance(node.op, ast.USub) and v is not None:
            return ast.copy_location(ast.Constant(-v), node)
        return node

    def visit_BinOp(self, node: ast.BinOp) -> ast.AST:
        self.generic_visit(node)
        a, b, op = node.left, node.right, node.op
        va, vb = _num(a), _num(b)
        if va is not None and vb is not None:
            if isinstance(op, ast.Add):
                return ast.copy_location(ast.Constant(va + vb), node)
            if isinstance(op, ast.Sub):
                return ast.copy_location(ast.Constant(va - vb), node)
            if isinstance(op, ast.Mult):
                return ast.copy_location(ast.Constant(va * vb), node)
        if isinstance(op, ast.Mult):
            if va == 0.0 or vb == 0.0:
                return ast.copy_location(ast.Constant(0.0), node)
            if va == 1.0:
                return b
            if vb == 1.0:
                return a
        if isinstance(op, (ast.Add, ast.Sub)) and vb == 0.0:
            return a
        if isinstance(op, ast.Add) and va == 0.0:
            return b
        if isinstance(op, ast.Sub) and va == 0.0:
            return ast.copy_location(ast.UnaryOp(ast.USub(), b), node)
        return node


def _num(node: ast.AST) -> float | None:
    """The value of a float literal node, else None."""
    if isinstance(node, ast.Constant) and type(node.value) is float:
        return node.value
    return None


@functools.lru_cache(maxsize=64)
def _hot_path_code(consts: tuple) -> Any:
    """The hot-path factory compiled for one model's parameters ``consts`` (sorted items)."""
    tree = _Specialise(dict(consts)).visit(ast.parse(_HOT_PATH_SOURCE))
    return compile(
        ast.fix_missing_locations(tree), "<lpv_sysid.models.quadrotor hot path>", "exec"
    )


class Quadrotor:
    """Seed 0 Eqs. (3), (6)-(8) with analytic linearisation (Eqs. 10-16).

    Hot path (plain floats, compiled per model from the equation sources above):
    ``derivatives_list(x16, u) -> list`` and ``rk4_step(x16, u, h) -> list`` (one classical
    RK4 step with ``u`` held), used by the simulators."""

    def __init__(self, params: QuadrotorParams | None = None) -> None:
        self.params = params if params is not None else QuadrotorParams()
        p = self.params
        self.mix = mixer(p.arm_length)
        self.mix_inv = np.linalg.inv(self.mix)
        self.inertia = np.array(p.inertia, dtype=float)
        self.inertia_inv = np.linalg.inv(self.inertia)
        # Plain-float hot path (numpy's per-call overhead dominates for 3- and 4-vectors):
        # the functions compiled from the equation sources above, parameters bound.
        ell = p.arm_length
        consts = dict(zip(K_NAMES, (p.K[k] for k in K_NAMES)))
        consts.update(
            s_arm=ell * _SQ2,
            l2=ell * ell,
            j_rot=p.j_rotor,
            a_om=p.a_omega,
            b_om=p.b_omega,
            om_lo=p.omega_min,
            om_hi=p.omega_max,
            g=p.g,
            m=p.mass,
        )
        for i in range(3):
            for j in range(3):
                consts[f"I{i}{j}"] = p.inertia[i][j]
                consts[f"Ii{i}{j}"] = float(self.inertia_inv[i][j])
        for i in range(4):
            for j in range(4):
                consts[f"mi{i}{j}"] = float(self.mix_inv[i][j])
        #: the parameter values the hot path is specialised on (name -> value)
        self.hot_path_constants = {k: float(v) for k, v in consts.items()}
        ns: dict = {}
        code = _hot_path_code(tuple(sorted(self.hot_path_constants.items())))
        exec(code, ns)  # noqa: S102 - compiled from this module's own source text
        self._fm, self._rotor_rates, self.derivatives_list, self.rk4_step = ns["_factory"](
            **consts
        )

    def __reduce__(self):
        return (Quadrotor, (self.params,))

    # ------------------------------------------------------------------ Eq. (6)
    def forces_moments(self, v, omega, Omega, Omega_dot=(0.0, 0.0, 0.0, 0.0)):
        """Applied force F and moment M in F_B (seed 0 Eq. 6) -> (F(3), M(3))."""
        F, M = self._fm(
            *[float(a) for a in v],
            *[float(a) for a in omega],
            *[float(a) for a in Omega],
            *[float(a) for a in Omega_dot],
        )
        return np.array(F), np.array(M)

    # ------------------------------------------------------------------ Eq. (8)
    def u_esc(self, u) -> np.ndarray:
        """Per-motor ESC command u_ESC = clip(Mix^-1 u, 0, 1) (seed 0 Eq. 8)."""
        return np.clip(self.mix_inv @ np.asarray(u, dtype=float), 0.0, 1.0)

    # ------------------------------------------------------------------ Eq. (3)
    # derivatives_list(x, u) -> list: the 16-state derivative on plain sequences (hot path)
    # rk4_step(x, u, h) -> list: one RK4 step of length h with u held (hot path)

    def derivatives(self, x16, u) -> np.ndarray:
        """Time derivative of the full 16-state model (seed 0 Eqs. 3, 6, 7, 8)."""
        x16 = np.asarray(x16, dtype=float)
        u = np.asarray(u, dtype=float)
        if x16.shape != (16,) or u.shape != (4,):
            raise ValueError(
                f"derivatives: expected x (16,) and u (4,), got {x16.shape}, {u.shape}"
            )
        return np.array(self.derivatives_list(x16.tolist(), u.tolist()))

    def derivatives12(self, x12, u) -> np.ndarray:
        """Time derivative of the 12-state controller model (delta = Mix Omega)."""
        x16 = full_state(x12, arm_length=self.params.arm_length)
        d16 = self.derivatives(x16, u)
        return np.concatenate([d16[3:5], d16[6:12], self.mix @ d16[12:16]])

    def specific_force(self, x16, u) -> np.ndarray:
        """Accelerometer specific force F/m in F_B (what an ideal IMU at the CG measures)."""
        x16 = np.asarray(x16, dtype=float)
        Od = self._rotor_rates(x16[12:16].tolist(), np.asarray(u, dtype=float).tolist())
        F, _ = self._fm(*x16[6:12].tolist(), *x16[12:16].tolist(), *Od)
        return np.array(F) / self.params.mass

    # ------------------------------------------------------------------ trim
    def trim(self, v_body, yaw_rate: float = 0.0) -> Trim:
        """Equilibrium for body velocity v_d and yaw rate psi-dot (seed 0 Sec. III).

        Solves v-dot = 0, omega-dot = 0 for (phi_0, theta_0, Omega_0) with
        ``scipy.optimize.least_squares`` inside the rotor-speed limits; Omega-dot = 0 fixes
        u_ESC,0 = a Omega_0 / b and u_0 = Mix u_ESC,0. Raises SolverError when no trim exists.
        """
        v_d = _as_finite("trim.v_body", v_body, (3,))
        if not math.isfinite(yaw_rate):
            raise SolverError("trim: yaw_rate is not finite")
        p = self.params
        om_h = math.sqrt(p.mass * p.g / max(-p.K["z_T0"], 1e-12))
        x0g = np.array([0.0, 0.0, om_h, om_h, om_h, om_h])
        lo = np.array([-1.2, -1.2] + [p.omega_min] * 4)
        hi = np.array([1.2, 1.2] + [p.omega_max] * 4)
        x0g[2:] = np.clip(x0g[2:], p.omega_min + 1.0, p.omega_max - 1.0)

        def body_rates(phi, th):
            # Eq. (2) inverted for Euler rates (0, 0, psi-dot)
            return (
                -math.sin(th) * yaw_rate,
                math.sin(phi) * math.cos(th) * yaw_rate,
                math.cos(phi) * math.cos(th) * yaw_rate,
            )

        def resid(z):
            w = body_rates(z[0], z[1])
            x = [0.0, 0.0, 0.0, z[0], z[1], 0.0, *v_d.tolist(), *w, *z[2:].tolist()]
            xd = self.derivatives_list(x, (self.mix @ (p.a_omega * z[2:] / p.b_omega)).tolist())
            return np.array(xd[6:12]) * np.array([1, 1, 1, 50, 50, 50])

        try:
            sol = optimize.least_squares(
                resid,
                x0g,
                bounds=(lo, hi),
                x_scale=np.r_[0.1, 0.1, [100.0] * 4],
                xtol=1e-14,
                ftol=1e-14,
                gtol=1e-14,
                max_nfev=2000,
            )
        except (ValueError, np.linalg.LinAlgError) as exc:
            raise SolverError(f"trim v_d={v_d.tolist()}: solver failed ({exc})") from None
        res = float(np.max(np.abs(resid(sol.x))))
        if not np.isfinite(res) or res > 1e-6:
            raise SolverError(
                f"trim v_d={v_d.tolist()} yaw_rate={yaw_rate}: no equilibrium inside the rotor "
                f"limits [{p.omega_min}, {p.omega_max}] rad/s (residual {res:.3g}, "
                f"Omega={np.round(sol.x[2:], 1).tolist()})"
            )
        phi, th = float(sol.x[0]), float(sol.x[1])
        Om = sol.x[2:].copy()
        u_esc = p.a_omega * Om / p.b_omega
        if (
            np.any(u_esc > 1.0)
            or np.any(Om >= p.omega_max - 1e-6)
            or np.any(Om <= p.omega_min + 1e-6)
        ):
            raise SolverError(
                f"trim v_d={v_d.tolist()}: equilibrium needs rotor speeds "
                f"{np.round(Om, 1).tolist()} at the limits [{p.omega_min}, {p.omega_max}] rad/s"
            )
        w = body_rates(phi, th)
        x16 = np.array([0, 0, 0, phi, th, 0.0, *v_d, *w, *Om])
        x12 = reduced_state(x16, p.arm_length)
        u0 = self.mix @ u_esc
        resid_max = float(
            np.max(np.abs(self.derivatives(x16, u0)[[3, 4, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15]]))
        )
        return Trim(
            v_d=v_d.copy(),
            yaw_rate=float(yaw_rate),
            x0=x12,
            u0=u0,
            full_state=x16,
            residual=resid_max,
        )

    # ------------------------------------------------------------------ Eqs. (10)-(16)
    def _aero_jacobians(self, K: Mapping[str, float], j_rotor: float, x12):
        """Partial derivatives of F and M (Eq. 6) w.r.t. nu = (v, omega) and delta.

        Returns dF/dnu (3x6), dF/ddelta (3x4), dM/dnu (3x6), dM/ddelta (3x4), dMz/du_r.
        delta^2 = Mix Omega^2 = Mix (Mix^-1 delta)^2, so d delta^2 / d delta
        = Mix diag(2 Omega) Mix^-1 (Eq. 7). The rotor reaction torque J_z delta_r-dot with
        delta-dot = -a delta + b u (unsaturated Eq. 8) adds -a J_z to dMz/d delta_r and
        b J_z to dMz/du_r.
        """
        ell = self.params.arm_length
        l2 = ell * ell
        a, b = self.params.a_omega, self.params.b_omega
        u, v, w, p, q, r = (float(t) for t in x12[2:8])
        dt, da, de, dr = (float(t) for t in x12[8:12])
        Om = self.mix_inv @ np.asarray(x12[8:12], dtype=float)
        D2 = self.mix @ np.diag(2.0 * Om) @ self.mix_inv  # d(delta^2)/d(delta)
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

    def linearize(self, trim_or_x, u0=None):
        """Analytic Jacobians A (12x12), B (12x4) of the 12-state model (seed 0 Eqs. 10-16).

        Accepts a ``Trim`` or a 12-state operating point ``x`` (then ``u0`` is unused: the
        Jacobians assume unsaturated motors, delta-dot = -a_Omega delta + b_Omega u).
        """
        x = np.asarray(trim_or_x.x0 if isinstance(trim_or_x, Trim) else trim_or_x, dtype=float)
        if x.shape != (12,):
            raise ValueError(f"linearize: expected a Trim or a 12-state, got shape {x.shape}")
        p = self.params
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
        dF_nu, dF_d, dM_nu, dM_d, dMz_dur = self._aero_jacobians(p.K, p.j_rotor, x)
        A[2:5, 2:8] += dF_nu / m
        A[2:5, 8:12] = dF_d / m
        # Eq. (3d): d/d omega of I^-1 (I omega x omega) = I^-1 ([I omega x] - [omega x] I)
        J, Ii = self.inertia, self.inertia_inv
        A[5:8, 5:8] = Ii @ (_skew(J @ om) - _skew(om) @ J)
        A[5:8, 2:8] += Ii @ dM_nu
        A[5:8, 8:12] = Ii @ dM_d
        B[5:8, 3] = Ii[:, 2] * dMz_dur
        # Eq. (15): actuator rows, d(delta)/dt = -a_Omega delta + b_Omega u
        A[8:12, 8:12] = -p.a_omega * np.eye(4)
        B[8:12, :] = p.b_omega * np.eye(4)
        return A, B

    def unknown_masks(self):
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
        dF_nu, dF_d, dM_nu, dM_d, dMz = self._aero_jacobians(Kg, 0.7, xg)
        maskA = np.zeros((12, 12), dtype=bool)
        maskB = np.zeros((12, 4), dtype=bool)
        maskA[2:5, 2:8] = dF_nu != 0
        maskA[2:5, 8:12] = dF_d != 0
        Ii = np.abs(self.inertia_inv) > 0
        maskA[5:8, 2:8] = (Ii.astype(int) @ (dM_nu != 0).astype(int)) > 0
        maskA[5:8, 8:12] = (Ii.astype(int) @ (dM_d != 0).astype(int)) > 0
        maskB[5:8, 3] = Ii[:, 2] & (dMz != 0)
        return maskA, maskB
