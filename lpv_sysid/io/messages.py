"""ROS message <-> array conversion: the only place message fields are touched.

Builders take a :class:`MsgFactory` so the same code makes rosbags dataclasses (CI, bag
files) and real rclpy messages (onboard). Messages are constructed with keyword arguments
for every field, floats are passed as Python ``float`` and numeric sequences through the
factory's adapters, which is what both rosbags and rclpy's generated classes accept.

Parsers accept either kind of message and return core quantities in the seed's frames
(NED world, FRD body, SI units); every frame conversion goes through
:mod:`lpv_sysid.io.frames`. Topic contents (docs/DESIGN.md):

============================  ==============================  ===================================
topic                         type                            content
============================  ==============================  ===================================
``state``                     nav_msgs/Odometry               ``odom`` (ENU) / ``base_link`` (FLU);
                                                              ENU position, ENU/FLU attitude,
                                                              body velocity and rates FLU
``rotor_speeds``              sensor_msgs/JointState          ``rotor_1..rotor_4``, velocity rad/s;
                                                              frame_id ``base_link`` measured
                                                              (ESC), ``estimated`` from the
                                                              motor outputs (seed 0 Eq. 8)
``imu``                       sensor_msgs/Imu                 FLU specific force and rates,
                                                              ENU/FLU orientation
``velocity_reference``        geometry_msgs/TwistStamped      ``base_link``; linear = v_d FLU,
                                                              angular.z = yaw-rate ref FLU
``excitation``                sensor_msgs/JointState          ``ue_t, ue_a, ue_e, ue_r``, position
``actuator_command``          sensor_msgs/JointState          ``ut, ua, ue, ur``, position
``status``                    diagnostic_msgs/DiagnosticArray one DiagnosticStatus per node
============================  ==============================  ===================================

Virtual actuator channels are named channels in the seed's FRD sense and are never frame
converted. Stamps are integer nanoseconds in the core (``stamp_ns``) and
``builtin_interfaces/Time`` on the wire; samples also carry ``t = stamp_ns / 1e9`` (s).
"""

from __future__ import annotations

import array
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.io import frames
from lpv_sysid.models.quadrotor import EXCITATION_NAMES, INPUT_NAMES  # owner of the names

__all__ = [
    "MessageError",
    "MsgFactory",
    "ROTOR_NAMES",
    "EXCITATION_NAMES",
    "INPUT_NAMES",
    "ODOM_FRAME",
    "BASE_FRAME",
    "TYPES",
    "StateSample",
    "StateArrays",
    "ImuSample",
    "StatusSample",
    "states_from_odometry",
    "channels_from_joint_states",
    "time_msg",
    "stamp_ns_from_time",
    "stamp_ns_of",
    "header_msg",
    "odometry_from_state",
    "state_from_odometry",
    "joint_state",
    "channels_from_joint_state",
    "rotor_speeds_msg",
    "rotor_speeds_from_joint_state",
    "rotor_source_of",
    "ROTOR_SOURCES",
    "ROTOR_ESTIMATED_FRAME",
    "excitation_msg",
    "excitation_from_joint_state",
    "actuator_command_msg",
    "actuator_command_from_joint_state",
    "imu_msg",
    "imu_from_msg",
    "twist_reference_msg",
    "reference_from_twist",
    "diagnostic_status",
    "diagnostic_array",
    "status_from_diagnostic_array",
    "DIAGNOSTIC_LEVELS",
]

ODOM_FRAME = "odom"
BASE_FRAME = "base_link"

ROTOR_NAMES = ("rotor_1", "rotor_2", "rotor_3", "rotor_4")  # PX4 quad-X numbering
#: where rotor speeds come from: "esc" (measured, ESC telemetry) or "estimated" (motor
#: outputs through the motor model); the JointState's header.frame_id tells them apart
ROTOR_SOURCES = ("esc", "estimated")
ROTOR_ESTIMATED_FRAME = "estimated"

