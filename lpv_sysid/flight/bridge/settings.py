"""The parameters of mavlink_bridge_node, declared once (no rclpy here).

The shell's own settings (:class:`BridgeNodeSettings`: transport, rates), then every field of
:class:`~lpv_sysid.mavlink.bridge.BridgeConfig` and of
:class:`~lpv_sysid.mavlink.bridge.mavros.MavrosConfig` (``mavros.*``), generated from the
dataclasses by :mod:`lpv_sysid.configuration.parameters` with the descriptions below; the node
declares :data:`SPECS` and :func:`split_parameters` sorts the declared values back into the
three mappings. :func:`handback_bound_s` is the bridge's orderly-shutdown bound.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from lpv_sysid.configuration import parameters
from lpv_sysid.mavlink.bridge import BridgeConfig, MavrosConfig

TRANSPORTS = ("mavlink", "mavros")

#: MavrosConfig fields supplied by the bridge's own parameters (one value for both transports)
MAVROS_SHARED = {
    "setpoint_rate_hz": "offboard.setpoint_rate_hz",
    "input_timeout": "offboard.input_timeout",
    "send_on_command": "offboard.send_on_command",
    "telemetry_max_age": "telemetry_max_age",
    "auto_start": "auto_start",
    "command": "command",
}


@dataclass(frozen=True)
class BridgeNodeSettings(parameters.Settings):
    """The parameters of the shell itself (the rest: :data:`PARAMETERS`)."""

    WHERE = "mavlink_bridge"

    transport: str = parameters.text(
        "mavlink",
        "mavlink (own MAVLink link to PX4) | mavros (MAVROS topics, docs/px4_transport.md)",
    )
    poll_rate_hz: float = parameters.double(250.0, "link poll rate [Hz]", 10.0, 2000.0)
    status_rate_hz: float = parameters.double(2.0, "status publication rate [Hz]", 0.1, 100.0)
    rate_setpoints: bool = parameters.flag(
        True,
        "transport mavlink: request PX4's ATTITUDE_TARGET (50 Hz unless link.streams sets it) and "
        "republish it on rate_setpoint -- the thrust + body-rate setpoints PX4 tracks: the "
        "input of `lpv-sysid identify --plant px4-rate` (phase 1), the echo of the commands "
        "(phase 2)",
    )
    publish_tf: bool = parameters.flag(
        False, "publish odom -> base_link on /tf from the state (REP-105; RViz, Foxglove)"
    )
    link_url_override: str = parameters.text(
        "",
        "the launch files' link_url argument: non-empty replaces link.url; empty (the "
        "launch default): link.url of the parameter file (the bridge logs which one it used)",
    )

    def validate(self) -> None:
        if self.transport not in TRANSPORTS:
            self.fail(f"transport must be 'mavlink' or 'mavros', got {self.transport!r}")


#: descriptions of the parameters generated from BridgeConfig (config/mavlink_bridge.yaml
#: explains each section); types, defaults and checks are BridgeConfig's
BRIDGE_DESCRIPTIONS = {
    "link.url": "pymavlink connection string (udpin:H:P, udpout:H:P, tcp:H:P, serial device)",
    "link.baud": "serial baud rate (serial URLs only)",
    "link.source_system": "our MAVLink system id (1..255)",
    "link.source_component": "our component id (191: onboard computer)",
    "link.target_system": "autopilot system id (0: the first autopilot HEARTBEAT)",
    "link.target_component": "autopilot component id",
    "link.dialect": "MAVLink dialect (PX4: development)",
    "link.heartbeat_period": "our HEARTBEAT period [s]",
    "link.link_timeout": "no autopilot HEARTBEAT for this long -> link lost [s]",
    "link.reconnect_period": "reopen period of a lost serial/TCP link [s]",
    "link.stream_request_period": "SET_MESSAGE_INTERVAL retry period for missing streams [s]",
    "link.streams": "requested telemetry rate [Hz] (0: off)",
    "link.signing_key_file": "MAVLink 2 signing key file (32 raw bytes or 64 hex chars); "
    "empty: unsigned",
    "link.signing_link_id": "signing link id",
    "link.allow_unsigned": "with a signing key: still accept unsigned messages",
    "offboard.setpoint_rate_hz": "setpoint stream rate [Hz] (PX4 needs > 2 Hz)",
    "offboard.prestream_time": "setpoints before OFFBOARD is requested [s] (PX4 needs > 1 s)",
    "offboard.arm": "arm the vehicle on start",
    "offboard.handback_chain": "PX4 modes tried in turn on hand-back until the HEARTBEAT "
    "confirms one (HOLD, POSCTL, ALTCTL, LAND, RTL)",
    "offboard.handback_mode": "tried before the chain (single-mode key of earlier releases); "
    "empty: the chain alone",
    "offboard.input_timeout": "no command for this long -> hand back [s]",
    "offboard.ack_timeout": "per attempt, for a COMMAND_ACK [s]",
    "offboard.ack_settle_s": "quiet time after the last ACK before a step counts [s]",
    "offboard.max_retries": "command retries per step",
    "offboard.mode_confirm_timeout": "after ACCEPTED, for the HEARTBEAT to show the mode [s]",
    "offboard.send_on_command": "forward each new command at once (latency)",
    "command": "velocity (phase 1) | attitude_rate (phase 2)",
    "velocity_frame": "velocity setpoint frame: body_ned (PX4 rotates by yaw) | local_ned",
    "use_yaw_rate": "velocity setpoints carry the yaw-rate reference",
    "arm_length": "attitude_rate: seed 0 Eq. (7) geometry [m]",
    "rate_p": "attitude_rate: PX4 MC_ROLLRATE_P, MC_PITCHRATE_P, MC_YAWRATE_P",
    "auto_start": "start offboard on the first command",
    "command_abort_factor": "attitude_rate: a command beyond this multiple of the range "
    "(thrust, body rate) aborts instead of being clipped",
    "telemetry_max_age": "attitude/velocity older than this is not fused [s]",
    "n_rotors": "number of rotors (ESC_STATUS / motor outputs)",
    "rotor_estimate.enabled": "estimate rotor speeds from motor outputs while no fresh ESC "
    "telemetry (seed 0 Eq. 8)",
    "rotor_estimate.source": "auto | actuator_output_status | servo_output_raw",
    "rotor_estimate.mapping": "motor output -> u_ESC: pwm | dshot | normalized | symmetric",
    "rotor_estimate.output_min": "override of the mapping's output range (NaN: the mapping's)",
    "rotor_estimate.output_max": "override of the mapping's output range (NaN: the mapping's)",
    "rotor_estimate.motor_outputs": "output channel (1-based) of rotor 1..n",
    "rotor_estimate.servo_port": "SERVO_OUTPUT_RAW port of the motors",
    "rotor_estimate.airframe": "YAML with a quadrotor section (empty: built-in airframe)",
    "rotor_estimate.a_omega": "motor time constant inverse [1/s] (NaN: the airframe's)",
    "rotor_estimate.b_omega": "motor gain [rad/s^2 per unit u_ESC] (NaN: the airframe's)",
    "rotor_estimate.omega_min": "idle rotor speed [rad/s] (NaN: the airframe's)",
    "rotor_estimate.omega_max": "maximum rotor speed [rad/s] (NaN: the airframe's)",
    "rotor_estimate.max_gap": "longer gaps between output samples restart the estimate [s]",
    "rotor_estimate.hold": "motor output between samples: zero (held) | linear (ramp)",
    "rotor_estimate.esc_timeout": "ESC telemetry older than this -> the estimate is used [s]",
    "envelope.enabled": "onboard safety envelope (violation -> hand-back)",
    "envelope.home": "auto | home_position | start",
    "envelope.floor": "floor above home [m]",
    "envelope.ceiling": "ceiling above home [m]",
    "envelope.floor_arm_margin": "the floor is active once above floor + margin [m]",
    "envelope.lookahead": "predictive floor/ceiling/fence on p + v * lookahead [s]",
    "envelope.radius": "horizontal geofence around home [m]",
    "envelope.max_tilt_deg": "largest tilt [deg]",
    "envelope.max_speed": "largest NED speed [m/s]",
    "envelope.max_setpoint": "velocity references above this are rejected [m/s]",
    "envelope.max_setpoint_yaw_rate": "yaw-rate references above this are rejected [rad/s]",
}
#: not a parameter: the MAV_TYPE of our HEARTBEAT identifies this program (onboard controller)
BRIDGE_EXCLUDED = ("link.mav_type",)

MAVROS_DESCRIPTIONS = {
    "mavros.namespace": "MAVROS node namespace (transport mavros)",
    "mavros.odom_frame_id": "frame_id of MAVROS local_position/odom",
    "mavros.base_frame_id": "MAVROS body frame (odom child, imu)",
    "mavros.prestream_timeout": "zero-velocity stream without a reference -> stop [s]",
    "mavros.use_diagnostics": "read the PX4 mode from /diagnostics (read-only; interfaces common)",
    "mavros.interfaces": "auto | mavros_msgs (mode, arming, hand-back, rate setpoints, rotor "
    "speeds) | common (common_interfaces only: velocity, no mode control)",
    "mavros.state_timeout": "mavros_msgs: no /mavros/state for this long -> no mode evidence [s]",
    "mavros.health_max_age": "mavros_msgs: preflight health evidence (battery, GPS, EKF, RC, "
    "home, streams) older than this counts as missing at start [s]",
    "mavros.rc_out_rate_hz": "mavros_msgs: SERVO_OUTPUT_RAW rate asked through "
    "set_message_interval (rc/out, estimated rotor speeds) [Hz]; 0: not asked",
    "mavros.preflight": "mavros_msgs: refuse start on a preflight NO-GO (PX4 parameters, "
    "firmware, sticks, telemetry through MAVROS)",
}

#: the rclpy declarations: the shell's settings, then BridgeConfig's and MavrosConfig's
#: fields (generated; nothing restated)
SPECS = {
    **parameters.specs(BridgeNodeSettings),
    **parameters.config_specs(BridgeConfig, BRIDGE_DESCRIPTIONS, exclude=BRIDGE_EXCLUDED),
    **parameters.config_specs(
        MavrosConfig,
        MAVROS_DESCRIPTIONS,
        prefix="mavros.",
        exclude=tuple(f"mavros.{k}" for k in MAVROS_SHARED),
    ),
}


def split_parameters(p: Mapping[str, Any]) -> tuple[dict, dict, dict]:
    """Declared values -> (shell settings, BridgeConfig mapping, MavrosConfig mapping)."""
    own = {k: p[k] for k in parameters.specs(BridgeNodeSettings)}
    mavros = {k.split(".", 1)[1]: v for k, v in p.items() if k.startswith("mavros.")}
    mavros.update({k: p[v] for k, v in MAVROS_SHARED.items()})
    bridge = parameters.nest(
        {k: v for k, v in p.items() if k not in own and not k.startswith("mavros.")}, SPECS
    )
    if own.get("link_url_override"):
        bridge.setdefault("link", {})["url"] = own["link_url_override"]
    return own, bridge, parameters.nest(mavros)


def link_url_source(p: Mapping[str, Any]) -> str:
    """Where the bridge's link URL comes from (logged at start): the ``link_url`` launch
    argument (``link_url_override``) wins over ``link.url`` of the parameter file."""
    if p.get("link_url_override"):
        return "link_url launch argument (link_url_override), replacing link.url"
    return "link.url of the parameter file"


def settings_from_params(p: Mapping[str, Any]) -> BridgeNodeSettings:
    """The shell's settings from the declared values, checked as at start (a parameter set
    while the node runs: see lpv_sysid/nodes/shell.py)."""
    return BridgeNodeSettings.from_dict(split_parameters(p)[0])


def handback_bound_s(offboard) -> float:
    """Longest a hand-back can take (the orderly-shutdown bound of the bridge), from the
    truth rules of mavlink/offboard/machine.py: each mode of the chain gets ``max_retries + 1``
    DO_SET_MODE attempts of ``ack_timeout`` and, once ACCEPTED, ``mode_confirm_timeout``
    for the HEARTBEAT; plus one poll-and-heartbeat period of slack."""
    per_mode = (offboard.max_retries + 1) * offboard.ack_timeout + offboard.mode_confirm_timeout
    return round(len(offboard.chain) * per_mode + 1.0, 3)
