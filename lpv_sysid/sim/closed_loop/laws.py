"""Control laws of the LPV closed loop: the static LPV state feedback of seed 0 Eqs. (17),
(31) and its reference-feedforward variant (seed 2 Sec. 5.1); why the feedforward law
pairs with ``moving_equilibrium=False``: :mod:`lpv_sysid.sim.closed_loop`.
"""

from __future__ import annotations

from typing import Callable, Optional, Sequence

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.sim.closed_loop.schedule import LastPointCache, ScheduledModel, fast_weights

# A control law u = law(t, x, v_d, ue_scaled) returning the total virtual command (Eq. 17).
ControlLaw = Callable[[float, np.ndarray, np.ndarray, np.ndarray], np.ndarray]


def linear_lpv_law(model: ScheduledModel, R: np.ndarray) -> ControlLaw:
    """Unsaturated law of Eqs. (17), (31): u = u0(v_d) + K(v_d)(x - x0(v_d)) + R (kappa u_e).

    ``ue_scaled`` passed to the returned function is already ``kappa u_e``.
    """
    R = np.asarray(R, dtype=float)

    def law(t: float, x: np.ndarray, v_d: np.ndarray, ue_scaled: np.ndarray) -> np.ndarray:
        return model.u0(v_d) + model.K(v_d) @ (x - model.x0(v_d)) + R @ ue_scaled

    setattr(law, "eq33_parts", ("linear", model, R, None, None))  # lets simulate_eq33 fuse it
    return law


class FeedforwardSchedule:
    """Vertex feedforward matrices F_i (and F_jerk,i) interpolated with the weights of Eq. (21).

    ``F`` (N, n_free + m, p) rows free states then inputs; ``F_jerk`` (N, n_free + m + n_rate, p)
    rows free states, inputs, rate states (synthesis/feedforward.py); ``free_index`` /
    ``rate_index`` positions of those states in x."""

    def __init__(
        self,
        vmin,
        vmax,
        F: np.ndarray,
        free_index: Sequence[int],
        n_x: int,
        F_jerk: Optional[np.ndarray] = None,
        rate_index: Sequence[int] = (),
    ) -> None:
        self.vmin = np.asarray(vmin, dtype=float)
        self.vmax = np.asarray(vmax, dtype=float)
        self.F = np.asarray(F, dtype=float)
        self.Fj = None if F_jerk is None else np.asarray(F_jerk, dtype=float)
        self.free = list(free_index)
        self.rate = list(rate_index)
        self.n_x = n_x
        if self.F.ndim != 3 or self.F.shape[1] <= len(self.free):
            raise ConfigError(f"feedforward: F must be (N, n_free + m, p), got {self.F.shape}")
        self._last: Optional[tuple] = None

    def _at(self, v_d: np.ndarray) -> tuple[np.ndarray, Optional[np.ndarray]]:
        """F(v_d), F_jerk(v_d); the last point is cached (RK stages and the law share v_d)."""
        key = np.asarray(v_d, dtype=float).tobytes()
        if self._last is None or self._last[0] != key:
            alpha = fast_weights(v_d, self.vmin, self.vmax)
            self._last = (
                key,
                np.tensordot(alpha, self.F, axes=1),
                None if self.Fj is None else np.tensordot(alpha, self.Fj, axes=1),
            )
        return self._last[1], self._last[2]

    def offsets(
        self, v_d: np.ndarray, a: np.ndarray, j: Optional[np.ndarray] = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(dx_ff (n_x,), du_ff (m,)) = F(v_d) a (+ F_jerk(v_d) j)."""
        Fv, Fjv = self._at(v_d)
        nf = len(self.free)
        y = Fv @ np.asarray(a, dtype=float)
        dx = np.zeros(self.n_x)
        dx[self.free] = y[:nf]
        du = y[nf:].copy()
        if Fjv is not None and j is not None:
            yj = Fjv @ np.asarray(j, dtype=float)
            m = du.size
            dx[self.free] += yj[:nf]
            du += yj[nf : nf + m]
            dx[self.rate] += yj[nf + m :]
        return dx, du


def feedforward_law(
    model: ScheduledModel, R: np.ndarray, ffs: FeedforwardSchedule, accel: Callable[[float], tuple]
) -> ControlLaw:
    """u = u0 + du_ff + K (x - x0 - dx_ff) + R (kappa u_e), (dx_ff, du_ff) from ``ffs`` at
    ``accel(t) = (a, j)`` (seed 2 Eq. 102 on seed 0 Eq. 31)."""
    R = np.asarray(R, dtype=float)
    if not isinstance(model, LastPointCache):
        model = LastPointCache(model)

    def law(t: float, x: np.ndarray, v_d: np.ndarray, ue_scaled: np.ndarray) -> np.ndarray:
        a, j = accel(t)
        dx, du = ffs.offsets(v_d, a, j)
        return model.u0(v_d) + du + model.K(v_d) @ (x - model.x0(v_d) - dx) + R @ ue_scaled

    setattr(law, "eq33_parts", ("feedforward", model, R, ffs, accel))  # for _FusedEq33
    return law
