"""excitation_node: plays a signal set as velocity reference and excitation u_e.

Shell around :class:`lpv_sysid.signals.excitation.ExcitationCore`. Publishes, at
``rate_hz`` from a timer that samples the core at the node clock's current time (so timer
jitter never accumulates): ``velocity_reference`` (TwistStamped) and ``excitation``
(JointState ``ue_t, ue_a, ue_e, ue_r``); ``status`` (DiagnosticArray) at
``status_rate_hz``. Services ``start`` / ``abort`` (std_srvs/Trigger). Before ``start``
the trim reference (vertex offset, zero excitation) is published.

Abort, from any source, fades everything (signal and offset) to zero within one ramp,
starting at once: the ``abort`` service, a ``status`` of another node named in
``abort_on_status_from`` that reports an abort (:data:`ABORT_MARKERS`: the controller's
safety abort, the bridge handing control back to PX4, the campaign aborting; a mere ERROR
such as a rejected message does not count), or the node clock jumping backwards (the signal's time
base is lost; the fade
then runs on a re-based monotonic time, :class:`~lpv_sysid.signals.excitation.MonotonicTime`).
The core clamps the abort time to the last sample, so no abort waits for a future stamp.

With ``gains_file`` (phase 2) the signal must fit the design envelope of those gains at
load (``certificate.design``: reference peaks and rates, excitation peaks, fade length); the
controller enforces the same envelope at run time. Parameters are declared once, in
:class:`ExcitationSettings`.

    ros2 run lpv_sysid excitation_node --ros-args --params-file config/excitation_node.yaml \
        -p signals_file:=signals.npz -p mode:=phase1
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistStamped
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from lpv_sysid.errors import ConfigError
from lpv_sysid.io import messages
from lpv_sysid.nodes import shell
from lpv_sysid.nodes import parameters
from lpv_sysid.signals.excitation import (
    DEFAULT_RAMP_S,
    ExcitationCore,
    MonotonicTime,
    check_design,
)
from lpv_sysid.signals.store import load_npz

NODE_NAME = "excitation"
MODES = ("phase1", "phase2")
#: a core that never starts: before ``start`` it outputs the offset, and an abort fades it
_NEVER_S = 1e9
#: status values by which a node reports an abort: lpv_controller ``aborted: true`` (its
#: safety abort, ERROR), mavlink_bridge ``state: HANDBACK | FAILED`` (control going or gone
#: back to PX4, mavlink/offboard.py), campaign ``phase: aborting | aborted | failed``
ABORT_MARKERS = {
    "aborted": ("true",),
    "state": ("HANDBACK", "FAILED"),
    "phase": ("aborting", "aborted", "failed"),
}


def reports_abort(status) -> bool:
    """Whether a DiagnosticStatus (io.messages.StatusSample) reports an abort."""
    return any(status.values.get(key, "") in values for key, values in ABORT_MARKERS.items())


@dataclass(frozen=True)
class ExcitationSettings(parameters.Settings):
    """The node's parameters (config/excitation_node.yaml): the one declaration."""

    WHERE = "excitation"

    signals_file: str = parameters.text("", "signals.npz (lpv-sysid signals)", nonempty=True)
    mode: str = parameters.text(
        "phase1",
        "phase1: vertex + multisine on u, v, w, yaw rate; phase2: v_d(t) and u_e(t)",
        choices=MODES,
    )
    rate_hz: float = parameters.double(100.0, "publication rate [Hz]", 1.0, 1000.0)
    status_rate_hz: float = parameters.double(2.0, "status publication rate [Hz]", 0.1, 100.0)
    vertex_frd: tuple = parameters.doubles(
        (0.0, 0.0, 0.0),
        "phase1: vertex body velocity (u, v, w) FRD [m/s]",
        lo=-20.0,
        hi=20.0,
        lengths=(3,),
    )
    yaw_rate_offset: float = parameters.double(
        0.0, "phase1: yaw-rate reference offset FRD [rad/s]", -3.0, 3.0
    )
    ramp_s: float = parameters.double(
        DEFAULT_RAMP_S, "raised-cosine fade in/out and abort fade [s]", 0.0, 60.0
    )
    start_delay_s: float = parameters.double(
        0.0, "delay between start and the signal [s]", 0.0, 60.0
    )
    auto_start: bool = parameters.flag(False, "start on launch without the service")
    gains_file: str = parameters.text(
        "",
        "phase2: gains.yaml whose design envelope the signal must "
        "fit (checked at load; empty: no check)",
    )
    abort_on_status_from: tuple = parameters.texts(
        ("lpv_controller", "mavlink_bridge", "campaign"),
        "fade out when one of these nodes (last component of the status name) reports an "
        "abort or a hand-back on status",
    )

    def validate(self) -> None:
        if self.gains_file and self.mode != "phase2":
            self.fail("gains_file is a phase-2 check; mode is phase1")


