"""The bridge core (:class:`BridgeCore`, its :class:`BridgeConfig` and :class:`BridgeOutput`):
link, telemetry decoder, offboard machine, envelope and setpoint transport in one step per
poll; the method is the :mod:`lpv_sysid.mavlink.bridge` docstring."""

from __future__ import annotations

import logging
import math
import struct
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Mapping

import numpy as np

from lpv_sysid.configuration import fields as cf
from lpv_sysid.control.envelope import Envelope, EnvelopeConfig, Violation
from lpv_sysid.errors import LpvSysidError, SafetyError
from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.bridge.transport import (
    ABSURD_FACTOR,
    ActuatorSetpoint,
    TransportContext,
    VelocitySetpoint,
    make_transport,
)
from lpv_sysid.mavlink.link import LinkConfig, LinkEvent, MavlinkLink
from lpv_sysid.mavlink.offboard import (
    STREAMING,
    OffboardConfig,
    OffboardMachine,
    SendCommand,
    SendSetpoint,
    State,
    StatusEvent,
)
from lpv_sysid.mavlink.telemetry import (
    ReceiverClock,
    RotorEstimateConfig,
    StateSample,
    TelemetryDecoder,
    with_motor_output_streams,
)

log = logging.getLogger(__name__)


#: nested sections of the bridge config -> their classes (each parsed by its from_dict)
_SECTIONS: dict[str, Any] = {
    "link": LinkConfig,
    "offboard": OffboardConfig,
    "rotor_estimate": RotorEstimateConfig,
    "envelope": EnvelopeConfig,
}


@dataclass(frozen=True)
class BridgeConfig:
    """``config/mavlink_bridge.yaml``: sections ``link``, ``offboard``, ``rotor_estimate``,
    ``envelope`` and the command path, checked by :meth:`validate` (also for a config built
    in code: :class:`BridgeCore` calls it; the parts that use a section check it)."""

    link: LinkConfig = field(default_factory=LinkConfig)
    offboard: OffboardConfig = field(default_factory=OffboardConfig)
    command: str = cf.text(
        "velocity",
        "setpoint kind: velocity | attitude_rate | rate_setpoint (the transports of "
        "make_transport, which checks it with the geometry)",
    )
    velocity_frame: str = cf.choice(
        "body_ned", ("body_ned", "local_ned"), "velocity setpoint frame (PX4 rotates by yaw)"
    )
    use_yaw_rate: bool = cf.flag(True, "velocity setpoints carry the yaw-rate reference")
    arm_length: float = cf.number(
        0.225, "attitude_rate: seed 0 Eq. (7) geometry [m]", lo=0.01, hi=10.0, unit=" m"
    )
    rate_p: tuple[float, float, float] = cf.numbers(
        (0.15, 0.15, 0.2),
        "attitude_rate: PX4 MC_ROLLRATE_P, MC_PITCHRATE_P, MC_YAWRATE_P; 0.01 .. 0.6 (PX4's "
        "ranges: omega_sp = omega + tau / K_p amplifies a smaller one)",
        length=3,
        lo=0.01,
        hi=0.6,
    )
    command_abort_factor: float = cf.number(
        ABSURD_FACTOR,
        "attitude_rate / rate_setpoint: a command beyond this multiple of the transport's "
        "range (thrust, body rate) aborts (hand-back) instead of being clipped; 1 .. 100",
        lo=1.0,
        hi=100.0,
    )
    auto_start: bool = cf.flag(False, "start the machine on the first command")
    telemetry_max_age: float = cf.number(
        0.5,
        "attitude/velocity older than this makes no state sample [s]; 0.01 .. 1 s: older "
        "telemetry is no feedback for a flying vehicle",
        lo=0.01,
        hi=1.0,
        unit=" s",
    )
    n_rotors: int = cf.count(4, "number of rotors (ESC_STATUS / motor outputs)", lo=1, hi=8)
    rotor_estimate: RotorEstimateConfig = field(
        default_factory=RotorEstimateConfig
    )  # no ESC telemetry
    envelope: EnvelopeConfig = field(default_factory=EnvelopeConfig)  # control/envelope.py

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "") -> "BridgeConfig":
        """The fields and sections of ``d``; ``where`` prefixes the paths (node parameters:
        none, so a message names the parameter, ``link.url``)."""
        kw = cf.parse_fields(cls, d, where, other_keys=_SECTIONS)
        for name, section in _SECTIONS.items():
            kw[name] = section.from_dict(d.get(name) or {}, cf.join(where, name))
        cfg = cls(**kw)
        cfg.validate(where)
        return cfg

    @classmethod
    def load(cls, path: str) -> "BridgeConfig":
        from lpv_sysid.io.files import read_yaml_mapping

        d = read_yaml_mapping(path)  # an explicitly given empty or non-mapping file is an error
        return cls.from_dict(d, path)

    def airborne_rates(self, url: str | None = None) -> "BridgeConfig":
        """This config for thrust + body-rate setpoints on a vehicle already in the air
        (phase 2, the broken-loop run): command ``attitude_rate`` (the caller may pick the
        rate-setpoint transport), no arming, no auto start, ``url`` overriding the link's."""
        link = replace(self.link, url=url) if url else self.link
        link.validate()
        return replace(
            self,
            link=link,
            command="attitude_rate",
            auto_start=False,
            offboard=replace(self.offboard, arm=False),
        )

    def validate(self, where: str = "") -> None:
        """The declared fields of the top level, then the command against its transport
        (:func:`make_transport` checks the kind and the geometry)."""
        cf.check_fields(self, where)
        cf.under(cf.join(where, "command"), self.transport)

    def transport(self):
        if self.command == "velocity":
            return make_transport(
                "velocity", frame=self.velocity_frame, use_yaw_rate=self.use_yaw_rate
            )
        if self.command == "attitude_rate":
            return make_transport(
                "attitude_rate",
                arm_length=self.arm_length,
                rate_p=self.rate_p,
                absurd_factor=self.command_abort_factor,
            )
        if self.command == "rate_setpoint":
            return make_transport(self.command, absurd_factor=self.command_abort_factor)
        return make_transport(self.command)


