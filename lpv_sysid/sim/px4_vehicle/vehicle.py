"""A simulated quadrotor that speaks MAVLink 2 like PX4 SITL (v1.16 behaviour subset).

Protocol (what a bridge, MAVSDK or a ground station sees):
- HEARTBEAT 1 Hz: MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_PX4, base_mode flags and the PX4
  custom mode (main << 16 | sub << 24), MAV_STATE_STANDBY/ACTIVE/CRITICAL (failsafe);
- COMMAND_LONG -> COMMAND_ACK. DO_SET_MODE (176) is answered twice as PX4 v1.16 does
  (``double_ack``, :data:`lpv_sysid.mavlink.px4.DOUBLE_ACK_COMMANDS`): ACCEPTED at once
  (PX4's MAVLink receiver), then the commander's verdict ``verdict_delay_s`` later
  (simulated time); only the verdict changes the mode. Commander rules (v1.16
  UserModeIntention, measured on SIH SITL): while disarmed every known mode is accepted;
  while armed a mode that cannot run is TEMPORARILY_REJECTED and the mode stays: OFFBOARD
  without a live setpoint stream (>= 2 setpoints in the last second, the newest younger
  than COM_OF_LOSS_T), and POSCTL, ALTCTL, MANUAL, STABILIZED, ACRO (``px4.STICK_MODES``)
  without stick input (``rc_present`` false, the default, and no MAVLink joystick, or
  COM_RC_IN_MODE excluding them). COMPONENT_ARM_DISARM (400), answered once (after
  ``verdict_delay_s``): DENIED in the air or in LAND/RTL, TEMPORARILY_REJECTED ("Resolve
  system health failures") when the current mode cannot run; disarming in the air only
  with the 21196 force code. Also answered: SET_MESSAGE_INTERVAL (511), REQUEST_MESSAGE
  (512), REQUEST_AUTOPILOT_CAPABILITIES (520), NAV_TAKEOFF (22), NAV_LAND (21), NAV_RETURN
  (20); anything else MAV_RESULT_UNSUPPORTED;
- PARAM_REQUEST_READ / PARAM_REQUEST_LIST / PARAM_SET -> PARAM_VALUE (INT32 parameters
  byte-wise encoded as PX4 does). A PARAM_SET value that is NaN, infinite, not an allowed
  enum value or outside the parameter's range (:data:`PARAMS`) is refused: the value stays,
  and PARAM_VALUE answers with the old one;
- MAVLink 2 signing (``signing_key_file``): unsigned or wrongly signed messages of any
  kind (PARAM_SET, COMMAND_LONG, setpoints) are dropped by the link unless
  ``allow_unsigned``;
- AUTOPILOT_VERSION (PX4 v1.16.0, MAVLink 2, offboard capabilities);
- telemetry at PX4's "onboard" link rates (:data:`DEFAULT_RATES`, ``stream_rates``
  overrides, SET_MESSAGE_INTERVAL at run time): ATTITUDE and ATTITUDE_QUATERNION (both),
  LOCAL_POSITION_NED, ODOMETRY (pose and velocity in MAV_FRAME_LOCAL_NED as EKF2 publishes
  them; ``time_usec`` is the estimator's IMU sample time, ``odometry_lag_s`` before the
  ATTITUDE_QUATERNION / LOCAL_POSITION_NED stamps of the same state, so a decoder that
  orders all streams by time sees ODOMETRY out of order, as with PX4), GLOBAL_POSITION_INT,
  HIGHRES_IMU, ESC_STATUS (only with ``esc_telemetry``; SIH and PWM ESCs have none: the
  stream can be configured but never sends), SERVO_OUTPUT_RAW (16 outputs, PWM us: motors
  1000 + 1000 u_ESC, disarmed and unused outputs 900, as SIH's pwm_out_sim) and
  ACTUATOR_OUTPUT_STATUS (``active`` 16, the same PWM values, or u_ESC in [0, 1] for the
  motors and 0 elsewhere with ``actuator_output_scale: normalized``; off by default as in
  PX4, SET_MESSAGE_INTERVAL enables it), RC_CHANNELS (only with an RC), SYS_STATUS
  (RC_RECEIVER present/healthy while stick input is valid; battery ``battery_remaining``
  less ``battery_drain`` per minute armed, ``battery_voltage``), EXTENDED_SYS_STATE,
  HOME_POSITION (only with ``home_set``, also on REQUEST_MESSAGE), GPS_RAW_INT
  (``gps_fix``) and ESTIMATOR_STATUS (EKF2 flags: healthy, or no horizontal position and a
  GPS glitch with ``ekf_healthy: false``) -- what preflight reads.

Behaviour:
- OFFBOARD accepts SET_POSITION_TARGET_LOCAL_NED (velocity, optional yaw rate,
  position; MAV_FRAME_LOCAL_NED, or MAV_FRAME_BODY_NED / BODY_FRD rotated by yaw only, as
  PX4 does) and SET_ATTITUDE_TARGET body rates + thrust (PX4 rate loop, P term only:
  tau = K_p (omega_sp - omega), unit quad-X allocation);
- offboard loss while armed (no setpoint for COM_OF_LOSS_T) -> failsafe COM_OBL_RC_ACT
  (``px4.OBL_ACTION_MODES``: 0 Position, 1 Altitude, 2 Stabilized, 3 Return, 4 Land,
  5 Hold; 6 Terminate and 7 Disarm stop the motors); the HEARTBEAT shows the failsafe
  mode and MAV_STATE_CRITICAL. A stick mode (0, 1, 2) without stick input cannot run: the
  vehicle logs "Matching flight task was not able to run, Nav state: N" and flies PX4's
  emergency Descend task (FlightTaskDescend: level attitude, vertical speed
  MPC_LAND_SPEED, no horizontal position or velocity control) down to the ground. The
  failsafe ends when the user selects a mode or on disarm (PX4's OnModeChangeOrDisarm);
  the mode shown is then the user's last choice again (e.g. OFFBOARD after a failsafe
  descent and "Disarmed by landing", as PX4 v1.16 SIH does);
- armed but no takeoff within COM_DISARM_PRFLT -> disarm; landed for COM_DISARM_LAND
  after a flight -> disarm. Disarming does not change the user's mode: the HEARTBEAT
  keeps showing it (e.g. OFFBOARD) until someone changes it, and no failsafe acts while
  disarmed;
- physics: seed 0 quadrotor (models/quadrotor/model.py, RK4 at ``physics_hz``; rotor speeds
  follow the first-order motor model of seed 0 Eq. 8, ESC_STATUS reports them) with the
  PX4-like cascaded controller (control/baseline.py) tracking the velocity setpoints of
  every mode (HOLD/POSCTL/ALTCTL hold position/altitude with a P loop, LAND descends at
  MPC_LAND_SPEED, RTL flies home then lands); flat ground at z = 0.

Network exposure: a ``udpout`` URL (PX4 SITL style: send to the offboard port) binds its
socket explicitly before the first datagram, to ``bind`` or, by default, to the local
interface that routes to the destination (127.0.0.1 for a loopback destination), never
to all interfaces; ``udpin:0.0.0.0`` and similar all-interface URLs are logged as a risk.

The vehicle is a polled object: ``step(now)`` advances physics to ``now`` (fixed steps),
serves the link and sends due telemetry. :meth:`SimVehicle.run_realtime` drives it from the
wall clock; tests may call ``step`` with a simulated clock (lock-step, faster than real time).

Modules (one job each; every layer is a class that :class:`SimVehicle` inherits, and the
names of the former single module are importable from here):
- ``sim_vehicle_config``: the options, the PX4 parameter and stream tables;
- ``sim_vehicle_state``: the state every layer shares;
- ``sim_vehicle_params``: the parameter protocol;
- ``sim_vehicle_setpoints``: offboard setpoints;
- ``sim_vehicle_telemetry``: the telemetry streams;
- ``sim_vehicle_commander``: commands, modes, arming, failsafes;
- ``sim_vehicle_physics``: physics and flight tasks;
- this module: the link, the UDP socket and the step loop.
"""

