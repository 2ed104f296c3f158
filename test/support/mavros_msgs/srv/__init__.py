"""Stand-in mavros_msgs.srv (MAVROS 2.10 definitions): SetMode, CommandBool, CommandLong,
VehicleInfoGet, MessageInterval, ParamPull."""

from _rosmsg_standin import make_service as _make

SetMode = _make("mavros_msgs", "SetMode")
CommandBool = _make("mavros_msgs", "CommandBool")
CommandLong = _make("mavros_msgs", "CommandLong")
VehicleInfoGet = _make("mavros_msgs", "VehicleInfoGet")
MessageInterval = _make("mavros_msgs", "MessageInterval")
ParamPull = _make("mavros_msgs", "ParamPull")
del _make
