"""Phase-1 vertex flights (seed 0 Sec. IV) under the baseline controller: the excitation,
one simulated run, and all runs of the experiment (module docstring of
:mod:`lpv_sysid.sim.phase1`)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from lpv_sysid.control.baseline import BaselineController, BaselineGains
from lpv_sysid.control.campaign import run_name
from lpv_sysid.errors import ConfigError, SafetyError
from lpv_sysid.models.quadrotor import TRIM_COLUMNS, Quadrotor, Trim, mixer
from lpv_sysid.sim.phase1.config import Phase1Config
from lpv_sysid.sim.vehicle import SensorConfig, SimVehicle

log = logging.getLogger(__name__)

REFERENCE_NAMES = ("u_d", "v_d", "w_d", "r_d")


@dataclass
class RunRecord:
    """Everything one simulated run produced (arrays in NED/FRD, SI units)."""

    name: str
    v_d: np.ndarray  # (3,) vertex body-velocity reference
    t_excite: float  # start of the excitation segment, s
    duration: float
    model_trim: Trim
    state_t: np.ndarray  # (N,)
    state_true: np.ndarray  # (N, 16) FULL_STATE_NAMES
    state_meas: np.ndarray  # (N, 16) estimator output (rotor columns = truth)
    rotor_t: np.ndarray  # (M,)
    rotor_meas: np.ndarray  # (M, 4) rad/s
    imu_t: np.ndarray  # (K,)
    imu_accel: np.ndarray  # (K, 3) specific force FRD
    imu_gyro: np.ndarray  # (K, 3) FRD
    cmd_t: np.ndarray  # (L,) control-rate time
    reference: np.ndarray  # (L, 4) u_d, v_d, w_d [m/s], r_d [rad/s]
    excitation: np.ndarray  # (L, 4) multisine part of the reference
    command: np.ndarray  # (L, 4) virtual command u = [ut, ua, ue, ur]
    meta: dict = field(default_factory=dict)

    def achieved_trim(self, average_s: float, arm_length: float) -> dict:
        """Mean over the last ``average_s`` of the trim segment (seed 0 Table 1 columns)."""
        t0 = max(0.0, self.t_excite - average_s)
        s = (self.state_t >= t0) & (self.state_t < self.t_excite)
        r = (self.rotor_t >= t0) & (self.rotor_t < self.t_excite)
        if not s.any() or not r.any():
            raise ConfigError(f"run {self.name}: no samples in the trim averaging window")
        xm = self.state_meas[s]
        delta = self.rotor_meas[r] @ mixer(arm_length).T
        vals = [
            *xm[:, 6:9].mean(axis=0),
            *np.degrees(xm[:, 3:5].mean(axis=0)),
            *delta.mean(axis=0),
        ]
        return {k: float(v) for k, v in zip(TRIM_COLUMNS, vals)}


def design_excitation(cfg: Phase1Config):
    """The phase-1 4-axis multisine (seed 0 Sec. IV): orthogonal, phase-optimised, flat
    spectrum in [f_min_hz, f_max_hz], one period of ``excite_s``, channels u, v, w, yaw-rate
    reference scaled to ``cfg.amplitudes`` (designed by :mod:`lpv_sysid.signals`)."""
    from lpv_sysid.signals.excitation import phase1_signals

    return phase1_signals(
        duration=cfg.excite_s,
        band=(cfg.f_min_hz, cfg.f_max_hz),
        peaks=cfg.amplitudes,
        sample_rate=50.0,
    )


def excitation_signal(cfg: Phase1Config, t: np.ndarray, signals=None) -> np.ndarray:
    """Excitation (N, 4) for excitation-segment times t in [0, excite_s], with cosine taper.

    ``signals`` is the designed :class:`~lpv_sysid.signals.multisine.SignalSet`
    (:func:`design_excitation`; designed here when None). It is evaluated as the exact sum
    of sinusoids at ``t``, so the control rate need not match the design grid.
    """
    if signals is None:
        signals = design_excitation(cfg)
    u = signals.evaluate(t)
    if cfg.taper_s > 0:
        w = np.ones_like(t)
        a = t < cfg.taper_s
        w[a] = 0.5 - 0.5 * np.cos(np.pi * t[a] / cfg.taper_s)
        b = t > cfg.excite_s - cfg.taper_s
        w[b] = 0.5 - 0.5 * np.cos(np.pi * (cfg.excite_s - t[b]) / cfg.taper_s)
        u = u * w[:, None]
    return u


def simulate_run(
    model: Quadrotor,
    gains: BaselineGains,
    sensors: SensorConfig,
    cfg: Phase1Config,
    v_d,
    name: str,
    seed: int,
    signals=None,
) -> RunRecord:
    """Fly one phase-1 run (trim then excitation) about body velocity ``v_d``.

    ``signals``: the designed excitation (:func:`design_excitation`), shared by all runs."""
    v_d = np.asarray(v_d, dtype=float)
    trim = model.trim(v_d)
    if gains.arm_length != model.params.arm_length:
        # the controller's output mixer must be the vehicle's (seed 0 Eq. 7)
        gains = replace(gains, arm_length=model.params.arm_length)
    phys = sensors.physics_hz
    d_ctrl = phys / gains.rate_hz
    if abs(d_ctrl - round(d_ctrl)) > 1e-9 or d_ctrl < 1:
        raise ConfigError(f"controller.rate_hz={gains.rate_hz} must divide sim.physics_hz={phys}")
    d_ctrl = int(round(d_ctrl))
    d_state, d_imu, d_rot = (
        sensors.decimation(r) for r in (sensors.state_hz, sensors.imu_hz, sensors.rotor_hz)
    )
    T = cfg.trim_s + cfg.excite_s
    n = int(round(T * phys))
    t_c = np.arange(0, n, d_ctrl) / phys
    exc = np.zeros((t_c.size, 4))
    on = t_c >= cfg.trim_s
    exc[on] = excitation_signal(cfg, t_c[on] - cfg.trim_s, signals)
    ref = exc + np.r_[v_d, 0.0]

    start = trim if cfg.start == "trim" else model.trim([0.0, 0.0, 0.0])
    veh = SimVehicle(model, SensorConfig(**{**sensors.to_dict(), "seed": seed}), start.full_state)
    veh.u = start.u0.tolist()
    ctrl = BaselineController(gains)
    ctrl.warm_start(start.x0, start.u0, start.v_d)

    ns, ni, nr = -(-n // d_state), -(-n // d_imu), -(-n // d_rot)
    state_t, state_true, state_meas = np.empty(ns), np.empty((ns, 16)), np.empty((ns, 16))
    imu_t, imu_a, imu_g = np.empty(ni), np.empty((ni, 3)), np.empty((ni, 3))
    rot_t, rot_m = np.empty(nr), np.empty((nr, 4))
    cmd = np.empty((t_c.size, 4))
    xm = np.empty(16)  # the measured state: set at k = 0 (d_state divides 0) before any use
    u = start.u0.tolist()
    for k in range(n):
        t = k / phys
        if k % d_state == 0:
            i = k // d_state
            state_t[i] = t
            state_true[i] = veh.x
            xm = veh.measure_state()
            state_meas[i] = xm
        if k % d_rot == 0:
            i = k // d_rot
            rot_t[i] = t
            rot_m[i] = veh.measure_rotors()
        if k % d_imu == 0:
            i = k // d_imu
            imu_t[i] = t
            imu_a[i], imu_g[i] = veh.measure_imu()
        if k % d_ctrl == 0:
            j = k // d_ctrl
            r = ref[j]
            # rigid-body state phi, theta, u, v, w, p, q, r of the measured 16-state
            rigid_body_state = (xm[3], xm[4], xm[6], xm[7], xm[8], xm[9], xm[10], xm[11])
            u = ctrl.step(t, rigid_body_state, (r[0], r[1], r[2]), r[3]).tolist()
            cmd[j] = u
        try:
            veh.step(u)
        except SafetyError as exc_:
            raise SafetyError(f"run {name}: {exc_}; check gains/limits") from None
    return RunRecord(
        name=name,
        v_d=v_d,
        t_excite=cfg.trim_s,
        duration=T,
        model_trim=trim,
        state_t=state_t,
        state_true=state_true,
        state_meas=state_meas,
        rotor_t=rot_t,
        rotor_meas=rot_m,
        imu_t=imu_t,
        imu_accel=imu_a,
        imu_gyro=imu_g,
        cmd_t=t_c,
        reference=ref,
        excitation=exc,
        command=cmd,
        meta={"seed": seed, "physics_hz": phys, "control_hz": gains.rate_hz},
    )


def run_phase1(
    model: Quadrotor,
    gains: BaselineGains,
    sensors: SensorConfig,
    cfg: Phase1Config,
    vertex_indices: Sequence[int] | None = None,
) -> list[RunRecord]:
    """All vertex runs (1-based Table 1 indices, default all) plus the hover validation."""
    verts = cfg.vertices()
    idx = list(range(1, len(verts) + 1)) if vertex_indices is None else list(vertex_indices)
    for i in idx:
        if not 1 <= i <= len(verts):
            raise ConfigError(f"vertex index {i} out of range 1..{len(verts)}")
    signals = design_excitation(cfg)
    runs = []
    for i in idx:
        log.info("phase 1: vertex %d %s", i, verts[i - 1])
        runs.append(
            simulate_run(
                model,
                gains,
                sensors,
                cfg,
                verts[i - 1],
                run_name(verts[i - 1]),
                seed=cfg.seed * 100 + i,
                signals=signals,
            )
        )
    if cfg.hover_validation:
        runs.append(
            simulate_run(
                model,
                gains,
                sensors,
                cfg,
                (0.0, 0.0, 0.0),
                "hover_validation",
                seed=cfg.seed * 100 + 99,
                signals=signals,
            )
        )
    return runs
