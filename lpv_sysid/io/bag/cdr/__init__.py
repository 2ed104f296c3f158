"""The CDR block codec of the bag readers and writers: fixed-layout records decoded and
encoded a topic at a time (:mod:`~lpv_sysid.io.bag.cdr.layout`) and message objects built
from decoded columns (:mod:`~lpv_sysid.io.bag.cdr.builder`); one serialized Odometry read
field by field for the controller's raw state subscription
(:mod:`~lpv_sysid.io.bag.cdr.record`).
"""

from __future__ import annotations

from lpv_sysid.io.bag.cdr.layout import CdrLayout, LayoutError, encode_block, records_close
from lpv_sysid.io.bag.cdr.record import OdometryRecord, odometry_record

__all__ = [
    "CdrLayout",
    "LayoutError",
    "OdometryRecord",
    "encode_block",
    "odometry_record",
    "records_close",
]
