"""Message classes for the rclpy stand-in, built from the rosbags Jazzy typestore.

Real rclpy message classes (rosidl_generator_py) differ from rosbags dataclasses in ways
the node shells can trip over, so the stand-in reproduces the rclpy behaviour:

- every field has a default (``Odometry()`` works); the constructor takes keyword
  arguments only and rejects unknown names (``AssertionError`` as in rclpy);
- field assignment is type checked as in the generated setters: ``float`` fields refuse
  ``int``, integer fields check their range, ``byte`` fields hold ``bytes`` of length 1,
  unbounded numeric sequences accept ``array.array`` or a Python sequence (not a numpy
  array) and are stored as ``array.array``; fixed-size numeric arrays are numpy arrays;
  nested fields must be instances of the stand-in class of that type;
- constants are class attributes (``DiagnosticStatus.ERROR == b'\\x02'``).

``to_rosbags`` / ``from_rosbags`` convert to and from the rosbags classes, which is how
``rclpy.serialization`` produces CDR bytes identical to rosbags' own.
"""

from __future__ import annotations

import array
import collections.abc
import sys
from collections import UserList, UserString
from types import ModuleType

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

BASE, NAME, ARRAY, SEQUENCE = 1, 2, 3, 4

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
# std_srvs is not part of the rosbags store; its definitions (Jazzy std_srvs) are added.
_EXTRA = {
    "std_srvs/srv/Trigger_Request": "uint8 structure_needs_at_least_one_member\n",
    "std_srvs/srv/Trigger_Response": "bool success\nstring message\n",
    "std_srvs/srv/Empty_Request": "uint8 structure_needs_at_least_one_member\n",
    "std_srvs/srv/Empty_Response": "uint8 structure_needs_at_least_one_member\n",
    "std_srvs/srv/SetBool_Request": "bool data\n",
    "std_srvs/srv/SetBool_Response": "bool success\nstring message\n",
}
# mavros_msgs (MAVROS 2.10, ROS 2) as far as the MAVROS transport uses it, and the
# geographic_msgs type its HomePosition needs; registered in dependency order.
_EXTRA.update(
    {
        "geographic_msgs/msg/GeoPoint": "float64 latitude\nfloat64 longitude\nfloat64 altitude\n",
        "mavros_msgs/msg/State": "std_msgs/Header header\nbool connected\nbool armed\n"
        "bool guided\nbool manual_input\nstring mode\nuint8 system_status\n",
        "mavros_msgs/msg/PositionTarget": "std_msgs/Header header\nuint8 coordinate_frame\n"
        "uint8 FRAME_LOCAL_NED = 1\nuint8 FRAME_LOCAL_OFFSET_NED = 7\n"
        "uint8 FRAME_BODY_NED = 8\nuint8 FRAME_BODY_OFFSET_NED = 9\nuint16 type_mask\n"
        "uint16 IGNORE_PX = 1\nuint16 IGNORE_PY = 2\nuint16 IGNORE_PZ = 4\n"
        "uint16 IGNORE_VX = 8\nuint16 IGNORE_VY = 16\nuint16 IGNORE_VZ = 32\n"
        "uint16 IGNORE_AFX = 64\nuint16 IGNORE_AFY = 128\nuint16 IGNORE_AFZ = 256\n"
        "uint16 FORCE = 512\nuint16 IGNORE_YAW = 1024\nuint16 IGNORE_YAW_RATE = 2048\n"
        "geometry_msgs/Point position\ngeometry_msgs/Vector3 velocity\n"
        "geometry_msgs/Vector3 acceleration_or_force\nfloat32 yaw\nfloat32 yaw_rate\n",
        "mavros_msgs/msg/AttitudeTarget": "std_msgs/Header header\nuint8 type_mask\n"
        "uint8 IGNORE_ROLL_RATE = 1\nuint8 IGNORE_PITCH_RATE = 2\nuint8 IGNORE_YAW_RATE = 4\n"
        "uint8 IGNORE_THRUST = 64\nuint8 IGNORE_ATTITUDE = 128\n"
        "geometry_msgs/Quaternion orientation\ngeometry_msgs/Vector3 body_rate\n"
        "float32 thrust\n",
        "mavros_msgs/msg/ESCStatusItem": "std_msgs/Header header\nint32 rpm\n"
        "float32 voltage\nfloat32 current\n",
        "mavros_msgs/msg/ESCStatus": "std_msgs/Header header\n"
        "mavros_msgs/ESCStatusItem[] esc_status\n",
        "mavros_msgs/msg/RCOut": "std_msgs/Header header\nuint16[] channels\n",
        "mavros_msgs/msg/HomePosition": "std_msgs/Header header\n"
        "geographic_msgs/GeoPoint geo\ngeometry_msgs/Point position\n"
        "geometry_msgs/Quaternion orientation\ngeometry_msgs/Vector3 approach\n",
        # the preflight's health evidence (MAVROS 2.10 gps_status / sys_status plugins)
        "mavros_msgs/msg/GPSRAW": "std_msgs/Header header\n"
        "uint8 GPS_FIX_TYPE_NO_GPS = 0\nuint8 GPS_FIX_TYPE_NO_FIX = 1\n"
        "uint8 GPS_FIX_TYPE_2D_FIX = 2\nuint8 GPS_FIX_TYPE_3D_FIX = 3\n"
        "uint8 GPS_FIX_TYPE_DGPS = 4\nuint8 GPS_FIX_TYPE_RTK_FLOAT = 5\n"
        "uint8 GPS_FIX_TYPE_RTK_FIXED = 6\nuint8 GPS_FIX_TYPE_STATIC = 7\n"
        "uint8 GPS_FIX_TYPE_PPP = 8\nuint8 fix_type\nint32 lat\nint32 lon\nint32 alt\n"
        "uint16 eph\nuint16 epv\nuint16 vel\nuint16 cog\nuint8 satellites_visible\n"
        "int32 alt_ellipsoid\nuint32 h_acc\nuint32 v_acc\nuint32 vel_acc\nint32 hdg_acc\n"
        "uint16 yaw\nuint8 dgps_numch\nuint32 dgps_age\n",
        "mavros_msgs/msg/EstimatorStatus": "std_msgs/Header header\n"
        "bool attitude_status_flag\nbool velocity_horiz_status_flag\n"
        "bool velocity_vert_status_flag\nbool pos_horiz_rel_status_flag\n"
        "bool pos_horiz_abs_status_flag\nbool pos_vert_abs_status_flag\n"
        "bool pos_vert_agl_status_flag\nbool const_pos_mode_status_flag\n"
        "bool pred_pos_horiz_rel_status_flag\nbool pred_pos_horiz_abs_status_flag\n"
        "bool gps_glitch_status_flag\nbool accel_error_status_flag\n",
        "mavros_msgs/srv/SetMode_Request": "uint8 base_mode\nstring custom_mode\n",
        "mavros_msgs/srv/SetMode_Response": "bool mode_sent\n",
        "mavros_msgs/srv/CommandBool_Request": "bool value\n",
        "mavros_msgs/srv/CommandBool_Response": "bool success\nuint8 result\n",
        "mavros_msgs/srv/CommandLong_Request": "bool broadcast\nuint16 command\n"
        "uint8 confirmation\nfloat32 param1\nfloat32 param2\nfloat32 param3\n"
        "float32 param4\nfloat32 param5\nfloat32 param6\nfloat32 param7\n",
        "mavros_msgs/srv/CommandLong_Response": "bool success\nuint8 result\n",
        "mavros_msgs/msg/RCIn": "std_msgs/Header header\nuint8 rssi\nuint16[] channels\n",
        "mavros_msgs/msg/VehicleInfo": "std_msgs/Header header\n"
        "uint8 HAVE_INFO_HEARTBEAT = 1\nuint8 HAVE_INFO_AUTOPILOT_VERSION = 2\n"
        "uint8 available_info\nuint8 sysid\nuint8 compid\nuint8 autopilot\nuint8 type\n"
        "uint8 system_status\nuint8 base_mode\nuint32 custom_mode\nstring mode\n"
        "uint32 mode_id\nuint64 capabilities\nuint32 flight_sw_version\n"
        "uint32 middleware_sw_version\nuint32 os_sw_version\nuint32 board_version\n"
        "string flight_custom_version\nuint16 vendor_id\nuint16 product_id\nuint64 uid\n",
        "mavros_msgs/srv/VehicleInfoGet_Request": "uint8 GET_MY_SYSID = 0\n"
        "uint8 GET_MY_COMPID = 0\nuint8 sysid\nuint8 compid\nbool get_all\n",
        "mavros_msgs/srv/VehicleInfoGet_Response": "bool success\n"
        "mavros_msgs/VehicleInfo[] vehicles\n",
        "mavros_msgs/srv/MessageInterval_Request": "uint32 message_id\nfloat32 message_rate\n",
        "mavros_msgs/srv/MessageInterval_Response": "bool success\n",
        "mavros_msgs/msg/ParamEvent": "std_msgs/Header header\nstring param_id\n"
        "rcl_interfaces/ParameterValue value\nuint16 param_index\nuint16 param_count\n",
        "mavros_msgs/srv/ParamPull_Request": "bool force_pull\n",
        "mavros_msgs/srv/ParamPull_Response": "bool success\nuint32 param_received\n",
        # rcl_interfaces' services are not in the rosbags store either
        "rcl_interfaces/srv/GetParameters_Request": "string[] names\n",
        "rcl_interfaces/srv/ListParameters_Request": "string[] prefixes\nuint64 depth\n",
        "rcl_interfaces/srv/ListParameters_Response": (
            "rcl_interfaces/ListParametersResult result\n"
        ),
        "rcl_interfaces/srv/GetParameters_Response": "rcl_interfaces/ParameterValue[] values\n",
    }
)
for _name, _text in _EXTRA.items():
    # rosbags files a .srv part under pkg/srv/msg/Name; register it under pkg/srv/Name.
    TYPESTORE.register({_name: v for v in get_types_from_msg(_text, _name).values()})