#: the rclpy declarations, generated from the one declaration (ExcitationSettings)
PARAMETERS = shell.settings_table(ExcitationSettings)


class ExcitationNode(shell.ShellNode):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, PARAMETERS, **kwargs)
        self.settings = s = ExcitationSettings.from_dict(self.params)
        self.mode = s.mode
        self.table = load_npz(s.signals_file)
        self.offset = np.asarray(s.vertex_frd) if self.mode == "phase1" else np.zeros(3)
        self.yaw_offset = s.yaw_rate_offset if self.mode == "phase1" else 0.0
        self.core = self._make_core(start_time=0.0)  # validates channels now, not at start
        if s.gains_file:
            self._check_gains(s.gains_file)
        self.clock = MonotonicTime(1.0 / s.rate_hz)
        self.started = False
        self.aborted = False
        self.abort_reason = ""
        self.f = messages.MsgFactory.rclpy()
        self.pub_ref = self.create_publisher(
            TwistStamped, "velocity_reference", shell.qos_for("velocity_reference")
        )
        self.pub_exc = self.create_publisher(JointState, "excitation", shell.qos_for("excitation"))
        self.pub_status = shell.StatusPublisher(self)  # status and /diagnostics
        self.create_subscription(
            DiagnosticArray, "status", self.on_status, shell.qos_for("status")
        )
        self.create_service(Trigger, "~/start", self.on_start)
        self.create_service(Trigger, "~/abort", self.on_abort)
        self.create_timer(1.0 / s.rate_hz, self.on_timer)
        self.create_timer(1.0 / s.status_rate_hz, self.publish_status)
        self.get_logger().info(
            f"{self.mode}: {self.table[1].shape[0]} samples of {list(self.table[2])} "
            f"({self.core.duration:.1f} s), {s.rate_hz:g} Hz; {shell.clock_source(self)}"
        )
        if s.auto_start:
            self._start()

    def _make_core(self, start_time: float) -> ExcitationCore:
        t, u, names = self.table
        if self.mode == "phase1":
            return ExcitationCore.phase1(
                t,
                u,
                names,
                start_time=start_time,
                vertex_velocity=self.offset,
                ramp=self.settings.ramp_s,
                yaw_rate_offset=self.yaw_offset,
            )
        return ExcitationCore.phase2(t, u, names, start_time=start_time, ramp=self.settings.ramp_s)

    def _check_gains(self, path: str) -> None:
        from lpv_sysid.io.formats import GainSchedule

        design = GainSchedule.load(path).certificate.design
        if design is None:
            raise ConfigError(
                f"{path}: certificate.design missing: cannot check the signal "
                "against what the gains were designed for"
            )
        t, u, names = self.table
        check_design(t, u, names, design, self.settings.ramp_s, where=self.settings.signals_file)

    # -- abort (every source) -----------------------------------------------------------
    def _abort(self, reason: str) -> None:
        """Fade out within one ramp from now (idempotent; the first reason is kept)."""
        if self.aborted:
            return
        self.aborted = True
        self.abort_reason = reason
        self._abort_at = self.now()
        if not self.started:
            # fade the trim offset too: a core that never starts, sampled now
            t, _ = self.clock.map(self.now())
            self.core = self._make_core(start_time=t + _NEVER_S)
            self.core.sample(t)
            self.started = True
        self.core.abort()
        self.get_logger().warning(
            f"excitation aborted ({reason}): fading to zero within {self.settings.ramp_s:g} s"
        )
        self.publish_status()

    def on_status(self, msg):
        try:
            _, statuses = messages.status_from_diagnostic_array(msg)
        except messages.MessageError:
            return
        own = self.get_fully_qualified_name()
        watched = self.settings.abort_on_status_from
        for st in statuses:
            node = st.name.rstrip("/").rsplit("/", 1)[-1]
            if st.name != own and node in watched and reports_abort(st):
                self._abort(f"{st.name}: {st.message}")
                return

    # -- services -----------------------------------------------------------------------
    def _start(self) -> str:
        t, _ = self.clock.map(self.now())
        self.core = self._make_core(start_time=t + self.settings.start_delay_s)
        self.started = True
        return (
            f"{self.mode} excitation starts at t={self.core.start_time:.3f} s, "
            f"ends at {self.core.end_time:.3f} s"
        )

    def on_start(self, request, response):
        if self.aborted:
            response.success = False
            response.message = f"aborted ({self.abort_reason}): restart the node to run again"
        elif self.started:
            response.success = False
            response.message = "already started"
        else:
            response.success = True
            response.message = self._start()
        self.get_logger().info(f"start: {response.message}")
        return response

    def on_abort(self, request, response):
        self._abort("abort service")
        response.success = True
        response.message = "excitation aborted: fading to zero"
        return response

    # -- timers -------------------------------------------------------------------------
    def on_timer(self):
        ns = self.now_ns()
        t, jump = self.clock.map(ns * 1e-9)
        if jump > 0.0:
            self._abort(f"node clock went back by {jump:.3f} s")
        if self.started:
            s = self.core.sample(t)
            v, r, u_e = s.velocity, s.yaw_rate, s.u_e
        else:
            v, r, u_e = self.offset, self.yaw_offset, np.zeros(4)
        self.pub_ref.publish(messages.twist_reference_msg(self.f, ns, v, r))
        self.pub_exc.publish(messages.excitation_msg(self.f, ns, u_e))
        self._shutdown_tick(ns * 1e-9)

    # -- orderly shutdown (nodes/shell.run) ----------------------------------------
    #: wall time without node-clock progress after which the shutdown stops waiting for the
    #: fade: under use_sim_time the clock source (sim_vehicle) may be shutting down too [s]
    CLOCK_STALL_S = 0.5

    def begin_shutdown(self):
        """Abort with reason "shutdown" while the context is valid: the fade to zero starts
        at once and is published by the timer (downstream sees the reference go to zero,
        not stop at full amplitude); status says so, and once more when the fade is done
        -- or when the node clock stops (sim time whose source is gone: nothing to fade
        against; the consumers see the stream end)."""
        self._shutdown = {"final": False, "clock": self.now(), "moved": time.monotonic()}
        self._abort("shutdown")
        self._shutdown["faded_at"] = self._abort_at + self.settings.ramp_s

    def shutdown_complete(self):
        sd = getattr(self, "_shutdown", None)
        if sd is None or sd["final"]:
            return sd is not None
        now = self.now()
        if now != sd["clock"]:
            sd["clock"], sd["moved"] = now, time.monotonic()
        elif time.monotonic() - sd["moved"] > self.CLOCK_STALL_S:
            self._final_status(f"node clock stopped at {now:.3f} s before the fade ended")
        return sd["final"]

    def shutdown_state(self):
        left = self._shutdown["faded_at"] - self.now()
        return f"fading out ({left:.2f} s of the {self.settings.ramp_s:g} s ramp left)"

    def _shutdown_tick(self, t_published: float) -> None:
        """After a published sample at node time ``t_published``: the final status once
        the fade is over (every output zero)."""
        sd = getattr(self, "_shutdown", None)
        if sd is not None and not sd["final"] and t_published >= sd["faded_at"]:
            self._final_status("faded out")

    def _final_status(self, how: str) -> None:
        self._shutdown["final"] = True
        self.publish_status()
        self.get_logger().info(f"excitation {how}: shutdown")

    def publish_status(self):
        prog = self.core.progress if self.started else None
        phase = "aborted" if self.aborted else (prog.phase if prog else "waiting_for_start")
        level = "WARN" if self.aborted else "OK"
        values = {
            "mode": self.mode,
            "phase": phase,
            "fraction": prog.fraction if prog else 0.0,
            "aborted": self.aborted,
            "abort_reason": self.abort_reason,
        }
        st = messages.diagnostic_status(
            self.f, level, self.get_fully_qualified_name(), phase, values
        )
        self.pub_status.publish(messages.diagnostic_array(self.f, self.now_ns(), [st]))


def main(args=None):
    return shell.run(ExcitationNode, args, NODE_NAME)


if __name__ == "__main__":
    main()
