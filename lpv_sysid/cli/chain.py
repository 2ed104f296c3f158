"""`lpv-sysid chain`: the whole two-phase job on a connected PX4 vehicle, end to end.

    lpv-sysid chain --connect udpin:127.0.0.1:14540 --out DIR [--set-param COM_OBL_RC_ACT=5]

The design is the **rate plant** (lpv_sysid/models/rate_plant.py): PX4 >= 1.14 accepts over
MAVLink only thrust + body-rate setpoints (SET_ATTITUDE_TARGET), so the plant that is
identified, certified and flown has PX4's rate loop inside, with inputs
(thrust, p_sp, q_sp, r_sp) exactly as sent (docs/px4_chain.md). Steps, each leaving its
artefacts in ``DIR``:

1. ``DIR/phase1``: the phase-1 campaign (``lpv-sysid fly phase1`` core, config
   ``config/campaign_chain.yaml``: box +-1.5/+-1.5/+-0.5 m/s, vertices 1 and 8 + hover, 17 s
   excitation, finish HOLD) with PX4's ATTITUDE_TARGET recorded on ``rate_setpoint``;
2. ``DIR/vertex_models.yaml``: pooled equation-error identification of the rate plant
   (lpv_sysid/ident/rate_plant.py) and its vertex models over the box;
3. ``DIR/signals``: phase-2 reference + excitation (config/signals_chain_phase2.yaml);
4. ``DIR/gains.yaml``: seed 0 Lemma 1 synthesis + independent verification
   (config/synthesis_chain.yaml: feasibility at gamma = 1 with a pole region that bounds the
   gains); the file's first line names the design (``# design: rate_plant ...``), as do
   ``DIR/chain_summary.yaml``, ``phase2_summary.yaml`` and the report. When phase 1 did not
   complete, models and gains are still written but phase 2 is not flown;
5. ``DIR/phase2``: the phase-2 flight under the LPV law (:func:`fly_phase2`): the vehicle,
   still in the air in HOLD after phase 1, is taken into OFFBOARD with the law's rate
   setpoints (RateSetpointTransport on BridgeCore's ``attitude_rate`` command, envelope
   enforced by the bridge), the signal is flown with raised-cosine fades, then LAND;
6. ``DIR/report.md``: measured u_e -> z gain against gamma (seed 0 Eqs. 26-29, by regression
   on the excitation, :func:`excitation_gain`), tracking RMS per axis, the design, what the
   vehicle did.

``lpv-sysid fly phase2 --connect URL --gains G --models M --signals S --out DIR`` flies step 5
alone (vehicle in the air, armed); ``lpv-sysid chain ... --phase1 OLD/phase1`` reruns steps 2-6
on the bags of an earlier phase-1 flight (the vehicle still in HOLD). The simulated ``lpv-sysid
demo`` / ``make demo`` is unchanged.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import signal
import threading
import time
from pathlib import Path
from typing import Any, Callable, Mapping, Optional

import numpy as np

from lpv_sysid.default_configs import config_file
from lpv_sysid.errors import ConfigError, LpvSysidError, SafetyError

COMMAND = "chain"
HELP = (
    "on a connected PX4: phase-1 campaign -> rate-plant identification -> signals -> synthesis + "
    "verification -> phase-2 flight under the LPV law -> report"
)

log = logging.getLogger(__name__)
EXIT_FAILED = 1


# ============================================================================ phase 2
@dataclasses.dataclass(frozen=True)
class Phase2Options:
    """Flight options of :func:`fly_phase2`."""

    kappa: float = 1.0  # excitation multiplier (seed 0 Eq. 33)
    control_rate_hz: float = 50.0  # law evaluations per second (on the newest state sample)
    ramp_s: float = 3.0  # raised-cosine fade of v_d and u_e at both ends
    lead_in_s: float = 2.0  # hover (v_d = 0) under the law before the signal starts
    duration: Optional[float] = None  # s of the signal (None: one period)
    max_tracking_error: float = 2.5  # m/s |v - v_d| per axis -> hand back
    start_timeout: float = 15.0  # s for OFFBOARD to be confirmed
    handback_timeout: float = 15.0
    finish: str = "LAND"  # mode after the signal (LAND | HOLD)
    max_rate: float = 2.0  # rad/s clip of the rate setpoints (transport)
    min_height: float = 8.0  # m above home needed to start

    def validate(self) -> None:
        if not (
            self.kappa >= 0
            and self.control_rate_hz > 0
            and self.ramp_s >= 0
            and self.lead_in_s >= 0
            and self.max_tracking_error > 0
            and self.max_rate > 0
        ):
            raise ConfigError(f"phase 2 options out of range: {self}")
        if self.finish.upper() not in ("LAND", "HOLD"):
            raise ConfigError(f"phase 2 finish must be LAND or HOLD, got {self.finish!r}")


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
    from lpv_sysid.control.lpv_controller import LpvController, LpvControllerConfig
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
    echo: Callable[[str], None] = print,
    link=None,
    handle_signals: bool = True,
    storage: str = "mcap",
) -> dict:
    """Fly the phase-2 signal under the LPV law on a PX4 vehicle that is armed and in the air
    (module docstring step 5); returns the summary (also ``DIR/phase2_summary.yaml``).
    Raises SafetyError before sending anything when the vehicle is not airborne."""
    from lpv_sysid.cli.fly import CampaignRecorder, tap_attitude_target, wait_for_vehicle
    from lpv_sysid.mavlink.bridge import BridgeCore
    from lpv_sysid.mavlink.offboard import STREAMING, State
    from lpv_sysid.mavlink.telemetry import StateSample
    from lpv_sysid.mavlink.transport import RateSetpointTransport
    from lpv_sysid.sim.phase2 import load_signals

    opts.validate()
    out = Path(out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError(f"--out {out}: exists and is not an empty directory")
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
    _save(out / "phase2_summary.yaml", summary)
    return summary


def excitation_gain(
    tsig: np.ndarray,
    z: np.ndarray,
    u_e: np.ndarray,
    fs: float,
    lags_s: float = 1.0,
    f_cut: float = 0.3,
    ridge: float = 1e-6,
) -> dict:
    """The u_e -> z gain of seed 0 Eqs. (26)-(29) on flight data (uniform grid ``tsig`` at
    ``fs``), not mixed with tracking error: the part z_e of z explained by the excitation through
    the FIR regression of :func:`lpv_sysid.sim.excitation_fir.excitation_response_fir`. Returns
    the energy ratio ||z_e||_2 / ||u_e||_2 over the fitted window (the flown signal's Eq. 29
    ratio), the FIR's peak gain at the excited frequencies (a lower estimate of the H-inf norm
    the certificate bounds), the fit's R^2 and the window (rows of ``tsig``)."""
    from lpv_sysid.sim.excitation_fir import excitation_response_fir

    try:
        z_e, info = excitation_response_fir(tsig, z, u_e, f_cut, lags_s, fs, ridge)
    except ConfigError as exc:
        return {"method": "FIR regression", "error": str(exc)}
    half = 0.5 / fs
    a = int(np.searchsorted(tsig, info["window_s"][0] - half))
    b = int(np.searchsorted(tsig, info["window_s"][1] + half))
    Ee = float((u_e[a:b] ** 2).sum() / fs)
    Ez = float((z_e[a:b] ** 2).sum() / fs)
    return {
        "method": (
            f"FIR regression of high-passed z (> {f_cut:g} Hz) on u_e, {info['lags']} lags "
            f"({lags_s:g} s)"
        ),
        "energy_ratio": math.sqrt(Ez / Ee) if Ee > 0 else float("nan"),
        "fir_peak_gain": info["fir_peak_gain"],
        "fit_r2": info["fit_r2"],
        "excitation_energy": Ee,
        "window": [a, b],
    }