#: message type of every topic of docs/DESIGN.md
TYPES = {
    "state": "nav_msgs/msg/Odometry",
    "rotor_speeds": "sensor_msgs/msg/JointState",
    "imu": "sensor_msgs/msg/Imu",
    "velocity_reference": "geometry_msgs/msg/TwistStamped",
    "excitation": "sensor_msgs/msg/JointState",
    "actuator_command": "sensor_msgs/msg/JointState",
    "status": "diagnostic_msgs/msg/DiagnosticArray",
}

DIAGNOSTIC_LEVELS = {"OK": 0, "WARN": 1, "ERROR": 2, "STALE": 3}
_INT32 = (-(2**31), 2**31 - 1)


class MessageError(ConfigError, ValueError):
    """A message cannot be built or parsed; the text names the field and the problem.
    ``row``: the index of the offending message for the parsers of many messages."""

    def __init__(self, message: str, row: int | None = None):
        super().__init__(message)
        self.row = row


# ------------------------------------------------------------------------ factory
def _float_list(values) -> list[float]:
    return [float(v) for v in values]


@dataclass(frozen=True)
class MsgFactory:
    """Message construction by type name ``pkg/msg/Name``.

    ``lookup`` returns the class; ``float_seq`` adapts an unbounded ``float64[]`` field,
    ``float_array`` a fixed-size ``float64[N]`` field and ``byte`` a ``byte`` field to
    what the backend accepts. Use :meth:`rosbags` or :meth:`rclpy`.
    """

    name: str
    lookup: Callable[[str], type]
    float_seq: Callable[[Any], Any]
    float_array: Callable[[Any], Any]
    byte: Callable[[int], Any]
    typestore: Any = None
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def rosbags(cls, typestore=None) -> "MsgFactory":
        """rosbags dataclasses from the ROS 2 Jazzy typestore (serialisable to CDR)."""
        if typestore is None:
            from rosbags.typesys import Stores, get_typestore

            typestore = get_typestore(Stores.ROS2_JAZZY)
        types = typestore.types

        def lookup(typename: str) -> type:
            try:
                return types[typename]
            except KeyError:
                raise MessageError(
                    f"unknown message type {typename!r} (not in the rosbags ROS2_JAZZY typestore)"
                ) from None

        def f64(values):
            return np.array(values, dtype=np.float64).reshape(-1)

        return cls("rosbags", lookup, f64, f64, int, typestore)

    @classmethod
    def rclpy(cls) -> "MsgFactory":
        """rclpy message classes via ``rosidl_runtime_py.utilities.get_message``; the import
        happens only here, so cores never pull in ROS."""
        try:
            from rosidl_runtime_py.utilities import get_message
        except ImportError as exc:
            raise ConfigError(
                f"MsgFactory.rclpy(): rosidl_runtime_py is not available ({exc}); "
                "source a ROS 2 Jazzy installation"
            ) from None

        def lookup(typename: str) -> type:
            try:
                return get_message(typename)
            except (ValueError, AttributeError, ImportError) as exc:
                raise MessageError(f"unknown message type {typename!r}: {exc}") from None

        def f64_fixed(values):
            return np.array(values, dtype=np.float64).reshape(-1)

        def f64_seq(values):
            return array.array("d", _float_list(np.asarray(values, dtype=float).reshape(-1)))

        return cls("rclpy", lookup, f64_seq, f64_fixed, lambda v: bytes([int(v)]))

    def get(self, typename: str) -> type:
        cls = self._cache.get(typename)
        if cls is None:
            cls = self.lookup(typename)
            self._cache[typename] = cls
        return cls

    def __call__(self, typename: str, **fields):
        return self.get(typename)(**fields)


