"""Message-level behaviour of lpv_controller_node, shared with ``lpv-sysid replay``.

No rclpy here: the node shell forwards subscription messages and timer ticks to
:class:`ControllerRuntime`, and ``lpv-sysid replay`` does the same with the messages of a
bag (rosbags classes via ``MsgFactory.rosbags()``), so a replay computes exactly what the
node would have published. Both build
:class:`~lpv_sysid.flight.controller.settings.ControllerSettings`, the one declaration of the
node's parameters (timeout rule included).

At construction, before any command can exist, the start-up checks of
:func:`~lpv_sysid.flight.controller.startup.load_flight_schedule` run (gains validated, law
hash, closed-loop stability, design envelope, ESC limits); any failure refuses to start,
naming the reason. Inputs are parsed and the command is built by
:mod:`lpv_sysid.flight.controller.messages`.

Per reference message: the reference v_d is passed through the design-envelope limiter
(:class:`~lpv_sysid.control.law.reference_limiter.ReferenceLimiter`, rate and acceleration of the
gains' designed v_d(t)) before scheduling and feedforward; an incoming reference beyond the
envelope x ``envelope_margin`` aborts. Per excitation message: ``kappa |u_e|`` beyond the
designed excitation peak x margin aborts.

Ticks (``tick_source``): ``timer`` steps the law every ``1 / rate_hz`` of the node clock on
the newest samples received; ``state`` steps it on each state sample at that sample's stamp
(:meth:`ControllerRuntime.on_input`), so the command is always computed on the freshest
state and carries its stamp -- the lock-stepped ``sim_vehicle`` of ``sim.launch.py`` waits for
exactly that command before it integrates on -- while the ``rate_hz`` timer only judges
staleness. Why: the loop delay costs stability margin (issue 27 measured the demo gains
unstable beyond 27.0-28.2 ms of loop delay at 250 Hz, 24.2-25.2 ms at 100 Hz; an earlier
figure of 8-12 ms was not reproduced with the current gains), and the wall-clock Python
graph on a loaded 2-core machine measured ~14 ms mean loop delay (state delivery p99 31 ms).

The loop-delay watchdog holds every command to the delay the proof assumes: the age of the
state a command is computed from (its header stamp to the node clock at the tick) must not
stay above the certified bound (the gains certificate's ``loop_delay.bound_s``; the
``loop_delay_bound_s`` parameter where the certificate states none, the smaller of both
otherwise) for ``loop_delay_tolerance_s`` or longer -- a ``loop_delay`` abort, not only a
staleness abort after the 50-100 ms timeouts, which a sustained 25-50 ms delay passes.

Per tick, once started: staleness of every input stream (receipt time and
header stamp against the node clock), scheduling box, the runtime LPV law
u = u0(v_d) + K(v_d)(x - x0(v_d)) + R kappa u_e (seed 0 Eq. 31, control/law/controller.py;
with the reference feedforward of gains.yaml F_ff/F_jerk the law's own filtered derivatives
of the limited v_d supply a = dv_d/dt and its rate) on x = [phi, theta, u, v, w, p, q, r,
Mix Omega] (seed 0 Eq. 14 without position and yaw; delta = Mix Omega, Eq. 7), and its bound
monitor. Any fault (stale / frozen / future-stamped / out-of-order / non-finite input, v_d
outside the box or its envelope, excitation too large, bound exceeded, loop delay above the
certified bound, abort request)
latches an abort in :class:`~lpv_sysid.control.safety.SafetySupervisor`: one ERROR status
naming the reason is published and no actuator command follows, so the bridge hands control
back to PX4 (and the excitation node fades out on that status).

Log lines of the core (the abort, refused inputs, the start-up checks) are queued and
handed to the shell by :meth:`ControllerRuntime.take_log`: the node logs them with its own
logger (timestamped, on /rosout), the replay with Python logging.

Parts: the runtime (:mod:`~lpv_sysid.flight.controller.runtime`), the node's parameters
(:mod:`~lpv_sysid.flight.controller.settings`), the start-up checks
(:mod:`~lpv_sysid.flight.controller.startup`), the messages as arrays
(:mod:`~lpv_sysid.flight.controller.messages`) and the replay of a recorded flight
(:mod:`~lpv_sysid.flight.controller.replay`).
"""

from __future__ import annotations

from lpv_sysid.flight.controller.messages import CommandBuilder, parse_input, parse_inputs
from lpv_sysid.flight.controller.replay import replay_controller
from lpv_sysid.flight.controller.runtime import ControllerRuntime
from lpv_sysid.flight.controller.settings import TIMEOUT_PERIODS, ControllerSettings
from lpv_sysid.flight.controller.startup import settle_gc

__all__ = [
    "CommandBuilder",
    "ControllerRuntime",
    "ControllerSettings",
    "TIMEOUT_PERIODS",
    "parse_input",
    "parse_inputs",
    "replay_controller",
    "settle_gc",
]