def inversion_error(
    t: np.ndarray,
    omega: np.ndarray,
    rate_p=(0.15, 0.15, 0.2),
    delays=(0.01, 0.02, 0.04),
    arm_length: float = 0.225,
    design_magnitudes=(0.01, 0.01, 0.05),
) -> dict:
    """How closely the rate-loop inversion of
    :class:`~lpv_sysid.mavlink.transport.AttitudeRateTransport`
    (omega_sp = omega_measured + tau / K_p) can make PX4 apply a commanded virtual torque,
    measured on flown body rates ``omega`` (N, 3) at times ``t``.

    PX4's proportional term then produces K_p (omega_sp - omega_now) = tau + K_p (omega(t - d) -
    omega(t)) with d the age of the telemetry the command was computed from (link + loop); the
    second term is the torque error (PX4's own I/D/FF terms come on top). Returned per delay:
    the rms of K_p (omega(t - d) - omega(t)) in PX4's normalised torque units, and the ratio to
    the virtual torques of the seed's design magnitudes (Delta_a, Delta_e, Delta_r of
    config/signals_phase2.yaml -> tau = u / (4 s) for roll/pitch, u / 4 for yaw, s = arm
    sqrt(2)/2). Ratios >= 1: the error is as large as the commanded input."""
    t = np.asarray(t, dtype=float)
    omega = np.asarray(omega, dtype=float)
    dt = 0.002
    g = np.arange(t[0], t[-1], dt)
    w = np.column_stack([np.interp(g, t, omega[:, k]) for k in range(3)])
    kp = np.asarray(rate_p, dtype=float)
    s = arm_length * math.sqrt(2.0) / 2.0
    da, de, dr = design_magnitudes
    tau = np.array([da / (4 * s), de / (4 * s), dr / 4.0])
    rows = []
    for d in delays:
        k = max(1, int(round(d / dt)))
        e = kp * np.sqrt(((w[k:] - w[:-k]) ** 2).mean(axis=0))
        rows.append(
            {
                "delay_s": float(d),
                "torque_error_rms": e.tolist(),
                "ratio_to_design_torque": (e / tau).tolist(),
            }
        )
    return {
        "rate_p": kp.tolist(),
        "design_torque": tau.tolist(),
        "omega_rms": np.sqrt((w**2).mean(axis=0)).tolist(),
        "by_delay": rows,
    }


