"""Stand-in std_srvs.srv (Jazzy definitions): Trigger, Empty, SetBool."""

from _rosmsg_standin import make_service as _make

Trigger = _make("std_srvs", "Trigger")
Empty = _make("std_srvs", "Empty")
SetBool = _make("std_srvs", "SetBool")
del _make
