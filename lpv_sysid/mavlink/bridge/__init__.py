"""Bridge core: link + telemetry decoder + offboard state machine + setpoint transport.

The rclpy shell (``nodes/mavlink_bridge_node.py``) is glue around :class:`BridgeCore`:

- timer (e.g. 200 Hz): ``out = core.poll(now)`` -> publish ``out.samples`` (StateSample,
  ImuSample, RotorSample in NED/FRD; convert with io/frames) and ``out.events``
  (``status`` topic); ``core.status(now)`` gives key/values for the DiagnosticStatus;
- subscriptions: ``core.on_velocity_reference(now, v_frd, yaw_rate, stamp)`` /
  ``core.on_actuator_command(now, u, stamp)``;
- services: ``core.start(now)``, ``core.abort(now, reason)`` (both return the status
  events they caused); on shutdown ``core.shutdown(now)`` (sends the hand-back command at
  once, returns the undelivered events) then ``core.close()``. Rejected commands and
  events caused by commands are delivered with the next ``poll``.

``sample_callback`` (optional) is called synchronously for every decoded sample, which
is what a controller uses to answer within the same poll (lowest latency). Commands go
out immediately when the machine is streaming (``send_on_command``), and again at the
configured rate.

Safety envelope (:mod:`lpv_sysid.control.envelope`, section ``envelope``): armed by
``start`` (home: the position at start on the ground, PX4's HOME_POSITION when the vehicle
is already armed), it checks every decoded state
sample and every velocity reference while the machine streams. A violation (floor,
predictive floor, ceiling, geofence, tilt, speed, setpoint magnitude, non-finite values)
puts an ``error`` StatusEvent naming it on the output and hands control back through the
offboard machine at once; a rejected setpoint is never encoded. ``core.envelope``
exposes the latched :class:`~lpv_sysid.control.envelope.Violation` and
``activate_floor``; ``status`` carries ``envelope*`` keys.
"""

from __future__ import annotations

from lpv_sysid.mavlink.bridge.core import BridgeConfig, BridgeCore
from lpv_sysid.mavlink.bridge.mavros import (
    DIAGNOSTICS_TOPIC,
    MODE_CONTROL,
    MavrosConfig,
    MavrosCore,
    MavrosOutput,
    MavrosState,
    body_reference_to_local_enu,
    cmd_vel_msg,
    vehicle_mode_from_statuses,
)
from lpv_sysid.mavlink.bridge.mavros_link import (
    MAVROS_MODE_NAMES,
    MavrosLink,
    RateTarget,
    ServiceRequest,
    VelocityTarget,
    mode_from_mavros,
)
from lpv_sysid.mavlink.bridge.transport import (
    ATTITUDE_TARGET_IGNORE_ATTITUDE,
    RATE_INPUT_NAMES,
    ActuatorSetpoint,
    AttitudeRateTransport,
    AttitudeTargetEcho,
    RateSetpointTransport,
    TransportContext,
    VelocitySetpoint,
    VelocityTransport,
    make_transport,
    rate_setpoint_from_attitude_target,
)

__all__ = [
    "ATTITUDE_TARGET_IGNORE_ATTITUDE",
    "ActuatorSetpoint",
    "AttitudeRateTransport",
    "AttitudeTargetEcho",
    "BridgeConfig",
    "BridgeCore",
    "DIAGNOSTICS_TOPIC",
    "MAVROS_MODE_NAMES",
    "MODE_CONTROL",
    "MavrosConfig",
    "MavrosCore",
    "MavrosLink",
    "MavrosOutput",
    "MavrosState",
    "RATE_INPUT_NAMES",
    "RateSetpointTransport",
    "RateTarget",
    "ServiceRequest",
    "TransportContext",
    "VelocitySetpoint",
    "VelocityTarget",
    "VelocityTransport",
    "body_reference_to_local_enu",
    "cmd_vel_msg",
    "make_transport",
    "mode_from_mavros",
    "rate_setpoint_from_attitude_target",
    "vehicle_mode_from_statuses",
]