def analyse_phase2(arr: Mapping[str, np.ndarray], gs, gamma: float, opts: Phase2Options) -> dict:
    """Tracking RMS per axis, measured u_e -> z gain (``excitation_gain``) vs gamma, saturation."""
    tsig = arr["tsig"]
    keep = tsig >= 0
    if keep.sum() < 20:
        return {"analysis": "no signal samples"}
    t = arr["t"][keep]
    x, vd, ue = arr["x"][keep], arr["v_d"][keep], arr["u_e"][keep]
    e = x[:, 2:5] - vd
    fs = 1.0 / float(np.median(np.diff(t)))
    Qinv = np.linalg.inv(np.asarray(gs.Q, dtype=float))
    z = e @ Qinv.T
    # resample on a uniform grid (the loop is paced by telemetry; jitter under load)
    tg = np.arange(t[0], t[-1], 1.0 / fs)
    zi = np.column_stack([np.interp(tg, t, z[:, k]) for k in range(z.shape[1])])
    uei = np.column_stack([np.interp(tg, t, ue[:, k]) for k in range(ue.shape[1])])
    gain = excitation_gain(tg - tg[0], zi, uei, fs)
    dt = np.diff(t, prepend=t[0])
    raw = math.sqrt(
        float((z**2 * dt[:, None]).sum()) / max(float((ue**2 * dt[:, None]).sum()), 1e-300)
    )
    sent, u = arr["sent"][keep], arr["u"][keep]
    clipped = int(np.any(np.abs(sent - u) > 1e-9, axis=1).sum())
    return {
        "tracking_rms": {a: float(np.sqrt(np.mean(e[:, k] ** 2))) for k, a in enumerate("uvw")},
        "tracking_max": {a: float(np.max(np.abs(e[:, k]))) for k, a in enumerate("uvw")},
        "reference_rms": {a: float(np.sqrt(np.mean(vd[:, k] ** 2))) for k, a in enumerate("uvw")},
        "gain_u_e_to_z": {
            **gain,
            "gamma": float(gamma),
            "within_gamma": bool(
                gain.get("fir_peak_gain", math.inf) <= gamma
                and gain.get("energy_ratio", math.inf) <= gamma
            ),
        },
        "raw_ratio_mixed_with_tracking": raw,
        "control_rate_hz": fs,
        "flown_signal_s": float(t[-1] - t[0]),
        "commands_clipped": clipped,
        "commands": int(len(t)),
    }


