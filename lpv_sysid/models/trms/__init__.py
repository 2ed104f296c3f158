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

Parts:

- :mod:`~lpv_sysid.models.trms.params`: names, Table 7 ranges, ``TrmsParams`` (Tables 5-6);
- :mod:`~lpv_sysid.models.trms.model`: ``Trms`` (Eqs. 1-6, 41-58, Sec. 5.1 equilibria);
- :mod:`~lpv_sysid.models.trms.polytope`: ``p_box``, ``psi_bounds``, ``euler_discrete``,
  ``TrmsPolytope``, ``bounding_box_polytope`` (Secs. 3.4-3.5).
"""

from __future__ import annotations

from lpv_sysid.models.trms.model import Trms
from lpv_sysid.models.trms.params import (
    P_NAMES,
    PSI_NAMES,
    REDUCED_PSI,
    TABLE7_RANGES,
    TS_PAPER,
    TrmsParams,
)
from lpv_sysid.models.trms.polytope import (
    TrmsPolytope,
    bounding_box_polytope,
    euler_discrete,
    p_box,
    psi_bounds,
)

__all__ = [
    "PSI_NAMES",
    "P_NAMES",
    "REDUCED_PSI",
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
