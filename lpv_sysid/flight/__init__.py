"""Flying, ROS-free: the cores that the ROS 2 nodes and the command line both run, so a
flight from ``lpv-sysid fly`` and one from ``ros2 launch`` are the same code.

* :mod:`~lpv_sysid.flight.campaign`: the phase-1 campaign flown on PX4 (the sequence, its
  runner, recording and outputs; the campaign node's runtime);
* :mod:`~lpv_sysid.flight.controller`: the phase-2 controller runtime (start-up checks, the
  LPV law, the safety supervisor) and its replay on a recorded flight;
* :mod:`~lpv_sysid.flight.phase2`: the phase-2 flight on PX4 and what it measured;
* :mod:`~lpv_sysid.flight.bridge`: the MAVLink/MAVROS bridge node's runtime;
* :mod:`~lpv_sysid.flight.excitation`: the excitation node's runtime;
* :mod:`~lpv_sysid.flight.sequencer`: the safe start order of a phase's nodes (the
  sequencer node's runtime);
* :mod:`~lpv_sysid.flight.chain`: the whole two-phase job on a connected PX4;
* :mod:`~lpv_sysid.flight.vehicle`: the vehicle-link steps around a flight (wait for the
  autopilot, confirmed PARAM_SET, the ATTITUDE_TARGET tap).
"""
