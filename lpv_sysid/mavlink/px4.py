"""PX4 conventions on top of MAVLink 2 (PX4 v1.14 - v1.16).

Everything the bridge, the simulated vehicle and the preflight check must agree on
lives here: the PX4 custom-mode encoding, the modes that need stick input, the
offboard-loss actions (COM_OBL_RC_ACT) and stick sources (COM_RC_IN_MODE), the command
ids and results (and which commands PX4 acknowledges twice), the PWM motor-output range
and PX4's byte-wise encoding of integer parameters. The MAVLink codec used by every
link and the ESC_STATUS message are in :mod:`lpv_sysid.mavlink.codec`.

PX4 custom mode (``HEARTBEAT.custom_mode``, ``MAV_CMD_DO_SET_MODE`` param2/param3)::

    custom_mode = main_mode << 16 | sub_mode << 24

e.g. OFFBOARD = main 6, HOLD = main 4 / sub 3 (AUTO.LOITER), LAND = main 4 / sub 6,
POSCTL = main 3.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass
from typing import Any

from lpv_sysid.errors import ConfigError

# --------------------------------------------------------------------------- modes
MAIN_MANUAL = 1
MAIN_ALTCTL = 2
MAIN_POSCTL = 3
MAIN_AUTO = 4
MAIN_ACRO = 5
MAIN_OFFBOARD = 6
MAIN_STABILIZED = 7

SUB_AUTO_READY = 1
SUB_AUTO_TAKEOFF = 2
SUB_AUTO_LOITER = 3
SUB_AUTO_MISSION = 4
SUB_AUTO_RTL = 5
SUB_AUTO_LAND = 6

MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_AUTO_ENABLED = 4
MAV_MODE_FLAG_GUIDED_ENABLED = 8
MAV_MODE_FLAG_STABILIZE_ENABLED = 16
MAV_MODE_FLAG_MANUAL_INPUT_ENABLED = 64
MAV_MODE_FLAG_SAFETY_ARMED = 128


@dataclass(frozen=True)
class Px4Mode:
    """A PX4 flight mode as (main, sub); ``name`` follows QGroundControl/MAVSDK."""

    main: int
    sub: int = 0

    @property
    def custom_mode(self) -> int:
        return encode_custom_mode(self.main, self.sub)

    @property
    def name(self) -> str:
        return _MODE_NAMES.get((self.main, self.sub), f"UNKNOWN({self.main}.{self.sub})")


MANUAL = Px4Mode(MAIN_MANUAL)
ALTCTL = Px4Mode(MAIN_ALTCTL)
POSCTL = Px4Mode(MAIN_POSCTL)
OFFBOARD = Px4Mode(MAIN_OFFBOARD)
STABILIZED = Px4Mode(MAIN_STABILIZED)
ACRO = Px4Mode(MAIN_ACRO)
HOLD = Px4Mode(MAIN_AUTO, SUB_AUTO_LOITER)
LAND = Px4Mode(MAIN_AUTO, SUB_AUTO_LAND)
RTL = Px4Mode(MAIN_AUTO, SUB_AUTO_RTL)
TAKEOFF = Px4Mode(MAIN_AUTO, SUB_AUTO_TAKEOFF)
MISSION = Px4Mode(MAIN_AUTO, SUB_AUTO_MISSION)
AUTO_READY = Px4Mode(MAIN_AUTO, SUB_AUTO_READY)

_MODE_NAMES = {
    (MAIN_MANUAL, 0): "MANUAL",
    (MAIN_ALTCTL, 0): "ALTCTL",
    (MAIN_POSCTL, 0): "POSCTL",
    (MAIN_OFFBOARD, 0): "OFFBOARD",
    (MAIN_STABILIZED, 0): "STABILIZED",
    (MAIN_ACRO, 0): "ACRO",
    (MAIN_AUTO, SUB_AUTO_READY): "READY",
    (MAIN_AUTO, SUB_AUTO_LOITER): "HOLD",
    (MAIN_AUTO, SUB_AUTO_LAND): "LAND",
    (MAIN_AUTO, SUB_AUTO_RTL): "RTL",
    (MAIN_AUTO, SUB_AUTO_TAKEOFF): "TAKEOFF",
    (MAIN_AUTO, SUB_AUTO_MISSION): "MISSION",
}
MODES_BY_NAME = {name: Px4Mode(*key) for key, name in _MODE_NAMES.items()}

#: hand-back modes the offboard state machine may choose (configurable by name).
HANDBACK_MODES = {"HOLD": HOLD, "POSCTL": POSCTL, "ALTCTL": ALTCTL, "LAND": LAND, "RTL": RTL}

#: modes whose flight task reads the pilot's sticks (manual control input). Without stick
#: input PX4 v1.16 refuses DO_SET_MODE to them while armed (the commander's verdict
#: TEMPORARILY_REJECTED; disarmed, every mode change is allowed and arming is refused
#: instead), and when a failsafe enters one of them (COM_OBL_RC_ACT 0/1/2)
#: the flight mode manager logs "Matching flight task was not able to run" and flies the
#: emergency Descend task instead: level attitude, MPC_LAND_SPEED down, no position hold.
STICK_MODES = frozenset({MANUAL, STABILIZED, ACRO, ALTCTL, POSCTL})

#: vehicle_status.nav_state of each mode (PX4 v1.16 VehicleStatus.msg), as PX4 logs it
NAV_STATES = {
    MANUAL: 0,
    ALTCTL: 1,
    POSCTL: 2,
    MISSION: 3,
    HOLD: 4,
    RTL: 5,
    ACRO: 10,
    OFFBOARD: 14,
    STABILIZED: 15,
    TAKEOFF: 17,
    LAND: 18,
}


def encode_custom_mode(main: int, sub: int = 0) -> int:
    """PX4 ``custom_mode``: main mode in bits 16-23, sub mode in bits 24-31."""
    if not (0 <= main <= 255 and 0 <= sub <= 255):
        raise ConfigError(f"PX4 mode main={main} sub={sub} out of range 0..255")
    return (main << 16) | (sub << 24)


def decode_custom_mode(custom_mode: int) -> Px4Mode:
    """Inverse of :func:`encode_custom_mode` (bits 0-15 are unused by PX4)."""
    return Px4Mode((custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF)


def mode_by_name(name: str) -> Px4Mode:
    try:
        return MODES_BY_NAME[name.upper()]
    except KeyError:
        raise ConfigError(f"unknown PX4 mode {name!r}; known: {sorted(MODES_BY_NAME)}") from None


def base_mode_flags(mode: Px4Mode, armed: bool) -> int:
    """HEARTBEAT.base_mode as PX4 commander fills it (mavlink_main get_mavlink_mode_state)."""
    flags = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if armed:
        flags |= MAV_MODE_FLAG_SAFETY_ARMED
    if mode.main in (MAIN_MANUAL, MAIN_ACRO, MAIN_STABILIZED):
        flags |= MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
        if mode.main == MAIN_STABILIZED:
            flags |= MAV_MODE_FLAG_STABILIZE_ENABLED
    elif mode.main in (MAIN_ALTCTL, MAIN_POSCTL):
        flags |= MAV_MODE_FLAG_MANUAL_INPUT_ENABLED | MAV_MODE_FLAG_STABILIZE_ENABLED
        if mode.main == MAIN_POSCTL:
            flags |= MAV_MODE_FLAG_GUIDED_ENABLED
    elif mode.main in (MAIN_AUTO, MAIN_OFFBOARD):
        flags |= (
            MAV_MODE_FLAG_AUTO_ENABLED
            | MAV_MODE_FLAG_STABILIZE_ENABLED
            | MAV_MODE_FLAG_GUIDED_ENABLED
        )
    return flags


# ------------------------------------------------------------------ firmware version
def decode_flight_sw_version(v: int) -> tuple[int, int, int, int]:
    """AUTOPILOT_VERSION.flight_sw_version: major<<24 | minor<<16 | patch<<8 | type."""
    return (v >> 24) & 0xFF, (v >> 16) & 0xFF, (v >> 8) & 0xFF, v & 0xFF


def encode_flight_sw_version(major: int, minor: int, patch: int, fw_type: int = 255) -> int:
    """FIRMWARE_VERSION_TYPE_OFFICIAL = 255."""
    return (major << 24) | (minor << 16) | (patch << 8) | fw_type


# ------------------------------------------------------------------------ parameters
class OblAction(enum.IntEnum):
    """COM_OBL_RC_ACT (PX4 v1.16 commander_params.c): action after offboard loss
    (COM_OF_LOSS_T)."""

    POSITION = 0
    ALTITUDE = 1
    STABILIZED = 2  # "Stabilized" in v1.16 (older releases called it "Manual")
    MANUAL = 2  # alias of STABILIZED (pre-v1.16 name); .name reports STABILIZED
    RETURN = 3
    LAND = 4
    HOLD = 5
    TERMINATE = 6
    DISARM = 7


#: flight mode PX4 enters for each COM_OBL_RC_ACT (6 Terminate / 7 Disarm: none, motors off)
OBL_ACTION_MODES = {
    OblAction.POSITION: POSCTL,
    OblAction.ALTITUDE: ALTCTL,
    OblAction.STABILIZED: STABILIZED,
    OblAction.RETURN: RTL,
    OblAction.LAND: LAND,
    OblAction.HOLD: HOLD,
}


class RcInMode(enum.IntEnum):
    """COM_RC_IN_MODE (PX4 v1.16): where manual control (stick) input may come from."""

    RC_ONLY = 0
    JOYSTICK_ONLY = 1  # MAVLink MANUAL_CONTROL only
    RC_AND_JOYSTICK = 2  # both, with fallback
    RC_OR_JOYSTICK = 3  # both, the first one seen is kept
    DISABLED = 4  # stick input disabled


def sticks_available(rc_in_mode: int, rc_present: bool, joystick_present: bool) -> bool:
    """Whether PX4 has manual control input for STICK_MODES under COM_RC_IN_MODE."""
    m = int(rc_in_mode)
    rc_ok = rc_present and m in (
        RcInMode.RC_ONLY,
        RcInMode.RC_AND_JOYSTICK,
        RcInMode.RC_OR_JOYSTICK,
    )
    joy_ok = joystick_present and m in (
        RcInMode.JOYSTICK_ONLY,
        RcInMode.RC_AND_JOYSTICK,
        RcInMode.RC_OR_JOYSTICK,
    )
    return bool(rc_ok or joy_ok)


MAV_PARAM_TYPE_UINT32 = 5  # PX4: only the parameter list's hash, _HASH_CHECK
MAV_PARAM_TYPE_INT32 = 6
MAV_PARAM_TYPE_REAL32 = 9


def param_to_wire(value: float | int, param_type: int) -> float:
    """PX4 sends INT32 parameters byte-wise: the int32 bits are carried in the float field."""
    if param_type == MAV_PARAM_TYPE_INT32:
        return struct.unpack("<f", struct.pack("<i", int(value)))[0]
    return float(value)


def param_from_wire(wire: float, param_type: int) -> float | int:
    """Inverse of :func:`param_to_wire` (PX4 byte-wise encoding,
    MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE)."""
    if param_type == MAV_PARAM_TYPE_INT32:
        return struct.unpack("<i", struct.pack("<f", wire))[0]
    if param_type == MAV_PARAM_TYPE_UINT32:  # _HASH_CHECK: a 32-bit hash, not a number
        return struct.unpack("<I", struct.pack("<f", wire))[0]
    return float(wire)


def param_id_str(param_id: Any) -> str:
    if isinstance(param_id, (bytes, bytearray)):
        param_id = param_id.decode("ascii", errors="replace")
    return str(param_id).rstrip("\x00")


# ------------------------------------------------------------------ commands, results
MAV_CMD_NAV_RETURN_TO_LAUNCH = 20
MAV_CMD_NAV_LAND = 21
MAV_CMD_NAV_TAKEOFF = 22
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_REQUEST_MESSAGE = 512
MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES = 520
#: MAV_CMD_COMPONENT_ARM_DISARM param2 that forces a disarm in the air
FORCE_DISARM_MAGIC = 21196

MAV_RESULT_ACCEPTED = 0
MAV_RESULT_TEMPORARILY_REJECTED = 1
MAV_RESULT_DENIED = 2
MAV_RESULT_UNSUPPORTED = 3
MAV_RESULT_FAILED = 4
MAV_RESULT_IN_PROGRESS = 5
MAV_RESULT_NAMES = {
    0: "ACCEPTED",
    1: "TEMPORARILY_REJECTED",
    2: "DENIED",
    3: "UNSUPPORTED",
    4: "FAILED",
    5: "IN_PROGRESS",
    6: "CANCELLED",
}

#: commands PX4 v1.16 answers twice: ACCEPTED at once from its MAVLink receiver, then the
#: commander's verdict 0-15 ms later (measured on v1.16.0 SIH SITL; e.g. TEMPORARILY_REJECTED
#: for POSCTL without stick input while armed). Arming was answered once there; clients must
#: handle one or two answers for any command (lpv_sysid.mavlink.offboard does).
DOUBLE_ACK_COMMANDS = frozenset({MAV_CMD_DO_SET_MODE})


def result_name(result: int) -> str:
    return MAV_RESULT_NAMES.get(int(result), f"MAV_RESULT {result}")


# ------------------------------------------------------------------- motor outputs
#: PX4 PWM output range (PWM_MAIN_MINx / PWM_MAIN_MAXx defaults) and the disarmed value of
#: SITL's pwm_out_sim; u_ESC in [0, 1] maps linearly onto [PWM_MIN_US, PWM_MAX_US]
PWM_MIN_US = 1000.0
PWM_MAX_US = 2000.0
PWM_DISARMED_US = 900.0


def pwm_from_u_esc(u_esc: float) -> float:
    """PWM pulse [us] for a normalised motor command u_ESC in [0, 1] (clipped)."""
    u = min(max(float(u_esc), 0.0), 1.0)
    return PWM_MIN_US + (PWM_MAX_US - PWM_MIN_US) * u