def _save(path: Path, d: dict) -> None:
    import yaml

    from lpv_sysid.cli.fly import _plain

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(_plain(d), sort_keys=False))


# =============================================================================== chain
def chain(
    url: str,
    out_dir: str | Path,
    params: Mapping[str, float] | None = None,
    campaign_config: str | Path | None = None,
    kappa: float = 1.0,
    k_sigma: float = 2.0,
    echo: Callable[[str], None] = print,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    link_factory: Callable[[], Any] | None = None,
    phase2: Phase2Options | None = None,
    preflight: bool = True,
    phase1_dir: str | Path | None = None,
) -> int:
    """The six steps of the module docstring; returns the exit status. ``phase1_dir``: use the
    bags of an earlier phase-1 flight (``--phase1``, e.g. after a chain stopped at a later
    step with the vehicle still in HOLD) instead of flying phase 1."""
    from lpv_sysid.cli.fly import FlyConfig, fly
    from lpv_sysid.cli.main import main as cli_main
    from lpv_sysid.ident import rate_plant as rid
    from lpv_sysid.io.yaml_file import save_yaml

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summary: dict = {"design": "rate_plant", "connect": url, "steps": []}
    t_all = clock()

    def step(title):
        echo(f"\n=== {title}")
        summary["steps"].append({"step": title, "t_start_s": round(clock() - t_all, 1)})

    def done(**kw):
        summary["steps"][-1].update({"t_end_s": round(clock() - t_all, 1), **kw})
        _save(out / "chain_summary.yaml", summary)

    cfg = FlyConfig.load(campaign_config or config_file("campaign_chain.yaml"))
    if phase1_dir is not None:
        step(f"phase-1 bags of an earlier flight ({phase1_dir})")
        p1 = Path(phase1_dir)
        from lpv_sysid.io.yaml_file import read_yaml_mapping

        cs = (
            read_yaml_mapping(p1 / "campaign_summary.yaml", finite=False)
            if (p1 / "campaign_summary.yaml").exists()
            else {}
        )
        ok1 = bool(cs.get("ok"))
        res = type(
            "Phase1",
            (),
            {
                "status": 0 if ok1 else EXIT_FAILED,
                "phase": cs.get("result", "unknown"),
                "reason": cs.get("reason") or "",
                "summary": cs,
            },
        )()
        bags = [p1 / b for b in (cs.get("bags") or {}).values()]
    else:
        step("phase-1 campaign on the vehicle (PX4 cascade, ATTITUDE_TARGET recorded)")
        res = fly(
            cfg,
            url,
            out / "phase1",
            params=params,
            clock=clock,
            sleep=sleep,
            echo=echo,
            record_rate_setpoints=True,
            preflight=preflight,
            link=link_factory() if link_factory else None,
        )
        bags = [out / "phase1" / b for b in (res.summary.get("bags") or {}).values()]
    done(status=res.status, result=res.phase, reason=res.reason, bags=[str(b) for b in bags])
    usable = []
    for b in bags:
        try:
            usable.append(rid.read_run(b))
        except LpvSysidError as exc:
            echo(f"  skipped {b.name}: {exc}")
    if not usable:
        summary["result"] = f"stopped: no usable phase-1 bag ({res.reason})"
        _save(out / "chain_summary.yaml", summary)
        echo(summary["result"])
        return EXIT_FAILED
    if res.status:
        echo(
            f"  phase 1 ended early ({res.reason}); identifying from the {len(usable)} usable "
            "run(s), "
            "phase 2 will not be flown"
        )
    step("rate-plant identification (pooled equation error)")
    params_rp, rep = rid.identify(usable)
    c = cfg.campaign
    save_yaml(
        rid.models_document(params_rp, c.box_min, c.box_max, k_sigma, rep),
        out / "vertex_models.yaml",
    )
    echo(format_identification(rep))
    done(
        result=f"{len(usable)} run(s), {rep['samples']} samples",
        rows=rep["rows"],
        runs=rep["runs"],
        k_sigma=k_sigma,
    )
    # the measurement behind the choice of plant: the inversion's torque error on these flights
    last = usable[-1]
    t_raw, om_raw = _raw_rates(next(b for b in bags if b.name == last.name))
    inv = inversion_error(t_raw, om_raw)  # unfiltered telemetry rates (noise included)
    inv["run"] = last.name
    summary["inversion_error"] = inv
    r20 = [r for r in inv["by_delay"] if abs(r["delay_s"] - 0.02) < 1e-9]
    if r20:
        echo(
            "  rate-loop inversion (AttitudeRateTransport) on this flight: torque error at 20 ms "
            "telemetry age "
            + ", ".join(
                f"{a} {e:.3g} ({q:.1f} x design)"
                for a, e, q in zip(
                    "pqr", r20[0]["torque_error_rms"], r20[0]["ratio_to_design_torque"]
                )
            )
        )
    steps = [
        (
            "phase-2 signals",
            [
                "signals",
                "--config",
                str(config_file("signals_chain_phase2.yaml")),
                "--out",
                str(out / "signals"),
            ],
        ),
        (
            "Lemma 1 synthesis + independent verification (rate plant)",
            [
                "synthesize",
                "--models",
                str(out / "vertex_models.yaml"),
                "--config",
                str(config_file("synthesis_chain.yaml")),
                "--summary",
                str(out / "signals" / "summary.yaml"),
                "--out",
                str(out / "gains.yaml"),
            ],
        ),
    ]
    for title, argv in steps:
        step(title)
        echo(f"$ lpv-sysid {' '.join(argv)}")
        rc = cli_main(argv)
        done(status=rc)
        if rc != 0:
            summary["result"] = f"stopped: step '{title}' failed with status {rc}"
            _save(out / "chain_summary.yaml", summary)
            _report(out, summary, None, rep)
            return EXIT_FAILED
    _mark_design(out / "gains.yaml")
    cli_main(["verify", "--gains", f"{out}/gains.yaml", "--models", f"{out}/vertex_models.yaml"])
    if res.status:
        # models and gains from the usable runs are written; flying phase 2 after a phase-1 fault
        # (stall, envelope, failsafe) would start from a state nobody checked
        summary["result"] = f"stopped before phase 2: phase 1 did not complete ({res.reason})"
        _save(out / "chain_summary.yaml", summary)
        _report(out, summary, None, rep)
        echo(summary["result"])
        return EXIT_FAILED
    step("phase-2 flight under the LPV law (rate plant)")
    opts = phase2 or Phase2Options(kappa=kappa)
    try:
        p2 = fly_phase2(
            out / "gains.yaml",
            out / "signals",
            out / "phase2",
            url=url,
            models=out / "vertex_models.yaml",
            opts=opts,
            clock=clock,
            sleep=sleep,
            echo=echo,
            link=link_factory() if link_factory else None,
        )
    except LpvSysidError as exc:
        p2 = {"ok": False, "reason": str(exc)}
    done(ok=p2.get("ok"), reason=p2.get("reason"))
    # the identified rate plant against the phase-2 flight (rate setpoints from the law, not PX4)
    bag2 = out / "phase2" / "bag_0000"  # state at the telemetry rate + the commands as sent
    if bag2.exists():
        try:
            p2["model_check_r2"] = rid.validate(params_rp, rid.read_run(bag2))
            echo(
                "  identified rate plant vs the phase-2 flight, R^2 per row: "
                + ", ".join(f"{k} {v}" for k, v in p2["model_check_r2"].items())
            )
        except LpvSysidError as exc:
            p2["model_check_r2"] = {"error": str(exc)}
    summary["phase2"] = {
        k: v
        for k, v in p2.items()
        if k in ("ok", "reason", "tracking_rms", "gain_u_e_to_z", "handback", "model_check_r2")
    }
    summary["result"] = "complete" if p2.get("ok") else f"phase 2: {p2.get('reason')}"
    summary["wall_s"] = round(clock() - t_all, 1)
    _save(out / "chain_summary.yaml", summary)
    _report(out, summary, p2, rep)
    echo(f"\nchain {summary['result']} in {summary['wall_s']:.0f} s; report: {out / 'report.md'}")
    return 0 if p2.get("ok") else EXIT_FAILED


