"""Sampled reference v_d and excitation u_e of the LPV closed loop, with first-order hold.

Signals are first-order hold (piecewise linear between samples, as ``scipy.signal.lsim``):
``v_d(t)`` and ``u_e(t)`` are linearly interpolated and ``dv_d/dt`` is the slope of the
current segment, so Eq. (34) is exact for the interpolated reference.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from lpv_sysid.errors import ConfigError


@dataclass(frozen=True)
class ReferenceSignals:
    """Sampled reference v_d (N, 3) and normalised excitation u_e (N, n_e) on grid t (N,).

    First-order hold between samples (see module docstring).
    """

    t: np.ndarray
    v_d: np.ndarray
    u_e: np.ndarray

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        v_d = np.atleast_2d(np.asarray(self.v_d, dtype=float))
        u_e = np.atleast_2d(np.asarray(self.u_e, dtype=float))
        if t.ndim != 1 or t.size < 2:
            raise ConfigError(
                f"signals: 't' must be a 1-D grid with >= 2 samples, got shape {t.shape}"
            )
        if not np.all(np.diff(t) > 0):
            raise ConfigError("signals: 't' must be strictly increasing")
        for name, arr in (("v_d", v_d), ("u_e", u_e)):
            if arr.shape[0] != t.size:
                raise ConfigError(
                    f"signals: '{name}' has {arr.shape[0]} samples, 't' has {t.size}"
                )
            if not np.all(np.isfinite(arr)):
                raise ConfigError(f"signals: '{name}' contains NaN or inf")
        if v_d.shape[1] != 3:
            raise ConfigError(
                f"signals: 'v_d' must have 3 columns (u_d, v_d, w_d), got {v_d.shape[1]}"
            )
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "v_d", v_d)
        object.__setattr__(self, "u_e", u_e)

    @property
    def dt(self) -> float:
        return float(np.min(np.diff(self.t)))

    def segment(self, t: float) -> int:
        """Index k of the FOH segment [t_k, t_k+1] containing t (clamped to the grid)."""
        k = int(np.searchsorted(self.t, t, side="right")) - 1
        return min(max(k, 0), self.t.size - 2)

    def at(
        self, t: float, segment: Optional[int] = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(v_d(t), dv_d/dt(t), u_e(t)) with first-order hold.

        ``segment`` forces the FOH segment (a fixed-step integrator on the grid passes it so
        that the slope dv_d/dt at a segment end is the one of the current interval).
        """
        k = self.segment(t) if segment is None else segment
        t0, t1 = self.t[k], self.t[k + 1]
        s = (t - t0) / (t1 - t0)
        s = min(max(s, 0.0), 1.0)
        vd = (1.0 - s) * self.v_d[k] + s * self.v_d[k + 1]
        vd_dot = (self.v_d[k + 1] - self.v_d[k]) / (t1 - t0)
        ue = (1.0 - s) * self.u_e[k] + s * self.u_e[k + 1]
        return vd, vd_dot, ue