_TYPECODE = {
    "float32": "f",
    "float64": "d",
    "int8": "b",
    "uint8": "B",
    "int16": "h",
    "uint16": "H",
    "int32": "i",
    "uint32": "I",
    "int64": "q",
    "uint64": "Q",
}
_DTYPE = {
    k: np.dtype(v)
    for k, v in {
        "float32": "f4",
        "float64": "f8",
        "int8": "i1",
        "uint8": "u1",
        "int16": "i2",
        "uint16": "u2",
        "int32": "i4",
        "uint32": "u4",
        "int64": "i8",
        "uint64": "u8",
    }.items()
}
_INT_RANGE = {
    "int8": (-(2**7), 2**7 - 1),
    "uint8": (0, 2**8 - 1),
    "int16": (-(2**15), 2**15 - 1),
    "uint16": (0, 2**16 - 1),
    "int32": (-(2**31), 2**31 - 1),
    "uint32": (0, 2**32 - 1),
    "int64": (-(2**63), 2**63 - 1),
    "uint64": (0, 2**64 - 1),
}
_FLOAT_MAX = {"float32": 3.4028234663852886e38, "float64": 1.7976931348623157e308}

_CLASSES: dict[str, type] = {}


def _is_sequence(value) -> bool:
    return isinstance(
        value, (collections.abc.Sequence, collections.abc.Set, UserList)
    ) and not isinstance(value, (str, UserString, bytes))


