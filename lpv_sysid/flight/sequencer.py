"""The safe start order of a flight graph (``sequencer_node``, the phase launch files).

A phase is flown by several nodes that each wait for their ``start`` service (none arms or
commands on its own): the bridge (pre-stream, OFFBOARD, arm), the LPV controller (phase 2:
commanding) and the excitation (the signal). Started out of order, the excitation plays into
a vehicle nobody is commanding, or the controller commands a bridge that is not streaming.
:class:`SequencerRuntime` runs ``steps`` in order, each only once the previous one has been
**confirmed** on that node's own ``status``: ``node`` calls its ``start`` and waits for
:data:`CONFIRM` (the bridge's offboard state, the controller's ``armed``, the excitation's
phase); ``node:ready`` calls nothing and waits for :data:`READY` (the bridge's MAVLink link
up). Phase 2 (default): bridge ready -> controller armed -> bridge in OFFBOARD -> excitation,
so PX4 is switched to OFFBOARD only while the controller's commands already stream; phase 1:
bridge in OFFBOARD (streaming the excitation node's vertex reference) -> excitation. A node
that refuses its start, does not confirm it within ``step_timeout_s``, or reports an abort
on ``status`` (the excitation's :func:`~lpv_sysid.flight.excitation.reports_abort` rule)
aborts every node the sequence started, in reverse order (the excitation fades out, the
controller stops, the bridge hands control back to PX4 and confirms the mode).

When the excitation, started by the sequence, reports its signal played to the end (phase
``done``), the flight is complete (``hand_back_when_done``): the bridge's abort hands control
back to PX4 (the mode confirmed by PX4, its ``handback_chain``) while the controller still
commands, then the controller and the excitation stop -- the ROS graph's end of phase 2, as
``lpv-sysid fly phase2`` hands back after a complete signal.

The sequence itself starts on the sequencer's own ``start`` service (one call for the
operator), or at once with ``auto_start``. ROS-free: the shell (``nodes/sequencer_node.py``)
calls the services the runtime asks for (``("call", (node, "start" | "abort"))`` outputs)
and hands it the answers and every ``status`` array.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

from lpv_sysid.configuration import parameters
from lpv_sysid.flight.excitation import reports_abort
from lpv_sysid.io import messages

#: node name -> (status key, values that confirm its start, what that means)
CONFIRM = {
    "mavlink_bridge": (
        "state",
        ("OFFBOARD_ACTIVE", "STREAMING"),
        "PX4 in OFFBOARD with setpoints streaming (MAVROS: streaming)",
    ),
    "lpv_controller": ("armed", ("true",), "the LPV law is commanding"),
    "excitation": ("phase", None, "the signal is playing"),
}
#: node name -> (status key, values that confirm it is ready, what that means) (``node:ready``)
READY = {
    "mavlink_bridge": ("link_up", ("true",), "MAVLink link to PX4 up"),
}
#: the phase-2 order (the sequencer's default)
PHASE2_STEPS = ("mavlink_bridge:ready", "lpv_controller", "mavlink_bridge", "excitation")
#: the phase-1 order
PHASE1_STEPS = ("mavlink_bridge", "excitation")
#: excitation phases that do not confirm a start
_NOT_PLAYING = ("waiting_for_start", "aborted", "aborting", "failed")

IDLE, STARTING, RUNNING, ABORTED = "idle", "starting", "running", "aborted"
#: the signal was flown to the end and the nodes were told to hand back / stop
COMPLETE = "complete"
#: the excitation phase of a signal played to its end (signals/excitation/player.py)
SIGNAL_DONE = "done"

Output = list[tuple[str, Any]]


@dataclass(frozen=True)
class SequencerSettings(parameters.Settings):
    """The parameters of sequencer_node, declared once."""

    WHERE = "sequencer"

    steps: tuple = parameters.texts(
        PHASE2_STEPS,
        "in order: 'node' (call its start, wait for its status to confirm) or 'node:ready' "
        "(wait for its status to say it is ready); nodes of this namespace",
    )
    auto_start: bool = parameters.flag(False, "run the sequence at once, without ~/start")
    step_timeout_s: float = parameters.double(
        30.0,
        "a node that has not confirmed its start after this aborts the sequence [s]",
        1.0,
        600.0,
    )
    hand_back_when_done: bool = parameters.flag(
        True,
        "once the excitation reports its signal done: hand back (bridge abort, PX4's mode "
        "confirmed), then stop the controller and the excitation",
    )
    rate_hz: float = parameters.double(10.0, "sequencing step rate [Hz]", 1.0, 100.0)
    status_rate_hz: float = parameters.double(1.0, "status publication rate [Hz]", 0.1, 100.0)

    def validate(self) -> None:
        if not self.steps:
            self.fail("steps must name at least one node")
        known = [*CONFIRM, *(f"{n}:ready" for n in READY)]
        unknown = [s for s in self.steps if s not in known]
        if unknown:
            self.fail(f"steps: unknown step(s) {unknown}; known: {known}")
        if len(set(self.steps)) != len(self.steps):
            self.fail(f"steps: a node is listed twice in {list(self.steps)}")


def split_step(step: str) -> tuple[str, str]:
    """``"node"`` -> ``(node, "start")``; ``"node:ready"`` -> ``(node, "ready")``."""
    node, _, action = step.partition(":")
    return node, action or "start"


def _rule(step: str) -> tuple:
    node, action = split_step(step)
    return READY[node] if action == "ready" else CONFIRM[node]


def confirmed(step: str, values: dict) -> bool:
    """Whether a node's status ``values`` confirm ``step`` (:data:`CONFIRM`, :data:`READY`;
    a MAVROS bridge, which has no link of its own, is ready at once)."""
    key, ok, _ = _rule(step)
    if step == "mavlink_bridge:ready" and values.get("transport") == "mavros":
        return True
    value = str(values.get(key, ""))
    if ok is None:
        return bool(value) and value not in _NOT_PLAYING
    return value.lower() in tuple(v.lower() for v in ok)


class SequencerRuntime:
    """See module docstring. ``service_ready(node, which)``: whether the node's ``start`` /
    ``abort`` service is available."""

    def __init__(
        self,
        settings: SequencerSettings,
        factory: messages.MsgFactory,
        name: str,
        service_ready: Callable[[str, str], bool],
    ) -> None:
        self.settings = settings
        self.f, self.name = factory, name
        self.service_ready = service_ready
        self.state = IDLE
        self.step = 0
        self.reason = ""
        self.started: list[str] = []  # nodes whose start was called
        self.values: dict[str, dict] = {}  # node -> last status values
        self._called_at: float | None = None
        self._log: list[tuple[str, str]] = []
        self._nodes = {split_step(s)[0] for s in settings.steps}

    def take_log(self) -> list[tuple[str, str]]:
        out, self._log = self._log, []
        return out

    # -- services -----------------------------------------------------------------------
    def start(self, now: float) -> tuple[bool, str, Output]:
        if self.state != IDLE:
            return False, f"sequence already {self.state}", []
        self.state, self.step, self._called_at = STARTING, 0, None
        self._log.append(("info", f"sequence: {' -> '.join(self.settings.steps)}"))
        return True, f"starting {' -> '.join(self.settings.steps)}", self.on_timer(now)

    def abort(self, now: float, reason: str = "abort service") -> tuple[bool, str, Output]:
        if self.state == ABORTED:
            return True, f"already aborted ({self.reason})", []
        self.state, self.reason = ABORTED, reason
        out: Output = [("call", (node, "abort")) for node in reversed(self.started)]
        self._log.append(
            ("error", f"sequence aborted: {reason}; abort sent to {list(reversed(self.started))}")
        )
        return True, f"aborted: {reason}", out + self.status(now)

    # -- inputs -------------------------------------------------------------------------
    def on_status(self, msg: Any, now: float) -> Output:
        """Every ``status`` array: the steps' values are kept; an abort reported by a node
        the sequence started aborts the sequence."""
        try:
            _, statuses = messages.status_from_diagnostic_array(msg)
        except messages.MessageError:
            return []
        for st in statuses:
            node = st.name.rstrip("/").rsplit("/", 1)[-1]
            if node not in self._nodes or st.name == self.name:
                continue
            self.values[node] = dict(st.values)
            if (
                self.state == RUNNING
                and self.settings.hand_back_when_done
                and node == "excitation"
                and node in self.started
                and str(st.values.get("phase", "")) == SIGNAL_DONE
            ):
                return self.complete(now)
            if self.state in (STARTING, RUNNING) and node in self.started and reports_abort(st):
                return self.abort(now, f"{st.name} reported an abort: {st.message}")[2]
        return []

    def complete(self, now: float) -> Output:
        """The signal was flown to its end: the bridge hands back first (the controller's
        commands still stream while PX4 switches), then the other started nodes stop, in
        reverse start order."""
        self.state, self.reason = COMPLETE, "signal complete"
        order = [n for n in self.started if n == "mavlink_bridge"] + [
            n for n in reversed(self.started) if n != "mavlink_bridge"
        ]
        self._log.append(
            ("info", f"signal complete: hand-back and stop sent to {order} in that order")
        )
        return [("call", (node, "abort")) for node in order] + self.status(now)

    def on_answer(self, node: str, which: str, success: bool, message: str, now: float) -> Output:
        """The answer of a service the runtime asked for."""
        self._log.append(("info" if success else "warn", f"{node}/{which}: {message}"))
        if which == "start" and not success and self.state == STARTING:
            return self.abort(now, f"{node} refused its start: {message}")[2]
        return []

    def on_timer(self, now: float) -> Output:
        if self.state != STARTING:
            return []
        steps = self.settings.steps
        step = steps[self.step]
        node, action = split_step(step)
        if self._called_at is None:
            if action == "ready":
                self._called_at = now
                self._log.append(("info", f"step {self.step + 1}/{len(steps)}: wait for {step}"))
            elif not self.service_ready(node, "start"):
                return []  # not up yet; the sequence waits (no timeout before the call)
            else:
                self._called_at = now
                if node not in self.started:
                    self.started.append(node)
                self._log.append(("info", f"step {self.step + 1}/{len(steps)}: start {node}"))
                return [("call", (node, "start"))] + self.status(now)
        if confirmed(step, self.values.get(node, {})):
            self._log.append(
                ("info", f"step {self.step + 1}/{len(steps)}: {step} confirmed ({_rule(step)[2]})")
            )
            self.step += 1
            self._called_at = None
            if self.step == len(steps):
                self.state = RUNNING
                self._log.append(("info", "sequence complete: every node started in order"))
                return self.status(now)
            return self.on_timer(now)
        if now - self._called_at > self.settings.step_timeout_s:
            key, _, meaning = _rule(step)
            got = self.values.get(node, {}).get(key, "no status")
            return self.abort(
                now,
                f"{step} not confirmed within {self.settings.step_timeout_s:g} s "
                f"(waiting for: {meaning}; {key}: {got})",
            )[2]
        return []

    def status(self, now: float) -> Output:
        steps = self.settings.steps
        if self.state == STARTING:
            message = f"step {self.step + 1}/{len(steps)}: waiting for {steps[self.step]}"
        elif self.state == ABORTED:
            message = f"aborted: {self.reason}"
        elif self.state == RUNNING:
            message = "running: every node started in order"
        elif self.state == COMPLETE:
            message = "complete: signal flown, hand-back sent"
        else:
            message = f"idle: call start to run {' -> '.join(steps)}"
        values = {
            "phase": self.state,
            "step": self.step,
            "steps": " -> ".join(steps),
            "started": " ".join(self.started),
            "reason": self.reason,
        }
        level = "ERROR" if self.state == ABORTED else "OK"
        st = messages.diagnostic_status(self.f, level, self.name, message, values)
        return [("status", messages.diagnostic_array(self.f, round(now * 1e9), [st]))]
