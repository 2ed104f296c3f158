"""Telemetry of the simulated vehicle at PX4's onboard-link rates: HEARTBEAT, the streams
of :data:`~lpv_sysid.sim.px4_vehicle.config.DEFAULT_RATES` (attitude, position, odometry,
IMU, ESC and actuator outputs, RC, system state, home) and AUTOPILOT_VERSION;
the behaviour is described in :mod:`lpv_sysid.sim.px4_vehicle.vehicle`."""

from __future__ import annotations

import math

import numpy as np

from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.telemetry import SIM_MARKER, euler_to_quat
from lpv_sysid.sim.px4_vehicle.state import MAV_TYPE_QUADROTOR, VehicleState

MAV_AUTOPILOT_PX4 = 12
MAV_STATE_STANDBY, MAV_STATE_ACTIVE, MAV_STATE_CRITICAL = 3, 4, 5
MAV_LANDED_STATE_ON_GROUND, MAV_LANDED_STATE_IN_AIR = 1, 2
MAV_FRAME_LOCAL_NED = 1
MAV_ESTIMATOR_TYPE_AUTOPILOT = 8
MAV_SYS_STATUS_SENSOR_RC_RECEIVER = 0x10000
MAV_SYS_STATUS_SENSOR_GPS = 0x20
SENSORS_BASE = 0x3FFF  # gyro .. motor outputs, all present/enabled/healthy
N_OUTPUTS = 16  # actuator outputs PX4 SIH reports (ACTUATOR_OUTPUT_STATUS.active)
HOME_LAT, HOME_LON, HOME_ALT = 47.397742, 8.545594, 488.0  # PX4 SITL default home


