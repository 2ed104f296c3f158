"""Phase-2 experiment simulation (seed 0 Sec. VII): the LPV-controlled excitation flight.

Two simulations of the same 7-channel signal (reference ``u_d, v_d, w_d`` and normalised
excitation ``ue_t, ue_a, ue_e, ue_r``, excitation multiplier ``kappa``):

(a) the LPV closed loop of Eq. (33) at nominal parameters (:mod:`lpv_sysid.sim.lpv_closed_loop`,
    scheduled model from ``vertex_models.yaml`` + ``gains.yaml`` via :mod:`lpv_sysid.models.lpv`);
    with reference feedforward in the gains (F_ff) also ``linear_ff``: the same linear model
    without Eq. (33)'s ``x0'`` term under the feedforward law (the linear counterpart of (b));
(b) the full nonlinear quadrotor of :mod:`lpv_sysid.models.quadrotor` under the runtime LPV law
    (:mod:`lpv_sysid.control.lpv_controller`) fed with the simulated *measured* state (sensor
    model of :mod:`lpv_sysid.sim.vehicle`), recorded to a rosbag2 with the DESIGN.md topics.

Both report the achieved u_e -> z gain (z = Q^-1 (v - v_d), Eq. 18) against the design gamma
(Eq. 29, see below), tracking (Figs. 8-9) and the correlation of the Eq. (6) regressors
(Fig. 10). The safety supervisor of :mod:`lpv_sysid.control.safety` stops run (b) -- excitation off, event reported -- when
the vehicle leaves the scheduling box (plus a margin), tilts beyond a limit, or its state
becomes non-finite; the runtime law's bound monitor flag stops it too.

On the nonlinear vehicle z also holds the lag in following v_d (absent from Eq. 33, where x0'
moves the equilibrium); the reference feedforward of gains.yaml (``--feedforward exact``: a and
its rate from the signal table; ``filtered``: the onboard derivative filter) removes most of it; :func:`excitation_gain_by_superposition` (``--superposition``) separates
the excitation response by flying with and without u_e under identical sensor noise.

What gamma bounds, and what the summary reports.  ``z = Q^-1 (v - v_d)`` holds three parts:
the response to the excitation ``u_e`` (the only part Lemma 1 bounds, Eq. 29), the lag in
following ``v_d`` (in Eq. 33 the response to the ``x0'`` forcing, on the vehicle the
acceleration it must produce) and the equilibrium offset ``Q^-1 (v0(v_d) - v_d)`` (the vertex
equilibria fly a velocity that differs from the commanded one, seed 0 Table 1).  Every run's
ratio is split (:func:`gain_decomposition`): ``excitation_gain`` = ``||z_e||_2 / ||kappa u_e||_2``
with ``z_e`` from superposition (Eq. 33 and ``linear_ff``: exact, a second run with ``-u_e``;
nonlinear with ``--superposition``: two more flights) or, on the nonlinear run otherwise, from
a FIR regression of ``z`` on ``u_e`` above the reference band (:func:`excitation_response_fir`);
the offset part exactly from the schedule; tracking = the rest.  ``within_gamma`` refers to
``excitation_gain``; ``total_ratio`` = ``||z||_2 / ||kappa u_e||_2`` mixes all three.

Outputs in ``--out DIR`` (read by :mod:`lpv_sysid.report`): ``summary.yaml``,
``eq33.npz`` / ``nonlinear.npz`` (time histories), PNG figures, and ``bag/`` (rosbag2).
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional, Protocol, Sequence

import numpy as np
import yaml

from lpv_sysid.errors import BagError, ConfigError, SafetyError
from lpv_sysid.sim.lpv_closed_loop import (
    VELOCITY_INDEX,
    ClosedLoopConfig,
    ControlLaw,
    ClosedLoopResult,
    ReferenceSignals,
    l2_norm,
    simulate_eq33,
)

log = logging.getLogger(__name__)

REFERENCE_CHANNELS = ("u_d", "v_d", "w_d")
EXCITATION_CHANNELS = ("ue_t", "ue_a", "ue_e", "ue_r")
SUMMARY_FORMAT = "lpv_sysid/phase2_summary@2"  # @2: excitation_gain / total_ratio / decomposition


# --------------------------------------------------------------------------- configuration
@dataclass(frozen=True)
class Phase2Config:
    """Options of the phase-2 simulation (CLI flags of ``simulate phase2``)."""

    kappa: float = 1.0  # excitation multiplier of Eq. (33)
    eq33_method: str = "rk4"  # "rk4" (fixed step on the signal grid) or "RK45" (ode45-like)
    box_margin: float = 1.0  # m/s beyond the scheduling box before the supervisor stops
    max_tilt_deg: float = 60.0  # |phi|, |theta| limit of the supervisor
    duration: Optional[float] = None  # truncate the signals to this many seconds
    ramp: Optional[float] = 2.0  # fade in/out of the excitation player (None: raw table)
    record_bag: bool = True
    storage: str = "mcap"
    seed: int = 0  # sensor-noise seed of run (b)
    run_eq33: bool = True
    run_nonlinear: bool = True
    monitor_margin: float = 1.2  # bound monitor of the runtime law: flag at gain > gamma x margin
    superposition: bool = False  # also estimate the excitation-only gain on the nonlinear model
    feedforward: str = "exact"  # reference feedforward of run (b): exact | filtered | off
    ff_filter_tau: float = 0.05  # s, derivative filter of the 'filtered' feedforward
    ff_jerk_tau: float = 0.2  # s, its jerk stage
    monitor_window: Optional[float] = None  # s, exponential forgetting of the bound monitor

    def __post_init__(self) -> None:
        if not (
            isinstance(self.kappa, (int, float)) and math.isfinite(self.kappa) and self.kappa > 0
        ):
            raise ConfigError(f"--kappa must be a finite number > 0, got {self.kappa!r}")
        if self.eq33_method not in ("RK45", "rk4"):
            raise ConfigError(f"eq33 method must be RK45 or rk4, got {self.eq33_method!r}")
        if not (self.box_margin >= 0 and math.isfinite(self.box_margin)):
            raise ConfigError(f"box margin must be >= 0, got {self.box_margin!r}")
        if not (0 < self.max_tilt_deg < 90):
            raise ConfigError(f"max tilt must be in (0, 90) deg, got {self.max_tilt_deg!r}")
        if self.duration is not None and not (self.duration > 0 and math.isfinite(self.duration)):
            raise ConfigError(f"--duration must be > 0, got {self.duration!r}")
        if not (self.monitor_margin > 0):
            raise ConfigError(f"--monitor-margin must be > 0, got {self.monitor_margin!r}")
        if self.feedforward not in ("exact", "filtered", "off"):
            raise ConfigError(
                f"--feedforward must be exact, filtered or off, got {self.feedforward!r}"
            )
        if not (math.isfinite(self.ff_filter_tau) and self.ff_filter_tau >= 0):
            raise ConfigError(f"--ff-filter-tau must be >= 0, got {self.ff_filter_tau!r}")
        if not (math.isfinite(self.ff_jerk_tau) and self.ff_jerk_tau >= 0):
            raise ConfigError(f"--ff-jerk-tau must be >= 0, got {self.ff_jerk_tau!r}")
        if self.monitor_window is not None and not (
            math.isfinite(self.monitor_window) and self.monitor_window > 0
        ):
            raise ConfigError(f"--monitor-window must be > 0, got {self.monitor_window!r}")
        if self.storage not in ("mcap", "sqlite3"):
            raise ConfigError(f"--storage must be mcap or sqlite3, got {self.storage!r}")


# --------------------------------------------------------------------------- safety
def make_supervisor(vmin: Sequence[float], vmax: Sequence[float], margin: float):
    """control.safety.SafetySupervisor watching the measured state stream and the box."""
    from lpv_sysid.control.safety import SafetyConfig, SafetySupervisor

    return SafetySupervisor(
        SafetyConfig(
            timeouts={},
            box_min=tuple(float(v) for v in vmin),
            box_max=tuple(float(v) for v in vmax),
            box_margin=float(margin),
        )
    )


def supervise(sup, t: float, x12: np.ndarray, max_tilt: float) -> Optional[str]:
    """Phase-2 trip conditions on the measured 12-state (latched in ``sup``).

    Non-finite state (``non_finite``); measured body velocity outside the scheduling box
    widened by the margin (``out_of_box``: the certificate of Lemma 1 only covers the box,
    Eq. 20); roll or pitch beyond ``max_tilt`` (``bound_exceeded``: Assumption 2 far from valid).
    Returns the event text once tripped, else None.
    """
    sup.on_input("state", t, x12, t)
    if not sup.aborted:
        sup.check_scheduling(t, np.asarray(x12, dtype=float)[list(VELOCITY_INDEX)])
    if not sup.aborted:
        tilt = max(abs(float(x12[0])), abs(float(x12[1])))
        if tilt > max_tilt:
            sup.on_bound_flag(
                t,
                True,
                f"attitude |phi|,|theta| = {math.degrees(tilt):.1f} deg > "
                f"{math.degrees(max_tilt):.1f} deg",
            )
    ev = sup.event
    if ev is None:
        return None
    what = (
        " (measured body velocity u, v, w vs the scheduling box)"
        if ev.reason == "out_of_box"
        else ""
    )
    return f"{ev.reason} at t={ev.t:.3f} s: {ev.detail}{what}"


# --------------------------------------------------------------------------- signals
def reference_signals(
    t: np.ndarray, u: np.ndarray, names: Sequence[str], duration: Optional[float] = None
) -> ReferenceSignals:
    """Pick the reference and excitation channels of ``signals.npz`` by name."""
    names = [str(n) for n in names]
    u = np.asarray(u, dtype=float)
    t = np.asarray(t, dtype=float)
    if u.ndim != 2 or u.shape[1] != len(names):
        raise ConfigError(
            f"signals.npz: 'u' has shape {u.shape}, 'names' has {len(names)} entries"
        )
    missing = [c for c in REFERENCE_CHANNELS + EXCITATION_CHANNELS if c not in names]
    if missing:
        raise ConfigError(f"signals.npz: channel(s) {missing} missing; have {names}")
    if duration is not None:
        keep = t <= t[0] + duration + 1e-12
        t, u = t[keep], u[keep]
    vd = u[:, [names.index(c) for c in REFERENCE_CHANNELS]]
    ue = u[:, [names.index(c) for c in EXCITATION_CHANNELS]]
    return ReferenceSignals(t, vd, ue)


def load_signals(
    signals_dir: str | Path, duration: Optional[float] = None, ramp: Optional[float] = None
) -> ReferenceSignals:
    """``DIR/signals.npz`` (t, u, names) -> ReferenceSignals; ConfigError naming the problem.

    With ``ramp`` (seconds) the table is played as the excitation node plays it
    (:meth:`lpv_sysid.signals.excitation.ExcitationCore.phase2`: raised-cosine fade in and out
    of that length around one period, so v_d starts and ends at zero, i.e. hover), sampled on
    the table's own time step; without it the raw table is used.
    """
    from lpv_sysid.signals.store import load_npz

    path = Path(signals_dir)
    if path.is_dir():
        path = path / "signals.npz"
    if not os.path.lexists(path):
        raise ConfigError(f"--signals: {path} not found")
    t, u, names = load_npz(str(path))  # safe open + signal-table checks (store.validate_table)
    names = list(names)
    sig = reference_signals(t, u, names)  # validates channels by name
    if ramp is None:
        return reference_signals(t, u, names, duration)
    from lpv_sysid.signals.excitation import ExcitationCore

    core = ExcitationCore.phase2(t, u, names, start_time=0.0, ramp=float(ramp))
    dt = float(np.median(np.diff(sig.t)))
    end = core.duration if duration is None else min(core.duration, float(duration))
    grid = np.arange(0.0, end + 0.5 * dt, dt)
    vel, _, ue = core.evaluate(grid)
    return ReferenceSignals(grid, vel, ue)


# --------------------------------------------------------------------------- regressors
def regressor_correlation_block(
    t: np.ndarray,
    x12: np.ndarray,
    arm_length: float,
    source: str,
    Omega: Optional[np.ndarray] = None,
) -> dict:
    """Fig. 10 correlation matrices of the Eq. (6) regressors for ``summary.yaml``.

    ``x12`` in DESIGN.md state order; ``Omega`` (N, 4) rotor speeds if known, else
    Omega = Mix^-1 delta from the virtual-actuator states.
    """
    from lpv_sysid.models.quadrotor import mixer
    from lpv_sysid.report.regressors import regressor_correlations, regressors, virtual_actuators

    mix = mixer(arm_length)
    x12 = np.asarray(x12, dtype=float)
    if Omega is None:
        Omega = np.linalg.solve(mix, x12[:, 8:12].T).T
    delta, delta_sq = virtual_actuators(Omega, mix)
    regs = regressors(t, x12[:, 2:5], x12[:, 5:8], delta, delta_sq, arm_length)
    corrs = regressor_correlations(regs)
    return {
        "source": source,
        "n_samples": int(t.size),
        "axes": {c.axis: c.to_dict() for c in corrs},
        "max_abs_offdiag": {c.axis: _finite_or_none(c.max_offdiag()) for c in corrs},
    }


def _finite_or_none(x: float) -> Optional[float]:
    return float(x) if x is not None and np.isfinite(x) else None


# --------------------------------------------------------------------------- nonlinear run (b)
@dataclass(frozen=True)
class NonlinearConfig:
    """Loop rates of run (b). The control law runs at ``control_hz`` (zero-order hold on the
    vehicle's fixed-step physics, which must be a multiple); the signals are sampled there."""

    control_hz: float = 100.0
    status_hz: float = 1.0

    def __post_init__(self) -> None:
        if not (self.control_hz > 0 and math.isfinite(self.control_hz)):
            raise ConfigError(f"control_hz must be > 0, got {self.control_hz!r}")


class BagSink(Protocol):
    """Where run (b) sends its samples (in the product: :class:`Phase2Bag`)."""

    def sample(
        self,
        t: float,
        x16_meas: np.ndarray,
        imu: tuple[np.ndarray, np.ndarray],
        Omega_meas: np.ndarray,
        v_d: np.ndarray,
        ue: np.ndarray,
        u: np.ndarray,
    ) -> None: ...
    def status(self, t: float, level: str, message: str, values: dict) -> None: ...


TOPIC_NAMESPACE = "/lpv_sysid"
BAG_TOPICS = (
    "state",
    "rotor_speeds",
    "imu",
    "velocity_reference",
    "excitation",
    "actuator_command",
    "status",
)


class Phase2Bag:
    """rosbag2 (mcap) recorder of run (b) with the DESIGN.md topics, written while flying.

    Messages are built by :mod:`lpv_sysid.io.messages` (all ENU/FLU conversions there) and
    written by :class:`lpv_sysid.io.bag.BagWriter`; stamps are nanoseconds from the run start.
    ``excitation`` carries the normalised u_e (DESIGN.md); kappa is in every ``status``.
    Use as a context manager: the bag is closed (and stays readable) also after an error.
    """

    def __init__(
        self,
        path: str | Path,
        storage: str = "mcap",
        namespace: str = TOPIC_NAMESPACE,
        node_name: str = "sim_phase2",
        kappa: float = 1.0,
    ) -> None:
        from lpv_sysid.io import messages as M
        from lpv_sysid.io.bag import BagWriter

        self.M = M
        self.f = M.MsgFactory.rosbags()
        self.path = Path(path)
        self.node_name = node_name
        self.kappa = float(kappa)
        self.topic = {name: f"{namespace}/{name}" for name in BAG_TOPICS}
        self.writer = BagWriter(str(self.path), storage=storage)
        self.counts = {name: 0 for name in BAG_TOPICS}

    def __enter__(self) -> "Phase2Bag":
        self.writer.open()
        for name in BAG_TOPICS:
            self.writer.add_topic(self.topic[name], self.M.TYPES[name])
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        return self.writer.__exit__(exc_type, exc, tb)

    def _write(self, name: str, ns: int, msg: Any) -> None:
        self.writer.write(self.topic[name], ns, msg)
        self.counts[name] += 1

    def sample(self, t, x16_meas, imu, Omega_meas, v_d, ue, u) -> None:
        M, f, ns = self.M, self.f, int(round(float(t) * 1e9))
        x = np.asarray(x16_meas, dtype=float)
        self._write("state", ns, M.odometry_from_state(f, ns, x[0:3], x[3:6], x[6:9], x[9:12]))
        self._write("rotor_speeds", ns, M.rotor_speeds_msg(f, ns, Omega_meas))
        self._write("imu", ns, M.imu_msg(f, ns, imu[0], imu[1], x[3:6]))
        self._write("velocity_reference", ns, M.twist_reference_msg(f, ns, v_d, 0.0))
        self._write(
            "excitation", ns, M.excitation_msg(f, ns, np.asarray(ue, dtype=float) / self.kappa)
        )
        self._write("actuator_command", ns, M.actuator_command_msg(f, ns, u))

    def status(self, t, level, message, values) -> None:
        M, f, ns = self.M, self.f, int(round(float(t) * 1e9))
        vals = {"phase": "phase2", "kappa": self.kappa}
        vals.update(values)
        st = M.diagnostic_status(f, level, self.node_name, message, vals)
        self._write("status", ns, M.diagnostic_array(f, ns, [st]))


def measured_x12(x16_meas: np.ndarray, Omega_meas: np.ndarray, mix: np.ndarray) -> np.ndarray:
    """Controller state (DESIGN.md order) from the estimator output and ESC rotor speeds."""
    x16_meas = np.asarray(x16_meas, dtype=float)
    return np.concatenate(
        [x16_meas[3:5], x16_meas[6:12], mix @ np.asarray(Omega_meas, dtype=float)]
    )


def simulate_nonlinear(
    vehicle: Any,
    law: ControlLaw,
    signals: ReferenceSignals,
    Q: np.ndarray,
    vmin: Sequence[float],
    vmax: Sequence[float],
    kappa: float = 1.0,
    gamma: Optional[float] = None,
    config: NonlinearConfig = NonlinearConfig(),
    box_margin: float = 1.0,
    max_tilt: float = math.radians(60.0),
    sink: Optional[BagSink] = None,
) -> RunRecord:
    """Seed 0 Sec. VII on the nonlinear quadrotor: the LPV law on measured states.

    ``vehicle`` is a :class:`lpv_sysid.sim.vehicle.SimVehicle` (fixed-step RK4 physics,
    noisy sensors) already placed at its initial state; ``law(t, x12, v_d, kappa u_e)`` returns
    the virtual command. Each control period: measure (estimator state + ESC rotor speeds),
    supervise, compute u, hold it over the physics steps. On a safety trip the excitation is
    switched off, a status is emitted and the run stops (on the vehicle PX4 takes over).
    The performance output uses the true velocity: z = Q^-1 (v - v_d) (Eq. 18).
    """
    mix = vehicle.model.mix
    n_phys = vehicle.cfg.physics_hz / config.control_hz
    if abs(n_phys - round(n_phys)) > 1e-9 or n_phys < 1:
        raise ConfigError(
            f"control_hz={config.control_hz} must divide the vehicle physics rate "
            f"{vehicle.cfg.physics_hz} Hz"
        )
    n_phys = int(round(n_phys))
    dt_c = 1.0 / config.control_hz
    t0, t_end = float(signals.t[0]), float(signals.t[-1])
    n_steps = int(math.floor((t_end - t0) / dt_c + 1e-9)) + 1
    sup = make_supervisor(vmin, vmax, box_margin)
    sup.arm(t0)
    status_every = (
        max(1, int(round(config.control_hz / config.status_hz))) if config.status_hz > 0 else 0
    )
    T, VD, X, XM, UE, U, OM = [], [], [], [], [], [], []
    event: Optional[str] = None
    for k in range(n_steps):
        t = t0 + k * dt_c
        v_d, _, ue = signals.at(t)
        x16_true = np.array(vehicle.x)
        x16_meas = vehicle.measure_state()
        Om_meas = vehicle.measure_rotors()
        x12m = measured_x12(x16_meas, Om_meas, mix)
        event = supervise(sup, t, x12m, max_tilt)
        if event is not None:
            ue = np.zeros_like(ue)
            if sink is not None:
                sink.status(
                    t,
                    "ERROR",
                    "safety abort: excitation off, run stopped",
                    {"event": event, "excitation": "off"},
                )
            break
        ue_s = kappa * ue
        try:
            u = np.asarray(law(t, x12m, v_d, ue_s), dtype=float)
        except SafetyError as exc:
            u = np.full(4, np.nan)
            detail = str(exc)
        else:
            detail = f"control law returned {u.tolist()}"
        if u.shape != (4,) or not np.all(np.isfinite(u)):
            event = f"non_finite at t={t:.3f} s: {detail}"
        elif (getattr(law, "last_info", None) or {}).get("bound_exceeded"):
            gain_est = law.ctrl.gain() if hasattr(law, "ctrl") else float("nan")
            sup.on_bound_flag(
                t,
                True,
                f"bound monitor: running ||z||/||u_e|| = {gain_est:.3g} above gamma x margin",
            )
            event = supervise(sup, t, x12m, max_tilt)
        if event is not None:
            if sink is not None:
                sink.status(
                    t,
                    "ERROR",
                    "safety abort: excitation off, run stopped",
                    {"event": event, "excitation": "off"},
                )
            break
        T.append(t)
        VD.append(v_d)
        X.append(_x12_of(x16_true, mix))
        XM.append(x12m)
        UE.append(ue_s)
        U.append(u)
        OM.append(x16_true[12:16])
        if sink is not None:
            sink.sample(t, x16_meas, vehicle.measure_imu(), Om_meas, v_d, ue_s, u)
            if status_every and k % status_every == 0:
                sink.status(t, "OK", "phase 2 excitation running", {"kappa": kappa})
        if k == n_steps - 1:
            break
        try:
            for _ in range(n_phys):
                vehicle.step(u)
        except FloatingPointError as exc:
            event = f"non_finite at t={t:.3f} s: {exc}"
            if sink is not None:
                sink.status(
                    t,
                    "ERROR",
                    "safety abort: excitation off, run stopped",
                    {"event": event, "excitation": "off"},
                )
            break
    if not T:
        raise SafetyError(f"phase 2 nonlinear run stopped before the first sample: {event}")
    t_arr = np.array(T)
    x_arr, vd_arr, ue_arr = np.array(X), np.array(VD), np.array(UE)
    err = x_arr[:, list(VELOCITY_INDEX)] - vd_arr
    z = np.linalg.solve(np.asarray(Q, dtype=float), err.T).T
    z_norm, ue_norm = l2_norm(t_arr, z), l2_norm(t_arr, ue_arr)
    gain = z_norm / ue_norm if ue_norm > 0 else float("inf")
    if sink is not None and event is None:
        sink.status(t_arr[-1], "OK", "phase 2 excitation complete", {"gain": gain})
    return RunRecord(
        name="nonlinear",
        t=t_arr,
        v_d=vd_arr,
        x12=x_arr,
        ue=ue_arr,
        u=np.array(U),
        z=z,
        gain=gain,
        z_norm=z_norm,
        ue_norm=ue_norm,
        completed=event is None,
        safety_event=event,
        extra={"x_meas": np.array(XM), "Omega": np.array(OM)},
        info={
            "control_hz": float(config.control_hz),
            "physics_hz": float(vehicle.cfg.physics_hz),
            "t_stop": float(t_arr[-1]),
            **(law.stats() if hasattr(law, "stats") else {}),
        },
    )


def _x12_of(x16: np.ndarray, mix: np.ndarray) -> np.ndarray:
    return np.concatenate([x16[3:5], x16[6:12], mix @ x16[12:16]])


# --------------------------------------------------------------------------- outputs
@dataclass
class RunRecord:
    """Time histories of one phase-2 simulation and its achieved gain (for the outputs)."""

    name: str  # "eq33" | "nonlinear"
    t: np.ndarray
    v_d: np.ndarray  # (N, 3)
    x12: np.ndarray  # (N, 12)
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
        return self.x12[:, list(VELOCITY_INDEX)]

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
            "x": self.x12,
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
        x12=res.x,
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
    figures: bool = True,
) -> dict[str, Path]:
    """Write ``summary.yaml``, ``<name>.npz`` and figures; return the written paths."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"--out: cannot create {out} ({exc.strerror})") from None
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
    if figures:
        from lpv_sysid.report import plots
        from lpv_sysid.report.markdown import regressor_correlations_from_summary

        for rec in records:
            if rec.t.size < 2:
                continue
            written[f"tracking_{rec.name}"] = plots.plot_tracking(
                rec.t, rec.v_d, rec.v, out / f"tracking_{rec.name}.png", rec.name
            )
            written[f"perturbation_{rec.name}"] = plots.plot_perturbation(
                rec.t, rec.v - rec.v_d, out / f"perturbation_{rec.name}.png", rec.name
            )
        if regressor_block is not None:
            written["regressor_correlation"] = plots.plot_regressor_correlations(
                regressor_correlations_from_summary(regressor_block),
                out / "regressor_correlation.png",
                f"Eq. (6) regressor correlation ({regressor_block['source']})",
            )
    return written


# --------------------------------------------------------------------------- what gamma bounds
def offset_output(problem: "Phase2Problem", v_d: np.ndarray) -> np.ndarray:
    """``Q^-1 (v0(v_d) - v_d)`` (N, 3): the equilibrium offset part of z, with ``v0(v_d)`` the
    velocity of the scheduled equilibrium (multilinear weights of the vertex ``x0``, Eq. 21)."""
    from lpv_sysid.models.lpv import multilinear_weights

    vi = list(VELOCITY_INDEX)
    v0 = np.array(
        [
            multilinear_weights(np.asarray(vd, dtype=float), problem.vmin, problem.vmax)[0]
            @ problem.x0[:, vi]
            for vd in np.asarray(v_d, dtype=float)
        ]
    )
    return np.linalg.solve(np.asarray(problem.Q, dtype=float), (v0 - v_d).T).T


def gain_decomposition(
    t: np.ndarray,
    z: np.ndarray,
    ue: np.ndarray,
    z_offset: np.ndarray,
    z_e: Optional[np.ndarray],
    method: str,
    **info,
) -> dict:
    """Norms of the parts of ``z`` (module docstring) and their ratios to ``||kappa u_e||_2``:
    ``excitation`` (``z_e``; its ratio is the gain gamma bounds), ``offset``, ``tracking`` =
    ``z - z_offset - z_e`` and ``total``.  The norms are not additive (the parts overlap in time)."""
    ue_norm = l2_norm(t, ue)

    def part(y):
        n = l2_norm(t, y)
        return {"z_norm": float(n), "ratio": float(n / ue_norm) if ue_norm > 0 else None}

    out = {"method": method, "ue_norm": float(ue_norm), "total": part(z), "offset": part(z_offset)}
    if z_e is None:
        out["excitation"] = {"z_norm": None, "gain": None}
        out["tracking_and_excitation"] = part(z - z_offset)
    else:
        ex = part(z_e)
        out["excitation"] = {"z_norm": ex["z_norm"], "gain": ex["ratio"]}
        out["tracking"] = part(z - z_offset - z_e)
    out.update(info)
    return out


def excitation_response_fir(
    t: np.ndarray,
    z: np.ndarray,
    ue: np.ndarray,
    f_cut: float = 0.3,
    lags_s: float = 1.0,
    fs: float = 50.0,
    ridge: float = 1e-6,
) -> tuple[np.ndarray, dict]:
    """The part of ``z`` driven by ``u_e`` on a flight without an unexcited twin (seed 0
    Eqs. 26-29 by regression): a causal FIR ``u_e -> z`` (lags 0..``lags_s``) fitted by least
    squares on the zero-phase high-passed (``f_cut``, below the excitation band, above most of
    the reference band: the slow tracking error is not the response to ``u_e``; LTI filters
    commute, so the FIR is unchanged) and decimated (``fs``) signals, then applied to the
    unfiltered ``u_e`` on the original grid.  Returns ``(z_e (N, 3), info)``; ``info.fit_r2`` is
    the share of the high-passed ``z`` it explains."""
    from scipy.signal import butter, sosfiltfilt

    t = np.asarray(t, dtype=float)
    if t.size < 10:
        raise ConfigError(f"FIR excitation response: {t.size} samples are too few")
    dt = float(np.median(np.diff(t)))
    tg = np.arange(t[0], t[-1], 1.0 / fs)
    sos_aa = butter(4, 0.4 * fs, fs=1.0 / dt, output="sos") if 1.0 / dt > 1.25 * fs else None

    def on_grid(y):
        y = sosfiltfilt(sos_aa, y, axis=0) if sos_aa is not None and y.shape[0] > 30 else y
        return np.column_stack([np.interp(tg, t, y[:, k]) for k in range(y.shape[1])])

    zg, ug = on_grid(np.asarray(z, dtype=float)), on_grid(np.asarray(ue, dtype=float))
    n, ne = ug.shape
    L = max(1, int(round(lags_s * fs)))
    if n < 4 * L * ne:
        raise ConfigError(
            f"FIR excitation response: {n} samples at {fs:g} Hz too few for {L} lags x {ne} inputs"
        )
    sos = butter(4, f_cut, btype="highpass", fs=fs, output="sos")
    zh, uh = sosfiltfilt(sos, zg, axis=0), sosfiltfilt(sos, ug, axis=0)

    def lagged(u, m):
        H = np.zeros((m, ne * L))
        for lag in range(L):
            H[lag:, lag * ne : (lag + 1) * ne] = u[: m - lag]
        return H

    H = lagged(uh, n)
    G = H.T @ H
    theta = np.linalg.solve(G + ridge * np.trace(G) / G.shape[0] * np.eye(G.shape[0]), H.T @ zh)
    res = zh - H @ theta
    r2 = 1.0 - float((res**2).sum()) / max(float((zh**2).sum()), 1e-300)
    # the FIR on the original grid: u_e resampled at fs is exact for its band (<= 5 Hz < fs / 2)
    ze_g = lagged(ug, n) @ theta
    z_e = np.column_stack([np.interp(t, tg, ze_g[:, k]) for k in range(ze_g.shape[1])])
    return z_e, {
        "fit_r2": float(r2),
        "f_cut_hz": float(f_cut),
        "lags_s": float(lags_s),
        "fs_hz": float(fs),
    }


def decompose_eq33(
    problem: "Phase2Problem",
    signals: ReferenceSignals,
    res: ClosedLoopResult,
    cfg: "Phase2Config",
    law=None,
    moving_equilibrium: bool = True,
) -> dict:
    """:func:`gain_decomposition` of an Eq. (33) run by exact superposition (the model is
    linear in the excitation).  With the moving equilibrium and the Eq. (31) law, started at
    ``x0(v_d(0))``, the unexcited solution is ``x0(v_d(t))`` itself (the ``x0'`` term of Eq. 34
    carries it), so ``z - z_offset`` is ``z_e`` and there is no tracking part; otherwise (the
    feedforward law without ``x0'``) the same closed loop with ``-u_e`` gives
    ``z(+) - z(-) = 2 z_e``."""
    z_off = offset_output(problem, res.v_d)
    if moving_equilibrium and law is None:
        return gain_decomposition(
            res.t,
            res.z,
            res.ue,
            z_off,
            res.z - z_off,
            "superposition (exact: the unexcited Eq. 33 run stays at x0(v_d))",
        )
    mirrored = ReferenceSignals(signals.t, signals.v_d, -signals.u_e)
    kw = {} if law is None else {"law": law}
    neg = simulate_eq33(
        problem.scheduled(),
        mirrored,
        problem.R,
        problem.Q,
        problem.gamma,
        ClosedLoopConfig(kappa=cfg.kappa, method=cfg.eq33_method),
        moving_equilibrium=moving_equilibrium,
        **kw,
    )
    z_e = 0.5 * (res.z - neg.z)
    return gain_decomposition(
        res.t, res.z, res.ue, z_off, z_e, "superposition (exact: the same run with -u_e)"
    )


# --------------------------------------------------------------------------- superposition estimate
def excitation_gain_by_superposition(
    make_vehicle: Callable[[], Any],
    make_law: Callable[[], ControlLaw],
    signals: ReferenceSignals,
    Q: np.ndarray,
    vmin: Sequence[float],
    vmax: Sequence[float],
    kappa: float,
    box_margin: float = 1.0,
    max_tilt: float = math.radians(60.0),
    arrays: bool = False,
) -> dict:
    """Excitation-attributable gain on the nonlinear quadrotor.

    On the nonlinear vehicle z = Q^-1 (v - v_d) also contains the lag in following v_d, which
    Eq. (33) removes through x0' and Lemma 1 does not bound. Two flights with identical sensor
    noise (fresh vehicles from ``make_vehicle``, same seed, no recording), one with kappa u_e and
    one with u_e = 0, give z_e = z_excited - z_reference, the response to the excitation
    (exact for a linear plant, first-order for the nonlinear one); the returned
    ``gain = ||z_e||_2 / ||kappa u_e||_2`` is comparable with gamma. ``make_law`` must return a
    fresh law each call (the runtime law has state); pass one without a tripping bound monitor.
    ``arrays``: also return ``t``, ``z_e`` and ``z_reference`` (not for summary.yaml).
    """
    quiet = ReferenceSignals(signals.t, signals.v_d, np.zeros_like(signals.u_e))
    runs = [
        simulate_nonlinear(
            make_vehicle(),
            make_law(),
            sig,
            Q,
            vmin,
            vmax,
            kappa=k,
            box_margin=box_margin,
            max_tilt=max_tilt,
        )
        for sig, k in ((signals, kappa), (quiet, 1.0))
    ]
    exc, ref = runs
    n = min(exc.t.size, ref.t.size)
    t = exc.t[:n]
    z_e = exc.z[:n] - ref.z[:n]
    ue_norm = l2_norm(t, exc.ue[:n])
    out = {
        "gain": float(l2_norm(t, z_e) / ue_norm) if ue_norm > 0 else None,
        "z_norm": float(l2_norm(t, z_e)),
        "ue_norm": float(ue_norm),
        "duration": float(t[-1] - t[0]),
        "reference_only_z_norm": float(l2_norm(t, ref.z[:n])),
        "complete": bool(exc.completed and ref.completed),
    }
    events = [
        f"{name}: {r.safety_event}"
        for name, r in (("excited", exc), ("reference only", ref))
        if r.safety_event
    ]
    if events:
        out["safety_events"] = events
    if arrays:
        out.update(t=t, z_e=z_e, z_reference=ref.z[:n])
    return out


# --------------------------------------------------------------------------- the whole run
@dataclass
class Phase2Problem:
    """What phase 2 flies: vertex gains/equilibria (gains.yaml), weights R, Q, the design gamma,
    and optionally the nominal vertex models (vertex_models.yaml) for Eq. (33)."""

    vmin: np.ndarray
    vmax: np.ndarray
    K: np.ndarray  # (N, n_u, n_x), Eq. (31)
    x0: np.ndarray  # (N, n_x)
    u0: np.ndarray  # (N, n_u)
    R: np.ndarray  # (n_u, n_e), Eq. (27)
    Q: np.ndarray  # (3, 3), Eq. (28)
    gamma: Optional[float]
    A: Optional[np.ndarray] = None  # (N, n_x, n_x) nominal vertex models (theta0)
    B: Optional[np.ndarray] = None  # (N, n_x, n_u)
    source: dict = field(default_factory=dict)
    F_ff: Optional[np.ndarray] = None  # (N, n_free + n_u, 3) reference feedforward (gains.yaml)
    F_jerk: Optional[np.ndarray] = None  # (N, n_free + n_u + n_rate, 3) its jerk term
    feedforward: Any = None  # its layout (io.formats.FeedforwardSpec), None: no feedforward
    state_names: tuple = ()

    def scheduled(self):
        """ScheduledLpv of the nominal model with the gains' equilibria (Eq. 33 inputs)."""
        from lpv_sysid.models.lpv import PolytopicModel, ScheduledLpv

        if self.A is None or self.B is None:
            raise ConfigError("Eq. (33) needs the vertex models (--models vertex_models.yaml)")
        pm = PolytopicModel(
            vmin=self.vmin, vmax=self.vmax, A=self.A, B=self.B, x0=self.x0, u0=self.u0
        )
        return ScheduledLpv(pm, self.K)


def load_problem(
    gains_path: str | Path, models_path: Optional[str | Path] = None
) -> Phase2Problem:
    """Phase2Problem from ``gains.yaml`` (+ ``vertex_models.yaml``), validated by
    :mod:`lpv_sysid.io.formats`: with a models file the gains must match it (names, box,
    vertex equilibria and the certificate's SHA-256 of the models file)."""
    from lpv_sysid.io.formats import GainSchedule, VertexModels

    gains_path = Path(gains_path)
    if not os.path.lexists(gains_path):
        raise ConfigError(f"--gains: {gains_path} not found")
    if models_path is not None and not os.path.lexists(models_path):
        raise ConfigError(f"--models: {models_path} not found")
    gs = GainSchedule.load(gains_path, models_path)
    source = {"gains": gains_path}
    A = B = None
    if models_path is not None:
        vm = VertexModels.load(models_path)
        source["models"] = Path(models_path)
        if vm.ts is None:
            A, B = vm.A, vm.B
        else:
            log.warning(
                "%s: discrete-time models (Ts=%g); Eq. (33) is continuous, skipped",
                models_path,
                vm.ts,
            )
    return Phase2Problem(
        vmin=np.asarray(gs.scheduling.min, dtype=float),
        vmax=np.asarray(gs.scheduling.max, dtype=float),
        K=gs.K,
        x0=gs.x0,
        u0=gs.u0,
        R=np.asarray(gs.R, dtype=float),
        Q=np.asarray(gs.Q, dtype=float),
        gamma=float(gs.gamma),
        A=A,
        B=B,
        source=source,
        F_ff=gs.F_ff,
        F_jerk=gs.F_jerk,
        feedforward=gs.feedforward,
        state_names=tuple(gs.state_names),
    )


def reference_acceleration(
    signals: ReferenceSignals,
) -> Callable[[float], tuple[np.ndarray, np.ndarray]]:
    """(a, j)(t) = (dv_d/dt, d2v_d/dt2) of the reference table for the feedforward: second-order
    central differences of the samples (np.gradient, applied twice; one-sided at the ends),
    linearly interpolated. For the phase-2 multisine (<= 0.5 Hz sampled at 50 Hz) the relative
    error is (2 pi f dt)^2 / 6 < 7e-4 per derivative."""
    t = signals.t
    acc = np.gradient(signals.v_d, t, axis=0, edge_order=2)
    jerk = np.gradient(acc, t, axis=0, edge_order=2)
    both = np.hstack([acc, jerk])
    p = acc.shape[1]

    def aj(tk: float) -> tuple[np.ndarray, np.ndarray]:
        k = min(max(int(np.searchsorted(t, tk, side="right")) - 1, 0), t.size - 2)
        s = min(max((tk - t[k]) / (t[k + 1] - t[k]), 0.0), 1.0)
        v = (1.0 - s) * both[k] + s * both[k + 1]
        return v[:p], v[p:]

    return aj


class RuntimeLaw:
    """The onboard law of :mod:`lpv_sysid.control.lpv_controller` as a ``ControlLaw``:
    ``u = u0(v_d) + du_ff + K(v_d)(x - x0(v_d) - dx_ff) + R (kappa u_e)`` with actuator saturation
    through the mixer and the bound monitor; the feedforward (when the gains carry F_ff) uses
    ``accel(t)`` (the reference's derivative) or, without it, the law's own filtered derivative
    of v_d (as on the vehicle). ``last_info`` holds the flags of the last step; counters record
    how often the command saturated or v_d was clamped."""

    def __init__(
        self,
        problem: "Phase2Problem",
        mix: Optional[np.ndarray] = None,
        config: Any = None,
        accel: Optional[Callable[[float], tuple]] = None,
    ) -> None:
        from lpv_sysid.control.lpv_controller import LpvController, LpvControllerConfig

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
            "monitor_gain_estimate": _finite_or_none(self.ctrl.gain()),
            "feedforward": mode,
            "monitor_window_s": self.ctrl.window,
        }


