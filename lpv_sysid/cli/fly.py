"""`lpv-sysid fly phase1`: fly the phase-1 campaign on a PX4 vehicle over MAVLink (no ROS).

    lpv-sysid fly phase1 --connect udpin:127.0.0.1:14540 --config config/campaign.yaml \\
        --out flight_01 [--signals signals_phase1/signals.npz] [--set-param COM_OBL_RC_ACT=5]

One process: the bridge core (link, telemetry, offboard state machine, safety envelope;
``lpv_sysid/mavlink/bridge.py``), the campaign sequencer (``lpv_sysid/control/campaign.py``)
and the recorder (``lpv_sysid/io/recorder.py``), on the wall clock (injectable: the tests
fly the package's simulated PX4 in lock-step with a simulated clock).

Sequence: optional PARAM_SET of ``--set-param`` values (each confirmed by the vehicle's
PARAM_VALUE), preflight (``lpv_sysid/mavlink/preflight.py``: NO-GO refuses to fly, e.g. an
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

``lpv-sysid fly phase2`` (:func:`lpv_sysid.cli.chain.fly_phase2`) flies the phase-2 signal under
the LPV law of a rate-plant design on a vehicle that is already armed and in the air.

Ctrl-C (or SIGTERM) or any fault: excitation off, hand-back confirmed by the HEARTBEAT (or
FAILED loudly), bags closed and readable, exit status 1 (130 after an interrupt) with
the reason. A second Ctrl-C stops waiting for the confirmation.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import signal
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Mapping

from lpv_sysid.errors import ConfigError, LpvSysidError, SafetyError

if TYPE_CHECKING:
    import numpy as np  # annotations only: the CLI imports numpy when a command runs

COMMAND = "fly"
HELP = (
    "fly on a PX4 vehicle over MAVLink: phase1 = campaign (take-off, vertices, hover, land, "
    "rosbag2); "
    "phase2 = LPV law on the rate plant (lpv_sysid/cli/chain.py)"
)

log = logging.getLogger(__name__)

NAMESPACE = "/lpv_sysid"
TOPICS = (
    "state",
    "rotor_speeds",
    "imu",
    "velocity_reference",
    "excitation",
    "actuator_command",
    "status",
)
#: with ``record_rate_setpoints``: PX4's ATTITUDE_TARGET (thrust + body-rate setpoints of its own
#: cascade) as a JointState (names ``transport.RATE_INPUT_NAMES``, ``position``), receive-time
#: stamps
RATE_TOPIC = "rate_setpoint"
EXIT_FAILED = 1
EXIT_INTERRUPTED = 130


# ================================================================================ config
@dataclass(frozen=True)
class FlyConfig:
    """``config/campaign.yaml`` (paths relative to the file's directory)."""

    campaign: Any  # CampaignConfig
    bridge_config: str = "mavlink_bridge.yaml"
    signals_config: str = "signals_phase1.yaml"
    identification_config: str = "identification.yaml"
    storage: str = "mcap"
    flight_log: bool = True
    preflight_timeout: float = 8.0
    link_timeout: float = 15.0  # s to wait for the vehicle's first HEARTBEAT
    loop_period: float = 0.005  # s, link poll period
    status_period: float = 1.0  # s, periodic status message in the bags
    source: str = ""

    KEYS = (
        "bridge_config",
        "signals_config",
        "identification_config",
        "campaign",
        "recording",
        "preflight",
        "runner",
    )

    @classmethod
    def from_dict(
        cls, d: Mapping[str, Any], base: str | Path = ".", source: str = ""
    ) -> "FlyConfig":
        from lpv_sysid.control.campaign import CampaignConfig
        from lpv_sysid.config_fields import check_keys, is_finite_number

        where = source or "campaign config"
        check_keys(d, cls.KEYS, where, list_allowed=True)
        base = Path(base)
        kw: dict[str, Any] = {"source": source}
        for k in ("bridge_config", "signals_config", "identification_config"):
            if k in d:
                if not isinstance(d[k], str) or not d[k]:
                    raise ConfigError(f"{where}: {k} must be a file name, got {d[k]!r}")
                kw[k] = str(base / d[k])
            else:
                kw[k] = str(base / getattr(cls, k))
        try:
            kw["campaign"] = CampaignConfig.from_dict(d.get("campaign") or {})
        except (ConfigError, TypeError) as exc:
            raise ConfigError(f"{where}: {exc}") from None
        rec = d.get("recording") or {}
        check_keys(rec, ("storage", "flight_log"), f"{where}: recording", list_allowed=True)
        if rec.get("storage", "mcap") not in ("mcap", "sqlite3"):
            raise ConfigError(
                f"{where}: recording.storage must be mcap or sqlite3, got {rec['storage']!r}"
            )
        kw["storage"] = rec.get("storage", "mcap")
        if not isinstance(rec.get("flight_log", True), bool):
            raise ConfigError(f"{where}: recording.flight_log must be true or false")
        kw["flight_log"] = rec.get("flight_log", True)
        pre = d.get("preflight") or {}
        check_keys(pre, ("timeout",), f"{where}: preflight", list_allowed=True)
        run = d.get("runner") or {}
        check_keys(
            run,
            ("link_timeout", "loop_period", "status_period"),
            f"{where}: runner",
            list_allowed=True,
        )
        for sect, key, name, lo, hi in (
            (pre, "timeout", "preflight_timeout", 0.5, 120.0),
            (run, "link_timeout", "link_timeout", 0.5, 600.0),
            (run, "loop_period", "loop_period", 0.0005, 0.05),
            (run, "status_period", "status_period", 0.05, 60.0),
        ):
            if key in sect:
                v = sect[key]
                if not is_finite_number(v) or not lo <= v <= hi:
                    raise ConfigError(
                        f"{where}: {name} must be a number in [{lo}, {hi}], got {v!r}"
                    )
                kw[name] = float(v)
        return cls(**kw)

    @classmethod
    def load(cls, path: str | Path) -> "FlyConfig":
        from lpv_sysid.io.yaml_file import read_yaml

        d = read_yaml(path)
        if not isinstance(d, dict):
            raise ConfigError(f"{path}: expected a mapping at top level")
        return cls.from_dict(d, Path(path).resolve().parent, str(path))


def load_signals(
    path: str | None, signals_config: str
) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """The phase-1 excitation table ``(t, u, names)``: ``signals.npz`` when given, else
    designed from the signal config (``lpv-sysid signals``)."""
    from lpv_sysid.signals.store import load_npz

    if path:
        return load_npz(path)
    from lpv_sysid.signals.config import load_config
    from lpv_sysid.signals.multisine import design

    sig = design(load_config(signals_config))
    return sig.t, sig.u, tuple(sig.names)


def bridge_config_for(path: str, url: str | None, campaign) -> Any:
    """The bridge config of the campaign: ``url`` overrides the link, arming is on (the
    campaign takes off), the velocity frame must be the campaign's."""
    from lpv_sysid.mavlink.bridge import BridgeConfig

    cfg = BridgeConfig.load(path)
    if cfg.command != "velocity":
        raise ConfigError(
            f"{path}: command must be 'velocity' for the phase-1 campaign, got {cfg.command!r}"
        )
    if cfg.velocity_frame != campaign.velocity_frame:
        raise ConfigError(
            f"{path}: velocity_frame {cfg.velocity_frame!r} differs from the campaign's "
            f"{campaign.velocity_frame!r} (the settle check measures in the command frame)"
        )
    link = dataclasses.replace(cfg.link, url=url) if url else cfg.link
    link.validate()
    return dataclasses.replace(
        cfg, link=link, offboard=dataclasses.replace(cfg.offboard, arm=True), auto_start=False
    )


def parse_params(items) -> dict[str, float]:
    out: dict[str, float] = {}
    for it in items or ():
        name, sep, value = str(it).partition("=")
        name = name.strip().upper()
        if not sep or not name or len(name) > 16:
            raise ConfigError(
                f"--set-param {it!r}: expected NAME=VALUE (PX4 names have <= 16 characters)"
            )
        try:
            v = float(value)
        except ValueError:
            raise ConfigError(f"--set-param {it!r}: value is not a number") from None
        if not math.isfinite(v):
            raise ConfigError(f"--set-param {it!r}: value must be finite")
        out[name] = v
    return out


# ====================================================================== vehicle helpers
def wait_for_vehicle(link, timeout: float, clock, sleep) -> None:
    t0 = clock()
    while clock() - t0 < timeout:
        now = clock()
        link.poll(now)
        link.step(now)
        if link.target_system and link.link_up(now):
            return
        sleep(0.005)
    raise SafetyError(f"no autopilot HEARTBEAT on {link.config.url} within {timeout:g} s")


def set_params(
    link, params: Mapping[str, float], clock, sleep, timeout: float = 5.0
) -> list[dict]:
    """PARAM_SET each value (type from a PARAM_REQUEST_READ first) and wait for the
    vehicle's PARAM_VALUE echo with that value; SafetyError when one is not confirmed."""
    from lpv_sysid.mavlink import px4

    done = []
    for name, value in params.items():
        t0 = clock()
        ptype = old = None
        sent_set = -math.inf
        sent_read = -math.inf
        confirmed = False
        while clock() - t0 < timeout and not confirmed:
            now = clock()
            for m in link.poll(now):
                if m.get_type() != "PARAM_VALUE" or m.get_srcSystem() != link.target_system:
                    continue
                if px4.param_id_str(m.param_id) != name:
                    continue
                v = px4.param_from_wire(m.param_value, m.param_type)
                same = math.isclose(
                    float(v), value, rel_tol=1e-6, abs_tol=1e-6
                )  # float32 on the wire
                if ptype is None:
                    ptype, old = int(m.param_type), v
                    confirmed = same  # already set: nothing to change
                elif sent_set > -math.inf and same:
                    confirmed = True
            link.step(now)
            if ptype is None and now - sent_read >= 0.5:
                sent_read = now
                link.send(
                    link.codec.param_request_read_encode(
                        link.target_system, link.target_component, name.encode("ascii"), -1
                    )
                )
            elif ptype is not None and not confirmed and now - sent_set >= 0.5:
                sent_set = now
                link.send(
                    link.codec.param_set_encode(
                        link.target_system,
                        link.target_component,
                        name.encode("ascii"),
                        px4.param_to_wire(value, ptype),
                        ptype,
                    )
                )
            sleep(0.005)
        if not confirmed:
            what = "unknown parameter or no answer" if ptype is None else f"vehicle kept {old}"
            raise SafetyError(
                f"PARAM_SET {name}={value:g} not confirmed within {timeout:g} s ({what})"
            )
        done.append({"name": name, "old": old, "new": value})
    return done


# ============================================================================ recording
class CampaignRecorder:
    """One rosbag2 per run (the runs recorder, split at each run) + the whole flight."""

    def __init__(
        self,
        out_dir: Path,
        storage: str,
        flight_log: bool,
        config_files=(),
        description="",
        rate_setpoints: bool = False,
    ) -> None:
        from lpv_sysid.io import messages
        from lpv_sysid.io.recorder import Recorder, RecorderConfig

        self.messages = messages
        self.f = messages.MsgFactory.rosbags()
        topics = {f"{NAMESPACE}/{n}": messages.TYPES[n] for n in TOPICS}
        if rate_setpoints:
            topics[f"{NAMESPACE}/{RATE_TOPIC}"] = messages.TYPES["actuator_command"]  # JointState
        self.runs = Recorder(
            RecorderConfig(
                out_dir=str(out_dir),
                topics=topics,
                storage=storage,
                config_files=tuple(config_files),
                description=description,
            )
        )
        self.flight = (
            Recorder(
                RecorderConfig(
                    out_dir=str(out_dir / "flight"),
                    topics=topics,
                    storage=storage,
                    description="whole flight (not a maneuver)",
                )
            )
            if flight_log
            else None
        )
        self.active: str | None = None  # run being recorded
        self.bags: dict[str, str] = {}  # run name -> bag directory name
        self.started = False
        self.error: str | None = None

    def start(self, now: float) -> None:
        self.runs.start(_ns(now))
        if self.flight is not None:
            self.flight.start(_ns(now))
        self.started = True

    def begin_run(self, name: str) -> str:
        bag = self.runs.split()
        self.active = name
        self.bags[name] = bag
        return bag

    def end_run(self) -> None:
        self.active = None

    def _write(self, topic: str, stamp: int, msg) -> None:
        if self.error is not None:
            return
        try:
            if self.active is not None:
                self.runs.record(f"{NAMESPACE}/{topic}", stamp, msg)
            if self.flight is not None:
                self.flight.record(f"{NAMESPACE}/{topic}", stamp, msg)
        except LpvSysidError as exc:
            self.error = str(exc)
            raise

    def state(self, t: float, pos_ned, euler, v_body, omega) -> None:
        st = _ns(t)
        self._write(
            "state",
            st,
            self.messages.odometry_from_state(self.f, st, pos_ned, euler, v_body, omega),
        )

    def imu(self, t: float, accel_frd, gyro_frd) -> None:
        st = _ns(t)
        self._write("imu", st, self.messages.imu_msg(self.f, st, accel_frd, gyro_frd))

    def rotors(self, t: float, omega, source: str = "esc") -> None:
        st = _ns(t)
        self._write("rotor_speeds", st, self.messages.rotor_speeds_msg(self.f, st, omega, source))

    def rate_setpoint(self, t: float, u) -> None:
        """(thrust, p_sp, q_sp, r_sp) on ``rate_setpoint`` (PX4's ATTITUDE_TARGET or our
        command)."""
        from lpv_sysid.mavlink.transport import RATE_INPUT_NAMES

        st = _ns(t)
        self._write(
            RATE_TOPIC, st, self.messages.joint_state(self.f, st, RATE_INPUT_NAMES, position=u)
        )

    def reference(self, t: float, v, r: float) -> None:
        st = _ns(t)
        self._write("velocity_reference", st, self.messages.twist_reference_msg(self.f, st, v, r))
        self._write(
            "excitation", st, self.messages.excitation_msg(self.f, st, (0.0, 0.0, 0.0, 0.0))
        )

    def status(self, t: float, level: str, message: str, values: Mapping[str, Any]) -> None:
        st = _ns(t)
        lv = {"info": "OK", "warn": "WARN", "error": "ERROR"}.get(level, level)
        msg = self.messages.diagnostic_array(
            self.f,
            st,
            [self.messages.diagnostic_status(self.f, lv, "lpv_sysid/fly", message, values)],
        )
        self._write("status", st, msg)

    def close(self, now: float) -> list[str]:
        errors = []
        for rec in (self.runs, self.flight):
            if rec is None:
                continue
            try:
                rec.stop(_ns(now))
            except LpvSysidError as exc:
                errors.append(str(exc))
        return errors


def _ns(t: float) -> int:
    return int(round(float(t) * 1e9))


def tap_attitude_target(link, callback: Callable[[float, Any], None]) -> None:
    """Wrap ``link.poll`` so every ATTITUDE_TARGET of the link's target reaches
    ``callback(receive_time, [thrust, p_sp, q_sp, r_sp])`` before the bridge sees the message
    (BridgeCore has no raw-message hook; the telemetry decoder ignores ATTITUDE_TARGET)."""
    from lpv_sysid.mavlink.transport import rate_setpoint_from_attitude_target

    poll = link.poll

    def tapped(now, *a, **kw):
        msgs = poll(now, *a, **kw)
        for m in msgs:
            if m.get_type() == "ATTITUDE_TARGET" and (
                not link.target_system or m.get_srcSystem() == link.target_system
            ):
                got = rate_setpoint_from_attitude_target(m)
                if got is not None:
                    callback(now, got[1])
        return msgs

    link.poll = tapped


# =============================================================================== runner
@dataclass
class FlyResult:
    status: int  # exit status
    phase: str
    reason: str
    summary: dict = field(default_factory=dict)
    out_dir: str = ""


class FlightRunner:
    """Drives bridge + campaign + recorder on ``clock`` (see module docstring)."""

    def __init__(
        self,
        bridge,
        campaign,
        recorder: CampaignRecorder | None,
        clock: Callable[[], float],
        sleep: Callable[[float], None],
        period: float = 0.005,
        status_period: float = 1.0,
        echo: Callable[[str], None] | None = None,
    ) -> None:
        self.bridge = bridge
        self.campaign = campaign
        self.rec = recorder
        self.clock = clock
        self.sleep = sleep
        self.period = period
        self.status_period = status_period
        self.echo = echo or (lambda s: None)
        self.interrupts = 0
        self.max_gap = 0.0
        self.late_loops = 0
        self._interrupts_handled = 0
        self.gave_up = False
        self.events: list[dict] = []
        self.t0 = clock()
        self._next_status = -math.inf
        self.rotor_sources: dict[str, int] = {}

    # ------------------------------------------------------------------ helpers
    def interrupt(self, signo: int = signal.SIGINT) -> None:
        self.interrupts += 1
        self._interrupt_name = signal.Signals(signo).name

    def _event(self, t: float, source: str, level: str, message: str, show: bool = False) -> None:
        self.events.append(
            {"t": round(t - self.t0, 3), "source": source, "level": level, "message": message}
        )
        if level != "info" or source == "campaign" or show:
            self.echo(f"[{t - self.t0:8.2f} s] {source}: {message}")
        if self.rec is not None and self.rec.started:
            self._safe(lambda: self.rec.status(t, level, f"{source}: {message}", self._values()))

    def _values(self) -> dict:
        c = self.campaign
        run = c.run
        st = self.bridge.machine
        d = {
            "phase": c.phase,
            "run": run.name
            if run is not None and c.phase in ("settle", "trim", "excitation")
            else "",
            "bridge_state": st.state.value,
            "vehicle_mode": st.vehicle_mode.name if st.vehicle_mode is not None else "unknown",
            "armed": st.armed,
        }
        if run is not None and c.phase in ("trim", "excitation"):
            d["v_d"] = " ".join(f"{x:g}" for x in run.vertex)
            res = c.results[-1] if c.results else None
            if res is not None and math.isfinite(res.t_excite):
                d["t_excite"] = res.t_excite
        d.update({k: v for k, v in self.bridge.envelope.status().items()})
        return d

    def _safe(self, fn) -> None:
        try:
            fn()
        except LpvSysidError as exc:
            if not self.campaign.finished:
                self.campaign.abort(self.clock(), f"recording failed: {exc}")
            log.error("recording failed: %s", exc)

    def _vehicle_status(self):
        from lpv_sysid.control.campaign import VehicleStatus

        m = self.bridge.machine
        env = self.bridge.envelope
        v = env.violation
        confirmed = getattr(m, "confirmed_mode", None)
        return VehicleStatus(
            m.state.value,
            m.reason,
            m.vehicle_mode.name if m.vehicle_mode is not None else None,
            bool(m.armed),
            env.home if env.home is not None else None,
            f"{v.kind}: {v.message}" if v is not None else None,
            confirmed.name if confirmed is not None else None,
        )

    # ------------------------------------------------------------------ loop
    def run(self) -> None:
        from lpv_sysid.control import campaign
        from lpv_sysid.mavlink.telemetry import ImuSample, RotorSample, StateSample

        c, b = self.campaign, self.bridge
        now = self.clock()
        self._handle(now, c.start(now))
        prev = now
        warn_gap = 0.5 * b.config.offboard.input_timeout
        while not c.finished:
            t_loop = self.clock()
            now = t_loop
            gap, prev = now - prev, now
            self.max_gap = max(self.max_gap, gap)
            if gap > warn_gap:
                # the computer did not keep up (load, swapping): PX4 got no setpoints meanwhile
                self.late_loops += 1
                self._event(
                    now,
                    "runner",
                    "warn",
                    f"loop stalled {gap:.3f} s (> {warn_gap:.3f} s = half the "
                    "bridge input_timeout): the companion computer is overloaded",
                )
            if self.interrupts > self._interrupts_handled and c.phase not in campaign.TERMINAL:
                self._interrupts_handled = self.interrupts
                if self.interrupts >= 2:
                    self._bridge_events(now, b.shutdown(now))
                    self.gave_up = True
                    self._event(
                        now,
                        "campaign",
                        "error",
                        "interrupted twice: stopped waiting for the "
                        "hand-back confirmation (HAND-BACK NOT CONFIRMED)",
                    )
                    break
                c.abort(now, f"interrupted ({getattr(self, '_interrupt_name', 'SIGINT')})")
            out = b.poll(now)
            for s in out.samples:
                if isinstance(s, StateSample):
                    c.on_state(s)
                    if self.rec is not None:
                        self._safe(
                            lambda s=s: self.rec.state(s.t, s.pos_ned, s.euler, s.v_body, s.omega)
                        )
                elif isinstance(s, RotorSample):
                    c.on_rotor(s.t, s.omega)
                    src = getattr(s, "source", "esc")
                    self.rotor_sources[src] = self.rotor_sources.get(src, 0) + 1
                    if self.rec is not None:
                        self._safe(lambda s=s, src=src: self.rec.rotors(s.t, s.omega, src))
                elif isinstance(s, ImuSample) and self.rec is not None:
                    self._safe(lambda s=s: self.rec.imu(s.t, s.accel_frd, s.gyro_frd))
            self._bridge_events(now, out.events)
            co = c.step(now, self._vehicle_status())
            self._handle(now, co)
            if self.rec is not None and now >= self._next_status:
                self._next_status = now + self.status_period
                self._safe(
                    lambda: self.rec.status(now, "info", f"campaign {c.phase}", self._values())
                )
            self.sleep(max(0.0, self.period - (self.clock() - t_loop)))
        from lpv_sysid.mavlink.offboard import STREAMING

        if b.machine.state in STREAMING:  # never leave a stream behind
            self.drain_handback(c.cfg.handback_timeout)

    def _bridge_events(self, now: float, events) -> None:
        for ev in events:
            level = getattr(ev, "level", "warn")
            text = getattr(ev, "reason", None)
            if text is None:
                text = f"{getattr(ev, 'kind', 'link')}: {getattr(ev, 'detail', '')}"
                level = "info" if getattr(ev, "kind", "") == "link_up" else "warn"
            prev, state = getattr(ev, "previous", None), getattr(ev, "state", None)
            moved = prev is not None and prev != state
            if moved:
                text = f"{prev} -> {state}: {text}"
            self._event(getattr(ev, "t", now), "bridge", level, text, show=moved)

    def _handle(self, now: float, co) -> None:
        from lpv_sysid.control import campaign

        b = self.bridge
        for ev in co.events:
            self._event(ev.t, "campaign", ev.level, f"{ev.phase}: {ev.message}")
        for a in co.actions:
            if isinstance(a, campaign.StartBridge):
                self._bridge_events(now, b.start(now))
            elif isinstance(a, campaign.AbortBridge):
                self._bridge_events(now, b.abort(now, a.reason))
            elif isinstance(a, campaign.FinishBridge):
                self._bridge_events(now, b.finish(now, a.mode))
            elif isinstance(a, campaign.ActivateFloor):
                b.envelope.activate_floor(now, a.reason)
            elif isinstance(a, campaign.RunStarted):
                if self.rec is not None:
                    self._safe(
                        lambda a=a: self.echo(
                            f"[{now - self.t0:8.2f} s] recording {a.run.name} -> "
                            f"{self.rec.begin_run(a.run.name)}"
                        )
                    )
            elif isinstance(a, campaign.RunEnded):
                if self.rec is not None:
                    self.rec.end_run()
        if co.command is not None and not self.campaign.finished:
            v, r = co.command
            if b.on_velocity_reference(now, v, r, stamp=now) and self.rec is not None:
                self._safe(lambda: self.rec.reference(now, v, r))

    def prime(self, timeout: float = 3.0) -> None:
        """Poll the bridge until the telemetry and a HEARTBEAT are in and, for a vehicle that is
        already armed, PX4's HOME_POSITION (requested once a second; the envelope's home),
        at most ``timeout``."""
        b = self.bridge
        t0 = self.clock()
        next_req = t0
        while self.clock() - t0 < timeout:
            now = self.clock()
            out = b.poll(now)
            for s in out.samples:
                if hasattr(s, "v_body"):
                    self.campaign.on_state(s)
            self._bridge_events(now, out.events)
            if (
                self.campaign.state is not None
                and b.machine.vehicle_mode is not None
                and (b.envelope.home_position is not None or not b.machine.armed)
            ):
                return  # disarmed: the home is where PX4 arms (envelope docstring)
            if now >= next_req:
                next_req = now + 1.0
                b.link.command_long(512, 242.0)  # MAV_CMD_REQUEST_MESSAGE HOME_POSITION
            self.sleep(self.period)

    def drain_handback(self, timeout: float) -> None:
        """After an exception: hand back at once and poll until confirmed (bounded)."""
        from lpv_sysid.mavlink.offboard import STREAMING, State

        b = self.bridge
        now = self.clock()
        self._bridge_events(now, b.shutdown(now))
        t0 = now
        while b.machine.state in STREAMING + (State.HANDBACK,) and self.clock() - t0 < timeout:
            now = self.clock()
            self._bridge_events(now, b.poll(now).events)
            self.sleep(self.period)


# =============================================================================== fly()
def fly(
    cfg: FlyConfig,
    url: str | None,
    out_dir: str | Path,
    signals: str | None = None,
    params: Mapping[str, float] | None = None,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    echo: Callable[[str], None] = print,
    handle_signals: bool = True,
    preflight: bool = True,
    link=None,
    record_rate_setpoints: bool = False,
) -> FlyResult:
    """The whole CLI sequence of the module docstring (also used by the tests with a
    simulated clock); returns the exit status and the summary. Bad input raises
    :class:`~lpv_sysid.errors.ConfigError` before anything is sent to the vehicle.

    ``record_rate_setpoints``: also record PX4's ATTITUDE_TARGET (the thrust and body-rate
    setpoints its cascade produced) on ``rate_setpoint`` in every bag, the input of the
    rate-plant identification (lpv_sysid/ident/rate_plant.py); request the stream in the
    bridge config (``link.streams: {ATTITUDE_TARGET: 50}``, config/mavlink_bridge_chain.yaml)."""
    import numpy as np

    from lpv_sysid.control.campaign import Campaign, ExcitationProfile, plan_campaign, trim_rows
    from lpv_sysid.mavlink.bridge import BridgeCore

    out = Path(out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError(f"--out {out}: exists and is not an empty directory")
    ccfg = cfg.campaign
    bcfg = bridge_config_for(cfg.bridge_config, url, ccfg)
    table = load_signals(signals, cfg.signals_config)
    prof = ExcitationProfile.from_table(*table, ramp=ccfg.ramp_s, periods=ccfg.periods)
    plan = plan_campaign(ccfg, prof, bcfg.envelope)
    ident_template = _identification_template(cfg.identification_config)
    echo(
        f"fly phase1: {len(plan.runs)} runs, excitation {prof.duration:.1f} s (peaks u v w "
        f"{' '.join(f'{p:.2f}' for p in prof.peak)} m/s, r {prof.yaw_peak:.2f} rad/s), window "
        f"[{ccfg.altitude_min:g}, {ccfg.altitude_max:g}] m, envelope floor "
        f"{bcfg.envelope.floor:g} m "
        f"ceiling {bcfg.envelope.ceiling:g} m radius {bcfg.envelope.radius:g} m"
    )
    echo(plan.describe())

    bridge = BridgeCore(bcfg, link=link)
    bridge.open(clock())
    summary: dict = {
        "connect": bcfg.link.url,
        "config": cfg.source,
        "signals": signals or cfg.signals_config,
    }
    runner = FlightRunner(
        bridge, Campaign(plan, table), None, clock, sleep, cfg.loop_period, cfg.status_period, echo
    )
    previous_handlers: dict = {}
    try:
        wait_for_vehicle(bridge.link, cfg.link_timeout, clock, sleep)
        echo(f"vehicle: system {bridge.link.target_system} on {bcfg.link.url}")
        if params:
            done = set_params(bridge.link, params, clock, sleep)
            summary["params_set"] = done
            for d in done:
                echo(f"PARAM_SET {d['name']}: {d['old']} -> {d['new']:g} (confirmed)")
        if preflight:
            from lpv_sysid.mavlink import preflight as pf

            checks = pf.run_checks(
                bridge.link,
                timeout=cfg.preflight_timeout,
                clock=clock,
                sleep=sleep,
                rotor_estimate=bcfg.rotor_estimate,
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
        rec = CampaignRecorder(
            out,
            cfg.storage,
            cfg.flight_log,
            config_files=[p for p in (cfg.source, cfg.bridge_config) if p and Path(p).is_file()],
            description=f"lpv-sysid fly phase1 on {bcfg.link.url}: one bag per run, "
            "see campaign_summary.yaml",
            rate_setpoints=record_rate_setpoints,
        )
        rec.start(clock())
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
        close_errors = runner.rec.close(clock()) if runner.rec is not None else []
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
    _write_outputs(out, summary, c, ident_template, plan, trim_rows, np)
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


def _identification_template(path: str) -> dict:
    from lpv_sysid.io.yaml_file import read_yaml

    try:
        d = read_yaml(path)
    except ConfigError:
        return {"identification": {}}
    return d if isinstance(d, dict) else {"identification": {}}


def _write_outputs(out: Path, summary: dict, c, ident_template: dict, plan, trim_rows, np) -> None:
    import yaml

    from lpv_sysid.sim.phase1 import write_trim_table

    cfg = plan.config
    (out / "campaign_summary.yaml").write_text(yaml.safe_dump(_plain(summary), sort_keys=False))
    rows = trim_rows(c.results)
    if rows:
        write_trim_table(rows, out)
    ident = dict(ident_template)
    sect = dict(ident.get("identification") or {})
    sect["vmin"] = [float(x) for x in cfg.box_min]
    sect["vmax"] = [float(x) for x in cfg.box_max]
    sect["trim_duration"] = float(cfg.trim_s)
    sect["trim_average"] = float(
        min(sect.get("trim_average", cfg.trim_average_s), cfg.trim_average_s)
    )
    ident["identification"] = sect
    (out / "identification.yaml").write_text(
        "# written by `lpv-sysid fly phase1`: the identification config with the campaign's box "
        "and\n"
        f"# trim duration; lpv-sysid identify --bags {out} --config {out / 'identification.yaml'} "
        "--out "
        "vertex_models.yaml\n" + yaml.safe_dump(ident, sort_keys=False)
    )


def _plain(x):
    """YAML-safe copy (numpy scalars/arrays -> Python)."""
    import numpy as np

    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return _plain(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def format_results(summary: dict) -> str:
    lines = [f"campaign {summary.get('result')}: {summary.get('reason') or 'ok'}"]
    hb = summary.get("handback") or {}
    if hb.get("duration_s") is not None:
        lines.append(f"hand-back: {hb['duration_s']:.2f} s -> {hb.get('mode')}")
    lines.append(
        f"{'run':<22} {'bag':<9} {'settle [s]':>10} {'rms u':>7} {'rms v':>7} {'rms w':>7} "
        f"{'rms r':>7}  achieved (command frame) [m/s]"
    )
    bags = summary.get("bags") or {}
    for r in summary.get("runs") or []:
        rms = r.get("tracking_rms") or {}

        def f(k):
            v = rms.get(k)
            return f"{v:7.3f}" if v is not None else f"{'-':>7}"

        st = r.get("settle_time_s")
        settle = f"{st:10.2f}" if st is not None else f"{'-':>10}"
        ach = " ".join(f"{v:+.2f}" for v in r.get("achieved_frame") or [] if v is not None)
        tag = "" if r.get("complete") else f"  INCOMPLETE: {r.get('reason')}"
        bag = bags.get(r["name"], "-")
        lines.append(
            f"{r['name']:<22} {bag:<9} {settle} {f('u')} {f('v')} {f('w')} {f('r')}  {ach}{tag}"
        )
    return "\n".join(lines)


# ================================================================================== CLI
def add_arguments(parser: argparse.ArgumentParser) -> None:
    modes = parser.add_subparsers(dest="mode", metavar="MODE")
    modes.required = True
    p = modes.add_parser(
        "phase1",
        help="phase-1 campaign: take-off, every vertex + hover validation, land",
        description="Arm and take off in OFFBOARD, fly every vertex of the body-velocity "
        "box (settle, trim, phase-1 multisine) and the hover validation run, "
        "then HOLD or LAND; one rosbag2 per run for `lpv-sysid identify`. "
        "Preflight NO-GO refuses to fly; Ctrl-C hands control back.",
    )
    p.add_argument(
        "--connect",
        required=True,
        metavar="URL",
        help="MAVLink URL, e.g. udpin:127.0.0.1:14540 (PX4 SITL) or /dev/ttyAMA0:921600",
    )
    p.add_argument("--config", required=True, type=Path, help="config/campaign.yaml")
    p.add_argument("--out", required=True, type=Path, help="output directory (new or empty)")
    p.add_argument(
        "--signals",
        default=None,
        help="phase-1 signals.npz (`lpv-sysid signals`); "
        "default: designed from the config's signals_config",
    )
    p.add_argument(
        "--set-param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="PARAM_SET before preflight, confirmed by the vehicle (repeatable), "
        "e.g. COM_OBL_RC_ACT=5 on a SITL without RC",
    )
    p.add_argument(
        "--dry-run", action="store_true", help="load and plan only; print the plan and exit"
    )
    p2 = modes.add_parser(
        "phase2",
        help="phase-2 flight under the LPV law (rate plant) on a vehicle in the air",
        description="Take the armed, airborne vehicle (e.g. in HOLD after `fly phase1` with "
        "finish: HOLD) into OFFBOARD with the LPV law's thrust + body-rate "
        "setpoints (rate plant, lpv_sysid/cli/chain.py), fly the phase-2 signal, "
        "hand back (LAND); bag, phase2_summary.yaml with the measured u_e -> z gain.",
    )
    p2.add_argument("--connect", required=True, metavar="URL", help="MAVLink URL")
    p2.add_argument(
        "--gains", required=True, help="rate-plant gains.yaml (lpv-sysid chain / synthesize)"
    )
    p2.add_argument(
        "--models", default=None, help="vertex_models.yaml the gains were designed for (checked)"
    )
    p2.add_argument(
        "--signals", required=True, help="phase-2 signals directory (lpv-sysid signals)"
    )
    p2.add_argument(
        "--bridge-config",
        default=None,
        help="bridge config (default config/mavlink_bridge_chain.yaml)",
    )
    p2.add_argument("--out", required=True, type=Path, help="output directory (new or empty)")
    p2.add_argument(
        "--kappa", type=float, default=1.0, help="excitation multiplier (seed 0 Eq. 33)"
    )
    p2.add_argument(
        "--finish", default="LAND", choices=("LAND", "HOLD"), help="mode after the signal"
    )
    p.add_argument(
        "--record-rate-setpoints",
        action="store_true",
        help="also record PX4's ATTITUDE_TARGET (thrust + body-rate setpoints) on rate_setpoint "
        "(rate-plant identification; request the stream, e.g. config/mavlink_bridge_chain.yaml)",
    )


def run(args: argparse.Namespace) -> int:
    if args.mode == "phase2":
        from lpv_sysid.cli.chain import Phase2Options, fly_phase2

        s = fly_phase2(
            args.gains,
            args.signals,
            args.out,
            url=args.connect,
            models=args.models,
            bridge_config=args.bridge_config,
            opts=Phase2Options(kappa=args.kappa, finish=args.finish),
        )
        print(
            f"phase 2 {'complete' if s.get('ok') else 'FAILED'}: {s.get('reason')}; "
            f"{args.out / 'phase2_summary.yaml'}"
        )
        return 0 if s.get("ok") else EXIT_FAILED
    cfg = FlyConfig.load(args.config)
    if args.dry_run:
        from lpv_sysid.control.campaign import ExcitationProfile, plan_campaign

        bcfg = bridge_config_for(cfg.bridge_config, args.connect, cfg.campaign)
        table = load_signals(args.signals, cfg.signals_config)
        prof = ExcitationProfile.from_table(
            *table, ramp=cfg.campaign.ramp_s, periods=cfg.campaign.periods
        )
        print(plan_campaign(cfg.campaign, prof, bcfg.envelope).describe())
        return 0
    res = fly(
        cfg,
        args.connect,
        args.out,
        signals=args.signals,
        params=parse_params(args.set_param),
        record_rate_setpoints=args.record_rate_setpoints,
    )
    if res.status:
        import sys

        print(f"lpv-sysid fly: {res.phase}: {res.reason}", file=sys.stderr)
    else:
        print(
            f"wrote {res.out_dir}: {len(res.summary.get('bags', {}))} bags, "
            "campaign_summary.yaml, "
            f"trims.yaml, identification.yaml"
        )
        print(
            f"next: lpv-sysid identify --bags {res.out_dir} --config "
            f"{Path(res.out_dir) / 'identification.yaml'} "
            f"--out vertex_models.yaml"
        )
    return res.status
