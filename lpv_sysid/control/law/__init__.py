"""The runtime robust LPV law of seed 0 Eqs. (17), (31) and what conditions its input.

``u = u0(v_d) + K(v_d) (x - x0(v_d)) + R kappa u_e`` with the multilinear weights of Eq. (21)
(:mod:`~lpv_sysid.control.law.weights`) on plain floats, the gain schedule packed once for the
loop (:mod:`~lpv_sysid.control.law.packing`), the law and its bound monitor
(:class:`LpvController`, :mod:`~lpv_sysid.control.law.controller`), its options
(:class:`LpvControllerConfig`, :mod:`~lpv_sysid.control.law.config`), the reference limiter
of the design envelope (:mod:`~lpv_sysid.control.law.reference_limiter`) and the derivative
filter of the reference feedforward (:mod:`~lpv_sysid.control.law.reference_rates`).
"""

from __future__ import annotations

from lpv_sysid.control.law.config import KAPPA_MAX, KAPPA_MIN, LpvControllerConfig, check_kappa
from lpv_sysid.control.law.controller import LpvController
from lpv_sysid.control.law.reference_limiter import ReferenceLimiter

__all__ = [
    "LpvController",
    "KAPPA_MAX",
    "KAPPA_MIN",
    "LpvControllerConfig",
    "check_kappa",
    "ReferenceLimiter",
]
