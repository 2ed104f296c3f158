"""The derivative filter of the reference that feeds the feedforward of the runtime law
(:mod:`lpv_sysid.control.law.controller`, seed 2 Sec. 5.1) when the caller does not pass
``a = dv_d/dt`` (and ``j = d2v_d/dt2``) itself.

``a`` is the derivative of the reference low-passed with time constant ``ff_filter_tau``
(``a = d/dt [v_d / (tau s + 1)]``, discretised exactly for a held input:
``y_k = y_k-1 + (1 - exp(-dt/tau)) (v_d,k - y_k-1)``, ``a_k = (y_k - y_k-1) / dt``, which gives
the exact slope of a ramp after the transient). Trade-off: the filter delays a by ~tau (phase
lag 2 pi f tau at frequency f: 0.2 s costs 36 deg at 0.5 Hz), a small tau passes the staircase
of a reference stream that is slower than the control rate and its noise (gain 1/tau at high
frequency). 0.2 s suits a 50 Hz reference with content up to ~0.5 Hz. The jerk ``j`` (for
``F_jerk``, synthesis/feedforward.py) is a second stage with its own time constant
``ff_jerk_tau`` applied to the filtered a. Measured on the phase-2 reference (band 0.01-0.2 Hz)
held at 50 Hz and sampled at 250 Hz: a has 28 / 13 / 12 % rms error for tau = 0.02 / 0.05 /
0.1 s; a jerk stage of 0.05 s is useless (error 2x the signal: it differentiates the
staircase), 0.1 s gives 60 %, hence the separate, longer ff_jerk_tau.

The filter runs on plain floats (3-vectors: numpy's per-call overhead costs more than the
arithmetic) and separates computing a step (:meth:`ReferenceRateFilter.rates`) from committing
it (:meth:`ReferenceRateFilter.commit`), so the law commits only once every input passed.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np


class ReferenceRateFilter:
    """Filtered ``(a, j)`` of a ``n``-axis reference (module docstring); ``tau`` and ``tau_j``
    in s (0: no filtering, the plain difference quotient)."""

    def __init__(self, n: int, tau: float, tau_j: float) -> None:
        self.n = n
        self.tau = float(tau)
        self.tau_j = float(tau_j)
        self.reset()

    def reset(self) -> None:
        self.vf: Optional[list] = None  # low-passed v_d
        self.alp: Optional[list] = None  # low-passed a (second stage, jerk)
        self.af: list = [0.0] * self.n  # a of the last committed step
        self.jf: list = [0.0] * self.n  # j of the last committed step
        self._k_dt = math.nan  # step of the cached filter gains k1, k2
        self._k1 = self._k2 = 0.0

    @property
    def vd_filt(self) -> Optional[np.ndarray]:
        """Low-passed v_d (None before the first step)."""
        return None if self.vf is None else np.array(self.vf)

    @property
    def a_lp(self) -> Optional[np.ndarray]:
        """Low-passed a (the jerk stage's state; None before the first step)."""
        return None if self.alp is None else np.array(self.alp)

    @property
    def a_filt(self) -> np.ndarray:
        """Filtered reference rate a = dv_d/dt of the last step."""
        return np.array(self.af)

    @property
    def j_filt(self) -> np.ndarray:
        """Filtered reference jerk j of the last step."""
        return np.array(self.jf)

    def rates(self, t: float, t_prev: Optional[float], vd: list) -> tuple:
        """The filter's step from ``t_prev`` (None: the first step) to ``t`` on the reference
        ``vd`` (floats), without committing it: ``(a, j, state)``, state for :meth:`commit`
        (None: unchanged)."""
        vf, alp = self.vf, self.alp
        if vf is None or alp is None or t_prev is None:
            zero = [0.0] * self.n
            return zero, zero, (list(vd), zero, zero, zero)
        dt = t - t_prev
        if dt <= 0.0:
            return self.af, self.jf, None
        if dt != self._k_dt:  # the gains of a constant period are computed once
            self._k_dt = dt
            self._k1 = 1.0 if self.tau == 0.0 else -math.expm1(-dt / self.tau)
            self._k2 = 1.0 if self.tau_j == 0.0 else -math.expm1(-dt / self.tau_j)
        k, k2 = self._k1, self._k2
        if self.n == 3:  # unrolled: the quadrotor's (u, v, w)
            v0, v1, v2 = vd
            f0, f1, f2 = vf
            l0, l1, l2 = alp
            y0, y1, y2 = f0 + k * (v0 - f0), f1 + k * (v1 - f1), f2 + k * (v2 - f2)
            a0, a1, a2 = (y0 - f0) / dt, (y1 - f1) / dt, (y2 - f2) / dt
            m0, m1, m2 = l0 + k2 * (a0 - l0), l1 + k2 * (a1 - l1), l2 + k2 * (a2 - l2)
            a3 = [a0, a1, a2]
            j3 = [(m0 - l0) / dt, (m1 - l1) / dt, (m2 - l2) / dt]
            return a3, j3, ([y0, y1, y2], [m0, m1, m2], a3, j3)
        a_new, j_new, vf_new, alp_new = [], [], [], []
        for vdk, vfk, alk in zip(vd, vf, alp):
            y = vfk + k * (vdk - vfk)
            ak = (y - vfk) / dt
            y2 = alk + k2 * (ak - alk)
            a_new.append(ak)
            j_new.append((y2 - alk) / dt)
            vf_new.append(y)
            alp_new.append(y2)
        return a_new, j_new, (vf_new, alp_new, a_new, j_new)

    def commit(self, state: Optional[tuple]) -> None:
        """Adopt a step of :meth:`rates` (None: keep the state)."""
        if state is not None:
            self.vf, self.alp, self.af, self.jf = state
