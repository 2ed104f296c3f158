"""The campaign's broken-loop run (issue 21 item 3), flown after the vertex runs on a PX4
vehicle that the campaign left armed and in the air (``finish: HOLD``).

:class:`~lpv_sysid.control.broken_loop.BrokenLoopRun` (a weak stabiliser with zippered
multisines superposed on the thrust and body-rate setpoints) is flown through
:class:`~lpv_sysid.mavlink.bridge.BridgeCore` as SET_ATTITUDE_TARGET thrust + body rates
(the rate plant's inputs, as phase 2 flies them): OFFBOARD from HOLD after a pre-stream of
the stabiliser alone, ``lead_in_s`` of the stabiliser in OFFBOARD, the run, then the
hand-back (``finish`` mode, confirmed by PX4's HEARTBEAT). The hover thrust the stabiliser
holds is PX4's own thrust setpoint (ATTITUDE_TARGET) averaged while it hovers in HOLD before
the switch. The run's envelope (tilt, speed) switches the excitation off and hands back; the
bridge's safety envelope hands back as on every flight.

Recorded in ``out_dir/bag_0000`` as a campaign run (:class:`CampaignRecorder`, the data
logger's topics): state, imu, rotor_speeds, status, actuator_command (the setpoints sent)
and rate_setpoint (PX4's ATTITUDE_TARGET echo), so ``identify --plant px4-rate`` and
:mod:`lpv_sysid.ident.rate_plant_dynamics` read it like every run; ``broken_loop_summary.yaml``
beside it.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from pathlib import Path
from typing import Callable

import numpy as np

from lpv_sysid.control.broken_loop import BrokenLoopConfig, BrokenLoopRun
from lpv_sysid.errors import ConfigError, SafetyError
from lpv_sysid.flight.campaign.outputs import _plain
from lpv_sysid.flight.campaign.recorder import CampaignRecorder

log = logging.getLogger(__name__)

BRIDGE_NAME = "/lpv_sysid/mavlink_bridge"
RUN_NAME = "broken_loop"


def fly_broken_loop(
    out_dir: str | Path,
    bridge_config: str | Path,
    url: str | None = None,
    cfg: BrokenLoopConfig = BrokenLoopConfig(),
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    echo: Callable[[str], None] = log.info,
    link=None,
    storage: str = "mcap",
    rate_hz: float = 50.0,
    lead_in_s: float = 2.0,
    hover_s: float = 2.0,
    min_height: float = 8.0,
    finish: str = "HOLD",
    handback_timeout: float = 15.0,
    hover_thrust: float | None = None,
) -> dict:
    """Fly the broken-loop run (module docstring); returns its summary (also written to
    ``out_dir/broken_loop_summary.yaml``). SafetyError before anything is sent when the
    vehicle is not armed, not high enough, or PX4 streams no thrust setpoint (``hover_thrust``
    given: used instead of PX4's setpoint)."""
    import yaml

    from lpv_sysid.flight.vehicle import (
        tap_attitude_target,
        wait_airborne,
        wait_for_vehicle,
    )
    from lpv_sysid.io import messages as m
    from lpv_sysid.mavlink.bridge import (
        RATE_INPUT_NAMES,
        BridgeConfig,
        BridgeCore,
        RateSetpointTransport,
    )
    from lpv_sysid.mavlink.offboard import STREAMING, State
    from lpv_sysid.mavlink.telemetry import ImuSample, RotorSample, StateSample

    out = Path(out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError(f"output directory {out}: exists and is not an empty directory")
    bcfg = BridgeConfig.load(str(bridge_config)).airborne_rates(url)
    f = m.MsgFactory.rosbags()
    core = BridgeCore(bcfg, link=link)
    core.transport = RateSetpointTransport(max_rate=cfg.max_rate)
    core.open(clock())
    rec: CampaignRecorder | None = None
    echoes: list = []

    def on_echo(t: float, u) -> None:
        echoes.append((t, float(u[0])))
        if rec is not None:
            rec.rate_setpoint(t, u)

    tap_attitude_target(core.link, on_echo)
    state: StateSample | None = None
    t0 = clock()

    def poll(now: float) -> None:
        nonlocal state
        o = core.poll(now)
        for smp in o.samples:
            if isinstance(smp, StateSample):
                state = smp
                if rec is not None:
                    rec.state(smp.t, smp.pos_ned, smp.euler, smp.v_body, smp.omega)
            elif rec is not None and isinstance(smp, ImuSample):
                rec.imu(smp.t, smp.accel_frd, smp.gyro_frd)
            elif rec is not None and isinstance(smp, RotorSample):
                rec.rotors(smp.t, smp.omega, smp.source)
        for ev in o.events:
            text = getattr(ev, "reason", None) or f"{getattr(ev, 'kind', '')}"
            if getattr(ev, "previous", None) != getattr(ev, "state", None):
                echo(f"[{now - t0:8.2f} s] bridge: {text}")
            if rec is not None:
                st = m.diagnostic_status(f, "OK", BRIDGE_NAME, text, core.status(now))
                rec.message("status", now, m.diagnostic_array(f, round(now * 1e9), [st]))

    summary: dict = {"connect": bcfg.link.url, "config": dataclasses.asdict(cfg)}
    ok, reason = False, ""
    try:
        wait_for_vehicle(core.link, 15.0, clock, sleep)
        state, height = wait_airborne(
            core, poll, lambda: state, clock, sleep, "broken-loop run", min_height
        )
        # hover thrust: PX4's own thrust setpoint while it holds position (HOLD)
        echoes.clear()
        th = clock()
        while clock() - th < hover_s:
            poll(clock())
            sleep(0.005)
        if hover_thrust is None and len(echoes) < 10:
            raise SafetyError(
                f"broken-loop run: PX4 sent {len(echoes)} ATTITUDE_TARGET in {hover_s:g} s "
                "(its thrust setpoint is the hover thrust): stream ATTITUDE_TARGET"
            )
        hover = (
            float(hover_thrust)
            if hover_thrust is not None
            else float(np.mean([e[1] for e in echoes]))
        )
        run = BrokenLoopRun(cfg, hover)
        summary.update(hover_thrust=hover, start_height_m=round(height, 2))
        echo(
            f"broken-loop run: vehicle at {height:.1f} m, hover thrust {hover:.3f} (PX4's "
            f"setpoint in {core.machine.vehicle_mode.name if core.machine.vehicle_mode else '?'}"
            f"), {cfg.duration_s:g} s, band {cfg.f_min:g}-{cfg.f_max:g} Hz"
        )
        rec = CampaignRecorder(
            out,
            storage,
            False,
            description=f"lpv-sysid broken-loop run on {bcfg.link.url}",
            rate_setpoints=True,
        )
        rec.start(clock())
        bag = rec.begin_run(RUN_NAME)
        period = 1.0 / rate_hz
        next_cmd = clock()
        t_active = None
        started = False
        sent = 0
        while True:
            now = clock()
            poll(now)
            st = core.machine.state
            if started and st not in STREAMING:
                reason = f"bridge left offboard ({st.value}): {core.machine.reason}"
                break
            if st == State.OFFBOARD_ACTIVE and t_active is None:
                t_active = now
                echo(f"[{now - t0:8.2f} s] broken loop: OFFBOARD active, stabiliser in control")
            if started and t_active is None and now - t0 > 60.0:
                reason = "OFFBOARD not confirmed"
                break
            if now >= next_cmd and state is not None:
                next_cmd = max(next_cmd + period, now)
                t_run = (now - t_active - lead_in_s) if t_active is not None else -1.0
                x = np.array([state.euler[0], state.euler[1], *state.v_body, *state.omega])
                cmd = run.command(t_run, x)
                core.on_actuator_command(now, cmd, stamp=state.t)
                rec.message(
                    "actuator_command",
                    now,
                    m.joint_state(f, round(state.t * 1e9), RATE_INPUT_NAMES, position=cmd),
                )
                sent += 1
                if not started:
                    core.start(now)
                    started = True
                if run.aborted is not None:
                    reason = f"broken-loop envelope: {run.aborted}"
                    break
                if t_run > cfg.duration_s:
                    ok = True
                    break
            sleep(0.002)
        now = clock()
        if core.machine.state in STREAMING:
            if ok:
                core.finish(now, finish.upper())
                echo(f"[{now - t0:8.2f} s] broken loop: run complete; hand-back to {finish}")
            else:
                core.abort(now, reason)
                echo(f"[{now - t0:8.2f} s] broken loop: ABORT: {reason}")
        th = clock()
        while (
            core.machine.state in STREAMING + (State.HANDBACK,) and clock() - th < handback_timeout
        ):
            poll(clock())
            sleep(0.005)
        hb = core.machine.state
        summary["handback"] = {
            "state": hb.value,
            "mode": core.machine.vehicle_mode.name if core.machine.vehicle_mode else None,
        }
        if hb != State.DONE:
            ok = False
            reason = reason or f"hand-back ended {hb.value}: {core.machine.reason}"
        summary.update(bag=bag, commands=sent)
    finally:
        if core.machine.state in STREAMING:
            core.shutdown(clock())
        if rec is not None:
            rec.end_run()
            summary["recording_errors"] = rec.close(clock()) or None
        core.close()
    summary.update(ok=bool(ok), reason=reason or "run complete")
    out.mkdir(parents=True, exist_ok=True)
    (out / "broken_loop_summary.yaml").write_text(yaml.safe_dump(_plain(summary), sort_keys=False))
    echo(f"broken loop: {summary['reason']}; hand-back {summary.get('handback')}")
    return summary
