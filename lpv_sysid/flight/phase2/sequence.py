"""Step 5 of the PX4 chain (:mod:`lpv_sysid.flight.chain`, also `lpv-sysid fly phase2`): the
phase-2 signal flown under the LPV law on a PX4 vehicle that is armed and in the air.

:func:`fly_phase2` flies it (the chain's docstring, step 5, says how), :func:`load_phase2_law`
and :func:`phase2_bridge_config` prepare the law and the bridge, :func:`save_summary` writes the
YAML summaries; the flown log is analysed by
:func:`lpv_sysid.flight.phase2.analysis.analyse_phase2`.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import signal
import threading
import time
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from lpv_sysid.configuration.defaults import config_file
from lpv_sysid.errors import ConfigError, SafetyError
from lpv_sysid.flight.phase2.analysis import analyse_phase2
from lpv_sysid.flight.phase2.options import Phase2Options

log = logging.getLogger(__name__)


def _fade(t: float, T: float, ramp: float) -> float:
    if ramp <= 0:
        return 1.0 if 0.0 <= t <= T else 0.0
    if t <= 0.0 or t >= T:
        return 0.0
    a = min(t, T - t) / ramp
    return 1.0 if a >= 1.0 else 0.5 - 0.5 * math.cos(math.pi * a)


def load_phase2_law(gains_path: str | Path, models_path: str | Path | None = None):
    """(LpvController, GainSchedule) from a rate-plant gains file (generic layout), checked
    against the models file when given."""
    from lpv_sysid.control.law import LpvController, LpvControllerConfig
    from lpv_sysid.io.formats import GainSchedule
    from lpv_sysid.models import rate_plant as rp

    gs = GainSchedule.load(gains_path, models_path, layout=None)
    if tuple(gs.state_names) != rp.STATE_NAMES or tuple(gs.input_names) != rp.INPUT_NAMES:
        raise ConfigError(
            f"{gains_path}: states {list(gs.state_names)} / inputs {list(gs.input_names)} are not "
            "the "
            f"rate plant's {list(rp.STATE_NAMES)} / {list(rp.INPUT_NAMES)} (a virtual-actuator "
            "design cannot be flown through SET_ATTITUDE_TARGET rate setpoints)"
        )
    ctrl = LpvController(
        gs, LpvControllerConfig(velocity_index=rp.VELOCITY_INDEX, feedforward=False)
    )
    return ctrl, gs


def phase2_bridge_config(path: str | Path, url: str | None):
    """The chain's bridge config for phase 2: command ``attitude_rate`` (BridgeCore's 4-value
    command path), no arming (the vehicle is in the air), the URL override."""
    from lpv_sysid.mavlink.bridge import BridgeConfig

    cfg = BridgeConfig.load(str(path))
    link = dataclasses.replace(cfg.link, url=url) if url else cfg.link
    link.validate()
    return dataclasses.replace(
        cfg,
        link=link,
        command="attitude_rate",
        auto_start=False,
        offboard=dataclasses.replace(cfg.offboard, arm=False),
    )


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
) -> dict:
    """Fly the phase-2 signal under the LPV law on a PX4 vehicle that is armed and in the air
    (module docstring step 5); returns the summary (also ``DIR/phase2_summary.yaml``).
    Raises SafetyError before sending anything when the vehicle is not airborne."""
    from lpv_sysid.flight.campaign import CampaignRecorder
    from lpv_sysid.flight.vehicle import tap_attitude_target, wait_for_vehicle
    from lpv_sysid.mavlink.bridge import BridgeCore, RateSetpointTransport
    from lpv_sysid.mavlink.offboard import STREAMING, State
    from lpv_sysid.mavlink.telemetry import StateSample
    from lpv_sysid.sim.phase2 import load_signals

    opts.validate()
    out = Path(out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError(f"output directory {out}: exists and is not an empty directory")
    ctrl, gs = load_phase2_law(gains, models)
    sig = load_signals(signals, duration=opts.duration)
    T = float(sig.t[-1] - sig.t[0])
    dt_sig = float(np.median(np.diff(sig.t)))
    bcfg = phase2_bridge_config(bridge_config or config_file("mavlink_bridge_chain.yaml"), url)
    core = BridgeCore(bcfg, link=link)
    core.transport = RateSetpointTransport(
        max_rate=opts.max_rate
    )  # the rate plant's inputs as sent
    core.open(clock())
    px4_sp: list = []
    tap_attitude_target(core.link, lambda t, u: px4_sp.append((t, np.asarray(u, float).copy())))
    interrupts = [0]
    prev_handlers: dict = {}
    summary: dict = {
        "design": "rate_plant",
        "gains": str(gains),
        "signals": str(signals),
        "connect": bcfg.link.url,
        "gamma": float(ctrl.gamma),
        "kappa": opts.kappa,
        "signal_duration_s": T,
    }
    log_rows: dict[str, list] = {k: [] for k in ("t", "x", "v_d", "u_e", "u", "sent", "tsig")}
    rec = None
    state: Optional[StateSample] = None
    reason, ok = "", False
    t0 = clock()

    def poll(now):
        nonlocal state
        o = core.poll(now)
        for s in o.samples:
            if isinstance(s, StateSample):
                state = s
                if rec is not None:
                    rec.state(s.t, s.pos_ned, s.euler, s.v_body, s.omega)
        for ev in o.events:
            text = (
                getattr(ev, "reason", None)
                or f"{getattr(ev, 'kind', '')}: {getattr(ev, 'detail', '')}"
            )
            lvl = getattr(ev, "level", "warn")
            if lvl != "info" or getattr(ev, "previous", None) != getattr(ev, "state", None):
                echo(f"[{now - t0:8.2f} s] bridge: {text}")
        return o

    try:
        if handle_signals and threading.current_thread() is threading.main_thread():
            for sgn in (signal.SIGINT, signal.SIGTERM):
                prev_handlers[sgn] = signal.signal(
                    sgn, lambda *_: interrupts.__setitem__(0, interrupts[0] + 1)
                )
        wait_for_vehicle(core.link, 15.0, clock, sleep)
        # telemetry + HOME_POSITION (the envelope's home when started armed)
        tw = clock()
        next_req = tw
        while clock() - tw < 8.0:
            now = clock()
            poll(now)
            if (
                state is not None
                and core.machine.vehicle_mode is not None
                and (core.envelope.home_position is not None or not core.machine.armed)
            ):
                break
            if now >= next_req:
                next_req = now + 1.0
                core.link.command_long(512, 242.0)  # MAV_CMD_REQUEST_MESSAGE HOME_POSITION
            sleep(0.005)
        if state is None or not core.machine.armed:
            raise SafetyError(
                "phase 2 starts in the air: the vehicle is not armed (fly phase 1 with "
                "finish: HOLD first, or take off)"
                if state is not None
                else "phase 2: no state telemetry from the vehicle"
            )
        hp = core.envelope.home_position
        height = -(state.pos_ned[2] - (hp[2] if hp is not None else 0.0))
        if height < opts.min_height:
            raise SafetyError(
                f"phase 2 needs >= {opts.min_height:g} m above home, vehicle at {height:.1f} m"
            )
        mode = core.machine.vehicle_mode
        echo(
            f"phase 2: vehicle armed at {height:.1f} m, mode "
            f"{mode.name if mode is not None else 'unknown'}; "
            f"signal {T:.1f} s, kappa {opts.kappa:g}, gamma {ctrl.gamma:.4g}, design rate_plant"
        )
        rec = CampaignRecorder(
            out,
            storage,
            False,
            description=f"lpv-sysid phase 2 (rate plant) on {bcfg.link.url}",
            rate_setpoints=True,
        )
        rec.start(clock())
        rec.begin_run("phase2")
        period = 1.0 / opts.control_rate_hz
        next_ctrl = clock()
        t_active = None
        started = False
        while True:
            now = clock()
            poll(now)
            st = core.machine.state
            if interrupts[0]:
                reason = "interrupted"
                break
            if started and st not in STREAMING:
                reason = f"bridge left offboard ({st.value}): {core.machine.reason}"
                break
            if st == State.OFFBOARD_ACTIVE and t_active is None:
                t_active = now
                echo(
                    f"[{now - t0:8.2f} s] phase 2: OFFBOARD active, law in control; signal after "
                    f"{opts.lead_in_s:g} s lead-in"
                )
            if not started and now - t0 > opts.start_timeout + 10.0:
                reason = "OFFBOARD not confirmed"
                break
            if t_active is None and started and now - tw > opts.start_timeout:
                reason = f"OFFBOARD not confirmed within {opts.start_timeout:g} s"
                break
            if now >= next_ctrl and state is not None and now - state.t <= bcfg.telemetry_max_age:
                next_ctrl = max(next_ctrl + period, now)
                tsig = (now - t_active - opts.lead_in_s) if t_active is not None else -1.0
                if tsig > T:
                    ok = True
                    break
                w = _fade(tsig, T, opts.ramp_s) if tsig >= 0 else 0.0
                k = int(min(max(round(tsig / dt_sig), 0), len(sig.t) - 1))
                v_d = w * sig.v_d[k] if tsig >= 0 else np.zeros(3)
                u_e = (opts.kappa * w * sig.u_e[k]) if tsig >= 0 else np.zeros(sig.u_e.shape[1])
                x = np.r_[state.euler[0], state.euler[1], state.v_body, state.omega]
                u, info = ctrl.step(now, x, v_d, u_e)
                sent = core.transport.clip(u)
                core.on_actuator_command(now, u, stamp=now)
                if not started:
                    core.start(now)
                    started = True
                    tw = now
                if rec is not None:
                    rec.reference(now, v_d, 0.0)
                    rec.rate_setpoint(now, sent)
                for key, val in (
                    ("t", now),
                    ("x", x),
                    ("v_d", v_d),
                    ("u_e", u_e),
                    ("u", u),
                    ("sent", sent),
                    ("tsig", tsig),
                ):
                    log_rows[key].append(val)
                err = np.abs(x[2:5] - v_d)
                if t_active is not None and err.max() > opts.max_tracking_error:
                    reason = (
                        f"tracking error {err.max():.2f} m/s > {opts.max_tracking_error:g} m/s "
                        f"(axis {'uvw'[int(err.argmax())]}) -> hand back"
                    )
                    break
            sleep(0.002)
        # hand back: finish mode after a complete signal, the abort chain otherwise
        now = clock()
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
            summary["recording_errors"] = rec.close(clock())
        core.close()
    summary["ok"] = bool(ok)
    summary["reason"] = reason or "signal complete"
    summary["envelope"] = core.envelope.status()
    arr = {k: np.asarray(v, dtype=float) for k, v in log_rows.items()}
    if px4_sp:
        arr["px4_t"] = np.array([p[0] for p in px4_sp])
        arr["px4_sp"] = np.array([p[1] for p in px4_sp])
    if len(arr["t"]):
        np.savez(out / "phase2_log.npz", **arr)
        summary.update(analyse_phase2(arr, gs, ctrl.gamma, opts))
    save_summary(out / "phase2_summary.yaml", summary)
    return summary


def save_summary(path: Path, d: dict) -> None:
    """``d`` as YAML at ``path`` (numpy values made plain, parents created)."""
    import yaml

    from lpv_sysid.flight.campaign.outputs import _plain

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(_plain(d), sort_keys=False))
