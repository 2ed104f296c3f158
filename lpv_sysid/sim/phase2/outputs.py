"""Outputs of a phase-2 run: the time histories (:class:`RunRecord`), ``summary.yaml``,
``<run>.npz`` and the figures (:func:`write_outputs`, read by :mod:`lpv_sysid.report`), and the
Fig. 10 regressor correlation block."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np
import yaml

from lpv_sysid.errors import ConfigError
from lpv_sysid.sim.closed_loop import VELOCITY_INDEX, ClosedLoopResult

SUMMARY_FORMAT = "lpv_sysid/phase2_summary@2"  # @2: excitation_gain / total_ratio / decomposition


@dataclass
class RunRecord:
    """Time histories of one phase-2 simulation and its achieved gain (for the outputs)."""

    name: str  # "eq33" | "nonlinear"
    t: np.ndarray
    v_d: np.ndarray  # (N, 3)
    controller_state: np.ndarray  # (N, 12) STATE_NAMES order
    ue: np.ndarray  # (N, 4) kappa u_e applied
    u: np.ndarray  # (N, 4) virtual command
    z: np.ndarray  # (N, 3) Q^-1 (v - v_d)
    gain: float
    z_norm: float
    ue_norm: float
    completed: bool = True
    safety_event: Optional[str] = None
    extra: dict = field(default_factory=dict)  # additional arrays for the npz
    info: dict = field(default_factory=dict)  # additional summary entries
    decomposition: Optional[dict] = None  # gain_decomposition of z

    @property
    def v(self) -> np.ndarray:
        return self.controller_state[:, list(VELOCITY_INDEX)]

    @property
    def excitation_gain(self) -> Optional[float]:
        """``||z_e||_2 / ||kappa u_e||_2`` (what gamma bounds), None when not decomposed."""
        d = self.decomposition
        return (
            None
            if not d or d.get("excitation", {}).get("gain") is None
            else float(d["excitation"]["gain"])
        )

    def summary(self, gamma: Optional[float]) -> dict:
        g = self.excitation_gain
        out = {
            "excitation_gain": g,
            "within_gamma": None if gamma is None or g is None else bool(g <= gamma),
            "total_ratio": float(self.gain),
            "z_norm": float(self.z_norm),
            "ue_norm": float(self.ue_norm),
            "decomposition": self.decomposition,
            "completed": bool(self.completed),
            "safety_event": self.safety_event,
            "duration": float(self.t[-1] - self.t[0]) if self.t.size else 0.0,
            "rms_tracking_error": [
                float(x) for x in np.sqrt(np.mean((self.v - self.v_d) ** 2, axis=0))
            ],
            "max_abs_tracking_error": float(np.max(np.abs(self.v - self.v_d)))
            if self.t.size
            else 0.0,
        }
        out.update(self.info)
        return out

    def arrays(self) -> dict[str, np.ndarray]:
        d = {
            "t": self.t,
            "v_d": self.v_d,
            "v": self.v,
            "x": self.controller_state,
            "ue": self.ue,
            "u": self.u,
            "z": self.z,
        }
        d.update(self.extra)
        return d


def record_from_eq33(res: ClosedLoopResult, name: str = "eq33") -> RunRecord:
    return RunRecord(
        name=name,
        t=res.t,
        v_d=res.v_d,
        controller_state=res.x,
        ue=res.ue,
        u=res.u,
        z=res.z,
        gain=res.gain,
        z_norm=res.z_norm,
        ue_norm=res.ue_norm,
        extra={"z_model": res.z_model, "dx": res.dx},
        info={
            "gain_model": float(res.gain_model),
            "method": res.method,
            "rhs_evaluations": int(res.n_steps),
        },
    )


def write_outputs(
    out_dir: str | Path,
    gamma: Optional[float],
    kappa: float,
    records: Sequence[RunRecord],
    skipped: Optional[dict[str, str]] = None,
    regressor_block: Optional[dict] = None,
    extra: Optional[dict] = None,
) -> dict[str, Path]:
    """Write ``summary.yaml`` and ``<name>.npz``; return the written paths (the figures of
    the run: :func:`lpv_sysid.report.write_phase2_figures`)."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"output directory: cannot create {out} ({exc.strerror})") from None
    written: dict[str, Path] = {}
    summary: dict[str, Any] = {
        "format": SUMMARY_FORMAT,
        "gamma": None if gamma is None else float(gamma),
        "kappa": float(kappa),
    }
    events = []
    for rec in records:
        summary[rec.name] = rec.summary(gamma)
        if rec.safety_event:
            events.append(f"{rec.name}: {rec.safety_event}")
        p = out / f"{rec.name}.npz"
        np.savez(p, **rec.arrays())
        written[rec.name] = p
    for name, reason in (skipped or {}).items():
        summary[name] = {"skipped": reason}
    summary["safety_events"] = events
    if regressor_block is not None:
        summary["regressor_correlation"] = regressor_block
    if extra:
        summary.update(extra)
    p = out / "summary.yaml"
    p.write_text(
        yaml.safe_dump(summary, sort_keys=False, default_flow_style=None), encoding="utf-8"
    )
    written["summary"] = p
    return written


# --------------------------------------------------------------------------- regressors
def regressor_correlation_block(
    t: np.ndarray,
    controller_state: np.ndarray,
    arm_length: float,
    source: str,
    Omega: Optional[np.ndarray] = None,
) -> dict:
    """Fig. 10 correlation matrices of the Eq. (6) regressors for ``summary.yaml``.

    ``controller_state`` (N, 12) in DESIGN.md state order; ``Omega`` (N, 4) rotor speeds
    if known, else Omega = Mix^-1 delta from the virtual-actuator states.
    """
    from lpv_sysid.ident.nonlinear import (
        fig10_regressors,
        regressor_correlations,
        virtual_actuators,
    )
    from lpv_sysid.models.quadrotor import mixer

    mix = mixer(arm_length)
    controller_state = np.asarray(controller_state, dtype=float)
    if Omega is None:
        Omega = np.linalg.solve(mix, controller_state[:, 8:12].T).T
    delta, delta_sq = virtual_actuators(Omega, mix)
    regs = fig10_regressors(
        t, controller_state[:, 2:5], controller_state[:, 5:8], delta, delta_sq, arm_length
    )
    corrs = regressor_correlations(regs)
    return {
        "source": source,
        "n_samples": int(t.size),
        "axes": {c.axis: c.to_dict() for c in corrs},
        "max_abs_offdiag": {c.axis: finite_or_none(c.max_offdiag()) for c in corrs},
    }


def finite_or_none(x: float) -> Optional[float]:
    return float(x) if x is not None and np.isfinite(x) else None