# ------------------------------------------------------------------------ helpers
def _finite(values, n: int | None, what: str) -> np.ndarray:
    try:
        a = np.asarray(values, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise MessageError(f"{what}: not numeric: {values!r}") from None
    if n is not None and a.size != n:
        raise MessageError(f"{what}: expected {n} values, got {a.size}")
    bad = ~np.isfinite(a)
    if bad.any():
        raise MessageError(f"{what}: non-finite value(s) at index {np.flatnonzero(bad).tolist()}")
    return a


def _xyz(v) -> np.ndarray:
    return np.array([v.x, v.y, v.z], dtype=float)


def _vector3(f: MsgFactory, v):
    return f("geometry_msgs/msg/Vector3", x=float(v[0]), y=float(v[1]), z=float(v[2]))


def _point(f: MsgFactory, v):
    return f("geometry_msgs/msg/Point", x=float(v[0]), y=float(v[1]), z=float(v[2]))


def _quaternion(f: MsgFactory, q_xyzw):
    return f(
        "geometry_msgs/msg/Quaternion",
        x=float(q_xyzw[0]),
        y=float(q_xyzw[1]),
        z=float(q_xyzw[2]),
        w=float(q_xyzw[3]),
    )


def _covariance(f: MsgFactory, cov, n: int, what: str):
    if cov is None:
        return f.float_array(np.zeros(n * n))
    c = np.asarray(cov, dtype=float)
    if c.size != n * n:
        raise MessageError(f"{what}: expected {n}x{n} = {n * n} values, got {c.size}")
    return f.float_array(c.reshape(-1))


def _check_frame(actual: str, expected: str | None, what: str) -> None:
    if expected is not None and actual != expected:
        raise MessageError(f"{what}: expected frame_id {expected!r}, got {actual!r}")


# -------------------------------------------------------------------------- stamps
def time_msg(f: MsgFactory, stamp_ns: int):
    """``builtin_interfaces/Time`` of integer nanoseconds (``nanosec`` in [0, 1e9))."""
    if isinstance(stamp_ns, float):
        if not math.isfinite(stamp_ns):
            raise MessageError(f"stamp: non-finite time {stamp_ns!r}")
        stamp_ns = round(stamp_ns)
    ns = int(stamp_ns)
    sec, nanosec = divmod(ns, 1_000_000_000)
    if not _INT32[0] <= sec <= _INT32[1]:
        raise MessageError(f"stamp: {ns} ns does not fit builtin_interfaces/Time (int32 seconds)")
    return f("builtin_interfaces/msg/Time", sec=int(sec), nanosec=int(nanosec))


def stamp_ns_from_time(t) -> int:
    """Integer nanoseconds of a ``builtin_interfaces/Time``."""
    sec, nanosec = int(t.sec), int(t.nanosec)
    if not 0 <= nanosec < 1_000_000_000:
        raise MessageError(f"stamp: nanosec {nanosec} outside [0, 1e9)")
    return sec * 1_000_000_000 + nanosec


def stamp_ns_of(msg) -> int:
    """Integer nanoseconds of ``msg.header.stamp``."""
    return stamp_ns_from_time(msg.header.stamp)


def header_msg(f: MsgFactory, stamp_ns: int, frame_id: str = ""):
    return f("std_msgs/msg/Header", stamp=time_msg(f, stamp_ns), frame_id=str(frame_id))


# --------------------------------------------------------------------------- state
@dataclass(frozen=True)
class StateSample:
    """Vehicle state in core frames: NED position (m), Euler ``[phi, theta, psi]`` (rad,
    seed 0 Eq. 1), FRD body velocity ``[u, v, w]`` (m/s), FRD body rates ``[p, q, r]``."""

    t: float
    pos_ned: np.ndarray
    euler: np.ndarray
    v_body: np.ndarray
    omega: np.ndarray
    stamp_ns: int = 0


def odometry_from_state(
    f: MsgFactory,
    stamp_ns: int,
    pos_ned,
    euler,
    v_body,
    omega,
    *,
    frame_id: str = ODOM_FRAME,
    child_frame_id: str = BASE_FRAME,
    pose_covariance=None,
    twist_covariance=None,
):
    """``nav_msgs/Odometry`` for the ``state`` topic from NED/FRD core quantities."""
    pos = frames.ned_to_enu(_finite(pos_ned, 3, "state.pos_ned"))
    q = frames.ros_orientation_from_euler(_finite(euler, 3, "state.euler"))
    v = frames.frd_to_flu(_finite(v_body, 3, "state.v_body"))
    w = frames.frd_to_flu(_finite(omega, 3, "state.omega"))
    pose = f("geometry_msgs/msg/Pose", position=_point(f, pos), orientation=_quaternion(f, q))
    twist = f("geometry_msgs/msg/Twist", linear=_vector3(f, v), angular=_vector3(f, w))
    return f(
        "nav_msgs/msg/Odometry",
        header=header_msg(f, stamp_ns, frame_id),
        child_frame_id=str(child_frame_id),
        pose=f(
            "geometry_msgs/msg/PoseWithCovariance",
            pose=pose,
            covariance=_covariance(f, pose_covariance, 6, "state.pose.covariance"),
        ),
        twist=f(
            "geometry_msgs/msg/TwistWithCovariance",
            twist=twist,
            covariance=_covariance(f, twist_covariance, 6, "state.twist.covariance"),
        ),
    )


def state_from_odometry(
    msg, *, frame_id: str | None = ODOM_FRAME, child_frame_id: str | None = BASE_FRAME
) -> StateSample:
    """Core state from a ``nav_msgs/Odometry`` (``None`` skips a frame check)."""
    _check_frame(msg.header.frame_id, frame_id, "state.header")
    _check_frame(msg.child_frame_id, child_frame_id, "state.child_frame_id")
    p, tw = msg.pose.pose, msg.twist.twist
    pp, o, tl, ta = p.position, p.orientation, tw.linear, tw.angular
    vals = (pp.x, pp.y, pp.z, o.x, o.y, o.z, o.w, tl.x, tl.y, tl.z, ta.x, ta.y, ta.z)
    try:
        f = [float(c) for c in vals]
    except (TypeError, ValueError):
        f = None
    if (
        f is not None
        and all(map(math.isfinite, f))
        and abs(math.sqrt(f[3] * f[3] + f[4] * f[4] + f[5] * f[5] + f[6] * f[6]) - 1.0) <= 1e-3
    ):
        # fast path (the controller's state rate): plain floats through io.frames
        pos_ned, euler, v_frd, w_frd = frames.odometry_ned_frd_from_ros_scalar(
            f[0:3], f[3:7], f[7:10], f[10:13]
        )
        ns = stamp_ns_of(msg)
        return StateSample(
            t=ns / 1e9,
            pos_ned=np.array(pos_ned),
            euler=np.array(euler),
            v_body=np.array(v_frd),
            omega=np.array(w_frd),
            stamp_ns=ns,
        )
    # validating path: names the offending field
    pos = _finite(_xyz(p.position), 3, "state.pose.pose.position")
    o = p.orientation
    q = _finite([o.x, o.y, o.z, o.w], 4, "state.pose.pose.orientation")
    if abs(np.linalg.norm(q) - 1.0) > 1e-3:
        raise MessageError(
            f"state.pose.pose.orientation: not a unit quaternion (norm {np.linalg.norm(q):.6g})"
        )
    v = _finite(_xyz(tw.linear), 3, "state.twist.twist.linear")
    w = _finite(_xyz(tw.angular), 3, "state.twist.twist.angular")
    ns = stamp_ns_of(msg)
    return StateSample(
        t=ns / 1e9,
        pos_ned=frames.enu_to_ned(pos),
        euler=frames.euler_from_ros_orientation(q),
        v_body=frames.flu_to_frd(v),
        omega=frames.flu_to_frd(w),
        stamp_ns=ns,
    )


@dataclass(frozen=True)
class StateArrays:
    """A time series of :class:`StateSample` as arrays: ``t`` (N,) s, ``stamp_ns`` (N,)
    int64, ``pos_ned``, ``euler``, ``v_body``, ``omega`` (N, 3)."""

    t: np.ndarray
    stamp_ns: np.ndarray
    pos_ned: np.ndarray
    euler: np.ndarray
    v_body: np.ndarray
    omega: np.ndarray


def states_from_odometry(
    msgs: Sequence, *, frame_id: str | None = ODOM_FRAME, child_frame_id: str | None = BASE_FRAME
) -> StateArrays:
    """Vectorised :func:`state_from_odometry` for a list of messages (bag replay): the
    fields are gathered in one pass and converted with array operations. Errors name the
    index of the offending message."""
    n = len(msgs)
    ns = np.empty(n, dtype=np.int64)
    raw = np.empty((n, 13))
    for i, msg in enumerate(msgs):
        if frame_id is not None and msg.header.frame_id != frame_id:
            raise MessageError(
                f"state[{i}].header: expected frame_id {frame_id!r}, got {msg.header.frame_id!r}",
                row=i,
            )
        if child_frame_id is not None and msg.child_frame_id != child_frame_id:
            raise MessageError(
                f"state[{i}].child_frame_id: expected frame_id {child_frame_id!r}, "
                f"got {msg.child_frame_id!r}",
                row=i,
            )
        p, o = msg.pose.pose.position, msg.pose.pose.orientation
        lin, ang = msg.twist.twist.linear, msg.twist.twist.angular
        raw[i] = (p.x, p.y, p.z, o.x, o.y, o.z, o.w, lin.x, lin.y, lin.z, ang.x, ang.y, ang.z)
        ns[i] = stamp_ns_from_time(msg.header.stamp)
    return _state_arrays(ns, raw)


#: Odometry leaves in the order of the (N, 13) array :func:`_state_arrays` converts
_ODOM_LEAVES = (
    "pose.pose.position.x",
    "pose.pose.position.y",
    "pose.pose.position.z",
    "pose.pose.orientation.x",
    "pose.pose.orientation.y",
    "pose.pose.orientation.z",
    "pose.pose.orientation.w",
    "twist.twist.linear.x",
    "twist.twist.linear.y",
    "twist.twist.linear.z",
    "twist.twist.angular.x",
    "twist.twist.angular.y",
    "twist.twist.angular.z",
)


def _state_arrays(ns: np.ndarray, raw: np.ndarray) -> StateArrays:
    """:class:`StateArrays` of stamps ``ns`` and the (N, 13) Odometry values
    ``raw`` (:data:`_ODOM_LEAVES`), checked finite and unit-quaternion row by row
    (:class:`MessageError` naming the first bad row, ``row`` set)."""
    bad = ~np.isfinite(raw)
    if np.any(bad):
        i, j = (int(k) for k in np.argwhere(bad)[0])
        where = _ODOM_LEAVES[j].rsplit(".", 1)[0]
        raise MessageError(f"state[{i}].{where}: non-finite value", row=i)
    norm = np.linalg.norm(raw[:, 3:7], axis=1)
    off = np.abs(norm - 1.0) > 1e-3
    if np.any(off):
        i = int(np.argmax(off))
        raise MessageError(
            f"state[{i}].pose.pose.orientation: not a unit quaternion (norm {norm[i]:.6g})",
            row=i,
        )
    return StateArrays(
        t=ns / 1e9,
        stamp_ns=ns,
        pos_ned=frames.enu_to_ned(raw[:, 0:3]),
        euler=frames.euler_from_ros_orientation(raw[:, 3:7]),
        v_body=frames.flu_to_frd(raw[:, 7:10]),
        omega=frames.flu_to_frd(raw[:, 10:13]),
    )


# --------------------------------------------------------------------- joint state
_JS_FIELDS = ("position", "velocity", "effort")


def joint_state(
    f: MsgFactory,
    stamp_ns: int,
    names: Sequence[str],
    *,
    position=None,
    velocity=None,
    effort=None,
    frame_id: str = "",
):
    """``sensor_msgs/JointState`` with named channels; unused value arrays stay empty."""
    names = [str(n) for n in names]
    if len(set(names)) != len(names):
        raise MessageError(f"joint_state.name: duplicate names in {names}")
    vals = {}
    for key, v in zip(_JS_FIELDS, (position, velocity, effort)):
        vals[key] = f.float_seq([] if v is None else _finite(v, len(names), f"joint_state.{key}"))
    return f(
        "sensor_msgs/msg/JointState", header=header_msg(f, stamp_ns, frame_id), name=names, **vals
    )


def channels_from_joint_state(msg, names: Sequence[str], field: str = "position"):
    """``(t, values)`` of the channels ``names`` (in that order) from ``msg.<field>``.

    Raises :class:`MessageError` when a name is missing, the value array does not match
    ``msg.name`` or a value is not finite.
    """
    if field not in _JS_FIELDS:
        raise MessageError(f"joint_state: field must be one of {_JS_FIELDS}, got {field!r}")
    have = list(msg.name)
    values = np.asarray(getattr(msg, field), dtype=float)
    if values.size != len(have):
        raise MessageError(
            f"joint_state.{field}: {values.size} values for {len(have)} names {have}"
        )
    index = {n: i for i, n in enumerate(have)}
    missing = [n for n in names if n not in index]
    if missing:
        raise MessageError(f"joint_state.name: missing channel(s) {missing}; message has {have}")
    out = values[[index[n] for n in names]]
    bad = [n for n, v in zip(names, out) if not np.isfinite(v)]
    if bad:
        raise MessageError(f"joint_state.{field}: non-finite value for channel(s) {bad}")
    ns = stamp_ns_of(msg)
    return ns / 1e9, out


def channels_from_joint_states(msgs: Sequence, names: Sequence[str], field: str = "position"):
    """Vectorised :func:`channels_from_joint_state`: ``(t (N,), values (N, len(names)))``."""
    n = len(msgs)
    t = np.empty(n)
    out = np.empty((n, len(names)))
    for i, msg in enumerate(msgs):
        try:
            t[i], out[i] = channels_from_joint_state(msg, names, field)
        except MessageError as exc:
            raise MessageError(f"message {i}: {exc}") from None
    return t, out


def rotor_speeds_msg(f: MsgFactory, stamp_ns: int, omega_rotors, source: str = "esc"):
    """``rotor_speeds``: rotor angular speeds Omega_1..4 (rad/s, PX4 numbering) in ``velocity``.

    ``source`` (:data:`ROTOR_SOURCES`) is carried in ``header.frame_id``: ``base_link`` for
    measured speeds (ESC telemetry), ``estimated`` for speeds estimated from the motor
    outputs; names and values are the same for both, so every consumer reads either.
    """
    if source not in ROTOR_SOURCES:
        raise MessageError(f"rotor_speeds: source must be one of {ROTOR_SOURCES}, got {source!r}")
    frame = ROTOR_ESTIMATED_FRAME if source == "estimated" else BASE_FRAME
    return joint_state(f, stamp_ns, ROTOR_NAMES, velocity=omega_rotors, frame_id=frame)


def rotor_speeds_from_joint_state(msg):
    """``(t, Omega(4))`` from a ``rotor_speeds`` JointState (either source)."""
    return channels_from_joint_state(msg, ROTOR_NAMES, field="velocity")


def rotor_source_of(msg) -> str:
    """``"estimated"`` when a ``rotor_speeds`` JointState carries estimated speeds, else
    ``"esc"`` (measured; any other frame_id, e.g. ``base_link`` of older recordings)."""
    return "estimated" if msg.header.frame_id == ROTOR_ESTIMATED_FRAME else "esc"


def excitation_msg(f: MsgFactory, stamp_ns: int, u_e):
    """``excitation``: normalised excitation ``u_e`` (4) in ``position``."""
    return joint_state(f, stamp_ns, EXCITATION_NAMES, position=u_e)


def excitation_from_joint_state(msg):
    return channels_from_joint_state(msg, EXCITATION_NAMES, field="position")


def actuator_command_msg(f: MsgFactory, stamp_ns: int, u):
    """``actuator_command``: virtual command ``u = [ut, ua, ue, ur]`` (seed 0 Eq. 7) in
    ``position``."""
    return joint_state(f, stamp_ns, INPUT_NAMES, position=u)


def actuator_command_from_joint_state(msg):
    return channels_from_joint_state(msg, INPUT_NAMES, field="position")


# ----------------------------------------------------------------------------- imu
@dataclass(frozen=True)
class ImuSample:
    """IMU in core frames: FRD specific force (m/s^2), FRD rates (rad/s) and, when the
    message carries an orientation, NED/FRD Euler angles (else ``None``)."""

    t: float
    specific_force: np.ndarray
    omega: np.ndarray
    euler: np.ndarray | None
    stamp_ns: int = 0


def imu_msg(
    f: MsgFactory,
    stamp_ns: int,
    specific_force_frd,
    omega_frd,
    euler=None,
    *,
    frame_id: str = BASE_FRAME,
):
    """``sensor_msgs/Imu`` (FLU). Without ``euler`` the orientation is marked unknown
    (``orientation_covariance[0] = -1``, as sensor_msgs/Imu documents)."""
    a = frames.frd_to_flu(_finite(specific_force_frd, 3, "imu.specific_force"))
    w = frames.frd_to_flu(_finite(omega_frd, 3, "imu.omega"))
    ocov = np.zeros(9)
    if euler is None:
        q = np.array([0.0, 0.0, 0.0, 1.0])
        ocov[0] = -1.0
    else:
        q = frames.ros_orientation_from_euler(_finite(euler, 3, "imu.euler"))
    return f(
        "sensor_msgs/msg/Imu",
        header=header_msg(f, stamp_ns, frame_id),
        orientation=_quaternion(f, q),
        orientation_covariance=f.float_array(ocov),
        angular_velocity=_vector3(f, w),
        angular_velocity_covariance=f.float_array(np.zeros(9)),
        linear_acceleration=_vector3(f, a),
        linear_acceleration_covariance=f.float_array(np.zeros(9)),
    )


def imu_from_msg(msg, *, frame_id: str | None = BASE_FRAME) -> ImuSample:
    _check_frame(msg.header.frame_id, frame_id, "imu.header")
    a = _finite(_xyz(msg.linear_acceleration), 3, "imu.linear_acceleration")
    w = _finite(_xyz(msg.angular_velocity), 3, "imu.angular_velocity")
    euler = None
    if float(np.asarray(msg.orientation_covariance, dtype=float)[0]) != -1.0:
        o = msg.orientation
        euler = frames.euler_from_ros_orientation(
            _finite([o.x, o.y, o.z, o.w], 4, "imu.orientation")
        )
    ns = stamp_ns_of(msg)
    return ImuSample(
        t=ns / 1e9,
        specific_force=frames.flu_to_frd(a),
        omega=frames.flu_to_frd(w),
        euler=euler,
        stamp_ns=ns,
    )


# --------------------------------------------------------------- velocity reference
def twist_reference_msg(
    f: MsgFactory, stamp_ns: int, v_d_frd, r_d_frd: float = 0.0, *, frame_id: str = BASE_FRAME
):
    """``geometry_msgs/TwistStamped``: body velocity reference (FLU) and yaw-rate reference
    in ``angular.z`` (FLU, i.e. ``-r_d``)."""
    v = frames.frd_to_flu(_finite(v_d_frd, 3, "velocity_reference.v_d"))
    r = _finite([r_d_frd], 1, "velocity_reference.r_d")[0]
    w = frames.frd_to_flu([0.0, 0.0, r])
    twist = f("geometry_msgs/msg/Twist", linear=_vector3(f, v), angular=_vector3(f, w))
    return f(
        "geometry_msgs/msg/TwistStamped", header=header_msg(f, stamp_ns, frame_id), twist=twist
    )


def enu_velocity_setpoint_msg(
    f: MsgFactory, stamp_ns: int, v_enu, yaw_rate_enu: float, frame_id: str
):
    """``geometry_msgs/TwistStamped`` already in a local ENU frame (MAVROS
    ``setpoint_velocity/cmd_vel``): linear = ENU velocity, angular = (0, 0, ENU yaw rate).
    The NED/FRD -> ENU conversion happens before, through :mod:`lpv_sysid.io.frames`."""
    v = _finite(v_enu, 3, "v_enu")
    r = _finite([yaw_rate_enu], 1, "yaw_rate_enu")[0]
    return f(
        "geometry_msgs/msg/TwistStamped",
        header=header_msg(f, stamp_ns, frame_id),
        twist=f(
            "geometry_msgs/msg/Twist", linear=_vector3(f, v), angular=_vector3(f, [0.0, 0.0, r])
        ),
    )


def reference_from_twist(msg, *, frame_id: str | None = BASE_FRAME):
    """``(t, v_d_frd(3), r_d_frd)`` from a ``velocity_reference`` TwistStamped."""
    _check_frame(msg.header.frame_id, frame_id, "velocity_reference.header")
    v = _finite(_xyz(msg.twist.linear), 3, "velocity_reference.twist.linear")
    w = _finite(_xyz(msg.twist.angular), 3, "velocity_reference.twist.angular")
    ns = stamp_ns_of(msg)
    return ns / 1e9, frames.flu_to_frd(v), float(frames.flu_to_frd(w)[2])


# --------------------------------------------------------------------------- status
@dataclass(frozen=True)
class StatusSample:
    level: int
    name: str
    message: str
    values: dict
    hardware_id: str = ""


def _level(level) -> int:
    if isinstance(level, str):
        try:
            return DIAGNOSTIC_LEVELS[level.upper()]
        except KeyError:
            raise MessageError(
                f"status.level: unknown level {level!r}; expected one of {list(DIAGNOSTIC_LEVELS)}"
            ) from None
    if isinstance(level, (bytes, bytearray)):
        if len(level) != 1:
            raise MessageError(f"status.level: expected one byte, got {level!r}")
        level = level[0]
    lv = int(level)
    if lv not in DIAGNOSTIC_LEVELS.values():
        raise MessageError(f"status.level: {lv} is not one of OK=0, WARN=1, ERROR=2, STALE=3")
    return lv


def _value_text(v) -> str:
    if isinstance(v, bool) or v is None:
        return str(v).lower() if isinstance(v, bool) else ""
    if isinstance(v, (float, np.floating)):
        return repr(float(v))  # shortest round-trip representation
    return str(v)


def diagnostic_status(
    f: MsgFactory,
    level,
    name: str,
    message: str = "",
    values: Mapping[str, Any] | None = None,
    hardware_id: str = "",
):
    """``diagnostic_msgs/DiagnosticStatus`` from a level (0-3 or ``"OK"``/``"WARN"``/
    ``"ERROR"``/``"STALE"``), name, message and a dict of values (stored as text;
    floats with ``repr`` so they parse back exactly)."""
    kvs = [
        f("diagnostic_msgs/msg/KeyValue", key=str(k), value=_value_text(v))
        for k, v in (values or {}).items()
    ]
    return f(
        "diagnostic_msgs/msg/DiagnosticStatus",
        level=f.byte(_level(level)),
        name=str(name),
        message=str(message),
        hardware_id=str(hardware_id),
        values=kvs,
    )


def diagnostic_array(f: MsgFactory, stamp_ns: int, statuses: Sequence):
    return f(
        "diagnostic_msgs/msg/DiagnosticArray",
        header=header_msg(f, stamp_ns, ""),
        status=list(statuses),
    )


def status_from_diagnostic_array(msg):
    """``(t, [StatusSample, ...])``; values come back as the strings that were sent."""
    out = []
    for i, s in enumerate(msg.status):
        try:
            lv = _level(s.level)
        except MessageError as exc:
            raise MessageError(f"status.status[{i}]: {exc}") from None
        out.append(
            StatusSample(
                level=lv,
                name=s.name,
                message=s.message,
                values={kv.key: kv.value for kv in s.values},
                hardware_id=s.hardware_id,
            )
        )
    ns = stamp_ns_of(msg)
    return ns / 1e9, out
