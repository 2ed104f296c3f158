"""mavros_msgs fields (MAVROS 2.x, ROS 2): setpoints out, state / rotor evidence in.

Only the MAVROS transport with ``mavros.interfaces`` ``mavros_msgs`` touches these types;
the factory looks them up by name, so nothing here imports mavros_msgs (the package works
without it). MAVROS's frame conventions (mavros ``setpoint_raw`` plugin, ``ftf``):

- ``PositionTarget``: ``FRAME_BODY_NED`` (8) vectors are given in ``base_link`` (FLU) and
  turned to FRD by MAVROS (``transform_frame_baselink_aircraft``: x, -y, -z);
  ``FRAME_LOCAL_NED`` (1) vectors in local ENU (``transform_frame_enu_ned``); ``yaw_rate``
  is the ENU z rate, negated by MAVROS; ``type_mask`` passes unchanged (the bits equal
  MAVLink's POSITION_TARGET_TYPEMASK);
- ``AttitudeTarget``: ``body_rate`` in FLU (MAVROS: x, -y, -z), ``thrust`` in [0, 1],
  ``type_mask`` unchanged (``IGNORE_ATTITUDE`` = 128), the orientation is base_link -> ENU
  (ignored with that bit; identity is sent).

So the core's NED/FRD values pass :mod:`lpv_sysid.io.frames` (``frd_to_flu``,
``ned_to_enu``) here and nowhere else.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lpv_sysid.io import frames
from lpv_sysid.io.messages.factory import MessageError, MsgFactory
from lpv_sysid.io.messages.fields import finite, header_msg, stamp_ns_of, vector3, xyz

POSITION_TARGET = "mavros_msgs/msg/PositionTarget"
ATTITUDE_TARGET = "mavros_msgs/msg/AttitudeTarget"
STATE = "mavros_msgs/msg/State"
ESC_STATUS = "mavros_msgs/msg/ESCStatus"
RC_OUT = "mavros_msgs/msg/RCOut"
HOME_POSITION = "mavros_msgs/msg/HomePosition"
RC_IN = "mavros_msgs/msg/RCIn"
VEHICLE_INFO_GET = "mavros_msgs/srv/VehicleInfoGet"
MESSAGE_INTERVAL = "mavros_msgs/srv/MessageInterval"
GET_PARAMETERS = "rcl_interfaces/srv/GetParameters"  # MAVROS mirrors FCU params as ROS ones
BATTERY = "sensor_msgs/msg/BatteryState"  # sys_status plugin: SYS_STATUS / BATTERY_STATUS
GPS_RAW = "mavros_msgs/msg/GPSRAW"  # gps_status plugin: GPS_RAW_INT
NAV_SAT_FIX = "sensor_msgs/msg/NavSatFix"  # global_position plugin: GPS_RAW_INT fix
ESTIMATOR_STATUS = "mavros_msgs/msg/EstimatorStatus"  # sys_status plugin: ESTIMATOR_STATUS
SET_MODE = "mavros_msgs/srv/SetMode"
COMMAND_BOOL = "mavros_msgs/srv/CommandBool"
COMMAND_LONG = "mavros_msgs/srv/CommandLong"  # command plugin: COMMAND_LONG, PX4's ACK
PARAM_EVENT = "mavros_msgs/msg/ParamEvent"  # param plugin: one per PARAM_VALUE
PARAM_PULL = "mavros_msgs/srv/ParamPull"  # param plugin: PARAM_REQUEST_LIST
LIST_PARAMETERS = "rcl_interfaces/srv/ListParameters"  # the FCU params MAVROS has pulled

#: the mavros_msgs types of the MAVROS transport, by role
MAVROS_TYPES = {
    "position_target": POSITION_TARGET,
    "attitude_target": ATTITUDE_TARGET,
    "state": STATE,
    "esc_status": ESC_STATUS,
    "rc_out": RC_OUT,
    "home_position": HOME_POSITION,
    "set_mode": SET_MODE,
    "command_bool": COMMAND_BOOL,
    "command_long": COMMAND_LONG,
    "rc_in": RC_IN,
    "vehicle_info_get": VEHICLE_INFO_GET,
    "message_interval": MESSAGE_INTERVAL,
    "get_parameters": GET_PARAMETERS,
    "battery": BATTERY,
    "gps_raw": GPS_RAW,
    "nav_sat_fix": NAV_SAT_FIX,
    "estimator_status": ESTIMATOR_STATUS,
    "param_event": PARAM_EVENT,
    "param_pull": PARAM_PULL,
    "list_parameters": LIST_PARAMETERS,
}
#: rcl_interfaces/ParameterValue.type of the numbers (PARAMETER_INTEGER, PARAMETER_DOUBLE)
PARAMETER_INTEGER, PARAMETER_DOUBLE = 2, 3

FRAME_LOCAL_NED = 1
FRAME_BODY_NED = 8
MAVLINK_FRAMES = (FRAME_LOCAL_NED, FRAME_BODY_NED)
#: mavros_msgs/EstimatorStatus fields in the order of MAVLink's ESTIMATOR_STATUS_FLAGS bits
#: (field k is bit 2**k: attitude 1 .. accel_error 2048; MAVROS sys_status plugin)
ESTIMATOR_FLAG_FIELDS = (
    "attitude_status_flag",
    "velocity_horiz_status_flag",
    "velocity_vert_status_flag",
    "pos_horiz_rel_status_flag",
    "pos_horiz_abs_status_flag",
    "pos_vert_abs_status_flag",
    "pos_vert_agl_status_flag",
    "const_pos_mode_status_flag",
    "pred_pos_horiz_rel_status_flag",
    "pred_pos_horiz_abs_status_flag",
    "gps_glitch_status_flag",
    "accel_error_status_flag",
)
#: sensor_msgs/NavSatStatus.STATUS_FIX: MAVROS publishes it when GPS_RAW_INT.fix_type > 2
NAV_SAT_STATUS_FIX = 0
#: GPS_RAW_INT fix types a NavSatFix status stands for (3D fix / no 3D fix) and the
#: satellite count it cannot tell (255: unknown, as in GPS_RAW_INT)
FIX_3D, NO_FIX, SATELLITES_UNKNOWN = 3, 1, 255


@dataclass(frozen=True)
class MavrosVehicleState:
    """``mavros_msgs/State``: ``connected`` (MAVROS hears the autopilot's HEARTBEAT),
    ``armed``, the PX4 ``mode`` string as MAVROS names it (``AUTO.LOITER``, ...) and the
    HEARTBEAT's ``system_status`` (MAV_STATE; PX4 sends MAV_STATE_CRITICAL while armed in a
    failsafe)."""

    stamp_ns: int
    connected: bool
    armed: bool
    mode: str
    system_status: int = 0


def position_target_msg(
    f: MsgFactory, stamp_ns: int, frame: int, type_mask: int, v_ned_or_frd, yaw_rate_frd: float
):
    """``PositionTarget`` carrying a velocity (+ yaw rate) setpoint for
    ``setpoint_raw/local``: ``v_ned_or_frd`` is FRD for ``FRAME_BODY_NED``, NED for
    ``FRAME_LOCAL_NED`` (MAVLink's SET_POSITION_TARGET_LOCAL_NED meaning); ``yaw_rate_frd``
    the NED/FRD yaw rate. Converted to MAVROS's FLU / ENU (module docstring)."""
    if frame not in MAVLINK_FRAMES:
        raise MessageError(f"PositionTarget: frame {frame} is not LOCAL_NED (1) or BODY_NED (8)")
    v = finite(v_ned_or_frd, 3, "velocity setpoint")
    r = float(finite([yaw_rate_frd], 1, "yaw-rate setpoint")[0])
    v_ros = frames.frd_to_flu(v) if frame == FRAME_BODY_NED else frames.ned_to_enu(v)
    return f(
        POSITION_TARGET,
        header=header_msg(f, stamp_ns, ""),
        coordinate_frame=int(frame),
        type_mask=int(type_mask),
        position=f("geometry_msgs/msg/Point", x=0.0, y=0.0, z=0.0),
        velocity=vector3(f, v_ros),
        acceleration_or_force=vector3(f, [0.0, 0.0, 0.0]),
        yaw=0.0,
        yaw_rate=-r,
    )


def attitude_target_msg(f: MsgFactory, stamp_ns: int, type_mask: int, rates_frd, thrust: float):
    """``AttitudeTarget`` for ``setpoint_raw/attitude``: FRD body rates [rad/s] as FLU
    ``body_rate``, normalised ``thrust``, identity orientation (ignored by ``type_mask``)."""
    w = finite(rates_frd, 3, "body-rate setpoint")
    t = float(finite([thrust], 1, "thrust setpoint")[0])
    return f(
        ATTITUDE_TARGET,
        header=header_msg(f, stamp_ns, ""),
        type_mask=int(type_mask),
        orientation=f("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0),
        body_rate=vector3(f, frames.frd_to_flu(w)),
        thrust=t,
    )


def velocity_setpoint_from_position_target(msg) -> tuple[int, int, np.ndarray, float]:
    """Inverse of :func:`position_target_msg` (what MAVROS hands PX4):
    ``(frame, type_mask, v (FRD or NED), yaw_rate (NED))``."""
    frame = int(msg.coordinate_frame)
    v = xyz(msg.velocity)
    v_mav = frames.flu_to_frd(v) if frame == FRAME_BODY_NED else frames.enu_to_ned(v)
    return frame, int(msg.type_mask), v_mav, -float(msg.yaw_rate)


def rate_setpoint_from_attitude_target_msg(msg) -> tuple[int, np.ndarray, float]:
    """Inverse of :func:`attitude_target_msg`: ``(type_mask, rates FRD, thrust)``."""
    return int(msg.type_mask), frames.flu_to_frd(xyz(msg.body_rate)), float(msg.thrust)


def state_from_msg(msg) -> MavrosVehicleState:
    """``mavros_msgs/State`` -> :class:`MavrosVehicleState`."""
    return MavrosVehicleState(
        stamp_ns_of(msg),
        bool(msg.connected),
        bool(msg.armed),
        str(msg.mode).strip(),
        int(msg.system_status),
    )


def esc_rpm_from_msg(msg) -> tuple[int, list[float]]:
    """``mavros_msgs/ESCStatus`` -> ``(stamp_ns, rpm of each ESC)``."""
    return stamp_ns_of(msg), [float(item.rpm) for item in msg.esc_status]


def rc_out_from_msg(msg) -> tuple[int, list[int]]:
    """``mavros_msgs/RCOut`` (PX4's SERVO_OUTPUT_RAW) -> ``(stamp_ns, PWM per channel)``."""
    return stamp_ns_of(msg), [int(c) for c in msg.channels]


def home_ned_from_msg(msg) -> np.ndarray:
    """``mavros_msgs/HomePosition.position`` (local ENU) -> NED [m]."""
    return frames.enu_to_ned(finite(xyz(msg.position), 3, "home position"))


def home_geo_from_msg(msg) -> tuple[float, float, float]:
    """``mavros_msgs/HomePosition.geo`` -> ``(latitude deg, longitude deg, altitude m)``."""
    g = msg.geo
    lat, lon, alt = finite([g.latitude, g.longitude, g.altitude], 3, "home geo")
    return float(lat), float(lon), float(alt)


def battery_from_msg(msg) -> tuple[float | None, float]:
    """``sensor_msgs/BatteryState`` as MAVROS fills it -> ``(remaining %, voltage V)``;
    ``percentage`` is 0..1 (MAVROS: ``battery_remaining / 100``, so PX4's unknown -1 comes
    as -0.01); NaN or negative: None (unknown)."""
    p = float(msg.percentage)
    pct = 100.0 * p if math.isfinite(p) and p >= 0.0 else None
    return pct, float(msg.voltage)


def gps_from_gpsraw(msg) -> tuple[int, int]:
    """``mavros_msgs/GPSRAW`` (PX4's GPS_RAW_INT) -> ``(fix_type, satellites_visible)``."""
    return int(msg.fix_type), int(msg.satellites_visible)


def gps_from_navsatfix(msg) -> tuple[int, int]:
    """``sensor_msgs/NavSatFix`` from MAVROS's global_position plugin -> the
    ``(fix_type, satellites_visible)`` it implies: STATUS_FIX (>= 0) only for
    ``fix_type > 2``, so :data:`FIX_3D`, else :data:`NO_FIX`; satellites unknown."""
    fix = int(msg.status.status) >= NAV_SAT_STATUS_FIX
    return (FIX_3D if fix else NO_FIX), SATELLITES_UNKNOWN


def estimator_flags_from_msg(msg) -> int:
    """``mavros_msgs/EstimatorStatus`` -> MAVLink ESTIMATOR_STATUS ``flags`` (bit 2**k for
    field k of :data:`ESTIMATOR_FLAG_FIELDS`)."""
    return sum(1 << k for k, name in enumerate(ESTIMATOR_FLAG_FIELDS) if bool(getattr(msg, name)))


def rc_in_from_msg(msg) -> tuple[int, int]:
    """``mavros_msgs/RCIn`` (PX4's RC_CHANNELS) -> ``(channel count, RSSI)``."""
    return len(msg.channels), int(msg.rssi)


def params_from_get_parameters(names, response) -> dict[str, float | int]:
    """``rcl_interfaces/srv/GetParameters`` answer for ``names`` -> the numbers that are
    set (a name MAVROS has not pulled yet answers PARAMETER_NOT_SET: left out)."""
    out: dict[str, float | int] = {}
    for name, v in zip(names, response.values):
        if int(v.type) == PARAMETER_INTEGER:
            out[str(name)] = int(v.integer_value)
        elif int(v.type) == PARAMETER_DOUBLE:
            out[str(name)] = float(v.double_value)
    return out


def vehicle_from_info_response(response):
    """The first ``mavros_msgs/VehicleInfo`` of a successful ``VehicleInfoGet``, else None."""
    if not bool(response.success) or len(response.vehicles) == 0:
        return None
    return response.vehicles[0]


#: mavros_msgs/VehicleInfo.available_info bit: AUTOPILOT_VERSION received
HAVE_INFO_AUTOPILOT_VERSION = 2


def autopilot_version_known(vi) -> bool:
    """``mavros_msgs/VehicleInfo`` holds PX4's AUTOPILOT_VERSION: ``available_info`` has
    :data:`HAVE_INFO_AUTOPILOT_VERSION` (MAVROS sets it when the message arrives; until then
    the version fields are zeros)."""
    return bool(int(vi.available_info) & HAVE_INFO_AUTOPILOT_VERSION)


def firmware_from_vehicle_info(vi) -> tuple[int, bytes, int, int, int, int, int] | None:
    """``mavros_msgs/VehicleInfo`` -> AUTOPILOT_VERSION's ``(flight_sw_version,
    flight_custom_version, board_version, vendor_id, product_id, uid)`` and HEARTBEAT's
    ``base_mode``; None while MAVROS has no AUTOPILOT_VERSION (``available_info`` without
    :data:`HAVE_INFO_AUTOPILOT_VERSION`: the version fields are zeros). MAVROS gives
    ``flight_custom_version`` as the hex text of the 8 bytes (measured with PX4 v1.16 SITL:
    ``'6ea3539157000000'``, ``available_info`` 3); text that is not 16 hex digits is kept
    as its first 8 UTF-8 bytes."""
    if not autopilot_version_known(vi):
        return None
    text = str(vi.flight_custom_version)
    try:
        custom = bytes.fromhex(text) if len(text) == 16 else text.encode()[:8]
    except ValueError:
        custom = text.encode()[:8]
    return (
        int(vi.flight_sw_version),
        custom,
        int(vi.board_version),
        int(vi.vendor_id),
        int(vi.product_id),
        int(vi.uid),
        int(vi.base_mode),
    )


def param_from_event(msg) -> tuple[str, float | int]:
    """``mavros_msgs/ParamEvent`` -> ``(PX4 parameter name, value)``: an integer parameter
    as int, a real one as float; MessageError for any other value type."""
    v = msg.value
    if int(v.type) == PARAMETER_INTEGER:
        return str(msg.param_id), int(v.integer_value)
    if int(v.type) == PARAMETER_DOUBLE:
        return str(msg.param_id), float(v.double_value)
    raise MessageError(f"param event {msg.param_id!r}: value type {int(v.type)} is no number")


def param_names_from_list(response) -> list[str]:
    """``rcl_interfaces/srv/ListParameters`` answer of MAVROS' param node -> the PX4
    parameter names (upper case; the node's own ROS parameters, e.g. ``use_sim_time``, are
    left out), sorted."""
    return sorted(str(n) for n in response.result.names if str(n) == str(n).upper())
