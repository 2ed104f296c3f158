"""Phase-2 flight of the nonlinear quadrotor under the runtime LPV law (seed 0 Sec. VII, run b).

:func:`simulate_nonlinear` flies the full nonlinear model of :mod:`lpv_sysid.models.quadrotor`
(fixed-step physics and sensor model of :mod:`lpv_sysid.sim.vehicle`) under a control law fed
with the simulated *measured* state; the safety supervisor of :mod:`lpv_sysid.control.safety`
stops the run (excitation off, event reported) when the vehicle leaves the scheduling box plus a
margin, tilts beyond a limit or its state becomes non-finite; the runtime law's bound monitor
flag stops it too. Samples go to a :class:`BagSink` (the product's:
:class:`lpv_sysid.sim.phase2.bag.Phase2Bag`).
:func:`excitation_gain_by_superposition` separates the excitation response by flying with and
without u_e under identical sensor noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Optional, Protocol, Sequence, Union

import numpy as np

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import ConfigError, SafetyError
from lpv_sysid.sim.closed_loop import VELOCITY_INDEX, ControlLaw, ReferenceSignals, l2_norm
from lpv_sysid.sim.phase2.outputs import RunRecord

#: a box corner: 3 floats (or an array of them)
Corner = Union[Sequence[float], np.ndarray]


@dataclass(frozen=True)
class NonlinearConfig:
    """Loop rates of run (b). The control law runs at ``control_hz`` (zero-order hold on the
    vehicle's fixed-step physics, which must be a multiple); the signals are sampled there."""

    control_hz: float = cf.number(
        100.0, "rate of the control law", lo=0.0, lo_open=True, hi=10_000.0, unit=" Hz"
    )
    status_hz: float = cf.number(
        1.0, "rate of the status messages", lo=0.0, lo_open=True, hi=1_000.0, unit=" Hz"
    )

    def __post_init__(self) -> None:
        cf.normalize_fields(self, "phase2")


class BagSink(Protocol):
    """Where run (b) sends its samples (the product's:
    :class:`~lpv_sysid.sim.phase2.bag.Phase2Bag`)."""

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


# --------------------------------------------------------------------------- safety
def make_supervisor(vmin: Corner, vmax: Corner, margin: float):
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


def supervise(sup, t: float, controller_state: np.ndarray, max_tilt: float) -> Optional[str]:
    """Phase-2 trip conditions on the measured 12-state (latched in ``sup``).

    Non-finite state (``non_finite``); measured body velocity outside the scheduling box
    widened by the margin (``out_of_box``: the certificate of Lemma 1 only covers the box,
    Eq. 20); roll or pitch beyond ``max_tilt`` (``bound_exceeded``: Assumption 2 far from valid).
    Returns the event text once tripped, else None.
    """
    sup.on_input("state", t, controller_state, t)
    if not sup.aborted:
        sup.check_scheduling(t, np.asarray(controller_state, dtype=float)[list(VELOCITY_INDEX)])
    if not sup.aborted:
        tilt = max(abs(float(controller_state[0])), abs(float(controller_state[1])))
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


# --------------------------------------------------------------------------- the flight
def measured_controller_state(
    x16_meas: np.ndarray, Omega_meas: np.ndarray, mix: np.ndarray
) -> np.ndarray:
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
    vmin: Corner,
    vmax: Corner,
    kappa: float = 1.0,
    gamma: Optional[float] = None,
    config: NonlinearConfig = NonlinearConfig(),
    box_margin: float = 1.0,
    max_tilt: float = math.radians(60.0),
    sink: Optional[BagSink] = None,
    stop_on_bound: bool = True,
) -> RunRecord:
    """Seed 0 Sec. VII on the nonlinear quadrotor: the LPV law on measured states.

    ``vehicle`` is a :class:`lpv_sysid.sim.vehicle.SimVehicle` (fixed-step RK4 physics,
    noisy sensors) already placed at its initial state; ``law(t, controller_state, v_d,
    kappa u_e)`` returns the virtual command. Each control period: measure (estimator state +
    ESC rotor speeds), supervise, compute u, hold it over the physics steps. On a safety trip
    the excitation is switched off, a status is emitted and the run stops (on the vehicle PX4
    takes over).
    The performance output uses the true velocity: z = Q^-1 (v - v_d) (Eq. 18).
    ``stop_on_bound``: the law's bound monitor stops the run (False for the superposition
    flights, whose z holds the reference-tracking part the monitor would stop on).
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
    T: list[float] = []
    VD, X, XM, UE, U, OM = [], [], [], [], [], []  # per control sample: arrays
    event: Optional[str] = None
    for k in range(n_steps):
        t = t0 + k * dt_c
        v_d, _, ue = signals.at(t)
        x16_true = np.array(vehicle.x)
        x16_meas = vehicle.measure_state()
        Om_meas = vehicle.measure_rotors()
        measured_state = measured_controller_state(x16_meas, Om_meas, mix)
        event = supervise(sup, t, measured_state, max_tilt)
        if event is not None:
            ue = np.zeros_like(ue)
            if sink is not None:
                _abort_status(sink, t, event)
            break
        ue_s = kappa * ue
        try:
            u = np.asarray(law(t, measured_state, v_d, ue_s), dtype=float)
        except SafetyError as exc:
            u = np.full(4, np.nan)
            detail = str(exc)
        else:
            detail = f"control law returned {u.tolist()}"
        if u.shape != (4,) or not np.all(np.isfinite(u)):
            event = f"non_finite at t={t:.3f} s: {detail}"
        elif stop_on_bound and (getattr(law, "last_info", None) or {}).get("bound_exceeded"):
            gain_est = law.ctrl.gain() if hasattr(law, "ctrl") else float("nan")
            sup.on_bound_flag(
                t,
                True,
                f"bound monitor: running ||z||/||u_e|| = {gain_est:.3g} above gamma x margin",
            )
            event = supervise(sup, t, measured_state, max_tilt)
        if event is not None:
            if sink is not None:
                _abort_status(sink, t, event)
            break
        T.append(t)
        VD.append(v_d)
        X.append(measured_controller_state(x16_true, x16_true[12:16], mix))
        XM.append(measured_state)
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
                _abort_status(sink, t, event)
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
        controller_state=x_arr,
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


def _abort_status(sink: BagSink, t: float, event: str) -> None:
    sink.status(
        t,
        "ERROR",
        "safety abort: excitation off, run stopped",
        {"event": event, "excitation": "off"},
    )


# ------------------------------------------------------------------ superposition estimate
def excitation_gain_by_superposition(
    make_vehicle: Callable[[], Any],
    make_law: Callable[[], ControlLaw],
    signals: ReferenceSignals,
    Q: np.ndarray,
    vmin: Corner,
    vmax: Corner,
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
    fresh law each call (the runtime law has state); its bound monitor does not stop these
    flights (``stop_on_bound=False``: z holds the tracking part as well).
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
            stop_on_bound=False,
        )
        for sig, k in ((signals, kappa), (quiet, 1.0))
    ]
    exc, ref = runs
    n = min(exc.t.size, ref.t.size)
    t = exc.t[:n]
    z_e = exc.z[:n] - ref.z[:n]
    ue_norm = l2_norm(t, exc.ue[:n])
    out: dict[str, Any] = {
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
