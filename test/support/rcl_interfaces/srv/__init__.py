"""Stand-in rcl_interfaces.srv (Jazzy definitions): GetParameters."""

from _rosmsg_standin import make_service as _make

GetParameters = _make("rcl_interfaces", "GetParameters")
del _make
