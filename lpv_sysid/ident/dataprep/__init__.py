"""Phase-1 recordings -> aligned arrays for identification (seed 0 Sec. IV, Table 1).

Sources (:mod:`lpv_sysid.ident.dataprep.streams`): a rosbag2 directory or an in-memory
simulated run, as :class:`~lpv_sysid.ident.dataprep.streams.Streams`.

Steps:

1. per topic: stamps from the message headers, sorted; duplicated stamps dropped; a gap
   longer than ``max_gap`` inside the analysed span, non-finite values, or too few samples
   raise :class:`BagError` naming the topic and the time;
2. resampling of every stream by a cubic spline onto one uniform grid at ``sample_rate``
   over the span that all streams cover; the grid is put on the rotor-speed stamps when
   that stream arrives at the grid rate (ESC telemetry is not anti-alias filtered:
   interpolating it between its samples would low-pass it, see ``_interp``);
3. the controller state of DESIGN.md, ``x = [phi, theta, u, v, w, p, q, r, dt, da, de, dr]``
   with ``delta = Mix Omega`` (seed 0 Eq. 7) from the measured rotor speeds;
4. the input ``u = [ut, ua, ue, ur]`` from ``actuator_command``, a zero-order-hold signal
   whose stamps are moved to the centre of each hold interval.  A real PX4 log may not
   contain the virtual command; then it is reconstructed from the measured rotor speeds by
   inverting the (known, separately identified) motor model Eq. (8):
   ``u = Mix u_ESC = (delta' + a_Omega delta) / b_Omega`` with the smoothed derivative of
   ``delta`` - the actuator rows then carry no information of their own (a_Omega, b_Omega
   are not identified from such a run, ``VertexData.motor_identifiable``; likewise when the
   rotor speeds were themselves estimated from the motor outputs) and the aerodynamic rows
   are unaffected.  ``VertexData.u_eff`` is the command after the ESC clip of Eq. (8),
   ``Mix clip(Mix^-1 u, 0, 1)``, applied to the command samples before resampling;
5. excitation start: an explicit value (simulation), else the first sample where the
   ``excitation`` topic leaves zero, else where the velocity reference leaves its initial
   value, else ``trim_duration`` after the start; the trim segment is the ``trim_duration``
   (10 s) before it (seed 0 Sec. IV), the fit segment everything after it;
6. the scheduling vertex ``v_d`` = mean velocity reference over the trim segment.
"""

from __future__ import annotations

from lpv_sysid.ident.dataprep.alignment import (
    align,
    format_table1,
    resample,
    snap_to_box,
    trim_row,
)
from lpv_sysid.ident.dataprep.px4_records import px4_record
from lpv_sysid.ident.dataprep.streams import (
    TOPICS,
    Streams,
    find_bags,
    streams_from_bag,
    streams_from_record,
)

__all__ = [
    "Streams",
    "TOPICS",
    "align",
    "find_bags",
    "format_table1",
    "px4_record",
    "resample",
    "snap_to_box",
    "streams_from_bag",
    "streams_from_record",
    "trim_row",
]