def _raw_rates(bag: Path) -> tuple[np.ndarray, np.ndarray]:
    """(t, omega (N, 3)) of a bag's ``state`` topic as recorded (no filtering)."""
    from lpv_sysid.io import bag as iobag
    from lpv_sysid.io import messages as M

    topic = [t for t in iobag.topic_info(str(bag)) if t.endswith("/state")][0]
    st = [M.state_from_odometry(m) for _, m in iobag.read_bag(str(bag), topics=[topic])[topic]]
    return np.array([x.t for x in st]), np.array([x.omega for x in st])


def _mark_design(gains: Path) -> None:
    """Name the plant in gains.yaml itself: a leading comment (the gains format has no free
    metadata key and the certified law hash covers only the law; the input names thrust,
    p_sp, q_sp, r_sp say the same to a program)."""
    from lpv_sysid.models import rate_plant as rp

    text = gains.read_text()
    if not text.startswith("# design: "):
        gains.write_text(
            f"# design: {rp.DESIGN} -- {rp.DESIGN_TEXT}; flown by `lpv-sysid chain` / "
            "`lpv-sysid fly phase2` (docs/px4_chain.md)\n" + text
        )


def format_identification(rep: dict) -> str:
    lines = ["  row   R^2     notes"]
    for row, d in rep["rows"].items():
        extra = ""
        if "delay_s" in d:
            extra = (
                f"bandwidth {d['bandwidth_rad_s']:.2f} rad/s, best delay {d['delay_s']:.2f} s, "
                "free-fit DC gain "
                f"{d['unconstrained']['dc_gain']}"
            )
        lines.append(f"  {row:<5} {d['r2']:.3f}   {extra}")
    p = rep["params"]
    lines.append("  " + ", ".join(f"{k} {p[k]:.3g}" for k in ("X_u", "Y_v", "Z_w", "Z_T")))
    return "\n".join(lines)


