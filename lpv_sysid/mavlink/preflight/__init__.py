"""Preflight go/no-go checks of a PX4 vehicle over MAVLink (used by ``lpv-sysid preflight``),
or on MAVROS's evidence (:func:`mavros_checks`, the bridge's MAVROS transport).

The checks gather, within a bounded time: an autopilot HEARTBEAT (link, autopilot type,
vehicle type, mode, arming state), AUTOPILOT_VERSION (firmware >= 1.14, MAVLink 2 and the
offboard setpoint capabilities), the parameters the safety path depends on, the
telemetry streams the bridge needs, the evidence of stick input (SYS_STATUS, RC_CHANNELS)
and the source of the rotor speeds (ESC_STATUS, else the motor outputs). Each check is
GO, WARN (does not block) or NO-GO; a check may carry a note with the reason and the fix.

Gathering ends as soon as every answer is in. Streams that may legitimately be absent
(ESC_STATUS on SIH / PWM vehicles, RC_CHANNELS without RC, HIGHRES_IMU) are waited for at
most ``grace`` seconds after the stream requests, never for the whole timeout.

Rules (PX4 v1.16, ``commander_params.c``):
- COM_OF_LOSS_T in (0, 2] s (offboard-loss detection delay; PX4 default 1 s);
- COM_OBL_RC_ACT, the action after offboard loss: 0 Position, 1 Altitude, 2 Stabilized,
  3 Return, 4 Land, 5 Hold, 6 Terminate, 7 Disarm. Position, Altitude and Stabilized fly
  on the pilot's sticks (``px4.STICK_MODES``): without stick input PX4 cannot run them
  ("Matching flight task was not able to run") and descends without position control
  (measured on PX4 v1.16 SIH: 17.6 m to the ground with 0, altitude held within 0.3 m
  with 5). They are NO-GO when there is no stick input; 2 is WARN even with sticks (the
  pilot must fly at once). 6 and 7 stop the motors in the air: NO-GO. 3, 4, 5: GO.
- stick input: none when COM_RC_IN_MODE = 4 (stick input disabled); else PX4's own
  verdict in SYS_STATUS (MAV_SYS_STATUS_SENSOR_RC_RECEIVER present = valid manual control
  from RC or joystick) when received, else RC_CHANNELS with channels and RSSI > 0;
- mode: OFFBOARD while disarmed is PX4's leftover after an auto-disarm (the commander
  keeps the last mode): WARN, not a reason for NO-GO (the bridge switches the mode itself
  after pre-streaming). OFFBOARD while armed means another controller flies: NO-GO;
- rotor speeds: ESC_STATUS (measured) GO; without it the bridge estimates them from
  ACTUATOR_OUTPUT_STATUS / SERVO_OUTPUT_RAW (``mavlink/telemetry/rotor_estimate.py``): GO, with a
  WARN when the output values do not fit the configured mapping; neither: NO-GO;
- COM_DISARM_PRFLT > 0 (pre-flight auto disarm enabled) else WARN;
- NAV_DLL_ACT, COM_RCL_EXCEPT, COM_RC_IN_MODE reported (informational);
- battery, GPS fix, EKF2 health, home position, and PX4's velocity and tilt limits
  (MPC_XY_VEL_MAX, MPC_Z_VEL_MAX_UP / _DN, MPC_TILTMAX_AIR) against what the planned box
  needs: :mod:`~lpv_sysid.mavlink.preflight.health` (NO-GO names the parameter and the
  value that flies the box);
- telemetry from other systems on the link is reported (WARN; the bridge ignores it).
"""

from __future__ import annotations

from lpv_sysid.mavlink.preflight.checks import judge, run_checks
from lpv_sysid.mavlink.preflight.gather import Facts
from lpv_sysid.mavlink.preflight.mavros import PARAMS, MavrosEvidence, mavros_checks
from lpv_sysid.mavlink.preflight.report import GO, NOGO, WARN, format_table, verdict

__all__ = [
    "Facts",
    "GO",
    "MavrosEvidence",
    "NOGO",
    "PARAMS",
    "WARN",
    "format_table",
    "judge",
    "mavros_checks",
    "run_checks",
    "verdict",
]