def _check_base(tname: str, value, field: str):
    """Return the stored value for a base-type field or raise AssertionError like rclpy."""
    if tname in ("float32", "float64"):
        assert isinstance(value, float), f"The '{field}' field must be of type 'float'"
        m = _FLOAT_MAX[tname]
        assert not (value < -m or value > m) or np.isinf(value), (
            f"The '{field}' field must be a {tname.replace('float', 'float ')}"
        )
        return value
    if tname in _INT_RANGE:
        assert isinstance(value, int), f"The '{field}' field must be of type 'int'"
        lo, hi = _INT_RANGE[tname]
        assert lo <= value <= hi, f"The '{field}' field must be an integer in [{lo}, {hi}]"
        return value
    if tname == "bool":
        assert isinstance(value, bool), f"The '{field}' field must be of type 'bool'"
        return value
    if tname == "byte":
        assert isinstance(value, (bytes, bytearray)) and len(value) == 1, (
            f"The '{field}' field must be of type 'bytes' or 'ByteString' with length 1"
        )
        return bytes(value)
    if tname == "char":
        assert isinstance(value, str) and len(value) == 1, (
            f"The '{field}' field must be of type 'str' with length 1"
        )
        return value
    if tname == "string":
        assert isinstance(value, str), f"The '{field}' field must be of type 'str'"
        return value
    raise AssertionError(f"unsupported base type {tname} for field '{field}'")


def _default_base(tname: str):
    if tname in ("float32", "float64"):
        return 0.0
    if tname in _INT_RANGE:
        return 0
    return {"bool": False, "byte": b"\x00", "char": "\x00", "string": ""}[tname]


def _element(desc):
    """(kind, tname) of an element descriptor."""
    kind, detail = desc
    return kind, (detail[0] if kind == BASE else detail)


