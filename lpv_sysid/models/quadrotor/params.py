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

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from lpv_sysid.configuration import fields as cf
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


def _positive(default: float, doc: str) -> Any:
    return cf.number(default, doc, lo=0.0, lo_open=True)


@dataclass(frozen=True)
class QuadrotorParams:
    """Physical parameters of the quadrotor (FlameWheel-450-like defaults), checked on every
    construction (``config/quadrotor.yaml`` section ``quadrotor``).

    ``K`` holds the lumped aerodynamic parameters of seed 0 Eq. (6) keyed by ``K_NAMES``.
    ``hub_height`` (h in seed 0 Fig. 2) enters Eq. (6) only through the lumped K (blade
    flapping moments); it is kept for documentation and for the inertia bookkeeping.
    """

    mass: float = _positive(1.6, "m [kg]")
    inertia: tuple = cf.matrix(
        ((0.0205, 0.0, 0.0), (0.0, 0.0215, 0.0), (0.0, 0.0, 0.0385)),
        "J [kg m^2], symmetric positive definite (seed 0 Eq. 3)",
        shape=(3, 3),
    )
    arm_length: float = _positive(0.225, "l [m] (seed 0 Eq. 7)")
    hub_height: float = cf.number(0.045, "h [m] (seed 0 Fig. 2)", lo=0.0)
    a_omega: float = _positive(12.31, "a_Omega [1/s] (seed 0 Eq. 8)")
    b_omega: float = _positive(1.399e4, "b_Omega [rad/s^2 per unit u_ESC] (seed 0 Eq. 8)")
    j_rotor: float = cf.number(2.5e-5, "J_z, rotor reaction inertia [kg m^2]", lo=0.0)
    K: Mapping[str, float] = cf.table(
        DEFAULT_K,
        "lumped aerodynamic parameters of seed 0 Eq. (6), name: value (module docstring); "
        "a file may give some, the others keep their defaults",
        item=cf.FieldSpec(cf.NUMBER),
        choices=K_NAMES,
    )
    omega_min: float = cf.number(120.0, "idle rotor speed [rad/s]", lo=0.0)
    omega_max: float = _positive(1100.0, "largest rotor speed [rad/s]")
    g: float = _positive(9.80665, "gravity [m/s^2]")

    def __post_init__(self) -> None:
        """The declared fields, then: omega_min < omega_max, J symmetric positive definite,
        every K of K_NAMES given."""
        cf.normalize_fields(self, "quadrotor")
        if self.omega_min >= self.omega_max:
            raise cf.error("quadrotor", "omega_min", "must be below omega_max")
        inertia = np.array(self.inertia)
        if not np.allclose(inertia, inertia.T):
            raise cf.error("quadrotor", "inertia", "must be symmetric")
        if np.any(np.linalg.eigvalsh(inertia) <= 0):
            raise cf.error("quadrotor", "inertia", "must be positive definite")
        missing = [k for k in K_NAMES if k not in self.K]
        if missing:
            raise cf.error("quadrotor", "K", f"missing parameter(s) {missing}")
        object.__setattr__(self, "K", {k: self.K[k] for k in K_NAMES})  # K_NAMES order

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "quadrotor") -> "QuadrotorParams":
        """The given keys; a partial ``K`` completes the default K."""
        kw = cf.parse_fields(cls, d, where)
        if "K" in kw:
            kw["K"] = {**DEFAULT_K, **kw["K"]}
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
