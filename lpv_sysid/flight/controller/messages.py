"""The controller's messages as arrays: its input topics parsed (:func:`parse_input`, and
:func:`parse_inputs` for a whole recording, the replay) and its ``actuator_command`` built
(:class:`CommandBuilder`). Field-level work goes through :mod:`lpv_sysid.io.messages`."""

from __future__ import annotations

from typing import Any

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.io.messages import (
    MsgFactory,
    actuator_command_msg,
    channels_from_joint_states,
    excitation_from_joint_state,
    joint_state,
    reference_from_twist,
    rotor_names_of,
    rotor_speeds_from_joint_state,
    odometry_cdr_frames,
    state_from_odometry,
    states_from_odometry,
)
from lpv_sysid.models.quadrotor import EXCITATION_NAMES, INPUT_NAMES, STATE_NAMES

INPUT_TOPICS = ("state", "rotor_speeds", "velocity_reference", "excitation")
OUTPUT_TOPICS = ("actuator_command", "status")
#: what the ``state`` topic contributes to the law's state (seed 0 Eq. 14 without position and
#: yaw): every entry of ``STATE_NAMES`` but the actuator states delta = Mix Omega (Eq. 7),
#: one per input, which the runtime computes from ``rotor_speeds``
BODY_STATE_NAMES = STATE_NAMES[: len(STATE_NAMES) - len(INPUT_NAMES)]


class CommandBuilder:
    """``actuator_command`` messages for the tick: the message of
    :func:`lpv_sysid.io.messages.actuator_command_msg` (``sensor_msgs/JointState``, the virtual
    channels ``INPUT_NAMES`` in ``position``) with the message classes looked up once.

    The command comes from the law, whose inputs are checked and whose output the mixer
    clips, so the per-message finiteness and duplicate-name checks of io.messages (5 of the
    7 us a message took) are not repeated; a stamp outside builtin_interfaces/Time goes
    through io.messages, which names the problem (test_nodes_controller compares both
    builders field by field).

    ``reuse``: one message, allocated here, is filled and returned by every call (stamp and
    ``position`` set; names, frame and the empty fields stay) -- for a caller that publishes
    each command before it asks for the next (the node: rclpy serialises on ``publish``)."""

    def __init__(
        self, factory: MsgFactory, names: tuple = INPUT_NAMES, reuse: bool = False
    ) -> None:
        self.f = factory
        self._time = factory.get("builtin_interfaces/msg/Time")
        self._header = factory.get("std_msgs/msg/Header")
        self._joint_state = factory.get("sensor_msgs/msg/JointState")
        #: the law's input names (the design's: ``ut, ua, ue, ur`` or the rate plant's
        #: ``thrust, p_sp, q_sp, r_sp``)
        self._names = [str(n) for n in names]
        self._seq = factory.float_seq
        self._msg = self._new(0, 0, np.zeros(len(self._names))) if reuse else None

    def __call__(self, stamp_ns: int, u: np.ndarray) -> Any:
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        if not -(2**31) <= sec < 2**31:
            if tuple(self._names) == tuple(INPUT_NAMES):
                return actuator_command_msg(self.f, stamp_ns, u)  # raises MessageError
            return joint_state(self.f, stamp_ns, self._names, position=u)  # raises MessageError
        msg = self._msg
        if msg is None:
            return self._new(sec, nanosec, u)
        stamp = msg.header.stamp
        stamp.sec = sec
        stamp.nanosec = nanosec
        msg.position = self._seq(u)
        return msg

    def _new(self, sec: int, nanosec: int, u: np.ndarray) -> Any:
        seq = self._seq
        return self._joint_state(
            header=self._header(stamp=self._time(sec=sec, nanosec=nanosec), frame_id=""),
            name=list(self._names),
            position=seq(u),
            velocity=seq([]),
            effort=seq([]),
        )


def parse_input(topic: str, msg) -> tuple[float, np.ndarray]:
    """``(header time [s], values)`` of one input message; MessageError when malformed.

    state: ``[phi, theta, u, v, w, p, q, r]`` (FRD); rotor_speeds: Omega (4);
    velocity_reference: ``[u_d, v_d, w_d, r_d]`` (FRD); excitation: u_e (4).
    """
    if topic == "state":
        s = state_from_odometry(msg)
        return s.t, np.concatenate([s.euler[:2], s.v_body, s.omega])
    if topic == "rotor_speeds":
        return rotor_speeds_from_joint_state(msg)
    if topic == "velocity_reference":
        t, v, r = reference_from_twist(msg)
        return t, np.append(v, r)
    if topic == "excitation":
        return excitation_from_joint_state(msg)
    raise ConfigError(f"lpv_controller: unknown input topic {topic!r}")


def parse_state_cdr(data: bytes) -> tuple[float, np.ndarray] | None:
    """:func:`parse_input` of a serialized ``state`` message (the node's raw subscription):
    the same ``(t, values)`` read from the CDR bytes; ``None`` when it needs the validating
    path (:func:`lpv_sysid.io.messages.odometry_cdr_frames`: deserialise it and call
    :func:`parse_input`); MessageError on a wrong frame or stamp."""
    got = odometry_cdr_frames(data)
    if got is None:
        return None
    ns, _, euler, v_frd, w_frd = got  # one array built, not four and their concatenation
    return ns / 1e9, np.array([euler[0], euler[1], *v_frd, *w_frd])


def parse_inputs(topic: str, msgs: list) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised :func:`parse_input` for a whole recording (replay); MessageError names
    the first malformed message."""
    if topic == "state":
        s = states_from_odometry(msgs)
        return s.t, np.column_stack([s.euler[:, :2], s.v_body, s.omega])
    names = {rotor_names_of(m.name) for m in msgs} if topic == "rotor_speeds" else set()
    if len(names) == 1:  # one source (measured or estimated) in the whole recording
        return channels_from_joint_states(msgs, names.pop(), field="velocity")
    if topic == "excitation":
        return channels_from_joint_states(msgs, EXCITATION_NAMES, field="position")
    t = np.empty(len(msgs))
    out = np.empty((len(msgs), 4))
    for i, m in enumerate(msgs):
        t[i], out[i] = parse_input(topic, m)
    return t, out