from __future__ import annotations

import math
import socket
import time
from typing import Any, Callable

from lpv_sysid.errors import ConfigError, LpvSysidError
from lpv_sysid.mavlink.link import parse_url, warn_if_all_interfaces
from lpv_sysid.sim.px4_vehicle.config import parse_hostport
from lpv_sysid.sim.px4_vehicle.params import ParamServer
from lpv_sysid.sim.px4_vehicle.physics import FlightPhysics


class SimVehicle(FlightPhysics, ParamServer):
    """See module docstring."""

    # ------------------------------------------------------------- lifecycle
    def open(self) -> None:
        self.link.open(self.t)
        self._opened = True
        try:
            self._bind_local()
        except BaseException:
            self.close()  # no socket left open whatever refused the local address
            raise

    def close(self) -> None:
        self.link.close()
        self._opened = False

    def _bind_local(self) -> None:
        """Bind a udpout socket before its first datagram (else the OS binds 0.0.0.0)."""
        sock = getattr(self.link.conn, "port", None)
        if not isinstance(sock, socket.socket):
            return
        device, _ = parse_url(self.config.url)
        if device.startswith("udpout:"):
            _, dest_host, dest_port = device.split(":")
            if self.config.bind is not None:
                host, port = parse_hostport(self.config.bind, "sim vehicle bind")
            else:
                host, port = _route_source(dest_host, int(dest_port)), 0
            warn_if_all_interfaces(f"sim vehicle {self.config.url!r} (bind {host}:{port})", host)
            try:
                sock.bind((host, port))
            except OSError as exc:
                self.close()
                raise LpvSysidError(
                    f"sim vehicle: cannot bind {host}:{port} for {self.config.url!r}: "
                    f"{exc.strerror or exc}"
                ) from None
        try:
            name = sock.getsockname()
            self.local_address = (str(name[0]), int(name[1]))
        except OSError:
            self.local_address = None

    # ------------------------------------------------------------------ loop
    def step(self, now: float) -> None:
        """Advance to ``now`` (seconds since boot): physics, messages, telemetry."""
        if self._opened:
            for msg in self.link.poll(now):
                self._handle(msg, now)
        while self.t + self.dt <= now + 1e-9:
            if self.armed:
                self.armed_s += self.dt
            self._physics_step()
            self._supervise(self.t)
            self._run_verdicts(self.t)
        self._run_verdicts(self.t)
        if self._opened:
            self._send_telemetry(now)

    def run_realtime(
        self,
        duration: float | None = None,
        stop: Callable[[], bool] | None = None,
        period: float = 0.002,
        speed: float = 1.0,
    ) -> None:
        """Drive :meth:`step` from the wall clock (bounded by ``duration`` simulated seconds).

        ``speed`` > 1 runs faster than real time (simulated time = speed x wall time); the
        peers then see a vehicle whose clock runs fast, which is fine for protocol tests.
        """
        if not (speed > 0 and math.isfinite(speed)):
            raise ConfigError(f"sim vehicle speed must be positive, got {speed!r}")
        w0 = time.monotonic()
        s0 = self.t
        while True:
            w = time.monotonic()
            now = s0 + (w - w0) * speed
            if duration is not None and now >= duration:
                break
            if stop is not None and stop():
                break
            self.step(now)
            time.sleep(max(0.0, period - (time.monotonic() - w)))

    # ------------------------------------------------------------- messages
    def _handle(self, m: Any, now: float) -> None:
        mt = m.get_type()
        if mt == "HEARTBEAT":
            self.gcs_last_heartbeat = now
            return
        tgt = getattr(m, "target_system", None)
        if tgt not in (None, 0, self.config.system_id):
            return
        if mt == "COMMAND_LONG":
            self._command(m, now)
        elif mt == "SET_POSITION_TARGET_LOCAL_NED":
            self._position_target(m, now)
        elif mt == "SET_ATTITUDE_TARGET":
            self._attitude_target(m, now)
        elif mt == "MANUAL_CONTROL":
            self._t_joystick = now
        elif mt == "PARAM_REQUEST_READ":
            self._param_request_read(m)
        elif mt == "PARAM_REQUEST_LIST":
            for name in self.params:
                self._send_param(name)
        elif mt == "PARAM_SET":
            self._param_set(m, now)


def _route_source(host: str, port: int) -> str:
    """The local address the OS would send from to ``host`` (a UDP connect sends nothing)."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.connect((host, port))
        return str(s.getsockname()[0])
    except OSError as exc:
        raise LpvSysidError(
            f"sim vehicle: no local interface routes to {host}:{port} ({exc}); "
            "give the local address in the bind field (HOST[:PORT])"
        ) from None
    finally:
        s.close()
