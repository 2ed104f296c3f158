"""Decode PX4 telemetry into core samples (SI units, NED world, FRD body).

MAVLink sources (PX4 sends all of them in NED/FRD):
- ATTITUDE_QUATERNION: q = (w, x, y, z) rotating FRD into NED, body rates p, q, r [rad/s]
- ATTITUDE: Euler angles (fallback when ATTITUDE_QUATERNION is not streamed)
- LOCAL_POSITION_NED: position and velocity in NED [m, m/s]
- ODOMETRY: position, quaternion, velocity (frame given by ``child_frame_id``), rates
- HIGHRES_IMU: specific force [m/s^2] and rates [rad/s] in FRD
- ESC_STATUS: motor speeds [rpm] -> Omega [rad/s] = |rpm| * 2 pi / 60 (PX4 numbering:
  ESC i drives rotor i of the quad-X of DESIGN.md; the seed's Omega is a speed magnitude)
- ACTUATOR_OUTPUT_STATUS / SERVO_OUTPUT_RAW: motor outputs -> estimated Omega through the
  motor model of seed 0 Eq. (8) (:mod:`lpv_sysid.mavlink.telemetry.rotor_estimate`)

The body velocity of seed 0 (u, v, w) is ``R_IB^T v_ned`` (seed 0 Eq. 1, R_IB maps FRD
into NED); rotations and quaternion conventions come from ``lpv_sysid.io.frames``. Each
sample carries the vehicle's own timestamp ``t_vehicle`` and ``t``, that time on the
caller's clock (:mod:`lpv_sysid.mavlink.telemetry.clock`: the lower envelope of receipt -
vehicle time), so a backlog read in one poll keeps each sample's own time and real age.

Telemetry hygiene
- Sources: with ``source_filter`` only messages of the target ``(system, component)`` are
  decoded (the bridge sets :attr:`TelemetryDecoder.target` from the link: configured, or
  the first autopilot HEARTBEAT); the others are counted per source
  (``stats.foreign``, :attr:`TelemetryDecoder.foreign_sources`), and messages before the
  target is known are counted in ``stats.untargeted``.
- Ordering: every message type keeps its own vehicle-time ordering (PX4 stamps ODOMETRY
  with the estimator's ``timestamp_sample``, which lags ATTITUDE_QUATERNION's time; one
  shared check dropped 8 % of good samples on real PX4). A message whose time goes
  backwards (less than 10 s: more is a reboot) is dropped and counted (``out_of_order``).
- One source per quantity on ``state``: attitude from ATTITUDE_QUATERNION, else ATTITUDE,
  else ODOMETRY; position/velocity from LOCAL_POSITION_NED, else ODOMETRY ("else" = the
  preferred stream has not been received for ``max_age`` s). Messages of a source that is
  not selected are kept (they take over at once when the preferred one stops) but produce
  no sample, so ``state`` carries no duplicates: one sample per update of the selected
  attitude or position stream (e.g. 100 Hz ATTITUDE_QUATERNION + 50 Hz LOCAL_POSITION_NED).
  PX4's default ODOMETRY and ATTITUDE streams thus never feed ``state`` while the preferred
  streams run.
- Rotor speeds: ESC telemetry wins while it is fresh (``esc_timeout``); otherwise the
  estimate from the motor outputs is published (``RotorSample.source``: ``"esc"`` or
  ``"estimated"``). ESC_STATUS reporting 0 rpm on every motor while the motor outputs say
  they run is not a measurement (ESCs without rpm telemetry) and does not count as fresh.

:meth:`TelemetryDecoder.staleness` reports the age of every stream.
"""

from __future__ import annotations

from lpv_sysid.mavlink.telemetry.clock import ReceiverClock, VehicleClock
from lpv_sysid.mavlink.telemetry.decoder import TelemetryDecoder
from lpv_sysid.mavlink.telemetry.provenance import (
    SIM_MARKER,
    VEHICLE_KINDS,
    VehicleRecord,
    vehicle_kind,
)
from lpv_sysid.mavlink.telemetry.rotor_estimate import (
    MAPPINGS,
    MOTOR_OUTPUT_STREAMS,
    MotorModel,
    RotorEstimateConfig,
    RotorSpeedEstimator,
    with_motor_output_streams,
)
from lpv_sysid.mavlink.telemetry.samples import (
    ATTITUDE_SOURCES,
    MOTOR_OUTPUT_SOURCES,
    POSITION_SOURCES,
    ImuSample,
    RotorSample,
    StateSample,
    euler_to_quat,
    quat_to_dcm,
)

__all__ = [
    "ATTITUDE_SOURCES",
    "ImuSample",
    "MAPPINGS",
    "MOTOR_OUTPUT_SOURCES",
    "MOTOR_OUTPUT_STREAMS",
    "MotorModel",
    "POSITION_SOURCES",
    "RotorEstimateConfig",
    "RotorSample",
    "RotorSpeedEstimator",
    "SIM_MARKER",
    "StateSample",
    "TelemetryDecoder",
    "VEHICLE_KINDS",
    "ReceiverClock",
    "VehicleClock",
    "VehicleRecord",
    "euler_to_quat",
    "quat_to_dcm",
    "vehicle_kind",
    "with_motor_output_streams",
]