def _report(out: Path, summary: dict, p2: Optional[dict], rep: dict) -> None:
    from lpv_sysid.io.yaml_file import read_yaml

    L = [
        "# PX4 chain report",
        "",
        "Design (plant) of every flight: phase 1 = PX4's own velocity/attitude/rate cascade "
        "(velocity "
        "setpoints); phase 2 = **rate plant** (PX4 rate loop inside the LPV model; inputs thrust "
        "+ body-rate "
        "setpoints sent as SET_ATTITUDE_TARGET; lpv_sysid/models/rate_plant.py).",
        "",
        f"Vehicle: `{summary.get('connect')}`. Result: **{summary.get('result')}**.",
        "",
        "## Steps",
        "",
        "| step | start [s] | end [s] | outcome |",
        "|---|---|---|---|",
    ]
    for s in summary["steps"]:
        outcome = (
            s.get("reason")
            or s.get("result")
            or ("status %s" % s.get("status") if "status" in s else "")
        )
        L.append(f"| {s['step']} | {s.get('t_start_s')} | {s.get('t_end_s', '-')} | {outcome} |")
    L += [
        "",
        "## Identification (pooled equation error)",
        "",
        "```",
        format_identification(rep),
        "```",
    ]
    inv = summary.get("inversion_error")
    if inv:
        L += [
            "",
            f"## Why the rate plant (measured on this flight's phase-1 run `{inv.get('run')}`)",
            "",
            "Torque error of the rate-loop inversion omega_sp = omega + tau/K_p, K_p (omega(t-d) "
            "- omega(t)) rms "
            "(PX4 normalised torque), against the seed's design virtual torques "
            f"{', '.join(f'{x:.3g}' for x in inv['design_torque'])} (roll, pitch, yaw):",
            "",
            "| telemetry age d [s] | roll | pitch | yaw | ratio to design (roll, pitch, yaw) |",
            "|---|---|---|---|---|",
        ]
        for r in inv["by_delay"]:
            e, q = r["torque_error_rms"], r["ratio_to_design_torque"]
            L.append(
                f"| {r['delay_s']:.2f} | {e[0]:.3g} | {e[1]:.3g} | {e[2]:.3g} | "
                f"{q[0]:.1f}, {q[1]:.1f}, {q[2]:.1f} |"
            )
    gains = out / "gains.yaml"
    if gains.exists():
        g = read_yaml(gains)
        cert = g.get("certificate", {})
        L += [
            "",
            "## Certificate",
            "",
            f"gamma (file) {g.get('gamma'):.4g}, certified {cert.get('gamma_achieved')}, "
            f"solver {cert.get('solver')}, {cert.get('lmi')}",
        ]
    if p2:
        L += [
            "",
            "## Phase 2 (what the vehicle did)",
            "",
            f"ok: {p2.get('ok')}; {p2.get('reason')}",
        ]
        hb = p2.get("handback") or {}
        L.append(f"hand-back: {hb.get('state')} {hb.get('mode')} ({hb.get('reason')})")
        if "tracking_rms" in p2:
            tr, ref = p2["tracking_rms"], p2["reference_rms"]
            L += [
                "",
                "| axis | tracking RMS [m/s] | max [m/s] | reference RMS [m/s] |",
                "|---|---|---|---|",
            ]
            for a in "uvw":
                L.append(f"| {a} | {tr[a]:.3f} | {p2['tracking_max'][a]:.3f} | {ref[a]:.3f} |")
            gi = p2["gain_u_e_to_z"]
            L += [
                "",
                f"u_e -> z (seed 0 Eqs. 26-29; {gi.get('method')}): energy ratio "
                f"{gi.get('energy_ratio', float('nan')):.4g}, FIR peak gain "
                f"{gi.get('fir_peak_gain', float('nan')):.4g}, "
                f"fit R^2 {gi.get('fit_r2', float('nan')):.3f} vs gamma {gi['gamma']:.4g} -> "
                f"{'within' if gi['within_gamma'] else 'NOT within'} gamma. Raw ||z||/||u_e|| "
                "mixed with tracking "
                f"error (for reference only): {p2['raw_ratio_mixed_with_tracking']:.4g}.",
                f"Commands clipped by the transport: {p2['commands_clipped']} of "
                f"{p2['commands']}; control rate "
                f"{p2['control_rate_hz']:.1f} Hz; signal flown {p2['flown_signal_s']:.1f} s.",
            ]
        mc = p2.get("model_check_r2")
        if mc:
            L += [
                "",
                "Identified rate plant (phase-1 data) against the phase-2 flight (rate setpoints "
                "from the "
                "law), R^2 of x' per row: " + ", ".join(f"{k} {v}" for k, v in mc.items()),
            ]
    (out / "report.md").write_text("\n".join(L) + "\n")


