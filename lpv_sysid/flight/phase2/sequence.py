"""Step 5 of the PX4 chain (:mod:`lpv_sysid.flight.chain`, also `lpv-sysid fly phase2`): the
phase-2 signal flown under the LPV law on a PX4 vehicle that is armed and in the air.

One flight path with the ROS graph of ``phase2.launch.py``: :func:`phase2_graph` builds the
phase-2 nodes' runtimes in process -- :class:`~lpv_sysid.flight.controller.ControllerRuntime`
from ``config/lpv_controller_px4.yaml`` (every start-up check of ``lpv_controller_node``: law
hash, sidecar stability, design envelope, the signal inside the box, kappa within the designed
excitation peak; at run time its safety supervisor, reference limiter and bound monitor) and
:class:`~lpv_sysid.flight.excitation.ExcitationRuntime` (the signal against the gains' design,
fades, abort on the controller's status) -- and :func:`fly_phase2` hands them the messages the
graph would carry: the bridge's telemetry as ``state``, the excitation node's
``velocity_reference`` / ``excitation``, the controller's ``actuator_command`` (thrust +
body-rate setpoints) to :class:`~lpv_sysid.mavlink.bridge.BridgeCore` (SET_ATTITUDE_TARGET,
envelope, hand-back). Everything is recorded as the data logger would (state, imu,
rotor_speeds, status, velocity_reference, excitation, actuator_command = the setpoints sent,
rate_setpoint = PX4's ATTITUDE_TARGET echo). :func:`save_summary` writes the YAML summaries;
the flown log is analysed by :func:`lpv_sysid.flight.phase2.analysis.analyse_phase2` and
:func:`~lpv_sysid.flight.phase2.analysis.loop_latency`.
"""

from __future__ import annotations

import dataclasses
import logging
import signal
import threading
import time
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np

from lpv_sysid.configuration.defaults import config_file
from lpv_sysid.errors import ConfigError
from lpv_sysid.flight.phase2.analysis import analyse_phase2, latency_from_bag
from lpv_sysid.flight.phase2.options import Phase2Options

log = logging.getLogger(__name__)


#: node names of the in-process graph (status names, as under ``ros2 launch``)
CONTROLLER_NAME = "/lpv_sysid/lpv_controller"
EXCITATION_NAME = "/lpv_sysid/excitation"
BRIDGE_NAME = "/lpv_sysid/mavlink_bridge"


@dataclasses.dataclass
class Phase2Graph:
    """The phase-2 nodes' runtimes, in process: :class:`ExcitationRuntime` (phase-2 mode, the
    signal checked against the gains' design envelope), :class:`ControllerRuntime` (every
    start-up check of ``lpv_controller_node``: law hash, sidecar stability, design envelope,
    the signal inside the box and kappa within the designed excitation peak; at run time its
    safety supervisor and bound monitor)."""

    controller: Any
    excitation: Any
    factory: Any


