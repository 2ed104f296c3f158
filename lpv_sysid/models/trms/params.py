"""TRMS (seed 2) variable names, Table 7 operating ranges and the constants of Tables 5-6 with
the derived ones of Eqs. (7)-(14), (21)-(27); conventions and the derivation of ``theta_v^0``:
:mod:`lpv_sysid.models.trms`."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any, Mapping

from lpv_sysid.configuration.fields import check_keys, is_finite_number
from lpv_sysid.errors import ConfigError

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
