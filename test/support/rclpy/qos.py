"""Stand-in for ``rclpy.qos`` (Jazzy enum values, profiles and compatibility rules)."""

import enum

from rclpy.duration import Duration


class InvalidQoSProfileException(Exception):
    def __init__(self, *args):
        Exception.__init__(self, "Invalid QoSProfile", *args)


class QoSPolicyEnum(enum.IntEnum):
    @classmethod
    def short_keys(cls):
        return [k.lower() for k in cls.__members__]

    @property
    def short_key(self):
        return self.name.lower()


class HistoryPolicy(QoSPolicyEnum):
    SYSTEM_DEFAULT = 0
    KEEP_LAST = 1
    KEEP_ALL = 2
    UNKNOWN = 3


class ReliabilityPolicy(QoSPolicyEnum):
    SYSTEM_DEFAULT = 0
    RELIABLE = 1
    BEST_EFFORT = 2
    UNKNOWN = 3
    BEST_AVAILABLE = 4


class DurabilityPolicy(QoSPolicyEnum):
    SYSTEM_DEFAULT = 0
    TRANSIENT_LOCAL = 1
    VOLATILE = 2
    UNKNOWN = 3
    BEST_AVAILABLE = 4


class LivelinessPolicy(QoSPolicyEnum):
    SYSTEM_DEFAULT = 0
    AUTOMATIC = 1
    MANUAL_BY_TOPIC = 3
    UNKNOWN = 4
    BEST_AVAILABLE = 5


QoSHistoryPolicy = HistoryPolicy
QoSReliabilityPolicy = ReliabilityPolicy
QoSDurabilityPolicy = DurabilityPolicy
QoSLivelinessPolicy = LivelinessPolicy


class QoSProfile:
    """QoS settings; ``history`` and/or ``depth`` are required as in rclpy >= Galactic."""

    __slots__ = [
        "_history",
        "_depth",
        "_reliability",
        "_durability",
        "_lifespan",
        "_deadline",
        "_liveliness",
        "_liveliness_lease_duration",
        "_avoid_ros_namespace_conventions",
    ]

    def __init__(self, **kwargs):
        allowed = {s[1:] for s in self.__slots__}
        bad = set(kwargs) - allowed
        assert not bad, "Invalid arguments passed to constructor: %r" % sorted(bad)
        if "history" not in kwargs:
            if "depth" not in kwargs:
                raise InvalidQoSProfileException("History and/or depth settings are required.")
            kwargs["history"] = HistoryPolicy.KEEP_LAST
        self.history = kwargs["history"]
        if self.history == HistoryPolicy.KEEP_LAST and kwargs.get("depth", 0) == 0:
            raise InvalidQoSProfileException("History set to KEEP_LAST without a depth setting.")
        self.depth = kwargs.get("depth", 0)
        self.reliability = kwargs.get("reliability", ReliabilityPolicy.RELIABLE)
        self.durability = kwargs.get("durability", DurabilityPolicy.VOLATILE)
        self.lifespan = kwargs.get("lifespan", Duration())
        self.deadline = kwargs.get("deadline", Duration())
        self.liveliness = kwargs.get("liveliness", LivelinessPolicy.SYSTEM_DEFAULT)
        self.liveliness_lease_duration = kwargs.get("liveliness_lease_duration", Duration())
        self.avoid_ros_namespace_conventions = kwargs.get("avoid_ros_namespace_conventions", False)

    def _prop(name, enum_cls=None):  # noqa: N805 - class-body helper
        def get(self):
            return getattr(self, "_" + name)

        def set_(self, value):
            if enum_cls is not None:
                value = enum_cls(value)
            elif name == "depth":
                assert isinstance(value, int) and value >= 0, "depth must be a non-negative int"
            setattr(self, "_" + name, value)

        return property(get, set_)

    history = _prop("history", HistoryPolicy)
    depth = _prop("depth")
    reliability = _prop("reliability", ReliabilityPolicy)
    durability = _prop("durability", DurabilityPolicy)
    liveliness = _prop("liveliness", LivelinessPolicy)
    lifespan = _prop("lifespan")
    deadline = _prop("deadline")
    liveliness_lease_duration = _prop("liveliness_lease_duration")
    avoid_ros_namespace_conventions = _prop("avoid_ros_namespace_conventions")
    del _prop

    def __eq__(self, other):
        if not isinstance(other, QoSProfile):
            return False
        return all(getattr(self, s) == getattr(other, s) for s in self.__slots__)

    def __repr__(self):
        return "QoSProfile(history=%s, depth=%d, reliability=%s, durability=%s)" % (
            self.history.name,
            self.depth,
            self.reliability.name,
            self.durability.name,
        )


qos_profile_sensor_data = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=5,
    reliability=ReliabilityPolicy.BEST_EFFORT,
    durability=DurabilityPolicy.VOLATILE,
)
qos_profile_system_default = QoSProfile(
    history=HistoryPolicy.SYSTEM_DEFAULT,
    reliability=ReliabilityPolicy.SYSTEM_DEFAULT,
    durability=DurabilityPolicy.SYSTEM_DEFAULT,
)
qos_profile_services_default = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
qos_profile_parameters = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1000,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
qos_profile_parameter_events = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1000,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
qos_profile_rosout_default = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1000,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)


class QoSPresetProfiles(enum.Enum):
    SYSTEM_DEFAULT = qos_profile_system_default
    SENSOR_DATA = qos_profile_sensor_data
    SERVICES_DEFAULT = qos_profile_services_default
    PARAMETERS = qos_profile_parameters
    PARAMETER_EVENTS = qos_profile_parameter_events

    @classmethod
    def get_from_short_key(cls, name):
        return cls[name.upper()].value


class QoSCompatibility(enum.IntEnum):
    OK = 0
    WARNING = 1
    ERROR = 2


def qos_check_compatible(publisher_qos, subscription_qos):
    """(QoSCompatibility, reason) following rmw_qos_profile_check_compatible (DDS rules).

    SYSTEM_DEFAULT resolves to RELIABLE / VOLATILE (the defaults of every Jazzy rmw).
    """

    def rel(p):
        r = p.reliability
        return ReliabilityPolicy.RELIABLE if r == ReliabilityPolicy.SYSTEM_DEFAULT else r

    def dur(p):
        d = p.durability
        return DurabilityPolicy.VOLATILE if d == DurabilityPolicy.SYSTEM_DEFAULT else d

    if (
        rel(publisher_qos) == ReliabilityPolicy.BEST_EFFORT
        and rel(subscription_qos) == ReliabilityPolicy.RELIABLE
    ):
        return (QoSCompatibility.ERROR, "ERROR: Best effort publisher and reliable subscription;")
    if (
        dur(publisher_qos) == DurabilityPolicy.VOLATILE
        and dur(subscription_qos) == DurabilityPolicy.TRANSIENT_LOCAL
    ):
        return (
            QoSCompatibility.ERROR,
            "ERROR: Volatile publisher and transient local subscription;",
        )
    return QoSCompatibility.OK, ""