def _default(desc):
    kind, detail = desc
    if kind == BASE:
        return _default_base(detail[0])
    if kind == NAME:
        return get_class(detail)()
    (ekind, edetail), size = detail
    etname = edetail[0] if ekind == BASE else edetail
    if kind == ARRAY:
        if ekind == BASE and etname in _DTYPE:
            return np.zeros(size, dtype=_DTYPE[etname])
        return [_default((ekind, edetail)) for _ in range(size)]
    if ekind == BASE and etname in _TYPECODE:
        return array.array(_TYPECODE[etname])
    return []


def _check(desc, value, field: str):
    kind, detail = desc
    if kind == BASE:
        return _check_base(detail[0], value, field)
    if kind == NAME:
        cls = get_class(detail)
        assert isinstance(value, cls), (
            f"The '{field}' field must be a sub message of type '{cls.__name__}'"
        )
        return value
    (ekind, edetail), size = detail
    etname = edetail[0] if ekind == BASE else edetail
    numeric = ekind == BASE and etname in _TYPECODE
    if kind == ARRAY:
        if numeric and isinstance(value, np.ndarray):
            assert value.dtype == _DTYPE[etname], (
                f"The '{field}' numpy.ndarray() must have the dtype of '{_DTYPE[etname]}'"
            )
            assert value.size == size, f"The '{field}' numpy.ndarray() must have a size of {size}"
            return value
        assert _is_sequence(value) and len(value) == size, (
            f"The '{field}' field must be a set or sequence with length {size}"
        )
        items = [_check((ekind, edetail), v, field) for v in value]
        return np.array(items, dtype=_DTYPE[etname]) if numeric else items
    # SEQUENCE (size 0: unbounded, else upper bound)
    if numeric and isinstance(value, array.array):
        assert value.typecode == _TYPECODE[etname], (
            f"The '{field}' array.array() must have the type code of '{_TYPECODE[etname]}'"
        )
        stored = value
    else:
        assert _is_sequence(value), (
            f"The '{field}' field must be a set or sequence and each value of type "
            f"'{etname if isinstance(etname, str) else etname}'"
        )
        items = [_check((ekind, edetail), v, field) for v in value]
        stored = array.array(_TYPECODE[etname], items) if numeric else items
    assert size == 0 or len(stored) <= size, (
        f"The '{field}' field must be a set or sequence with length <= {size}"
    )
    return stored


class _StandinMessage:
    """Mixin giving a rosbags dataclass the construction/assignment rules of rclpy."""

    _lpv_typename: str = ""
    _lpv_fields: tuple = ()

    def __init__(self, **kwargs):
        fields = dict(self._lpv_fields)
        assert all(k in fields for k in kwargs), (
            "Invalid arguments passed to constructor: %s"
            % ", ".join(sorted(k for k in kwargs if k not in fields))
        )
        for name, desc in self._lpv_fields:
            if name in kwargs:
                setattr(self, name, kwargs[name])
            else:
                object.__setattr__(self, name, _default(desc))

    def __setattr__(self, name, value):
        fields = dict(self._lpv_fields)
        if name not in fields:
            raise AttributeError(f"'{type(self).__name__}' object has no attribute '{name}'")
        object.__setattr__(self, name, _check(fields[name], value, name))

    def __eq__(self, other):
        if type(other) is not type(self):
            return False
        for name, _ in self._lpv_fields:
            a, b = getattr(self, name), getattr(other, name)
            if isinstance(a, (np.ndarray, array.array)):
                if not np.array_equal(np.asarray(a), np.asarray(b)):
                    return False
            elif a != b:
                return False
        return True

    __hash__ = None

    def __repr__(self):
        args = ", ".join(f"{n}={getattr(self, n)!r}" for n, _ in self._lpv_fields)
        return f"{self._lpv_typename.replace('/', '.')}({args})"

    @classmethod
    def get_fields_and_field_types(cls) -> dict[str, str]:
        out = {}
        for name, (kind, detail) in cls._lpv_fields:
            if kind == BASE:
                out[name] = detail[0]
            elif kind == NAME:
                out[name] = detail.replace("/msg/", "/")
            else:
                (ek, ed), size = detail
                et = ed[0] if ek == BASE else ed.replace("/msg/", "/")
                out[name] = (
                    f"{et}[{size}]"
                    if kind == ARRAY
                    else f"sequence<{et}{', %d' % size if size else ''}>"
                )
        return out


