"""Message-level behaviour of mavlink_bridge_node (no rclpy here).

The node shell (``nodes/mavlink_bridge_node.py``) creates the publishers, subscriptions and
timers :class:`BridgeRuntime` lists for the selected ``transport`` and forwards messages,
timer ticks and service calls to it; the runtime answers with ``[(key, message), ...]`` to
publish (keys of :attr:`BridgeRuntime.publishers`) and queues its log lines
(:meth:`BridgeRuntime.take_log`, logged by the shell with the node's logger).

``transport: mavlink``: :class:`~lpv_sysid.mavlink.bridge.BridgeCore` (own MAVLink link):
the timer at ``poll_rate_hz`` polls the link, decoded telemetry goes out on ``state``,
``imu`` and ``rotor_speeds``; ``velocity_reference`` / ``actuator_command`` are forwarded as
setpoints; when commands stop for ``offboard.input_timeout`` s, on ``abort`` or on
shutdown the core hands control back to PX4. ``transport: mavros``:
:class:`~lpv_sysid.mavlink.bridge.mavros.MavrosCore`: MAVROS odometry and IMU are republished on
``state`` / ``imu``, references streamed on MAVROS's ``cmd_vel`` by a timer at twice the
setpoint rate. Either way the core's events and status values make the ``status``
DiagnosticArray (:meth:`BridgeRuntime.status`): the last warn/error event names the level
and message, every event is logged.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence, Union

from lpv_sysid.errors import LpvSysidError
from lpv_sysid.flight.bridge.settings import BridgeNodeSettings, handback_bound_s, split_parameters
from lpv_sysid.io import messages
from lpv_sysid.mavlink.bridge import (
    DIAGNOSTICS_TOPIC,
    MODE_CONTROL,
    BridgeConfig,
    BridgeCore,
    MavrosConfig,
    MavrosCore,
    RATE_INPUT_NAMES,
    MavrosOutput,
    cmd_vel_msg,
)
from lpv_sysid.mavlink.telemetry import ImuSample, RotorSample, StateSample

#: the package input topics parsed by the shell (``ShellNode.parse_input``: a bad message is
#: dropped with a throttled warning) before :meth:`BridgeRuntime.on_sample`
PARSERS = {
    "velocity_reference": messages.reference_from_twist,
    "actuator_command": messages.actuator_command_from_joint_state,
}
#: ``command: rate_setpoint`` (the rate-plant design): ``actuator_command`` carries the rate
#: plant's inputs (thrust, p_sp, q_sp, r_sp), sent as SET_ATTITUDE_TARGET unchanged but clipped
RATE_PLANT_PARSERS = {
    **PARSERS,
    "actuator_command": lambda msg: messages.channels_from_joint_state(
        msg, RATE_INPUT_NAMES, field="position"
    ),
}
#: rate of PX4's ATTITUDE_TARGET requested with ``command: rate_setpoint`` unless configured [Hz]
ATTITUDE_TARGET_HZ = 50.0


def with_attitude_target_stream(cfg: BridgeConfig) -> BridgeConfig:
    """``cfg`` with PX4's ATTITUDE_TARGET requested at :data:`ATTITUDE_TARGET_HZ` (the echo of
    the rate setpoints it tracks, recorded on ``rate_setpoint``) unless its rate is
    configured (also 0 = off)."""
    import dataclasses

    if any(name == "ATTITUDE_TARGET" for name, _ in cfg.link.streams):
        return cfg
    streams = tuple(cfg.link.streams) + (("ATTITUDE_TARGET", ATTITUDE_TARGET_HZ),)
    return dataclasses.replace(cfg, link=dataclasses.replace(cfg.link, streams=streams))


#: core states in which the orderly shutdown needs no more spinning
SHUTDOWN_DONE = ("IDLE", "DONE", "FAILED")


@dataclass(frozen=True)
class Endpoint:
    """A publisher or subscription the shell creates: ``key`` names the message type and
    the handler, ``topic`` the topic (relative: in the node's namespace); ``qos``
    ``sensor`` | ``reliable``, or empty for the package topic table's QoS."""

    key: str
    topic: str
    qos: str = ""


Output = list[tuple[str, Any]]


class BridgeRuntime:
    """See module docstring. ``params``: the declared values of
    :data:`~lpv_sysid.flight.bridge.settings.SPECS`; ``factory`` builds the messages;
    ``sigterm_timeout_s`` / ``teardown_margin_s``: what a launch leaves the orderly shutdown
    (a hand-back chain longer than their difference is warned)."""

    def __init__(
        self,
        params: Mapping[str, Any],
        factory: messages.MsgFactory,
        name: str,
        sigterm_timeout_s: float,
        teardown_margin_s: float,
    ) -> None:
        own, bridge, mavros = split_parameters(params)
        self.settings = s = BridgeNodeSettings.from_dict(own)
        self.f, self.name = factory, name
        self._log: list[tuple[str, str]] = []
        self._shutting_down = False
        self.link: BridgeCore | None = None
        self.mavros: MavrosCore | None = None
        #: the orderly-shutdown bound [s] (None: the shell's default)
        self.shutdown_timeout_s: float | None = None
        self.publishers = [Endpoint("state", "state"), Endpoint("imu", "imu")]
        self.subscriptions = [Endpoint("velocity_reference", "velocity_reference")]
        self.core: Union[MavrosCore, BridgeCore]
        #: the parsers of the package input topics for this configuration (the shell's)
        self.parsers: Mapping[str, Any] = PARSERS
        if s.transport == "mavros":
            self.core = self.mavros = MavrosCore(MavrosConfig.from_dict(mavros))
            cfg = self.mavros.config
            self.publishers.append(Endpoint("cmd_vel", cfg.topic("cmd_vel"), "reliable"))
            self.subscriptions += [
                Endpoint("mavros_odom", cfg.topic("odom"), "sensor"),
                Endpoint("mavros_imu", cfg.topic("imu"), "sensor"),
            ]
            if cfg.use_diagnostics:
                self.subscriptions.append(
                    Endpoint("mavros_diagnostics", DIAGNOSTICS_TOPIC, "sensor")
                )
            # twice the setpoint rate: the core sends when due; stale input is seen within
            # half a setpoint period
            self.timer_period_s = 0.5 / cfg.setpoint_rate_hz
            self._log.append(
                (
                    "info",
                    f"MAVROS {cfg.namespace}: setpoints on {cfg.topic('cmd_vel')}; "
                    f"mode control: {MODE_CONTROL}",
                )
            )
        else:
            cfg_b = BridgeConfig.from_dict(bridge)
            if cfg_b.command == "rate_setpoint":
                self.parsers = RATE_PLANT_PARSERS
            if s.rate_setpoints:
                cfg_b = with_attitude_target_stream(cfg_b)
            self.core = self.link = BridgeCore(cfg_b)
            #: PX4's ATTITUDE_TARGET (the setpoints it tracks) seen since the last poll
            self._echo: list[tuple[float, Any]] = []
            self.publishers.append(Endpoint("rotor_speeds", "rotor_speeds"))
            if s.rate_setpoints:
                self.publishers.append(Endpoint("rate_setpoint", "rate_setpoint"))
            self.subscriptions.append(Endpoint("actuator_command", "actuator_command"))
            if cfg_b.command != "velocity":
                # phase 2: the excitation node's velocity_reference is the controller's input,
                # not a setpoint of this bridge (each one was rejected with a WARN status:
                # 100 status messages a second on the stand-in graph)
                self.subscriptions = [
                    e for e in self.subscriptions if e.key != "velocity_reference"
                ]
            self.timer_period_s = 1.0 / s.poll_rate_hz
            self._log += self._handback_lines(sigterm_timeout_s, teardown_margin_s)

    def _handback_lines(self, sigterm_timeout_s: float, margin_s: float) -> list[tuple[str, str]]:
        assert self.link is not None  # transport mavlink
        cfg = self.link.config
        bound = self.shutdown_timeout_s = handback_bound_s(cfg.offboard)
        lines = [
            (
                "info",
                f"MAVLink {cfg.link.url}, command {cfg.command}; hand-back chain "
                f"{list(cfg.offboard.handback_chain)} within {bound:g} s",
            )
        ]
        budget = sigterm_timeout_s - margin_s
        if bound > budget:
            lines.append(
                (
                    "warn",
                    f"the hand-back chain may need {bound:g} s, more than the "
                    f"{budget:g} s a launch Ctrl-C leaves before SIGTERM: launch with "
                    f"sigterm_timeout:={bound + margin_s:g}",
                )
            )
        return lines

    def take_log(self) -> list[tuple[str, str]]:
        """Queued ``(level, text)`` lines (level: info | warn | error), oldest first."""
        out, self._log = self._log, []
        return out

    def open(self, now: float) -> None:
        """Open the MAVLink link (transport mavlink; MAVROS owns its link); PX4's
        ATTITUDE_TARGET is republished on ``rate_setpoint``."""
        if self.link is not None:
            from lpv_sysid.flight.vehicle import tap_attitude_target

            self.link.open(now)
            if self.settings.rate_setpoints:
                tap_attitude_target(self.link.link, lambda t, u: self._echo.append((t, u)))

    # -- inputs ---------------------------------------------------------------------------
    def on_sample(self, key: str, parsed: tuple, now: float) -> Output:
        """A package input parsed by :data:`PARSERS` ``[key]``: forwarded to the core."""
        if key == "velocity_reference":
            t, v, r = parsed
            out = self.core.on_velocity_reference(now, v, r, stamp=t)
            return self._mavros_out(out, now) if isinstance(out, MavrosOutput) else []
        if self.link is not None and key == "actuator_command":
            self.link.on_actuator_command(now, parsed[1], stamp=parsed[0])
        return []

    def on_message(self, key: str, msg: Any, now: float) -> Output:
        """A MAVROS message (transport mavros): ``mavros_odom`` / ``mavros_imu`` are parsed in
        MAVROS's frames (a bad one is counted and reported by the core) and republished on
        ``state`` / ``imu``; ``mavros_diagnostics`` gives the PX4 mode."""
        core = self.mavros
        if core is None:
            return []
        if key == "mavros_diagnostics":
            try:
                _, statuses = messages.status_from_diagnostic_array(msg)
            except LpvSysidError:
                return []  # other nodes' diagnostics are not ours to judge
            core.on_diagnostics(now, statuses)
            return []
        cfg, f = core.config, self.f
        odom = key == "mavros_odom"
        try:
            if odom:
                s = messages.state_from_odometry(
                    msg, frame_id=cfg.odom_frame_id, child_frame_id=cfg.base_frame_id
                )
            else:
                i = messages.imu_from_msg(msg, frame_id=cfg.base_frame_id)
        except LpvSysidError as exc:
            core.reject(now, f"{cfg.topic('odom' if odom else 'imu')} rejected: {exc}")
            return []
        if odom:
            st = core.on_odometry(now, s)
            if st is None:
                return []
            return [
                (
                    "state",
                    messages.odometry_from_state(
                        f, st.stamp_ns, st.pos_ned, st.euler, st.v_body, st.omega
                    ),
                )
            ]
        imu = core.on_imu(now, i)
        if imu is None:
            return []
        return [
            ("imu", messages.imu_msg(f, imu.stamp_ns, imu.specific_force, imu.omega, imu.euler))
        ]

    # -- services -------------------------------------------------------------------------
    def start(self, now: float) -> tuple[bool, str, Output]:
        """The ``start`` service: ``(success, message, output)`` (the status to publish)."""
        events = self.core.start(now)
        return True, f"offboard: {self.core.state.value}", self.status(now, events)

    def abort(self, now: float, reason: str = "abort service") -> tuple[bool, str, Output]:
        """The ``abort`` service: hand control back; ``(success, message, output)``."""
        events = self.core.abort(now, reason)
        message = f"handing control back to PX4: {self.core.state.value}"
        return True, message, self.status(now, events)

    # -- loop -----------------------------------------------------------------------------
    def on_timer(self, now: float) -> Output:
        """The ``timer_period_s`` timer: poll the link (mavlink) or step the MAVROS stream."""
        if self.mavros is not None:
            return self._mavros_out(self.mavros.step(now), now)
        assert self.link is not None
        out = self.link.poll(now)
        f = self.f
        pubs: Output = []
        for s in out.samples:
            stamp = round(s.t * 1e9)
            if isinstance(s, StateSample):
                pubs.append(
                    (
                        "state",
                        messages.odometry_from_state(
                            f, stamp, s.pos_ned, s.euler, s.v_body, s.omega
                        ),
                    )
                )
            elif isinstance(s, ImuSample):
                pubs.append(("imu", messages.imu_msg(f, stamp, s.accel_frd, s.gyro_frd)))
            elif isinstance(s, RotorSample):
                pubs.append(
                    ("rotor_speeds", messages.rotor_speeds_msg(f, stamp, s.omega, s.source))
                )
        for t, u in self._echo:
            pubs.append(
                (
                    "rate_setpoint",
                    messages.joint_state(f, round(t * 1e9), RATE_INPUT_NAMES, position=u),
                )
            )
        self._echo.clear()
        if out.events:
            pubs += self.status(now, out.events)
        return pubs

    def _mavros_out(self, out: MavrosOutput, now: float) -> Output:
        assert self.mavros is not None
        frame = self.mavros.config.odom_frame_id
        pubs: Output = [
            ("cmd_vel", cmd_vel_msg(self.f, round(sp.t * 1e9), sp, frame)) for sp in out.setpoints
        ]
        if out.events:
            pubs += self.status(now, out.events)
        return pubs

    def status(self, now: float, events: Sequence[Any] = ()) -> Output:
        """The ``status`` array: the core's values; level and message of the last warn/error
        event (else OK and the core state); every event is logged."""
        values = self.core.status(now)
        level, message = "OK", self.core.state.value
        for ev in events:
            lv = getattr(ev, "level", "warn" if getattr(ev, "kind", "") != "link_up" else "info")
            text = getattr(ev, "reason", None) or f"{ev.kind}: {ev.detail}"
            self._log.append((lv, text))
            if lv in ("warn", "error"):
                level = "ERROR" if lv == "error" or level == "ERROR" else "WARN"
                message = text
        st = messages.diagnostic_status(self.f, level, self.name, message, values)
        return [("status", messages.diagnostic_array(self.f, round(now * 1e9), [st]))]

    # -- orderly shutdown -----------------------------------------------------------------
    def shutdown(self, now: float) -> Output:
        """Hand control back (once); the poll timer keeps running until PX4's HEARTBEAT
        confirms the hand-back mode (or the chain fails)."""
        if self._shutting_down:
            return []
        self._shutting_down = True
        return self.status(now, self.core.shutdown(now))

    def shutdown_complete(self) -> bool:
        return self.core.state.value in SHUTDOWN_DONE

    def shutdown_state(self, now: float) -> str:
        return f"hand-back {self.core.state.value}: {self.core.status(now).get('reason', '')}"

    def close(self) -> None:
        self.core.close()
