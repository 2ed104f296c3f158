"""Safety margins over a phase-2 run, recomputed from its logged time histories.

For the go/no-go table and the margin plots of the report (no plotting here). Per run
(``phase2/<name>.npz`` of :mod:`lpv_sysid.sim.phase2`: ``t``, ``x`` / ``x_meas`` in the x12 layout
``phi, theta, u, v, w, p, q, r, dt, da, de, dr``, ``u`` the virtual command, ``z``, ``ue``):

- **tilt** ``max(|phi|, |theta|)`` [deg] of the state the supervisor sees (``x_meas`` when
  logged, else ``x``) against the supervisor's limit (``max_tilt_deg``);
- **ESC headroom**: ``u_ESC = Mix^-1 u`` (seed 0 Eq. 7, :func:`lpv_sysid.models.quadrotor.mixer`)
  and ``min(u_ESC, 1 - u_ESC)`` over the four motors, the fraction of the ESC command range left
  before the runtime law saturates (0 = saturated; lpv_controller step 5);
- **distance to the box edge**: ``min_k min(v_k - vmin_k, vmax_k - v_k)`` [m/s] of the body
  velocity against the scheduling box of the certificate (negative: outside the box; the
  supervisor stops at ``-box_margin``);
- **bound-monitor ratio**: the runtime law's running ``sqrt(E_z / E_e)`` (lpv_controller step 7:
  rectangle rule on the logged ``z`` and ``kappa u_e``, exponential forgetting with the run's
  ``monitor_window_s``), judged once ``E_e`` reaches ``monitor_min_energy``, against
  ``gamma x monitor_margin``.

Limits come from the phase-2 summary where it records them (``gamma``, ``box``, a ``limits``
mapping, the run's ``monitor_window_s``), else from the defaults of the code that flew the run
(:class:`lpv_sysid.sim.phase2.Phase2Config`, :class:`lpv_sysid.control.law.controller.
LpvControllerConfig`, :class:`lpv_sysid.models.quadrotor.QuadrotorParams`); :attr:`Limits.source`
says which.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Optional

import numpy as np

from lpv_sysid.errors import ConfigError

#: x12 columns (lpv_sysid.models.quadrotor.STATE_NAMES order)
PHI, THETA = 0, 1
VELOCITY = slice(2, 5)


@dataclass(frozen=True)
class Limits:
    """Limits the margins are measured against (module docstring)."""

    max_tilt_deg: float
    box_min: np.ndarray
    box_max: np.ndarray
    box_margin: float
    gamma: Optional[float]
    monitor_margin: float
    monitor_min_energy: float
    arm_length: float
    source: dict = field(default_factory=dict)  # limit name -> where it came from

    @property
    def monitor_limit(self) -> Optional[float]:
        return None if self.gamma is None else self.gamma * self.monitor_margin


def limits_from_summary(summary: Optional[Mapping[str, Any]]) -> Limits:
    """:class:`Limits` of a phase-2 summary (``phase2/summary.yaml`` mapping, or None)."""
    from lpv_sysid.control.law import LpvControllerConfig
    from lpv_sysid.models.quadrotor import QuadrotorParams
    from lpv_sysid.sim.phase2 import Phase2Config

    s = dict(summary or {})
    rec_raw = s.get("limits")
    rec: dict = rec_raw if isinstance(rec_raw, dict) else {}
    src: dict[str, str] = {}

    def pick(name: str, default: float, where: str) -> float:
        if rec.get(name) is not None:
            src[name] = "phase2 summary limits"
            return float(rec[name])
        src[name] = f"default of {where} (not recorded in the summary)"
        return float(default)

    box = s.get("box") if isinstance(s.get("box"), dict) else None
    if box is None or box.get("min") is None or box.get("max") is None:
        raise ConfigError("phase2/summary.yaml: box: the scheduling box {min, max} is missing")
    lo, hi = np.asarray(box["min"], dtype=float), np.asarray(box["max"], dtype=float)
    if lo.shape != hi.shape or lo.ndim != 1 or not np.all(lo < hi):
        raise ConfigError("phase2/summary.yaml: box: need min < max per axis")
    src["box"] = "phase2 summary box"
    gamma = s.get("gamma")
    src["gamma"] = "phase2 summary gamma"
    return Limits(
        max_tilt_deg=pick("max_tilt_deg", Phase2Config.max_tilt_deg, "sim.phase2.Phase2Config"),
        box_min=lo,
        box_max=hi,
        box_margin=pick("box_margin", Phase2Config.box_margin, "sim.phase2.Phase2Config"),
        gamma=None if gamma is None else float(gamma),
        monitor_margin=pick(
            "monitor_margin", Phase2Config.monitor_margin, "sim.phase2.Phase2Config"
        ),
        monitor_min_energy=pick(
            "monitor_min_energy",
            LpvControllerConfig.monitor_min_energy,
            "control.lpv_controller.LpvControllerConfig",
        ),
        arm_length=pick("arm_length", QuadrotorParams.arm_length, "models.quadrotor"),
        source=src,
    )


def tilt_deg(x12: np.ndarray) -> np.ndarray:
    """``max(|phi|, |theta|)`` in degrees per sample."""
    x = np.asarray(x12, dtype=float)
    return np.degrees(np.maximum(np.abs(x[:, PHI]), np.abs(x[:, THETA])))


def esc_headroom(u: np.ndarray, arm_length: float) -> np.ndarray:
    """``min over motors of min(u_ESC, 1 - u_ESC)`` with ``u_ESC = Mix^-1 u`` (Eq. 7)."""
    from lpv_sysid.models.quadrotor import mixer

    esc = np.linalg.solve(mixer(arm_length), np.asarray(u, dtype=float).T).T
    return np.min(np.minimum(esc, 1.0 - esc), axis=1)


def box_distance(v: np.ndarray, vmin: np.ndarray, vmax: np.ndarray) -> np.ndarray:
    """Signed distance [m/s] of each velocity sample to the nearest face of the box."""
    v = np.asarray(v, dtype=float)
    return np.min(np.minimum(v - vmin, vmax - v), axis=1)


def running_gain(
    t: np.ndarray,
    z: np.ndarray,
    ue: np.ndarray,
    min_energy: float,
    window: Optional[float] = None,
) -> np.ndarray:
    """The bound monitor's ``sqrt(E_z / E_e)`` per sample (NaN until judged), rectangle rule
    with the step since the previous sample, as the runtime law integrates."""
    t = np.asarray(t, dtype=float)
    z2 = np.sum(np.asarray(z, dtype=float) ** 2, axis=1)
    e2 = np.sum(np.asarray(ue, dtype=float) ** 2, axis=1)
    out = np.full(t.size, np.nan)
    ez = ee = ee_total = 0.0
    for k in range(t.size):
        dt = t[k] - t[k - 1] if k > 0 else 0.0
        if dt > 0.0:
            if window is not None:
                lam = math.exp(-dt / window)
                ez *= lam
                ee *= lam
            ez += float(z2[k]) * dt
            ee += float(e2[k]) * dt
            ee_total += float(e2[k]) * dt
        if ee_total >= min_energy and ee > 0.0:
            out[k] = math.sqrt(ez / ee)
    return out


@dataclass(frozen=True)
class RunMargins:
    """Margin time histories of one run and their extremes (module docstring)."""

    run: str
    t: np.ndarray
    tilt_deg: np.ndarray
    esc_headroom: np.ndarray
    box_distance: np.ndarray
    monitor_ratio: np.ndarray
    limits: Limits
    state_source: str  # "x_meas" (what the supervisor saw) or "x"

    @staticmethod
    def _at(t: np.ndarray, y: np.ndarray, worst: str) -> tuple[float, float]:
        if not np.any(np.isfinite(y)):
            return float("nan"), float("nan")
        k = int(np.nanargmax(y) if worst == "max" else np.nanargmin(y))
        return float(y[k]), float(t[k])

    def extremes(self) -> dict[str, tuple[float, float]]:
        """name -> (worst value, time of it): max tilt, min headroom, min box distance, max
        judged monitor ratio."""
        return {
            "tilt_deg": self._at(self.t, self.tilt_deg, "max"),
            "esc_headroom": self._at(self.t, self.esc_headroom, "min"),
            "box_distance": self._at(self.t, self.box_distance, "min"),
            "monitor_ratio": self._at(self.t, self.monitor_ratio, "max"),
        }


def run_margins(
    name: str,
    arrays: Mapping[str, np.ndarray],
    limits: Limits,
    monitor_window: Optional[float] = None,
) -> RunMargins:
    """:class:`RunMargins` of one logged run (``phase2/<name>.npz`` arrays)."""
    for key in ("t", "x", "u", "z", "ue"):
        if key not in arrays:
            raise ConfigError(f"phase2/{name}.npz: array '{key}' missing (needed for margins)")
    t = np.asarray(arrays["t"], dtype=float)
    src = "x_meas" if "x_meas" in arrays else "x"
    x = np.asarray(arrays[src], dtype=float)
    if x.ndim != 2 or x.shape[0] != t.size or x.shape[1] < 5:
        raise ConfigError(f"phase2/{name}.npz: '{src}' must be (N, 12), got {x.shape}")
    return RunMargins(
        run=name,
        t=t,
        tilt_deg=tilt_deg(x),
        esc_headroom=esc_headroom(arrays["u"], limits.arm_length),
        box_distance=box_distance(x[:, VELOCITY], limits.box_min, limits.box_max),
        monitor_ratio=running_gain(
            t, arrays["z"], arrays["ue"], limits.monitor_min_energy, monitor_window
        ),
        limits=limits,
        state_source=src,
    )
