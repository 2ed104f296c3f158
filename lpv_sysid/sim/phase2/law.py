"""The onboard LPV law of :mod:`lpv_sysid.control.law.controller` as a phase-2 ``ControlLaw``."""

from __future__ import annotations

from typing import Any, Callable, Optional

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.sim.closed_loop import ReferenceSignals
from lpv_sysid.sim.phase2.inputs import Phase2Problem, reference_acceleration
from lpv_sysid.sim.phase2.outputs import finite_or_none


class RuntimeLaw:
    """The onboard law of :mod:`lpv_sysid.control.law.controller` as a ``ControlLaw``:
    ``u = u0(v_d) + du_ff + K(v_d)(x - x0(v_d) - dx_ff) + R (kappa u_e)`` with actuator saturation
    through the mixer and the bound monitor; the feedforward (when the gains carry F_ff) uses
    ``accel(t)`` (the reference's derivative) or, without it, the law's own filtered derivative
    of v_d (as on the vehicle). ``last_info`` holds the flags of the last step; counters record
    how often the command saturated or v_d was clamped."""

    def __init__(
        self,
        problem: Phase2Problem,
        mix: Optional[np.ndarray] = None,
        config: Any = None,
        accel: Optional[Callable[[float], tuple]] = None,
    ) -> None:
        from lpv_sysid.control.law import LpvController, LpvControllerConfig

        self.ctrl = LpvController(
            problem, config if config is not None else LpvControllerConfig(), mix
        )
        self.accel = accel
        self.last_info: dict = {}
        self.steps = self.saturated = self.clamped = 0

    def __call__(
        self, t: float, x: np.ndarray, v_d: np.ndarray, ue_scaled: np.ndarray
    ) -> np.ndarray:
        a, j = (None, None) if self.accel is None else self.accel(float(t))
        u, info = self.ctrl.step(
            float(t),
            np.asarray(x, dtype=float),
            np.asarray(v_d, dtype=float),
            np.asarray(ue_scaled, dtype=float),
            a,
            j,
        )
        self.last_info = info
        self.steps += 1
        self.saturated += int(info.get("saturated", False))
        self.clamped += int(info.get("clamped", False))
        return u

    def stats(self) -> dict:
        mode = "off" if not self.ctrl.has_ff else ("filtered" if self.accel is None else "exact")
        if self.ctrl.has_jerk:
            mode += " + jerk"
        return {
            "law_steps": self.steps,
            "saturated_steps": self.saturated,
            "clamped_steps": self.clamped,
            "monitor_gain_estimate": finite_or_none(self.ctrl.gain()),
            "feedforward": mode,
            "monitor_window_s": self.ctrl.window,
        }


def runtime_law(
    problem: Phase2Problem,
    mix: Optional[np.ndarray] = None,
    monitor_margin: float = 1.2,
    feedforward: str = "off",
    signals: Optional[ReferenceSignals] = None,
    monitor_window: Optional[float] = None,
    ff_filter_tau: float = 0.05,
    ff_jerk_tau: float = 0.2,
) -> RuntimeLaw:
    """The control law of run (b) (see :class:`RuntimeLaw`); ``feedforward``: ``exact`` (a from
    :func:`reference_acceleration` of ``signals``), ``filtered`` (the law's derivative filter,
    time constant ``ff_filter_tau``) or ``off``. Gains without F_ff fly without feedforward."""
    from lpv_sysid.control.law import LpvControllerConfig

    if feedforward not in ("exact", "filtered", "off"):
        raise ConfigError(f"feedforward must be exact, filtered or off, got {feedforward!r}")
    if feedforward == "exact" and signals is None:
        raise ConfigError("feedforward 'exact' needs the reference signals")
    cfg = LpvControllerConfig(
        monitor_margin=float(monitor_margin),
        feedforward=feedforward != "off",
        ff_filter_tau=float(ff_filter_tau),
        ff_jerk_tau=float(ff_jerk_tau),
        monitor_window=monitor_window,
    )
    accel = (
        reference_acceleration(signals) if signals is not None and feedforward == "exact" else None
    )
    return RuntimeLaw(problem, mix, cfg, accel)
