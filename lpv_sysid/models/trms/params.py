"""TRMS (seed 2) variable names, Table 7 operating ranges and the constants of Tables 5-6 with
the derived ones of Eqs. (7)-(14), (21)-(27); conventions and the derivation of ``theta_v^0``:
:mod:`lpv_sysid.models.trms`."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Mapping

from lpv_sysid.configuration import fields as cf

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


def _c(default: float, doc: str, positive: bool = True) -> float:
    """A TRMS constant (seed 2 Tables 5-6): finite, > 0 (``positive``) or >= 0."""
    return cf.number(default, doc, lo=0.0, lo_open=positive)


@dataclass(frozen=True)
class TrmsParams:
    """TRMS constants, seed 2 Tables 5 (manufacturer) and 6 (identified), checked on every
    construction. SI units, rotor speeds in V. Lengths, masses, the motor constants and the
    rotor inertias are > 0; the gains and friction coefficients >= 0."""

    # Table 5 (known)
    k_g: float = _c(0.2, "gyroscopic momentum gain", positive=False)
    l_t: float = _c(0.282, "length of the tail part of the beam [m]")
    l_m: float = _c(0.246, "length of the main part of the beam [m]")
    l_b: float = _c(0.290, "length of the counter-weight beam [m]")
    l_cb: float = _c(0.276, "distance of the counter-weight from the joint [m]")
    r_ts: float = _c(0.1, "radius of the tail shield [m]")
    r_ms: float = _c(0.155, "radius of the main shield [m]")
    m_cb: float = _c(0.068, "mass of the counter-weight [kg]")
    m_b: float = _c(0.022, "mass of the counter-weight beam [kg]")
    m_m: float = _c(0.014, "mass of the main part of the beam [kg]")
    m_mr: float = _c(0.236, "mass of the main motor and rotor [kg]")
    m_ms: float = _c(0.219, "mass of the main shield [kg]")
    m_t: float = _c(0.015, "mass of the tail part of the beam [kg]")
    m_tr: float = _c(0.221, "mass of the tail motor and rotor [kg]")
    m_ts: float = _c(0.119, "mass of the tail shield [kg]")
    k_a: float = _c(0.0202, "motor torque constant")
    R_a: float = _c(8.0, "armature resistance [Ohm]")
    k_1: float = _c(6.5, "tail motor input gain", positive=False)
    k_2: float = _c(8.5, "main motor input gain", positive=False)
    # Table 6 (identified)
    B_tr: float = _c(0.0086, "tail rotor friction", positive=False)
    B_mr: float = _c(0.0026, "main rotor friction", positive=False)
    k_thp: float = _c(0.0027, "tail rotor drag, omega_h > 0", positive=False)
    k_thn: float = _c(0.0028, "tail rotor drag, omega_h < 0", positive=False)
    J_tr: float = _c(0.0059, "tail rotor moment of inertia")
    J_mr: float = _c(0.0254, "main rotor moment of inertia")
    k_t: float = _c(0.0, "tail rotor reaction on the pitch", positive=False)
    k_m: float = _c(0.0017, "main rotor reaction on the yaw", positive=False)
    k_tvp: float = _c(0.0168, "main rotor drag, omega_v > 0", positive=False)
    k_tvn: float = _c(0.0155, "main rotor drag, omega_v < 0", positive=False)
    k_oh: float = _c(0.0185, "yaw friction", positive=False)
    k_ov: float = _c(0.1026, "pitch friction", positive=False)
    k_fhp: float = _c(0.0566, "tail thrust, omega_h > 0", positive=False)
    k_fhn: float = _c(0.0660, "tail thrust, omega_h < 0", positive=False)
    k_fvp: float = _c(0.3819, "main thrust, omega_v > 0", positive=False)
    k_fvn: float = _c(0.2197, "main thrust, omega_v < 0", positive=False)
    k_chp: float = _c(0.0158, "cable torque, theta_h > 0", positive=False)
    k_chn: float = _c(0.0111, "cable torque, theta_h < 0", positive=False)
    k_cvp: float = _c(0.0623, "cable torque (pitch), positive branch", positive=False)
    k_cvn: float = _c(0.0563, "cable torque (pitch), negative branch", positive=False)
    g: float = _c(9.81, "gravity [m/s^2]")

    def __post_init__(self) -> None:
        cf.normalize_fields(self, "trms")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "trms") -> "TrmsParams":
        return cls(**cf.parse_fields(cls, d, where))

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
