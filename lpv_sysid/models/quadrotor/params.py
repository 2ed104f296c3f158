"""Physical parameters of the seed 0 quadrotor (Hopwood & Woolsey) and their validation.

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
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from lpv_sysid.errors import ConfigError

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


def as_finite(name: str, value: Any, shape: tuple[int, ...] | None = None) -> np.ndarray:
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
        inertia = as_finite("quadrotor.inertia", self.inertia, (3, 3))
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
