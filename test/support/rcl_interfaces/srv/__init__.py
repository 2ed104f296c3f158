"""Stand-in rcl_interfaces.srv (Jazzy definitions): GetParameters, ListParameters."""

from _rosmsg_standin import make_service as _make

GetParameters = _make("rcl_interfaces", "GetParameters")
ListParameters = _make("rcl_interfaces", "ListParameters")
del _make
