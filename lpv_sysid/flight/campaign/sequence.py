"""The phase-1 campaign flown on a PX4 vehicle over MAVLink, ROS-free (`lpv-sysid fly phase1`).

    lpv-sysid fly phase1 --connect udpin:127.0.0.1:14540 --config config/campaign.yaml \\
        --out flight_01 [--signals signals_phase1/signals.npz] [--set-param COM_OBL_RC_ACT=5]

One process: the bridge core (link, telemetry, offboard state machine, safety envelope;
``lpv_sysid/mavlink/bridge/core.py``), the campaign sequencer
(``lpv_sysid/control/campaign/sequencer.py``) and the recorder
(``lpv_sysid/io/recorder/recorder.py``), on the wall clock (injectable: the tests fly the package's
simulated PX4 in lock-step with a simulated clock).

Sequence: optional PARAM_SET of ``--set-param`` values (each confirmed by the vehicle's
PARAM_VALUE), preflight (``lpv_sysid/mavlink/preflight/checks.py``: NO-GO refuses to fly, e.g. an
offboard-loss action that needs sticks the vehicle does not have), the campaign (arm and
take off in OFFBOARD, every vertex and the hover run, HOLD or LAND), then the outputs:

- ``DIR/bag_NNNN/``: one rosbag2 per run (trim + excitation), the topics, types and
  layout of the data logger and ``lpv-sysid simulate phase1`` (``/lpv_sysid/state``,
  ``rotor_speeds``, ``imu``, ``velocity_reference`` as flown, ``excitation``,
  ``actuator_command``, ``status``), ``DIR/experiment.yaml`` (recorder metadata), so
  ``lpv-sysid identify --bags DIR --config DIR/identification.yaml`` runs on it unchanged;
- ``DIR/flight/``: the whole flight (take-off, transitions, hand-back), not a maneuver;
- ``DIR/campaign_summary.yaml``: plan, per-run settle time, tracking RMS per axis,
  achieved equilibrium, bag of each run, hand-back time and mode, preflight table, events;
- ``DIR/trims.yaml`` / ``trims.md`` (seed 0 Table 1 layout), ``DIR/identification.yaml``
  (the identification config with the campaign's box and trim duration),
  ``DIR/signals/signals.npz`` (the excitation flown).

Ctrl-C (or SIGTERM) or any fault: excitation off, hand-back confirmed by the HEARTBEAT (or
FAILED loudly), bags closed and readable, exit status 1 (130 after an interrupt) with
the reason. A second Ctrl-C stops waiting for the confirmation.

Parts: inputs (:mod:`~lpv_sysid.flight.campaign.config`), vehicle-link steps
(:mod:`~lpv_sysid.flight.vehicle`), recording (:mod:`~lpv_sysid.flight.campaign.recorder`),
the loop (:mod:`~lpv_sysid.flight.campaign.runner`), outputs
(:mod:`~lpv_sysid.flight.campaign.outputs`); this module holds the sequence (:func:`fly`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import signal
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping

from lpv_sysid.errors import ConfigError
from lpv_sysid.flight.campaign.config import FlyConfig, bridge_config_for, load_signals
from lpv_sysid.flight.campaign.outputs import (
    format_results,
    identification_template,
    write_outputs,
)
from lpv_sysid.flight.campaign.recorder import CampaignRecorder
from lpv_sysid.flight.campaign.runner import FlightRunner
from lpv_sysid.flight.vehicle import (
    request_parameter_list,
    set_params,
    tap_attitude_target,
    tap_messages,
    wait_for_vehicle,
)
from lpv_sysid.mavlink.telemetry import VehicleRecord

log = logging.getLogger(__name__)

EXIT_FAILED = 1
EXIT_INTERRUPTED = 130


# =============================================================================== result
@dataclass
class FlyResult:
    status: int  # exit status
    phase: str
    reason: str
    summary: dict = field(default_factory=dict)
    out_dir: str = ""


# =============================================================================== fly()
def fly(
    cfg: FlyConfig,
    url: str | None,
    out_dir: str | Path,
    signals: str | None = None,
    params: Mapping[str, float] | None = None,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    echo: Callable[[str], None] = log.info,
    handle_signals: bool = True,
    preflight: bool = True,
    link=None,
    record_rate_setpoints: bool = False,
    epoch_ns: int | None = None,
    confirm: Callable[[str], bool] | None = None,
    endurance_s: float | None = None,
    resumed_from: Mapping | None = None,
    keep_params: list | None = None,
) -> FlyResult:
    """The whole CLI sequence of the module docstring (also used by the tests with a
    simulated clock); returns the exit status and the summary. Bad input raises
    :class:`~lpv_sysid.errors.ConfigError` before anything is sent to the vehicle.

    ``record_rate_setpoints``: also record PX4's ATTITUDE_TARGET (the thrust and body-rate
    setpoints its cascade produced) on ``rate_setpoint`` in every bag, the input of the
    rate-plant identification (lpv_sysid/ident/rate_plant.py); request the stream in the
    bridge config (``link.streams: {ATTITUDE_TARGET: 50}``, config/mavlink_bridge_chain.yaml).

    Stamps: the bags carry wall-clock (epoch) nanoseconds; telemetry (state, rotor speeds,
    IMU) at the time PX4 sampled it (``time_boot_ms`` through the vehicle record's live clock
    estimate), commands at the flight clock ``round(clock() * 1e9)`` shifted by
    ``time.time_ns() - round(clock() * 1e9)`` taken when the bridge opens, or, with
    ``epoch_ns``, by ``epoch_ns - round(clock() * 1e9)`` (a declared epoch for a simulated
    clock). ``experiment.yaml`` gets ``clock`` (that offset) and ``vehicle``
    (:class:`~lpv_sysid.mavlink.telemetry.VehicleRecord`: kind, firmware, airframe, PX4
    parameter snapshot, battery at start and end, PX4's boot on the bag clock).

    ``confirm(question)``: asked after preflight GO, before anything arms; False ends the
    flight without arming (None: no question, ``fly --yes``). Every parameter changed by
    ``params`` is set back to its old value when the flight ends, whatever the reason
    (confirmed by PARAM_VALUE; what could not be restored is reported with the command that
    does it); with ``keep_params`` (a list) the changes are appended to it instead and stay
    set: the caller restores them (``lpv-sysid chain``: its parameters hold for the whole job,
    phase 2 included). ``endurance_s``: hover endurance of the battery (preflight's battery check
    asks for the plan's worst-case use plus the reserve)."""
    import numpy as np

    from lpv_sysid.control.campaign import Campaign, ExcitationProfile, plan_campaign, trim_rows
    from lpv_sysid.mavlink.bridge import BridgeCore

    out = Path(out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError(f"output directory {out}: exists and is not an empty directory")
    ccfg = cfg.campaign
    bcfg = bridge_config_for(cfg.bridge_config, url, ccfg)
    table = load_signals(signals, cfg.signals_config)
    prof = ExcitationProfile.from_table(*table, ramp=ccfg.ramp_s, periods=ccfg.periods)
    plan = plan_campaign(ccfg, prof, bcfg.envelope)
    budget = plan.budget(endurance_s) if endurance_s else plan.budget()
    ident_template = identification_template(cfg.identification_config)
    echo(
        f"fly phase1: {len(plan.runs)} runs, excitation {prof.duration:.1f} s (peaks u v w "
        f"{' '.join(f'{p:.2f}' for p in prof.peak)} m/s, r {prof.yaw_peak:.2f} rad/s), window "
        f"[{ccfg.altitude_min:g}, {ccfg.altitude_max:g}] m, envelope floor "
        f"{bcfg.envelope.floor:g} m "
        f"ceiling {bcfg.envelope.ceiling:g} m radius {bcfg.envelope.radius:g} m"
    )
    echo(plan.describe())
    echo(budget.describe())

    bridge = BridgeCore(bcfg, link=link)
    bridge.open(clock())
    vehicle = VehicleRecord()
    t_start = clock()
    clock_offset = (time.time_ns() if epoch_ns is None else int(epoch_ns)) - int(
        round(t_start * 1e9)
    )
    tap_messages(
        bridge.link, lambda now, m: vehicle.absorb(m, int(round(now * 1e9)) + clock_offset)
    )
    summary: dict = {
        "connect": bcfg.link.url,
        # ``fly phase1 --resume``: the stopped flight and its completed runs (resume_config)
        **({"resumed_from": dict(resumed_from)} if resumed_from else {}),
        "config": cfg.source,
        "signals": signals or cfg.signals_config,
        # the times in this summary are on the flight clock; bag stamps add this offset
        "clock": {
            "kind": "utc" if epoch_ns is None else "declared",
            "offset_ns": clock_offset,
        },
    }
    runner = FlightRunner(
        bridge, Campaign(plan, table), None, clock, sleep, cfg.loop_period, cfg.status_period, echo
    )
    previous_handlers: dict = {}
    try:
        wait_for_vehicle(bridge.link, cfg.link_timeout, clock, sleep)
        echo(f"vehicle: system {bridge.link.target_system} on {bcfg.link.url}")
        # the PX4 parameter snapshot of experiment.yaml arrives during the preflight, before
        # anything time-critical runs
        request_parameter_list(bridge.link)
        if params:
            # with keep_params the caller's list: what was confirmed before a fault is in it
            summary["params_set"] = keep_params if keep_params is not None else []
            apply_params(bridge.link, params, clock, sleep, echo, summary["params_set"])
        if preflight:
            from lpv_sysid.mavlink import preflight as pf

            checks = pf.run_checks(
                bridge.link,
                timeout=cfg.preflight_timeout,
                clock=clock,
                sleep=sleep,
                rotor_estimate=bcfg.rotor_estimate,
                demands=plan.demands(),
                battery_needed_pct=budget.battery_needed_pct,
            )
            echo(pf.format_table(checks))
            summary["preflight"] = [dataclasses.asdict(c) for c in checks]
            if not pf.verdict(checks):
                bad = [
                    f"{c.name} ({c.value}{': ' + c.note if c.note else ''})"
                    for c in checks
                    if c.verdict == pf.NOGO
                ]
                reason = "preflight NO-GO, not flying: " + "; ".join(bad)
                echo(f"fly phase1: {reason}")
                return FlyResult(EXIT_FAILED, "idle", reason, summary)
        if confirm is not None and not confirm(
            f"arm and take off to {ccfg.takeoff_altitude:g} m on {bcfg.link.url}, then fly "
            f"{len(plan.runs)} runs ({budget.time_worst_s / 60:.1f} min at most)?"
        ):
            reason = "not confirmed by the operator: nothing armed"
            echo(f"fly phase1: {reason}")
            return FlyResult(EXIT_FAILED, "idle", reason, summary)
        rec = CampaignRecorder(
            out,
            cfg.storage,
            cfg.flight_log,
            config_files=[p for p in (cfg.source, cfg.bridge_config) if p and Path(p).is_file()],
            description=f"lpv-sysid fly phase1 on {bcfg.link.url}: one bag per run, "
            "see campaign_summary.yaml",
            rate_setpoints=record_rate_setpoints,
            clock_offset_ns=clock_offset,
        )
        # telemetry stamped at PX4's sample time on the bag clock (the same clock as a ULog
        # imported with --clock-from), not at its receive time
        rec.vehicle_clock = vehicle.bag_ns_of
        rec.start(clock())
        rec.annotate(
            "clock",
            {
                "kind": "utc" if epoch_ns is None else "declared",
                "offset_ns": clock_offset,
                "meaning": "bag stamp = round(flight clock [s] * 1e9) + offset_ns; the flight "
                "clock is time.monotonic (fly) or the simulation's",
            },
        )
        runner.rec = rec
        if record_rate_setpoints:
            tap_attitude_target(
                bridge.link, lambda t, u: runner._safe(lambda: rec.rate_setpoint(t, u))
            )
        (out / "signals").mkdir(exist_ok=True)
        from lpv_sysid.signals.store import save_npz

        save_npz(str(out / "signals" / "signals.npz"), *table)
        if handle_signals and threading.current_thread() is threading.main_thread():
            for s in (signal.SIGINT, signal.SIGTERM):
                previous_handlers[s] = signal.signal(s, lambda signo, _f: runner.interrupt(signo))
        try:
            runner.prime()
            runner.run()
        except BaseException:
            runner.drain_handback(ccfg.handback_timeout)
            raise
    finally:
        for s, h in previous_handlers.items():
            signal.signal(s, h)
        if runner.rec is not None:
            runner._safe(lambda: runner.rec.annotate("vehicle", vehicle.summary()))
        close_errors = runner.rec.close(clock()) if runner.rec is not None else []
        if summary.get("params_set") and keep_params is None:
            summary["params_restored"] = restore_params(
                bridge.link, summary["params_set"], clock, sleep, echo
            )
        bridge.close()
    c = runner.campaign
    summary.update(c.summary())
    summary["bags"] = dict(runner.rec.bags) if runner.rec is not None else {}
    summary["rotor_speeds_source"] = dict(runner.rotor_sources)
    summary["runner"] = {
        "max_loop_gap_s": round(runner.max_gap, 4),
        "stalled_loops": runner.late_loops,
        "loop_period_s": cfg.loop_period,
    }
    summary["bridge_status"] = bridge.status(clock())
    summary["events"] = runner.events
    if close_errors:
        summary["recording_errors"] = close_errors
    write_outputs(out, summary, c, ident_template, plan, trim_rows, np)
    echo(format_results(summary))
    if runner.gave_up:
        summary["result"], summary["ok"] = "failed", False
        summary["reason"] = (
            c.reason + "; " if c.reason else ""
        ) + "hand-back NOT confirmed (interrupted twice)"
    status = (
        0
        if c.ok and not runner.gave_up
        else (EXIT_INTERRUPTED if runner.interrupts else EXIT_FAILED)
    )
    if close_errors:
        status = status or EXIT_FAILED
    return FlyResult(status, summary["result"], summary["reason"], summary, str(out))


def apply_params(
    link, params: Mapping[str, float], clock, sleep, echo, changed: list[dict]
) -> list[dict]:
    """PARAM_SET each of ``params`` (confirmed by PARAM_VALUE), one by one, appending each
    confirmed change to ``changed`` as it happens, so a fault halfway leaves in ``changed``
    exactly what :func:`restore_params` must set back."""
    for name, value in params.items():
        (d,) = set_params(link, {name: value}, clock, sleep)
        changed.append(d)
        echo(f"PARAM_SET {d['name']}: {d['old']} -> {d['new']:g} (confirmed)")
    return changed


@contextlib.contextmanager
def vehicle_link(cfg: FlyConfig, url: str | None, clock, sleep, link=None):
    """A link to the vehicle of ``cfg`` (its bridge config at ``url``) with the autopilot's
    HEARTBEAT in, for parameter work between flights (``lpv-sysid chain``); closed on exit.
    Nothing is commanded: the bridge core is opened, not started."""
    from lpv_sysid.mavlink.bridge import BridgeCore

    bridge = BridgeCore(bridge_config_for(cfg.bridge_config, url, cfg.campaign), link=link)
    bridge.open(clock())
    try:
        wait_for_vehicle(bridge.link, cfg.link_timeout, clock, sleep)
        yield bridge.link
    finally:
        bridge.close()


def restore_params(link, changed: list[dict], clock, sleep, echo) -> list[dict]:
    """Set every parameter of ``changed`` (``set_params``' records) back to its old value,
    confirmed by PARAM_VALUE; what cannot be restored is reported with the commands that
    restore it by hand. Returns one record per parameter (name, value, restored)."""
    from lpv_sysid.errors import LpvSysidError

    out = []
    for d in changed:
        name, old = d["name"], d["old"]
        if old is None or old == d["new"]:
            continue
        try:
            set_params(link, {name: float(old)}, clock, sleep)
            echo(f"PARAM_SET {name}: {d['new']:g} -> {old} (restored, confirmed)")
            out.append({"name": name, "value": old, "restored": True})
        except LpvSysidError as exc:
            echo(
                f"PARAM {name} NOT restored ({exc}): set it back by hand, e.g. QGroundControl "
                f"MAVLink console `param set {name} {old}`"
            )
            out.append({"name": name, "value": old, "restored": False})
    return out


def plan_flight(cfg: FlyConfig, url: str | None, signals: str | None = None):
    """The campaign plan of ``cfg`` (its bridge envelope at ``url``) without flying: what
    ``lpv-sysid fly phase1 --dry-run`` prints (:meth:`CampaignPlan.describe`)."""
    from lpv_sysid.control.campaign import ExcitationProfile, plan_campaign

    bcfg = bridge_config_for(cfg.bridge_config, url, cfg.campaign)
    table = load_signals(signals, cfg.signals_config)
    prof = ExcitationProfile.from_table(
        *table, ramp=cfg.campaign.ramp_s, periods=cfg.campaign.periods
    )
    return plan_campaign(cfg.campaign, prof, bcfg.envelope)