@dataclass
class BridgeOutput:
    samples: list[Any] = field(default_factory=list)
    events: list[Any] = field(default_factory=list)  # StatusEvent | LinkEvent


class BridgeCore:
    """See module docstring."""

    def __init__(
        self,
        config: BridgeConfig,
        link: Any = None,  # MavlinkLink (default) or mavros_link.MavrosLink
        sample_callback: Callable[[Any], None] | None = None,
    ) -> None:
        config.validate()
        self.config = config
        self.link = link or MavlinkLink(
            with_motor_output_streams(config.link, config.rotor_estimate)
        )
        # telemetry only from the link's target (configured, or the first autopilot HEARTBEAT)
        # a link whose messages are stamped on this clock already (MAVROS: ROS time) keeps
        # the stamps; PX4's boot times are mapped (telemetry/clock.py)
        self.telemetry = TelemetryDecoder(
            config.n_rotors,
            config.telemetry_max_age,
            rotor_estimate=config.rotor_estimate,
            source_filter=True,
            clock=ReceiverClock() if getattr(self.link, "RECEIVER_CLOCK", False) else None,
        )
        self.transport = config.transport()
        self.machine = OffboardMachine(config.offboard, self.transport.neutral())
        self.sample_callback = sample_callback
        self.rejected_commands = 0
        self._t0: float | None = None
        self._last_stamp = -math.inf
        self._pending_events: list[Any] = []
        self._link_was_up = False
        self._state: StateSample | None = None
        self._last_ack: tuple[int, int] | None = None
        self.envelope = Envelope(config.envelope)

    # ----------------------------------------------------------- lifecycle
    def open(self, now: float) -> None:
        """Open the link; if the device is not there yet, report it and retry in poll()."""
        self._t0 = now
        try:
            self.link.open(now)
        except LpvSysidError as exc:
            self.link.stats.io_errors += 1
            self._pending_events.append(
                LinkEvent(
                    now, "io_error", f"{exc}; retrying every {self.config.link.reconnect_period} s"
                )
            )

    def close(self) -> None:
        self.link.close()

    # ----------------------------------------------------------------- loop
    def poll(self, now: float) -> BridgeOutput:
        out = BridgeOutput()
        if self._t0 is None:
            self._t0 = now
        for msg in self.link.poll(now):
            self._on_message(msg, now, out)
        self.link.step(now)
        for ev in self.link.events():
            out.events.append(ev)
        up = self.link.link_up(now)
        if up != self._link_was_up:
            self._link_was_up = up
            self._run(self.machine.on_link(now, up), now, out)
        self._run(self.machine.step(now), now, out)
        out.events[:0] = self._pending_events
        self._pending_events = []
        return out

    def _on_message(self, msg: Any, now: float, out: BridgeOutput) -> None:
        mtype = msg.get_type()
        if mtype == "HEARTBEAT":
            # mode, ACK and home evidence only from the target autopilot component
            if self.link.from_autopilot(msg) and msg.autopilot != 8:
                mode = px4.decode_custom_mode(msg.custom_mode)
                armed = bool(msg.base_mode & px4.MAV_MODE_FLAG_SAFETY_ARMED)
                if not self._link_was_up:
                    self._link_was_up = True
                    self._run(self.machine.on_link(now, True), now, out)
                self._run(self.machine.on_heartbeat(now, mode, armed), now, out)
            return
        if mtype == "COMMAND_ACK":
            if self.link.from_autopilot(msg):
                self._run(self.machine.on_ack(now, msg.command, msg.result), now, out)
            return
        if mtype == "HOME_POSITION":
            if self.link.from_autopilot(msg):
                self.envelope.set_home_position((msg.x, msg.y, msg.z))
            return
        link = self.link
        if link.target_system and not link.ambiguous_target:
            self.telemetry.target = (link.target_system, link.target_component)
        else:
            self.telemetry.target = None
        for s in self.telemetry.on_message(msg, now):
            if isinstance(s, StateSample):
                self._state = s
                if self.machine.state in STREAMING:
                    v = self.envelope.check_state(s)
                    self._envelope_notices(out)
                    if v is not None:
                        self._envelope_abort(now, v, out)
            out.samples.append(s)
            if self.sample_callback is not None:
                self.sample_callback(s)

    # ------------------------------------------------------------- inputs
    def on_velocity_reference(
        self, now: float, v_frd: Any, yaw_rate: float = 0.0, stamp: float | None = None
    ) -> bool:
        bad = self.envelope.check_setpoint(now, v_frd, yaw_rate)
        if bad is not None:
            # never encoded; while streaming it is an envelope violation -> hand-back
            reason = f"velocity reference rejected: {bad.message}"
            if self.machine.state in STREAMING:
                out = BridgeOutput()
                self.rejected_commands += 1
                log.warning(reason)
                self._envelope_abort(
                    now, self.envelope.trip(Violation(now, bad.kind, reason)), out
                )
                self._pending_events.extend(out.events)
                return False
            return self._reject(now, reason)
        v = np.asarray(v_frd, dtype=float)
        if self.config.command != "velocity":
            return self._reject(
                now, f"velocity reference ignored: bridge command is {self.config.command!r}"
            )
        v_cmd = (float(v[0]), float(v[1]), float(v[2]))
        return self._command(now, VelocitySetpoint(v_cmd, float(yaw_rate)), stamp)

    def on_actuator_command(self, now: float, u: Any, stamp: float | None = None) -> bool:
        try:
            a = np.asarray(u, dtype=float)
        except (TypeError, ValueError):
            return self._reject(now, f"actuator command rejected: not numeric ({u!r})")
        if a.shape != (4,) or not np.isfinite(a).all():
            return self._reject(
                now,
                f"actuator command rejected: needs 4 finite values (ut, ua, ue, ur), "
                f"got {a.tolist()!r}",
            )
        if self.config.command not in ("attitude_rate", "rate_setpoint"):
            return self._reject(
                now, f"actuator command ignored: bridge command is {self.config.command!r}"
            )
        u_cmd = (float(a[0]), float(a[1]), float(a[2]), float(a[3]))
        return self._command(now, ActuatorSetpoint(u_cmd), stamp)

    def start(self, now: float) -> list[Any]:
        """Begin pre-streaming (service ``start``) and arm the envelope; returns the status
        events it caused."""
        out = BridgeOutput()
        self._start_machine(now, out)
        return out.events

    def abort(self, now: float, reason: str = "abort requested") -> list[Any]:
        """Hand control back (service ``abort``); returns the status events it caused."""
        out = BridgeOutput()
        self._run(self.machine.abort(now, reason), now, out)
        return out.events

    def finish(self, now: float, mode: str = "LAND") -> list[Any]:
        """End the session in ``mode`` (e.g. LAND after a campaign) with the offboard
        machine's confirmation rules (``OffboardMachine.finish``); returns its events."""
        out = BridgeOutput()
        self._run(self.machine.finish(now, mode), now, out)
        return out.events

    def shutdown(self, now: float) -> list[Any]:
        """Hand control back at once (node shutdown); returns all undelivered status events."""
        out = BridgeOutput()
        self._run(self.machine.shutdown(now), now, out)
        events, self._pending_events = self._pending_events + out.events, []
        return events

    # ------------------------------------------------------------ status
    def status(self, now: float) -> dict[str, str]:
        d = self.machine.status(now)
        d.update({f"link_{k}": str(v) for k, v in self.link.stats.as_dict().items()})
        d["link_up"] = str(self.link.link_up(now))
        d["rejected_commands"] = str(self.rejected_commands)
        tel = self.telemetry
        d["telemetry_out_of_order"] = str(tel.stats.out_of_order)
        d["foreign_messages"] = str(tel.stats.foreign)
        d["foreign_sources"] = " ".join(
            f"{s}/{c}:{n}" for (s, c), n in sorted(tel.foreign_sources.items())
        )
        d["attitude_source"] = tel.attitude_source(now) or "none"
        d["position_source"] = tel.position_source(now) or "none"
        d["rotor_source"] = tel.rotor_source or "none"
        d.update(self.envelope.status())
        for k, age in self.telemetry.staleness(now).items():
            d[f"age_{k}_s"] = f"{age:.3f}" if math.isfinite(age) else "inf"
        return d

    @property
    def state(self) -> State:
        return self.machine.state

    # ---------------------------------------------------------- internals
    def _command(self, now: float, sp: Any, stamp: float | None) -> bool:
        if stamp is not None:
            if stamp < self._last_stamp:
                return self._reject(
                    now, f"out-of-order command (stamp {stamp:.6f} < {self._last_stamp:.6f})"
                )
            self._last_stamp = stamp
        out = BridgeOutput()
        self._run(self.machine.on_command(now, sp), now, out)
        if self.config.auto_start and self.machine.state == State.IDLE:
            self._start_machine(now, out)
        self._pending_events.extend(out.events)
        return True

    def _start_machine(self, now: float, out: BridgeOutput) -> None:
        if self.machine.state not in STREAMING and self.machine.state != State.HANDBACK:
            s = self._state
            fresh = s is not None and now - s.t <= self.config.telemetry_max_age
            pos = s.pos_ned if s is not None and fresh else None
            bad = self.envelope.arm(now, pos, vehicle_armed=self.machine.armed)
            self._envelope_notices(out)
            if bad is not None:
                reason = f"start refused: envelope: {bad.message}"
                log.error(reason)
                out.events.append(
                    StatusEvent(
                        now, self.machine.state.value, self.machine.state.value, reason, "error"
                    )
                )
                return
        self._run(self.machine.start(now), now, out)

    def _envelope_notices(self, out: BridgeOutput) -> None:
        for n in self.envelope.notices():
            log.info(n.message)
            out.events.append(
                StatusEvent(
                    n.t, self.machine.state.value, self.machine.state.value, n.message, n.level
                )
            )

    def _envelope_abort(self, now: float, v: Violation, out: BridgeOutput) -> None:
        reason = f"envelope violation ({v.kind}): {v.message}"
        log.error(reason)
        out.events.append(
            StatusEvent(now, self.machine.state.value, self.machine.state.value, reason, "error")
        )
        self._run(self.machine.abort(now, reason), now, out)

    def _reject(self, now: float, reason: str) -> bool:
        self.rejected_commands += 1
        log.warning(reason)
        self._pending_events.append(
            StatusEvent(now, self.machine.state.value, self.machine.state.value, reason, "error")
        )
        return False

    def _ctx(self, now: float) -> TransportContext:
        s = self._state
        if s is not None and now - s.t > self.config.telemetry_max_age:
            s = None  # stale: no attitude or rates for the transport
        return TransportContext(
            int(max(now - (self._t0 or now), 0.0) * 1000) & 0xFFFFFFFF,
            self.link.target_system or 1,
            self.link.target_component,
            s.q_wxyz if s is not None else None,
            s.omega if s is not None else None,
        )

    def _run(self, actions: list[Any], now: float, out: BridgeOutput) -> None:
        for a in actions:
            if isinstance(a, SendSetpoint):
                if self.link.codec is None:
                    continue
                try:
                    for m in self.transport.encode(self.link.codec, a.setpoint, self._ctx(now)):
                        self.link.send(m)  # packing (float32) can overflow too
                except (SafetyError, OverflowError, struct.error, ValueError) as exc:
                    self._run(self.machine.abort(now, f"setpoint not encodable: {exc}"), now, out)
                    out.events.append(
                        StatusEvent(
                            now,
                            self.machine.state.value,
                            self.machine.state.value,
                            f"setpoint not encodable: {exc}",
                            "error",
                        )
                    )
                    continue
            elif isinstance(a, SendCommand):
                self.link.command_long(a.command, *a.params, confirmation=a.attempt - 1)
            else:
                out.events.append(a)