def get_class(typename: str) -> type:
    """Stand-in class for ``pkg/msg/Name`` (or ``pkg/srv/Name_Request``)."""
    if typename in _CLASSES:
        return _CLASSES[typename]
    if typename not in TYPESTORE.fielddefs:
        raise LookupError(f"unknown message type {typename!r}")
    consts, fields = TYPESTORE.fielddefs[typename]
    short = typename.rsplit("/", 1)[-1]
    ns = {
        "_lpv_typename": typename,
        "_lpv_fields": tuple(fields),
        "__slots__": (),
        "__module__": ".".join(typename.split("/")[:2]),
        "__qualname__": short,
    }
    for cname, ctype, cvalue in consts:
        ns[cname] = bytes([cvalue]) if ctype == "byte" else cvalue
    cls = type(short, (_StandinMessage,), ns)
    _CLASSES[typename] = cls
    return cls


def populate(module_globals: dict, package: str, kind: str = "msg") -> None:
    """Fill a ``<package>.msg`` module with every type of that package."""
    prefix = f"{package}/{kind}/"
    for typename in sorted(TYPESTORE.fielddefs):
        if typename.startswith(prefix):
            cls = get_class(typename)
            module_globals[typename[len(prefix) :]] = cls


def make_service(package: str, name: str) -> type:
    """A service class with ``Request`` and ``Response`` like rosidl_generator_py."""
    req = get_class(f"{package}/srv/{name}_Request")
    resp = get_class(f"{package}/srv/{name}_Response")
    req.__qualname__ = req.__name__ = f"{name}_Request"
    resp.__qualname__ = resp.__name__ = f"{name}_Response"
    svc = type(
        name,
        (),
        {
            "Request": req,
            "Response": resp,
            "__module__": f"{package}.srv",
            "_lpv_typename": f"{package}/srv/{name}",
        },
    )
    return svc


def to_rosbags(msg):
    """Convert a stand-in message into the equivalent rosbags dataclass instance."""
    typename = msg._lpv_typename
    cls = TYPESTORE.types[typename]
    kwargs = {}
    for name, desc in msg._lpv_fields:
        kwargs[name] = _to_rb(desc, getattr(msg, name))
    return cls(**kwargs)


def _to_rb(desc, value):
    kind, detail = desc
    if kind == BASE:
        if detail[0] == "byte":
            return value[0]
        if detail[0] == "char":
            return ord(value)
        return value
    if kind == NAME:
        return to_rosbags(value)
    (ekind, edetail), _ = detail
    etname = edetail[0] if ekind == BASE else edetail
    if ekind == BASE and etname in _DTYPE:
        return np.asarray(value, dtype=_DTYPE[etname])
    if ekind == BASE and etname == "byte":  # rosbags holds byte[] as a uint8 array
        return np.array([v[0] for v in value], dtype=np.uint8)
    if ekind == BASE and etname == "bool":  # and bool[] as a bool array
        return np.array(value, dtype=bool)
    return [_to_rb((ekind, edetail), v) for v in value]


def from_rosbags(obj, typename: str | None = None):
    """Convert a rosbags dataclass instance into the stand-in class of its type."""
    typename = typename or obj.__msgtype__
    cls = get_class(typename)
    msg = cls()
    for name, desc in cls._lpv_fields:
        setattr(msg, name, _from_rb(desc, getattr(obj, name)))
    return msg


def _from_rb(desc, value):
    kind, detail = desc
    if kind == BASE:
        t = detail[0]
        if t == "byte":
            return bytes([int(value)])
        if t == "char":
            return chr(int(value))
        if t in ("float32", "float64"):
            return float(value)
        if t in _INT_RANGE:
            return int(value)
        return value
    if kind == NAME:
        return from_rosbags(value, detail)
    (ekind, edetail), _ = detail
    etname = edetail[0] if ekind == BASE else edetail
    if ekind == BASE and etname in _DTYPE:
        arr = np.asarray(value, dtype=_DTYPE[etname])
        return arr if kind == ARRAY else array.array(_TYPECODE[etname], arr.tolist())
    if ekind == BASE and etname == "bool":
        return [bool(v) for v in value]
    return [_from_rb((ekind, edetail), v) for v in value]


def serialize(msg) -> bytes:
    return bytes(TYPESTORE.serialize_cdr(to_rosbags(msg), msg._lpv_typename))


def deserialize(data: bytes, msg_type: type):
    typename = msg_type._lpv_typename
    return from_rosbags(TYPESTORE.deserialize_cdr(bytes(data), typename), typename)


def is_message_class(obj) -> bool:
    return isinstance(obj, type) and issubclass(obj, _StandinMessage)


def is_service_class(obj) -> bool:
    return (
        isinstance(obj, type)
        and hasattr(obj, "Request")
        and hasattr(obj, "Response")
        and is_message_class(obj.Request)
    )


def module(name: str) -> ModuleType:
    return sys.modules[name]