def phase2_graph(
    gains: str | Path,
    signals: str | Path,
    models: str | Path | None = None,
    opts: Phase2Options = Phase2Options(),
    controller_config: str | Path | None = None,
    excitation_config: str | Path | None = None,
) -> Phase2Graph:
    """Build the runtimes of :class:`Phase2Graph` from the shipped node parameter files
    (``config/lpv_controller_px4.yaml``, ``config/excitation_node.yaml``) with the flight's
    files and options; ConfigError (the node's own words) when anything is refused. Nothing
    talks to a vehicle here."""
    from lpv_sysid.configuration.parameters import yaml_parameters
    from lpv_sysid.flight.controller import ControllerRuntime, ControllerSettings
    from lpv_sysid.flight.excitation import ExcitationRuntime, ExcitationSettings
    from lpv_sysid.io.messages import MsgFactory
    from lpv_sysid.models import rate_plant as rp

    opts.validate()
    sig = Path(signals)
    npz = sig / "signals.npz" if sig.is_dir() else sig
    factory = MsgFactory.rosbags()
    cp = yaml_parameters(
        str(controller_config or config_file("lpv_controller_px4.yaml")), "lpv_controller"
    )
    cp.update(
        gains_file=str(gains),
        models_file=str(models or ""),
        signals_file=str(npz),
        excitation_gain=float(opts.kappa),
    )
    ctrl = ControllerRuntime(ControllerSettings.from_dict(cp), factory, CONTROLLER_NAME)
    if ctrl.design != rp.DESIGN:
        raise ConfigError(
            f"{gains}: a {ctrl.design} design cannot be flown through SET_ATTITUDE_TARGET rate "
            f"setpoints; phase 2 on PX4 flies the rate plant ({rp.DESIGN_TEXT})"
        )
    ep = yaml_parameters(
        str(excitation_config or config_file("excitation_node.yaml")), "excitation"
    )
    ep.update(
        mode="phase2",
        signals_file=str(npz),
        gains_file=str(gains),
        rate_hz=float(opts.control_rate_hz),
        ramp_s=float(opts.ramp_s),
        start_delay_s=float(opts.lead_in_s),
        duration_s=float(opts.duration or 0.0),
        auto_start=False,
    )
    exc = ExcitationRuntime(ExcitationSettings.from_dict(ep), factory, EXCITATION_NAME)
    return Phase2Graph(ctrl, exc, factory)


def controller_loop_delay_s(
    gains: str | Path, controller_config: str | Path | None = None
) -> float:
    """The configured loop delay [s] of the controller phase 2 flies
    (:attr:`ControllerSettings.loop_delay_s` of ``config/lpv_controller_px4.yaml`` or
    ``controller_config``): what its start-up check holds against the certificate's
    ``loop_delay.bound_s``, and what ``verify`` checks (``loop config``) for the chain."""
    from lpv_sysid.configuration.parameters import yaml_parameters
    from lpv_sysid.flight.controller import ControllerSettings

    cp = yaml_parameters(
        str(controller_config or config_file("lpv_controller_px4.yaml")), "lpv_controller"
    )
    cp.update(gains_file=str(gains))
    return ControllerSettings.from_dict(cp).loop_delay_s


def load_phase2_law(gains_path: str | Path, models_path: str | Path | None = None):
    """(LpvController, GainSchedule) of a rate-plant gains file after every start-up check of
    ``lpv_controller_node`` (:class:`lpv_sysid.flight.controller.ControllerRuntime`)."""
    from lpv_sysid.configuration.parameters import yaml_parameters
    from lpv_sysid.flight.controller import ControllerRuntime, ControllerSettings
    from lpv_sysid.io.messages import MsgFactory
    from lpv_sysid.models import rate_plant as rp

    cp = yaml_parameters(str(config_file("lpv_controller_px4.yaml")), "lpv_controller")
    cp.update(gains_file=str(gains_path), models_file=str(models_path or ""))
    rt = ControllerRuntime(ControllerSettings.from_dict(cp), MsgFactory.rosbags())
    if rt.design != rp.DESIGN:
        raise ConfigError(
            f"{gains_path}: states {list(rt.schedule.state_names)} / inputs "
            f"{list(rt.schedule.input_names)} are not the rate plant's {list(rp.STATE_NAMES)} / "
            f"{list(rp.INPUT_NAMES)} (a virtual-actuator design cannot be flown through "
            "SET_ATTITUDE_TARGET rate setpoints)"
        )
    return rt.law, rt.schedule