class TelemetryStreams(VehicleState):
    """Due telemetry sent at each step; single messages on request."""

    def motor_outputs(self) -> tuple[np.ndarray, np.ndarray]:
        """(u_ESC in [0, 1], PWM us) of the motors as PX4 writes them (disarmed: 0, 900 us)."""
        if not self.armed:
            n = len(self.x[12:16])
            return np.zeros(n), np.full(n, px4.PWM_DISARMED_US)
        u_esc = np.asarray(self.model.u_esc(self.u), dtype=float)
        return u_esc, np.array([px4.pwm_from_u_esc(u) for u in u_esc])

    def _outputs16(self) -> tuple[list[float], list[float]]:
        """All 16 outputs (normalised, PWM): motors first, the unused ones idle at 0 / 900 us."""
        u_esc, pwm = self.motor_outputs()
        pad = N_OUTPUTS - len(pwm)
        return [float(u) for u in u_esc] + [0.0] * pad, [float(p) for p in pwm] + [
            px4.PWM_DISARMED_US
        ] * pad

    def _stream_has_data(self, mid: int) -> bool:
        sid = self._stream_ids
        if mid == sid["ESC_STATUS"]:
            return self.config.esc_telemetry
        if mid == sid["RC_CHANNELS"]:
            return self.config.rc_present
        if mid == sid["ATTITUDE_TARGET"]:
            if self._rates_setpoint() is None:
                self.att_sp_echo = None  # out of body-rate OFFBOARD: no echo (see below)
                return False
            return True
        if mid == sid["HOME_POSITION"]:
            return self.config.home_set
        return True

    def _rates_setpoint(self):
        """The SET_ATTITUDE_TARGET rates setpoint PX4 is tracking (OFFBOARD), else None."""
        sp = self.setpoint
        if self.mode == px4.OFFBOARD and sp is not None and sp.kind == "rates":
            return sp
        return None

    def battery_remaining(self) -> int:
        """SYS_STATUS.battery_remaining [%]: the start charge less the drain while armed."""
        used = self.config.battery_drain * self.armed_s / 60.0
        return max(0, int(math.floor(self.config.battery_remaining - used)))

    def estimator_flags(self) -> int:
        """ESTIMATOR_STATUS.flags (MAV ESTIMATOR_* bits) of a healthy EKF2 with GPS, or of
        one without horizontal position and with a GPS glitch (``ekf_healthy: false``)."""
        m = self._mod
        base = m.ESTIMATOR_ATTITUDE | m.ESTIMATOR_VELOCITY_VERT | m.ESTIMATOR_POS_VERT_ABS
        if not self.config.ekf_healthy:
            return base | m.ESTIMATOR_GPS_GLITCH
        return (
            base
            | m.ESTIMATOR_VELOCITY_HORIZ
            | m.ESTIMATOR_POS_HORIZ_REL
            | m.ESTIMATOR_POS_HORIZ_ABS
            | m.ESTIMATOR_PRED_POS_HORIZ_REL
            | m.ESTIMATOR_PRED_POS_HORIZ_ABS
        )

    def _send_telemetry(self, now: float) -> None:
        if now >= self._next_hb:
            self._next_hb = now + 1.0
            self._heartbeat()
        for mid, interval in self.intervals.items():
            if interval <= 0:
                continue
            nxt = self._next_send.get(mid, 0.0)
            if now >= nxt:
                self._next_send[mid] = nxt + interval if now - nxt < interval else now + interval
                if self._stream_has_data(mid):
                    self._send_stream(mid, now)

    def _heartbeat(self) -> None:
        state = MAV_STATE_ACTIVE if self.armed else MAV_STATE_STANDBY
        if self.failsafe_reason and self.armed:
            state = MAV_STATE_CRITICAL
        self.link.send(
            self.link.codec.heartbeat_encode(
                MAV_TYPE_QUADROTOR,
                MAV_AUTOPILOT_PX4,
                px4.base_mode_flags(self.mode, self.armed),
                self.mode.custom_mode,
                state,
            )
        )

    def _send_autopilot_version(self) -> None:
        mod = self._mod
        caps = 0
        for name in (
            "MISSION_FLOAT",
            "PARAM_FLOAT",
            "MISSION_INT",
            "COMMAND_INT",
            "PARAM_ENCODE_BYTEWISE",
            "SET_ATTITUDE_TARGET",
            "SET_POSITION_TARGET_LOCAL_NED",
            "MAVLINK2",
        ):
            caps |= int(getattr(mod, f"MAV_PROTOCOL_CAPABILITY_{name}"))
        self.link.send(
            self.link.codec.autopilot_version_encode(
                caps,
                px4.encode_flight_sw_version(1, 16, 0),
                0,
                0,
                0,
                SIM_MARKER,  # flight_custom_version: tells this simulation from a PX4
                b"\0" * 8,
                b"\0" * 8,
                0,
                0,
                0x1234ABCD,
                [0] * 18,
            )
        )

    def _send_stream(self, mid: int, now: float) -> None:
        c = self.link.codec
        x = self.x
        ms = int(self.t * 1000) & 0xFFFFFFFF
        us = int(self.t * 1e6)
        noise = self.config.sensor_noise

        def rn(s: float, n: int = 3) -> np.ndarray:
            """Sensor noise of standard deviation ``s`` (zeros with sensor_noise off)."""
            return self._rng.normal(0.0, s, n) if noise else np.zeros(n)

        R = self._R(x)
        v_ned = R @ x[6:9]
        sid = self._stream_ids
        if mid == sid["ATTITUDE_QUATERNION"]:
            q = euler_to_quat(*x[3:6])
            w = x[9:12] + rn(0.005)
            c_msg = c.attitude_quaternion_encode(
                ms, *[float(v) for v in q], *[float(v) for v in w], [0.0] * 4
            )
        elif mid == sid["ATTITUDE"]:
            w = x[9:12] + rn(0.005)
            c_msg = c.attitude_encode(ms, *[float(v) for v in x[3:6]], *[float(v) for v in w])
        elif mid == sid["LOCAL_POSITION_NED"]:
            p = x[0:3] + rn(0.01)
            v = v_ned + rn(0.02)
            c_msg = c.local_position_ned_encode(ms, *[float(a) for a in p], *[float(a) for a in v])
        elif mid == sid["GLOBAL_POSITION_INT"]:
            lat = HOME_LAT + x[0] / 111319.5
            lon = HOME_LON + x[1] / (111319.5 * math.cos(math.radians(HOME_LAT)))
            hdg = int(math.degrees(x[5]) % 360 * 100)
            c_msg = c.global_position_int_encode(
                ms,
                int(lat * 1e7),
                int(lon * 1e7),
                int((HOME_ALT - x[2]) * 1000),
                int(-x[2] * 1000),
                *[int(v * 100) for v in v_ned],
                hdg,
            )
        elif mid == sid["HIGHRES_IMU"]:
            if self.armed and not self.landed:
                acc = np.asarray(self.model.specific_force(x, self.u), dtype=float)
            else:
                acc = R.T @ np.array([0.0, 0.0, -9.80665])
            acc = acc + rn(0.05)
            gyr = x[9:12] + rn(0.005)
            c_msg = c.highres_imu_encode(
                us,
                *[float(a) for a in acc],
                *[float(a) for a in gyr],
                0.2,
                0.0,
                0.4,
                1013.0,
                0.0,
                float(-x[2]),
                25.0,
                0x1FF,
                0,
            )
        elif mid == sid["ESC_STATUS"]:
            rpm = [int(round(o * 60.0 / (2 * math.pi))) for o in x[12:16]]
            c_msg = self._esc_cls(0, us, rpm, [16.0] * 4, [0.0] * 4)
        elif mid == sid["SERVO_OUTPUT_RAW"]:
            _, pwm = self._outputs16()
            c_msg = c.servo_output_raw_encode(us & 0xFFFFFFFF, 0, *[int(round(v)) for v in pwm])
        elif mid == sid["ACTUATOR_OUTPUT_STATUS"]:
            u16, pwm = self._outputs16()
            vals = pwm if self.config.actuator_output_scale == "pwm" else u16
            c_msg = c.actuator_output_status_encode(us, N_OUTPUTS, vals + [0.0] * (32 - N_OUTPUTS))
        elif mid == sid["RC_CHANNELS"]:
            chans = [1500, 1500, 1500, 1500, 1000, 1000, 1000, 1000] + [0] * 10  # sticks centred
            c_msg = c.rc_channels_encode(ms, 8, *chans, 200)
        elif mid == sid["SYS_STATUS"]:
            sensors = SENSORS_BASE | (
                MAV_SYS_STATUS_SENSOR_RC_RECEIVER if self.sticks_available(now) else 0
            )
            health = sensors & ~(MAV_SYS_STATUS_SENSOR_GPS if self.config.gps_fix < 3 else 0)
            c_msg = c.sys_status_encode(
                sensors,
                sensors,
                health,
                100,
                int(self.config.battery_voltage * 1000),
                500 if self.armed else 20,
                self.battery_remaining(),
                0,
                0,
                0,
                0,
                0,
                0,
            )
        elif mid == sid["GPS_RAW_INT"]:
            fix = self.config.gps_fix
            lat = HOME_LAT + x[0] / 111319.5
            lon = HOME_LON + x[1] / (111319.5 * math.cos(math.radians(HOME_LAT)))
            c_msg = c.gps_raw_int_encode(
                us,
                fix,
                int(lat * 1e7),
                int(lon * 1e7),
                int((HOME_ALT - x[2]) * 1000),
                80 if fix >= 3 else 9999,
                120 if fix >= 3 else 9999,
                int(100 * math.hypot(v_ned[0], v_ned[1])),
                0,
                12 if fix >= 3 else 0,
            )
        elif mid == sid["ESTIMATOR_STATUS"]:
            c_msg = c.estimator_status_encode(
                us, self.estimator_flags(), 0.1, 0.1, 0.1, 0.1, 0.0, 0.0, 0.5, 0.8
            )
        elif mid == sid["EXTENDED_SYS_STATE"]:
            c_msg = c.extended_sys_state_encode(
                0, MAV_LANDED_STATE_ON_GROUND if self.landed else MAV_LANDED_STATE_IN_AIR
            )
        elif mid == sid["HOME_POSITION"]:
            c_msg = c.home_position_encode(
                int(HOME_LAT * 1e7),
                int(HOME_LON * 1e7),
                int(HOME_ALT * 1000),
                0.0,
                0.0,
                0.0,
                [1.0, 0.0, 0.0, 0.0],
                0.0,
                0.0,
                0.0,
                us,
            )
        elif mid == sid["ATTITUDE_TARGET"]:
            sp = self._rates_setpoint()
            if sp is None:
                return
            rates = sp.rates if sp.rates is not None else np.zeros(3)
            # as PX4 (streams/ATTITUDE_TARGET.hpp): fresh body rates (vehicle_rates_setpoint),
            # but thrust and time_boot_ms of the last vehicle_attitude_setpoint, which nothing
            # publishes in body-rate OFFBOARD: held from the episode's first rate setpoint (the
            # hover thrust the bridge pre-streams, as PX4's last HOLD setpoint would be)
            if self.att_sp_echo is None:
                self.att_sp_echo = (ms, float(sp.thrust))
            c_msg = c.attitude_target_encode(
                self.att_sp_echo[0],
                7,  # ATTITUDE_TARGET_TYPEMASK: attitude ignored (a rates setpoint)
                [float(a) for a in euler_to_quat(*x[3:6])],
                float(rates[0]),
                float(rates[1]),
                float(rates[2]),
                self.att_sp_echo[1],
            )
        elif mid == sid["ODOMETRY"]:
            # EKF2 vehicle_odometry: timestamp_sample = IMU sample time (before the publish
            # time that stamps ATTITUDE_QUATERNION / LOCAL_POSITION_NED); pose and velocity NED
            q = euler_to_quat(*x[3:6])
            tv = max(self.t - self.config.odometry_lag_s, 0.0)
            nan = float("nan")
            pose_cov = [nan] * 21
            vel_cov = [nan] * 21
            for i, var in ((0, 1e-4), (6, 1e-4), (11, 1e-4), (15, 1e-6), (18, 1e-6), (20, 1e-6)):
                pose_cov[i] = var
            for i in (0, 6, 11):
                vel_cov[i] = 1e-4
            c_msg = c.odometry_encode(
                int(tv * 1e6),
                MAV_FRAME_LOCAL_NED,
                MAV_FRAME_LOCAL_NED,
                *[float(a) for a in x[0:3]],
                [float(a) for a in q],
                *[float(a) for a in v_ned],
                *[float(a) for a in x[9:12]],
                pose_cov,
                vel_cov,
                0,
                MAV_ESTIMATOR_TYPE_AUTOPILOT,
                0,
            )
        else:
            return
        self.link.send(c_msg)
