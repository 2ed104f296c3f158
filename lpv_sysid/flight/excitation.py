"""Message-level behaviour of excitation_node: start, abort (every source), fade, status.

No rclpy here: the node shell (:mod:`lpv_sysid.nodes.excitation_node`) reads its clocks and
forwards timer ticks, ``status`` messages and service calls to :class:`ExcitationRuntime`,
which returns the ``(topic, message)`` pairs to publish, in order (messages built by a
:class:`~lpv_sysid.io.messages.MsgFactory`). Its parameters are declared once, in
:class:`ExcitationSettings`.

The signal is played by :class:`lpv_sysid.signals.excitation.ExcitationCore`, sampled at the
node clock's current time on every tick (so timer jitter never accumulates):
``velocity_reference`` and ``excitation`` (``ue_t, ue_a, ue_e, ue_r``). Before ``start`` the
trim reference (vertex offset, zero excitation) is published.

Abort, from any source, fades everything (signal and offset) to zero within one ramp,
starting at once: the ``abort`` service, a ``status`` of another node named in
``abort_on_status_from`` that reports an abort (:data:`ABORT_MARKERS`: the controller's
safety abort, the bridge handing control back to PX4, the campaign aborting; a mere ERROR
such as a rejected message does not count), or the node clock jumping backwards (the
signal's time base is lost; the fade then runs on a re-based monotonic time,
:class:`~lpv_sysid.signals.excitation.MonotonicTime`). The core clamps the abort time to the
last sample, so no abort waits for a future stamp. Shutdown is an abort "shutdown" whose fade
is played out; the final status follows once the fade is over, or once the node clock has
not moved for :data:`CLOCK_STALL_S` of wall time.

With ``gains_file`` (phase 2) the signal must fit the design envelope of those gains at
load (``certificate.design``: reference peaks and rates, excitation peaks, fade length); the
controller enforces the same envelope at run time.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, Callable, Optional

import numpy as np

from lpv_sysid.configuration import parameters
from lpv_sysid.errors import ConfigError
from lpv_sysid.io import messages
from lpv_sysid.signals.excitation import (
    DEFAULT_RAMP_S,
    ExcitationCore,
    MonotonicTime,
    check_design,
)
from lpv_sysid.signals.store import load_npz

_LOG = logging.getLogger(__name__)

MODES = ("phase1", "phase2")
#: a core that never starts: before ``start`` it outputs the offset, and an abort fades it
_NEVER_S = 1e9
#: status values by which a node reports an abort: lpv_controller ``aborted: true`` (its
#: safety abort, ERROR), mavlink_bridge ``state: HANDBACK | FAILED`` (control going or gone
#: back to PX4, mavlink/offboard/machine.py), campaign ``phase: aborting | aborted | failed``
ABORT_MARKERS = {
    "aborted": ("true",),
    "state": ("HANDBACK", "FAILED"),
    "phase": ("aborting", "aborted", "failed"),
}
#: wall time without node-clock progress after which the shutdown stops waiting for the
#: fade: under use_sim_time the clock source (sim_vehicle) may be shutting down too [s]
CLOCK_STALL_S = 0.5

#: ``(topic, message)`` pairs to publish, in order (velocity_reference, excitation, status)
Outputs = list[tuple[str, Any]]


#: :data:`ABORT_MARKERS` compared case-folded and without surrounding blanks: "True",
#: "TRUE", "handback" and "Aborted " are the same report (a publisher's spelling must not
#: hide an abort)
_FOLDED = {
    key.casefold(): frozenset(v.casefold() for v in values)
    for key, values in ABORT_MARKERS.items()
}


def reports_abort(status) -> bool:
    """Whether a DiagnosticStatus (io.messages.StatusSample) reports an abort (keys and
    values of :data:`ABORT_MARKERS`, case-insensitive)."""
    for key, value in status.values.items():
        wanted = _FOLDED.get(str(key).strip().casefold())
        if wanted is not None and str(value).strip().casefold() in wanted:
            return True
    return False


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
    duration_s: float = parameters.double(
        0.0,
        "phase2: play only the first duration_s of the table, fades inside it (0: one period, "
        "fades around it)",
        0.0,
        1e5,
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
        if self.duration_s and self.mode != "phase2":
            self.fail("duration_s shortens a phase-2 signal; mode is phase1")


def _python_log(level: str, text: str) -> None:
    _LOG.log({"error": logging.ERROR, "warn": logging.WARNING}.get(level, logging.INFO), text)


class ExcitationRuntime:
    """See module docstring. Time arguments: ``now_ns`` the node clock, ``wall_s`` a
    monotonic wall clock (only the shutdown's clock-stall rule reads it). ``log(level,
    text)`` (level ``info``, ``warn`` or ``error``) receives the log lines."""

    def __init__(
        self,
        settings: ExcitationSettings,
        factory: messages.MsgFactory,
        name: str = "/lpv_sysid/excitation",
        log: Optional[Callable[[str, str], None]] = None,
    ):
        self.settings = s = settings
        self.f = factory
        self.name = name
        self.log = log or _python_log
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
        self.abort_at = -np.inf  # node time of the abort
        self._shutdown: Optional[dict] = None

    def _make_core(self, start_time: float) -> ExcitationCore:
        t, u, names = self.table
        if self.mode == "phase1":
            return ExcitationCore.phase1(
                t,
                u,
                names,
                start_time=start_time,
                vertex_velocity=self.offset.tolist(),
                ramp=self.settings.ramp_s,
                yaw_rate_offset=self.yaw_offset,
            )
        if self.settings.duration_s > 0.0:
            # a part of the period: played as it is, fades inside (no wrap to the table start)
            keep = t <= t[0] + self.settings.duration_s + 1e-9
            return ExcitationCore.phase2(
                t[keep],
                u[keep],
                names,
                start_time=start_time,
                ramp=self.settings.ramp_s,
                periodic=False,
            )
        return ExcitationCore.phase2(t, u, names, start_time=start_time, ramp=self.settings.ramp_s)

    def _check_gains(self, path: str) -> None:
        from lpv_sysid.io.formats import GainSchedule

        design = GainSchedule.load(path, auto_layout=True).certificate.design
        if design is None:
            raise ConfigError(
                f"{path}: certificate.design missing: cannot check the signal "
                "against what the gains were designed for"
            )
        t, u, names = self.table
        check_design(t, u, names, design, self.settings.ramp_s, where=self.settings.signals_file)

    # -- start ----------------------------------------------------------------------------
    def start(self, now_ns: int) -> tuple[bool, str]:
        """The ``start`` service: (success, message). The signal starts ``start_delay_s``
        after ``now_ns``; refused once started or aborted."""
        if self.aborted:
            return False, f"aborted ({self.abort_reason}): restart the node to run again"
        if self.started:
            return False, "already started"
        t, _ = self.clock.map(now_ns * 1e-9)
        self.core = self._make_core(start_time=t + self.settings.start_delay_s)
        self.started = True
        return True, (
            f"{self.mode} excitation starts at t={self.core.start_time:.3f} s, "
            f"ends at {self.core.end_time:.3f} s"
        )

    # -- abort (every source) -------------------------------------------------------------
    def abort(self, now_ns: int, reason: str) -> Outputs:
        """Fade out within one ramp from now (idempotent; the first reason is kept); the
        status saying so."""
        if self.aborted:
            return []
        now = now_ns * 1e-9
        self.aborted = True
        self.abort_reason = reason
        self.abort_at = now
        if not self.started:
            # fade the trim offset too: a core that never starts, sampled now
            t, _ = self.clock.map(now)
            self.core = self._make_core(start_time=t + _NEVER_S)
            self.core.sample(t)
            self.started = True
        self.core.abort()
        self.log(
            "warn",
            f"excitation aborted ({reason}): fading to zero within {self.settings.ramp_s:g} s",
        )
        return [("status", self.status(now_ns))]

    def on_status(self, msg, now_ns: int) -> Outputs:
        """A ``status`` DiagnosticArray: abort when a watched node (not this one) reports
        an abort (:func:`reports_abort`); an unreadable array is ignored."""
        try:
            _, statuses = messages.status_from_diagnostic_array(msg)
        except messages.MessageError:
            return []
        watched = self.settings.abort_on_status_from
        for st in statuses:
            node = st.name.rstrip("/").rsplit("/", 1)[-1]
            if st.name != self.name and node in watched and reports_abort(st):
                return self.abort(now_ns, f"{st.name}: {st.message}")
        return []

    # -- tick -----------------------------------------------------------------------------
    def on_timer(self, now_ns: int) -> Outputs:
        """One sample at the node clock ``now_ns``: reference and excitation (after the
        abort status when the clock went back; before the final status once a shutdown
        fade is over)."""
        t, jump = self.clock.map(now_ns * 1e-9)
        out = self.abort(now_ns, f"node clock went back by {jump:.3f} s") if jump > 0.0 else []
        if self.started:
            s = self.core.sample(t)
            v, r, u_e = s.velocity, s.yaw_rate, s.u_e
        else:
            v, r, u_e = self.offset, self.yaw_offset, np.zeros(4)
        out.append(("velocity_reference", messages.twist_reference_msg(self.f, now_ns, v, r)))
        out.append(("excitation", messages.excitation_msg(self.f, now_ns, u_e)))
        sd = self._shutdown
        if sd is not None and not sd["final"] and now_ns * 1e-9 >= sd["faded_at"]:
            out += self._final_status(now_ns, "faded out")
        return out

    # -- orderly shutdown -----------------------------------------------------------------
    def begin_shutdown(self, now_ns: int, wall_s: float) -> Outputs:
        """Abort with reason "shutdown": the fade to zero starts at once and is published
        by the ticks (downstream sees the reference go to zero, not stop at full
        amplitude); status says so, and once more when the fade is done -- or when the node
        clock stops (sim time whose source is gone: nothing to fade against; the consumers
        see the stream end), :meth:`poll_shutdown`."""
        self._shutdown = {"final": False, "clock": now_ns * 1e-9, "moved": wall_s}
        out = self.abort(now_ns, "shutdown")
        self._shutdown["faded_at"] = self.abort_at + self.settings.ramp_s
        return out

    @property
    def shutdown_done(self) -> bool:
        """Whether the shutdown's final status is out."""
        return self._shutdown is not None and self._shutdown["final"]

    def poll_shutdown(self, now_ns: int, wall_s: float) -> Outputs:
        """The clock-stall rule: the final status once the node clock has not moved for
        :data:`CLOCK_STALL_S` of wall time ``wall_s``."""
        sd = self._shutdown
        if sd is None or sd["final"]:
            return []
        now = now_ns * 1e-9
        if now != sd["clock"]:
            sd["clock"], sd["moved"] = now, wall_s
        elif wall_s - sd["moved"] > CLOCK_STALL_S:
            return self._final_status(
                now_ns, f"node clock stopped at {now:.3f} s before the fade ended"
            )
        return []

    def shutdown_state(self, now_ns: int) -> str:
        assert self._shutdown is not None
        left = self._shutdown["faded_at"] - now_ns * 1e-9
        return f"fading out ({left:.2f} s of the {self.settings.ramp_s:g} s ramp left)"

    def _final_status(self, now_ns: int, how: str) -> Outputs:
        assert self._shutdown is not None
        self._shutdown["final"] = True
        out: Outputs = [("status", self.status(now_ns))]
        self.log("info", f"excitation {how}: shutdown")
        return out

    # -- status ---------------------------------------------------------------------------
    def status(self, now_ns: int):
        """The ``status`` DiagnosticArray: mode, phase, fraction, abort and its reason."""
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
        st = messages.diagnostic_status(self.f, level, self.name, phase, values)
        return messages.diagnostic_array(self.f, now_ns, [st])