def fly_phase2(
    gains: str | Path,
    signals: str | Path,
    out_dir: str | Path,
    url: str | None = None,
    models: str | Path | None = None,
    bridge_config: str | Path | None = None,
    opts: Phase2Options = Phase2Options(),
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    echo: Callable[[str], None] = log.info,
    link=None,
    handle_signals: bool = True,
    storage: str = "mcap",
    confirm: Callable[[str], bool] | None = None,
    epoch_ns: int | None = None,
) -> dict:
    """Fly the phase-2 signal under the LPV law on a PX4 vehicle that is armed and in the air
    (module docstring step 5); returns the summary (also ``DIR/phase2_summary.yaml``).

    The law is :class:`~lpv_sysid.flight.controller.ControllerRuntime` and the signal
    :class:`~lpv_sysid.flight.excitation.ExcitationRuntime`, fed the messages the ROS graph
    would carry (:func:`phase2_graph`): every file the controller node refuses is refused here,
    with its words, before the link is opened. ``confirm(question)``: asked after those checks,
    before the link is opened (False: ``{"ok": False, "confirmed": False}``, nothing sent; None:
    no question, ``fly --yes``). Raises SafetyError before sending anything when the vehicle is
    not airborne.

    Time and provenance (as ``fly phase1``): every stamp is wall-clock (epoch) ns -- the
    flight runs on ``clock() + offset``, the offset taken once at start from
    ``time.time_ns()`` (or from ``epoch_ns``, a declared epoch for a simulated clock) and
    written to ``experiment.yaml`` (``clock``); ``experiment.yaml`` also gets ``vehicle``
    (:class:`~lpv_sysid.mavlink.telemetry.VehicleRecord`: kind SIMULATED / SITL / HITL / SIH /
    FLOWN, firmware, airframe, the PX4 parameter snapshot, battery, site, PX4's boot on the
    bag clock: a ULog of the flight lines up with the bag through ``vehicle.px4_clock``)."""
    from lpv_sysid.flight.campaign import CampaignRecorder
    from lpv_sysid.flight.vehicle import (
        request_parameter_list,
        tap_attitude_target,
        tap_messages,
        wait_airborne,
        wait_for_vehicle,
    )
    from lpv_sysid.mavlink.telemetry import VehicleRecord
    from lpv_sysid.io import messages as m
    from lpv_sysid.mavlink.bridge import BridgeConfig, BridgeCore, RateSetpointTransport
    from lpv_sysid.mavlink.offboard import STREAMING, State
    from lpv_sysid.mavlink.telemetry import ImuSample, RotorSample, StateSample

    opts.validate()
    out = Path(out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError(f"output directory {out}: exists and is not an empty directory")
    graph = phase2_graph(gains, signals, models, opts)  # every start-up check, nothing sent
    ctrl, exc, f = graph.controller, graph.excitation, graph.factory
    for level, line in ctrl.take_log():
        echo(f"controller: {line}")
    names = tuple(ctrl.schedule.input_names)
    gamma = float(ctrl.law.gamma)
    T = float(exc.core.duration)
    bcfg = BridgeConfig.load(
        str(bridge_config or config_file("mavlink_bridge_chain.yaml"))
    ).airborne_rates(url)
    if confirm is not None and not confirm(
        f"take the airborne vehicle on {bcfg.link.url} into OFFBOARD under the LPV law "
        f"({gains}) and fly the phase-2 signal?"
    ):
        return {"ok": False, "confirmed": False, "reason": "not confirmed: nothing sent"}
    clock_offset_ns = (time.time_ns() if epoch_ns is None else int(epoch_ns)) - round(
        clock() * 1e9
    )
    clock = epoch_clock(clock, clock_offset_ns)
    core = BridgeCore(bcfg, link=link)
    core.transport = RateSetpointTransport(max_rate=opts.max_rate)  # the law's inputs as sent
    core.open(clock())
    vehicle = VehicleRecord()
    tap_messages(core.link, lambda now, msg: vehicle.absorb(msg, round(now * 1e9)))
    rec_box: list = [None]
    px4_sp: list = []

    def on_echo(t: float, u) -> None:  # PX4's ATTITUDE_TARGET: the setpoints it is tracking
        px4_sp.append((t, np.asarray(u, float).copy()))
        if rec_box[0] is not None:
            rec_box[0].rate_setpoint(t, u)

    tap_attitude_target(core.link, on_echo)
    interrupts = [0]
    prev_handlers: dict = {}
    summary: dict = {
        "design": "rate_plant",
        "gains": str(gains),
        "signals": str(signals),
        "connect": bcfg.link.url,
        "gamma": gamma,
        "kappa": opts.kappa,
        "signal_duration_s": T,
    }
    log_rows: dict[str, list] = {
        k: [] for k in ("t", "x", "v_d", "u_e", "u", "sent", "tsig", "t_state")
    }
    rec = None
    state: Optional[StateSample] = None
    reason, ok = "", False
    live = [True]  # the controller is fed until the flight loop ends (then hand-back only)
    t0 = clock()

    def record(topic: str, t: float, msg) -> None:
        if rec is not None:
            rec.message(topic, t, msg)

    def poll(now):
        """Poll the link: telemetry recorded (and the state handed to the controller)."""
        nonlocal state
        o = core.poll(now)
        outs: list = []
        for smp in o.samples:
            stamp = round(smp.t * 1e9)
            if isinstance(smp, StateSample):
                state = smp
                msg = m.odometry_from_state(
                    f, stamp, smp.pos_ned, smp.euler, smp.v_body, smp.omega
                )
                record("state", now, msg)
                if live[0]:
                    outs += ctrl.on_input("state", msg, now)
            elif isinstance(smp, ImuSample):
                record("imu", now, m.imu_msg(f, stamp, smp.accel_frd, smp.gyro_frd))
            elif isinstance(smp, RotorSample):
                record("rotor_speeds", now, m.rotor_speeds_msg(f, stamp, smp.omega, smp.source))
        if o.events:
            lines = []
            level = "OK"
            for ev in o.events:
                text = (
                    getattr(ev, "reason", None)
                    or f"{getattr(ev, 'kind', '')}: {getattr(ev, 'detail', '')}"
                )
                lvl = getattr(ev, "level", "warn")
                if lvl in ("warn", "error"):
                    level = "ERROR" if lvl == "error" or level == "ERROR" else "WARN"
                lines.append(text)
                if lvl != "info" or getattr(ev, "previous", None) != getattr(ev, "state", None):
                    echo(f"[{now - t0:8.2f} s] bridge: {text}")
            st = m.diagnostic_status(f, level, BRIDGE_NAME, lines[-1], core.status(now))
            record("status", now, m.diagnostic_array(f, round(now * 1e9), [st]))
        return outs

    try:
        if handle_signals and threading.current_thread() is threading.main_thread():
            for sgn in (signal.SIGINT, signal.SIGTERM):
                prev_handlers[sgn] = signal.signal(
                    sgn, lambda *_: interrupts.__setitem__(0, interrupts[0] + 1)
                )
        wait_for_vehicle(core.link, 15.0, clock, sleep)
        # the vehicle record of experiment.yaml: PX4's parameter snapshot and its firmware
        request_parameter_list(core.link)
        core.link.command_long(512, 148.0)  # MAV_CMD_REQUEST_MESSAGE AUTOPILOT_VERSION
        # telemetry + HOME_POSITION (the envelope's home when started armed)
        state, height = wait_airborne(
            core, poll, lambda: state, clock, sleep, "phase 2", opts.min_height
        )
        tw = clock()  # OFFBOARD's start-timeout origin, reset when the bridge starts
        mode = core.machine.vehicle_mode
        echo(
            f"phase 2: vehicle armed at {height:.1f} m, mode "
            f"{mode.name if mode is not None else 'unknown'}; "
            f"signal {T:.1f} s, kappa {opts.kappa:g}, gamma {gamma:.4g}, design rate_plant"
        )
        rec = CampaignRecorder(
            out,
            storage,
            False,
            description=f"lpv-sysid phase 2 (rate plant) on {bcfg.link.url}",
            rate_setpoints=True,
        )
        rec_box[0] = rec
        rec.start(clock())
        rec.annotate(
            "clock",
            {
                "kind": "utc" if epoch_ns is None else "declared",
                "offset_ns": clock_offset_ns,
                "meaning": "bag stamp = round(flight clock [s] * 1e9) + offset_ns; the flight "
                "clock is time.monotonic (fly) or the simulation's",
            },
        )
        rec.begin_run("phase2")
        exc_period = 1.0 / exc.settings.rate_hz
        ctrl_period = 1.0 / ctrl.settings.rate_hz
        status_period = 1.0 / ctrl.settings.status_rate_hz
        next_exc = next_ctrl = next_status = clock()
        t_active = None
        bridge_started = False
        while True:
            now = clock()
            outs = poll(now)
            st = core.machine.state
            if interrupts[0]:
                reason = "interrupted"
                break
            if bridge_started and st not in STREAMING:
                reason = f"bridge left offboard ({st.value}): {core.machine.reason}"
                break
            if st == State.OFFBOARD_ACTIVE and t_active is None:
                t_active = now
                started, why = exc.start(round(now * 1e9))
                echo(
                    f"[{now - t0:8.2f} s] phase 2: OFFBOARD active, law in control; {why} "
                    f"(after {opts.lead_in_s:g} s lead-in)"
                )
            if not bridge_started and now - t0 > opts.start_timeout + 10.0:
                reason = "OFFBOARD not confirmed"
                break
            if t_active is None and bridge_started and now - tw > opts.start_timeout:
                reason = f"OFFBOARD not confirmed within {opts.start_timeout:g} s"
                break
            if now >= next_exc:  # the excitation node's timer
                next_exc = max(next_exc + exc_period, now)
                for topic, msg in exc.on_timer(round(now * 1e9)):
                    record(topic, now, msg)
                    if topic in ("velocity_reference", "excitation"):
                        outs += ctrl.on_input(topic, msg, now)
            if not ctrl.supervisor.armed and not ctrl.supervisor.aborted:
                ctrl.start(now, wait_for_inputs=True)  # once every input stream has arrived
            if now >= next_ctrl:  # the controller's rate_hz timer (staleness watch)
                next_ctrl = max(next_ctrl + ctrl_period, now)
                outs += ctrl.on_timer(now)
            if now >= next_status:
                next_status = max(next_status + status_period, now)
                outs.append(("status", ctrl.status(now)))
            for level, line in ctrl.take_log():
                echo(f"[{now - t0:8.2f} s] controller: {line}")
            aborted = False
            for topic, msg in outs:
                if topic == "status":
                    record(topic, now, msg)
                    for o2 in exc.on_status(msg, round(now * 1e9)):
                        record(o2[0], now, o2[1])
                    continue
                t_cmd, u = m.channels_from_joint_state(msg, names, field="position")
                sent = core.transport.clip(u)
                t_send = clock()  # logged: the bag's actuator_command log time - its stamp
                core.on_actuator_command(t_send, u, stamp=t_cmd)  # is the loop's latency
                record(topic, t_send, msg)
                if not bridge_started:
                    core.start(now)
                    bridge_started = True
                    tw = now
                x = np.asarray(ctrl.body_state, float)
                v_d = np.asarray(ctrl.reference_at(t_cmd), float)
                tsig = (now - exc.core.start_time) if t_active is not None else -1.0
                ue = ctrl._ue_scaled if tsig >= 0 else None
                for key, val in (
                    ("t", now),
                    ("x", x),
                    ("v_d", v_d),
                    ("u_e", np.zeros(len(names)) if ue is None else np.asarray(ue, float)),
                    ("u", u),
                    ("sent", sent),
                    ("tsig", tsig if tsig <= T else -1.0),
                    ("t_state", t_cmd),
                ):
                    log_rows[key].append(val)
                err = np.abs(x[2:5] - v_d)
                if t_active is not None and err.max() > opts.max_tracking_error:
                    reason = (
                        f"tracking error {err.max():.2f} m/s > {opts.max_tracking_error:g} m/s "
                        f"(axis {'uvw'[int(err.argmax())]}) -> hand back"
                    )
                    aborted = True
                    break
            ev = ctrl.supervisor.event
            if ev is not None:
                reason = f"lpv_controller safety abort: {ev.reason}: {ev.detail}"
                break
            if aborted:
                break
            if t_active is not None and exc.started and now >= exc.core.end_time:
                ok = True
                break
            sleep(0.002)
        # hand back: finish mode after a complete signal, the abort chain otherwise
        live[0] = False
        now = clock()
        if not ok:
            for o2 in exc.abort(round(now * 1e9), reason or "phase 2 ended"):
                record(o2[0], now, o2[1])
        if core.machine.state in STREAMING:
            if ok:
                core.finish(now, opts.finish.upper())
                echo(
                    f"[{now - t0:8.2f} s] phase 2: signal complete; hand-back to "
                    f"{opts.finish.upper()}"
                )
            else:
                core.abort(now, reason)
                echo(f"[{now - t0:8.2f} s] phase 2: ABORT: {reason}")
        th = clock()
        while (
            core.machine.state in STREAMING + (State.HANDBACK,)
            and clock() - th < opts.handback_timeout
        ):
            poll(clock())
            sleep(0.005)
        hb = core.machine.state
        summary["handback"] = {
            "state": hb.value,
            "reason": core.machine.reason,
            "mode": core.machine.vehicle_mode.name if core.machine.vehicle_mode else None,
            "duration_s": round(clock() - th, 3),
        }
        echo(f"phase 2: hand-back {hb.value}: {core.machine.reason}")
        if hb != State.DONE:
            ok = False
            reason = reason or f"hand-back ended {hb.value}: {core.machine.reason}"
    except BaseException:
        # any fault inside the flight: hand back at once and wait (bounded) for the confirmation
        if core.machine.state in STREAMING:
            core.shutdown(clock())
            th = clock()
            while core.machine.state == State.HANDBACK and clock() - th < opts.handback_timeout:
                poll(clock())
                sleep(0.005)
        raise
    finally:
        for sgn, h in prev_handlers.items():
            signal.signal(sgn, h)
        if core.machine.state in STREAMING:
            core.shutdown(clock())
        if rec is not None:
            rec.end_run()
            rec.annotate("vehicle", vehicle.summary())
            summary["recording_errors"] = rec.close(clock())
        core.close()
    summary["ok"] = bool(ok)
    summary["reason"] = reason or "signal complete"
    box = ctrl.schedule.scheduling
    # what the report draws on the time histories (phase2_log.npz): the limits of this flight
    summary["limits"] = {
        "box_min": [float(x) for x in box.min],
        "box_max": [float(x) for x in box.max],
        "max_tracking_error_m_s": float(opts.max_tracking_error),
        "min_height_m": float(opts.min_height),
        "thrust": [float(core.transport.thrust_min), float(core.transport.thrust_max)],
        "max_rate_rad_s": float(core.transport.max_rate),
        "input_names": list(names),
    }
    summary["envelope"] = core.envelope.status()
    summary["controller"] = {
        "commands": ctrl.commands,
        "abort": (
            f"{ctrl.supervisor.event.reason}: {ctrl.supervisor.event.detail}"
            if ctrl.supervisor.event is not None
            else None
        ),
        "gain_estimate": float(ctrl.law.gain()),
        **{f"{k}_count": v for k, v in ctrl.flags.items()},
    }
    arr = {k: np.asarray(v, dtype=float) for k, v in log_rows.items()}
    if px4_sp:
        arr["px4_t"] = np.array([p[0] for p in px4_sp])
        arr["px4_sp"] = np.array([p[1] for p in px4_sp])
    if len(arr["t"]):
        np.savez(out / "phase2_log.npz", **arr)
        summary.update(analyse_phase2(arr, ctrl.schedule, gamma, opts))
    if rec is not None and "phase2" in rec.bags:  # from the recorded stamps, as for the ROS graph
        summary["bag"] = rec.bags["phase2"]
        summary["latency_state_to_setpoint_ms"] = latency_from_bag(out / rec.bags["phase2"])
    save_summary(out / "phase2_summary.yaml", summary)
    return summary


def epoch_clock(clock: Callable[[], float], offset_ns: int) -> Callable[[], float]:
    """``clock`` shifted to the epoch: ``clock() + offset_ns * 1e-9`` (s). A float at ~1.8e9 s
    resolves 0.24 us, far below the 1 ms of the stamps' sources (MAVLink ``time_boot_ms``)."""
    off = offset_ns * 1e-9
    return lambda: clock() + off


def save_summary(path: Path, d: dict) -> None:
    """``d`` as YAML at ``path`` (numpy values made plain, parents created)."""
    import yaml

    from lpv_sysid.flight.campaign.outputs import _plain

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(_plain(d), sort_keys=False))
