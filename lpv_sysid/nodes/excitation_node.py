"""excitation_node: plays a signal set as velocity reference and excitation u_e.

Shell around :class:`lpv_sysid.signals.excitation.ExcitationCore`. Publishes, at
``rate_hz`` from a timer that samples the core at the node clock's current time (so timer
jitter never accumulates): ``velocity_reference`` (TwistStamped) and ``excitation``
(JointState ``ue_t, ue_a, ue_e, ue_r``); ``status`` (DiagnosticArray) at
``status_rate_hz``. Services ``start`` / ``abort`` (std_srvs/Trigger). Before ``start``
the trim reference (vertex offset, zero excitation) is published; ``abort`` fades
everything to zero within one ramp (excitation off).

    ros2 run lpv_sysid excitation_node --ros-args --params-file config/excitation_node.yaml \
        -p signals_file:=signals.npz -p mode:=phase1
"""

from __future__ import annotations

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistStamped
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from lpv_sysid.errors import LpvSysidError
from lpv_sysid.io import messages as M
from lpv_sysid.nodes import _common as C
from lpv_sysid.signals.excitation import ExcitationCore
from lpv_sysid.signals.store import load_npz

NODE_NAME = "excitation"
MODES = ("phase1", "phase2")

PARAMETERS = [
    ("signals_file", "", C.typed(Parameter.Type.STRING, "signals.npz (lpv-sysid signals)")),
    ("mode", "phase1", C.typed(Parameter.Type.STRING,
                               "phase1: vertex + multisine on u, v, w, yaw rate; "
                               "phase2: v_d(t) and u_e(t)")),
    ("rate_hz", 100.0, C.double("publication rate [Hz]", 1.0, 1000.0)),
    ("status_rate_hz", 2.0, C.double("status publication rate [Hz]", 0.1, 100.0)),
    ("vertex_frd", [0.0, 0.0, 0.0], C.typed(
        Parameter.Type.DOUBLE_ARRAY, "phase1: vertex body velocity (u, v, w) FRD [m/s]")),
    ("yaw_rate_offset", 0.0, C.double("yaw-rate reference offset FRD [rad/s]", -3.0, 3.0)),
    ("ramp_s", 1.0, C.double("raised-cosine fade in/out and abort fade [s]", 0.0, 60.0)),
    ("start_delay_s", 0.0, C.double("delay between start and the signal [s]", 0.0, 60.0)),
    ("auto_start", False, C.typed(Parameter.Type.BOOL, "start on launch without the service")),
]


class ExcitationNode(C.ShellNode):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, PARAMETERS, **kwargs)
        p = self.params
        self.mode = p["mode"]
        if self.mode not in MODES:
            raise LpvSysidError(f"parameter 'mode' must be one of {MODES}, got {self.mode!r}")
        if not p["signals_file"]:
            raise LpvSysidError("parameter 'signals_file' is empty: give the signals.npz to play")
        vertex = np.asarray(p["vertex_frd"], dtype=float)
        if vertex.shape != (3,):
            raise LpvSysidError(f"parameter 'vertex_frd' needs 3 values, got {list(vertex)}")
        self.table = load_npz(p["signals_file"])
        self.offset = vertex if self.mode == "phase1" else np.zeros(3)
        self.yaw_offset = p["yaw_rate_offset"] if self.mode == "phase1" else 0.0
        self.core = self._make_core(start_time=0.0)   # validates channels now, not at start
        self.started = False
        self.aborted = False
        self.f = M.MsgFactory.rclpy()
        self.pub_ref = self.create_publisher(TwistStamped, "velocity_reference",
                                             C.qos_for("velocity_reference"))
        self.pub_exc = self.create_publisher(JointState, "excitation", C.qos_for("excitation"))
        self.pub_status = self.create_publisher(DiagnosticArray, "status", C.qos_for("status"))
        self.create_service(Trigger, "~/start", self.on_start)
        self.create_service(Trigger, "~/abort", self.on_abort)
        self.create_timer(1.0 / p["rate_hz"], self.on_timer)
        self.create_timer(1.0 / p["status_rate_hz"], self.publish_status)
        self.get_logger().info(
            f"{self.mode}: {self.table[1].shape[0]} samples of {list(self.table[2])} "
            f"({self.core.duration:.1f} s), {p['rate_hz']:g} Hz")
        if p["auto_start"]:
            self._start()

    def _make_core(self, start_time: float) -> ExcitationCore:
        t, u, names = self.table
        if self.mode == "phase1":
            return ExcitationCore.phase1(t, u, names, start_time=start_time,
                                         vertex_velocity=self.offset, ramp=self.params["ramp_s"],
                                         yaw_rate_offset=self.yaw_offset)
        return ExcitationCore.phase2(t, u, names, start_time=start_time,
                                     ramp=self.params["ramp_s"])

    # -- services -----------------------------------------------------------------------
    def _start(self) -> str:
        t = self.now()
        self.core = self._make_core(start_time=t + self.params["start_delay_s"])
        self.started = True
        return f"{self.mode} excitation starts at t={self.core.start_time:.3f} s, " \
               f"ends at {self.core.end_time:.3f} s"

    def on_start(self, request, response):
        if self.aborted:
            response.success = False
            response.message = "aborted: restart the node to run again"
        elif self.started:
            response.success = False
            response.message = "already started"
        else:
            response.success = True
            response.message = self._start()
        self.get_logger().info(f"start: {response.message}")
        return response

    def on_abort(self, request, response):
        self.aborted = True
        if self.started:
            self.core.abort()
        response.success = True
        response.message = "excitation aborted: fading to zero"
        self.get_logger().warning(response.message)
        self.publish_status()
        return response

    # -- timers -------------------------------------------------------------------------
    def on_timer(self):
        ns = self.now_ns()
        if self.started:
            s = self.core.sample(ns * 1e-9)
            v, r, u_e = s.velocity, s.yaw_rate, s.u_e
        elif self.aborted:
            v, r, u_e = np.zeros(3), 0.0, np.zeros(4)
        else:
            v, r, u_e = self.offset, self.yaw_offset, np.zeros(4)
        self.pub_ref.publish(M.twist_reference_msg(self.f, ns, v, r))
        self.pub_exc.publish(M.excitation_msg(self.f, ns, u_e))

    def publish_status(self):
        prog = self.core.progress if self.started else None
        phase = prog.phase if prog else ("aborted" if self.aborted else "waiting_for_start")
        level = "WARN" if self.aborted else "OK"
        values = {"mode": self.mode, "phase": phase,
                  "fraction": prog.fraction if prog else 0.0, "aborted": self.aborted}
        st = M.diagnostic_status(self.f, level, self.get_fully_qualified_name(), phase, values)
        self.pub_status.publish(M.diagnostic_array(self.f, self.now_ns(), [st]))


def main(args=None):
    return C.run(ExcitationNode, args, NODE_NAME)


if __name__ == "__main__":
    main()