def runtime_law(
    problem: "Phase2Problem",
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
    from lpv_sysid.control.lpv_controller import LpvControllerConfig

    if feedforward not in ("exact", "filtered", "off"):
        raise ConfigError(f"--feedforward must be exact, filtered or off, got {feedforward!r}")
    if feedforward == "exact" and signals is None:
        raise ConfigError("feedforward 'exact' needs the reference signals")
    cfg = LpvControllerConfig(
        monitor_margin=float(monitor_margin),
        feedforward=feedforward != "off",
        ff_filter_tau=float(ff_filter_tau),
        ff_jerk_tau=float(ff_jerk_tau),
        monitor_window=monitor_window,
    )
    accel = reference_acceleration(signals) if feedforward == "exact" else None
    return RuntimeLaw(problem, mix, cfg, accel)


def load_vehicle_config(path: Optional[str | Path], seed: Optional[int] = None):
    """(QuadrotorParams, SensorConfig) from ``config/quadrotor.yaml`` (sections quadrotor, sim)."""
    from dataclasses import replace

    from lpv_sysid.models.quadrotor import QuadrotorParams
    from lpv_sysid.sim.vehicle import SensorConfig

    if path is None:
        qp, sens = QuadrotorParams(), SensorConfig()
    else:
        from lpv_sysid.sim.phase1 import load_config

        qp, _, sens, _ = load_config(path)
    if seed is not None:
        sens = replace(sens, seed=int(seed))
    return qp, sens


@dataclass
class Phase2Result:
    records: dict[str, RunRecord]
    skipped: dict[str, str]
    written: dict[str, Path]
    summary_path: Path


def run(
    problem: Phase2Problem,
    signals: ReferenceSignals,
    cfg: Phase2Config,
    quad_params: Any,
    sensors: Any,
    out_dir: str | Path,
    law: Optional[ControlLaw] = None,
) -> Phase2Result:
    """Runs (a) and (b), writes the outputs (see module docstring) and returns them."""
    from lpv_sysid.models.quadrotor import Quadrotor
    from lpv_sysid.sim.vehicle import SimVehicle

    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"--out: cannot create {out} ({exc.strerror})") from None
    records: dict[str, RunRecord] = {}
    skipped: dict[str, str] = {}
    v_box = (problem.vmin, problem.vmax)
    if cfg.run_nonlinear and cfg.record_bag and (out / "bag").exists():
        raise ConfigError(f"--out: {out / 'bag'} exists; choose an empty output directory")
    outside = np.any((signals.v_d < problem.vmin - 1e-9) | (signals.v_d > problem.vmax + 1e-9))
    if outside:
        raise ConfigError(
            "signals: the reference v_d leaves the scheduling box of the gains "
            f"[{problem.vmin.tolist()}, {problem.vmax.tolist()}]"
        )
    if cfg.run_eq33:
        if problem.A is None:
            skipped["eq33"] = "no vertex models (vertex_models.yaml) to simulate Eq. (33)"
        else:
            try:
                res = simulate_eq33(
                    problem.scheduled(),
                    signals,
                    problem.R,
                    problem.Q,
                    problem.gamma,
                    ClosedLoopConfig(kappa=cfg.kappa, method=cfg.eq33_method),
                )
                records["eq33"] = record_from_eq33(res)
                records["eq33"].decomposition = decompose_eq33(problem, signals, res, cfg)
            except SafetyError as exc:
                skipped["eq33"] = f"diverged: {exc}"
            if problem.F_ff is not None and cfg.feedforward != "off":
                # linear model without the x0' term + the feedforward law (lpv_closed_loop docstring)
                from lpv_sysid.sim.lpv_closed_loop import FeedforwardSchedule, feedforward_law

                try:
                    sched = problem.scheduled()
                    names = list(problem.state_names)
                    spec = problem.feedforward
                    ffs = FeedforwardSchedule(
                        problem.vmin,
                        problem.vmax,
                        problem.F_ff,
                        [names.index(s_) for s_ in spec.free_states],
                        len(names),
                        problem.F_jerk,
                        [names.index(s_) for s_ in spec.rate_states],
                    )
                    res = simulate_eq33(
                        sched,
                        signals,
                        problem.R,
                        problem.Q,
                        problem.gamma,
                        ClosedLoopConfig(kappa=cfg.kappa, method=cfg.eq33_method),
                        law=feedforward_law(
                            sched, problem.R, ffs, reference_acceleration(signals)
                        ),
                        moving_equilibrium=False,
                    )
                    records["linear_ff"] = record_from_eq33(res, "linear_ff")
                    records["linear_ff"].decomposition = decompose_eq33(
                        problem,
                        signals,
                        res,
                        cfg,
                        feedforward_law(sched, problem.R, ffs, reference_acceleration(signals)),
                        moving_equilibrium=False,
                    )
                except SafetyError as exc:
                    skipped["linear_ff"] = f"diverged: {exc}"
    else:
        skipped["eq33"] = "not requested"
    bag_path = None
    if cfg.run_nonlinear:
        quad = Quadrotor(quad_params)
        trim = quad.trim(signals.v_d[0])
        vehicle = SimVehicle(quad, sensors, x0=trim.full_state)
        law = law or runtime_law(
            problem,
            quad.mix,
            cfg.monitor_margin,
            cfg.feedforward,
            signals,
            cfg.monitor_window,
            cfg.ff_filter_tau,
            cfg.ff_jerk_tau,
        )
        kw = dict(
            kappa=cfg.kappa,
            gamma=problem.gamma,
            box_margin=cfg.box_margin,
            max_tilt=math.radians(cfg.max_tilt_deg),
        )
        if cfg.record_bag:
            bag_path = out / "bag"
            try:
                with Phase2Bag(bag_path, cfg.storage, kappa=cfg.kappa) as bag:
                    rec = simulate_nonlinear(
                        vehicle, law, signals, problem.Q, *v_box, sink=bag, **kw
                    )
            except BagError as exc:
                # the bag is closed (readable up to the failure); keep the other results, then fail
                skipped["nonlinear"] = f"recording failed: {exc}"
                write_outputs(out, problem.gamma, cfg.kappa, list(records.values()), skipped)
                raise
            rec.info["bag"] = str(bag_path)
            rec.info["bag_messages"] = dict(bag.counts)
        else:
            rec = simulate_nonlinear(vehicle, law, signals, problem.Q, *v_box, **kw)
        z_off = offset_output(problem, rec.v_d)
        if cfg.superposition:
            # bound monitor effectively off: it would stop on the reference-tracking part of z
            sp = excitation_gain_by_superposition(
                lambda: SimVehicle(quad, sensors, x0=trim.full_state),
                lambda: runtime_law(
                    problem,
                    quad.mix,
                    1e12,
                    cfg.feedforward,
                    signals,
                    None,
                    cfg.ff_filter_tau,
                    cfg.ff_jerk_tau,
                ),
                signals,
                problem.Q,
                *v_box,
                kappa=cfg.kappa,
                box_margin=cfg.box_margin,
                max_tilt=math.radians(cfg.max_tilt_deg),
                arrays=True,
            )
            t_sp, z_e = sp.pop("t"), sp.pop("z_e")
            sp.pop("z_reference")
            rec.info["superposition"] = sp
            n = min(t_sp.size, rec.t.size)
            rec.decomposition = gain_decomposition(
                rec.t[:n],
                rec.z[:n],
                rec.ue[:n],
                z_off[:n],
                z_e[:n],
                "superposition (two more flights, with and without u_e, same sensor noise)",
            )
        elif rec.t.size >= 10:
            try:
                z_e, info = excitation_response_fir(rec.t, rec.z - z_off, rec.ue)
                rec.decomposition = gain_decomposition(
                    rec.t,
                    rec.z,
                    rec.ue,
                    z_off,
                    z_e,
                    "FIR regression of z on u_e above the reference band",
                    **info,
                )
            except ConfigError as exc:
                rec.decomposition = gain_decomposition(
                    rec.t, rec.z, rec.ue, z_off, None, f"not separated: {exc}"
                )
        records["nonlinear"] = rec
    else:
        skipped["nonlinear"] = "not requested"
    # Fig. 10 data: the nonlinear flight when it completed; else the Eq. (33) run (what the
    # seed used); else whatever part of the nonlinear flight there is.
    block = None
    nl, eq = records.get("nonlinear"), records.get("eq33")
    order = [nl, eq] if nl is not None and nl.completed else [eq, nl]
    for rec in order:
        if rec is not None and rec.t.size >= 10:
            block = regressor_correlation_block(
                rec.t, rec.x12, quad_params.arm_length, rec.name, rec.extra.get("Omega")
            )
            block["complete_run"] = bool(rec.completed)
            break
    extra = {
        "box": {"min": problem.vmin.tolist(), "max": problem.vmax.tolist()},
        "inputs": {k: str(v) for k, v in problem.source.items()},
        "signals": {
            "duration": float(signals.t[-1] - signals.t[0]),
            "samples": int(signals.t.size),
            "ramp": cfg.ramp,
        },
    }
    written = write_outputs(
        out, problem.gamma, cfg.kappa, list(records.values()), skipped, block, extra
    )
    if bag_path is not None:
        written["bag"] = bag_path
    return Phase2Result(records, skipped, written, written["summary"])