# ================================================================================== CLI
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--connect", required=True, metavar="URL", help="MAVLink URL of the PX4 vehicle"
    )
    parser.add_argument("--out", required=True, type=Path, help="output directory")
    parser.add_argument(
        "--campaign",
        default=None,
        help="phase-1 campaign config (default config/campaign_chain.yaml)",
    )
    parser.add_argument(
        "--set-param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="PARAM_SET before phase 1 (e.g. COM_OBL_RC_ACT=5 on a SITL without RC)",
    )
    parser.add_argument(
        "--kappa", type=float, default=1.0, help="phase-2 excitation multiplier (seed 0 Eq. 33)"
    )
    parser.add_argument(
        "--phase1",
        default=None,
        metavar="DIR",
        help="use the bags of an earlier phase-1 flight (its DIR/phase1) instead of flying "
        "phase 1; the vehicle must be armed and in the air (HOLD) for phase 2",
    )
    parser.add_argument(
        "--k-sigma",
        type=float,
        default=2.0,
        help="model intervals nominal +- k std of the identified entries (0: nominal only)",
    )


def run(args: argparse.Namespace) -> int:
    from lpv_sysid.cli.fly import parse_params

    return chain(
        args.connect,
        args.out,
        params=parse_params(args.set_param),
        campaign_config=args.campaign,
        kappa=args.kappa,
        k_sigma=args.k_sigma,
        phase1_dir=args.phase1,
    )
