"""PX4 offboard state machine (pure: no I/O, no clock; ``now`` is always passed in).

::

    IDLE --start--> PRESTREAM --(> prestream_time of setpoints)--> SWITCHING
    SWITCHING --(OFFBOARD confirmed)--> ARMING (arm configured, disarmed) | OFFBOARD_ACTIVE
    ARMING --(armed confirmed)--> OFFBOARD_ACTIVE
    any streaming state --abort / finish / stale input / link loss / shutdown--> HANDBACK
    HANDBACK --(a mode of the chain confirmed)--> DONE (requested) | FAILED (fault, "warn")
    HANDBACK --(chain exhausted)--> FAILED ("error": "hand-back NOT confirmed ...")
    SWITCHING --(rejected / retries exhausted)--> FAILED (HANDBACK if the vehicle shows OFFBOARD)
    ARMING --(rejected / retries exhausted)--> HANDBACK
    OFFBOARD_ACTIVE --(vehicle left OFFBOARD by itself)--> FAILED (pilot or PX4 has it)
    OFFBOARD_ACTIVE --(vehicle disarmed: landed, auto-disarm)--> HANDBACK (PX4 would keep
                                                                 reporting OFFBOARD)

PX4 facts (v1.16): setpoints must stream at >= 2 Hz for > 1 s before OFFBOARD is
accepted; the switch is MAV_CMD_DO_SET_MODE (176) with param1 = 1
(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), param2 = main mode, param3 = sub mode; arming is
MAV_CMD_COMPONENT_ARM_DISARM (400) param1 = 1. DO_SET_MODE is answered twice
(:data:`lpv_sysid.mavlink.px4.DOUBLE_ACK_COMMANDS`): ACCEPTED at once from PX4's MAVLink
receiver, then the commander's verdict some ms later (TEMPORARILY_REJECTED for POSCTL
without stick input while armed, for instance); arming is answered once or twice. A
HEARTBEAT (1 Hz) is the only proof of the mode. While disarmed PX4 accepts every mode
(even OFFBOARD without a stream); the arming verdict then decides.

Truth rules:

- every COMMAND_ACK of the pending command is kept (``status()['acks']``); a rejection,
  also one after an ACCEPTED, is a failure of that step (TEMPORARILY_REJECTED of the
  OFFBOARD switch or of arming is retried up to ``max_retries``, other rejections are not);
- a step is *confirmed* only when no ACK of the current attempt rejected it,
  ``ack_settle_s`` passed since the last ACK (and since sending) without a new one, and a
  HEARTBEAT received after the command was first sent shows exactly the requested mode
  (or arming state). If the vehicle showed that state already before the command (e.g.
  the stale OFFBOARD PX4 keeps after an auto-disarm), the HEARTBEAT proves nothing and a
  final ACCEPTED is required as well;
- hand-back: the modes of ``handback_chain`` (default HOLD, then LAND) are tried in turn;
  a rejection, ``max_retries`` unanswered resends, or no confirmation within
  ``mode_confirm_timeout`` of the ACCEPTED moves on to the next mode. DONE / FAILED name
  the confirmed mode; when nothing is confirmed the machine ends FAILED with level
  ``error`` and the reason "hand-back NOT confirmed: ...; PX4 failsafe in charge";
- while the hand-back is in progress the transport's neutral setpoint (velocity: zero =
  brake and hover) keeps streaming at ``setpoint_rate_hz``, so the hand-back itself does
  not trigger PX4's offboard-loss failsafe (COM_OF_LOSS_T -> COM_OBL_RC_ACT, which without
  stick input is an uncontrolled descent for Position/Altitude/Stabilized); the stream
  stops once a mode is confirmed or the chain is exhausted. A transport without a neutral
  setpoint (attitude_rate) streams nothing and the failsafe is the backstop.

Inputs: :meth:`~OffboardMachine.start`, :meth:`~OffboardMachine.on_command`,
:meth:`~OffboardMachine.on_heartbeat`, :meth:`~OffboardMachine.on_ack`,
:meth:`~OffboardMachine.on_link`, :meth:`~OffboardMachine.abort`,
:meth:`~OffboardMachine.finish`, :meth:`~OffboardMachine.shutdown` and
:meth:`~OffboardMachine.step` at the caller's poll rate; :meth:`~OffboardMachine.status`
for diagnostics.

``finish(now, mode)`` ends a campaign in a chosen mode (e.g. LAND): from a streaming
state it hands back with ``mode`` first (then the rest of the chain), in HANDBACK it
re-targets, from IDLE / DONE / FAILED it requests ``mode`` with the same confirmation
rules (DONE names the confirmed mode). Landing awareness: after DONE / FAILED the machine
reports once, when the HEARTBEAT shows a vehicle that was armed during the run disarmed
(PX4 auto-disarms COM_DISARM_LAND after landing): a StatusEvent "vehicle disarmed in
<mode>" and ``status()['disarmed'] == 'True'``.
A vehicle seen out of OFFBOARD after DONE / FAILED that goes back to OFFBOARD (nobody
streams any more: PX4's offboard-loss failsafe acts) is reported each time, a StatusEvent
of level ``error`` "vehicle back in OFFBOARD after the run ended" and
``status()['reverted_to_offboard']`` counts it.

Outputs of :meth:`OffboardMachine.step` and the input methods are lists of
:class:`SendSetpoint`, :class:`SendCommand` and :class:`StatusEvent`.
"""

from __future__ import annotations

from lpv_sysid.mavlink.offboard.config import OffboardConfig
from lpv_sysid.mavlink.offboard.machine import OffboardMachine
from lpv_sysid.mavlink.offboard.state import (
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_SET_MODE,
    STREAMING,
    SendCommand,
    SendSetpoint,
    State,
    StatusEvent,
)

__all__ = [
    "MAV_CMD_COMPONENT_ARM_DISARM",
    "MAV_CMD_DO_SET_MODE",
    "OffboardConfig",
    "OffboardMachine",
    "STREAMING",
    "SendCommand",
    "SendSetpoint",
    "State",
    "StatusEvent",
]
