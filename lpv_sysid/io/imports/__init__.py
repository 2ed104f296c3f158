"""Flight data recorded by other tools -> the package's own bags: PX4 ULog files and foreign
rosbag2 recordings (MAVROS, ``/fmu/out`` px4_msgs), so ``identify`` and ``report`` read a
flight flown with the user's own tools unchanged.

Each importer gives a :class:`FlightRecord` (core frames: NED world, FRD body, SI), split into
runs (:func:`runs_of`: offboard segments or ``START:END`` windows) and written as one rosbag2
per run with the data logger's recorder (:func:`write_runs`): topics ``state``, ``imu``,
``rotor_speeds``, ``velocity_reference``, ``rate_setpoint``, ``status`` under
``/lpv_sysid``, ``experiment.yaml`` with the provenance (firmware, board, airframe, PX4
parameters, battery, vehicle kind, clock).

=========================================  ===================================================
:mod:`~lpv_sysid.io.imports.record`        :class:`FlightRecord`, runs and windows
:mod:`~lpv_sysid.io.imports.uorb`          uORB topics -> :class:`FlightRecord` (ULog, px4_msgs)
:mod:`~lpv_sysid.io.imports.ulog`          PX4 ULog through pyulog, its provenance
:mod:`~lpv_sysid.io.imports.foreign_bag`   MAVROS and ``/fmu/out`` px4_msgs rosbag2 directories
:mod:`~lpv_sysid.io.imports.writer`        runs -> rosbag2 directories + ``experiment.yaml``
=========================================  ===================================================
"""

from __future__ import annotations

from lpv_sysid.io.imports.foreign_bag import FLAVOURS, flavour_of, read_foreign_bag
from lpv_sysid.io.imports.record import (
    Channels,
    Event,
    FlightRecord,
    Run,
    StateSeries,
    parse_window,
    px4_clock_of,
    runs_of,
)
from lpv_sysid.io.imports.ulog import VEHICLE_KINDS, firmware_release, read_ulog, vehicle_kind
from lpv_sysid.io.imports.uorb import NAV_STATE_OFFBOARD, flight_from_uorb, uorb_name
from lpv_sysid.io.imports.writer import ImportedRun, import_flight, write_runs

__all__ = [
    "Channels",
    "Event",
    "FLAVOURS",
    "FlightRecord",
    "ImportedRun",
    "NAV_STATE_OFFBOARD",
    "Run",
    "StateSeries",
    "VEHICLE_KINDS",
    "firmware_release",
    "flavour_of",
    "import_flight",
    "flight_from_uorb",
    "parse_window",
    "px4_clock_of",
    "read_foreign_bag",
    "read_ulog",
    "runs_of",
    "uorb_name",
    "vehicle_kind",
    "write_runs",
]
