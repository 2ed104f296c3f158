"""``sensor_msgs/JointState`` topics with named channels: ``rotor_speeds`` (rotor angular
speeds, measured or estimated), ``excitation`` (u_e) and ``actuator_command`` (virtual
inputs u). Virtual actuator channels are named in the seed's FRD sense and never frame
converted."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from lpv_sysid.io.messages.factory import MessageError, MsgFactory
from lpv_sysid.io.messages.fields import BASE_FRAME, finite, header_msg, stamp_ns_of
from lpv_sysid.models.quadrotor import EXCITATION_NAMES, INPUT_NAMES  # owner of the names

ROTOR_NAMES = ("rotor_1", "rotor_2", "rotor_3", "rotor_4")  # PX4 quad-X numbering
#: where rotor speeds come from: "esc" (measured, ESC telemetry) or "estimated" (motor
#: outputs through the motor model); the joint names tell them apart (``rotor_1`` measured,
#: ``rotor_1_estimated`` estimated); ``header.frame_id`` is a frame, ``base_link``, for both
ROTOR_SOURCES = ("esc", "estimated")
ROTOR_ESTIMATED_NAMES = tuple(f"{n}_estimated" for n in ROTOR_NAMES)
#: the frame_id that marked estimated speeds in recordings before issue 24 (still read)
ROTOR_ESTIMATED_FRAME = "estimated"

JOINT_STATE_FIELDS = ("position", "velocity", "effort")


def joint_state(
    f: MsgFactory,
    stamp_ns: int,
    names: Sequence[str],
    *,
    position=None,
    velocity=None,
    effort=None,
    frame_id: str = "",
):
    """``sensor_msgs/JointState`` with named channels; unused value arrays stay empty."""
    names = [str(n) for n in names]
    if len(set(names)) != len(names):
        raise MessageError(f"joint_state.name: duplicate names in {names}")
    vals = {}
    for key, v in zip(JOINT_STATE_FIELDS, (position, velocity, effort)):
        vals[key] = f.float_seq([] if v is None else finite(v, len(names), f"joint_state.{key}"))
    return f(
        "sensor_msgs/msg/JointState", header=header_msg(f, stamp_ns, frame_id), name=names, **vals
    )


def channels_from_joint_state(msg, names: Sequence[str], field: str = "position"):
    """``(t, values)`` of the channels ``names`` (in that order) from ``msg.<field>``.

    Raises :class:`MessageError` when a name is missing, the value array does not match
    ``msg.name`` or a value is not finite.
    """
    if field not in JOINT_STATE_FIELDS:
        raise MessageError(
            f"joint_state: field must be one of {JOINT_STATE_FIELDS}, got {field!r}"
        )
    have = list(msg.name)
    values = np.asarray(getattr(msg, field), dtype=float)
    if values.size != len(have):
        raise MessageError(
            f"joint_state.{field}: {values.size} values for {len(have)} names {have}"
        )
    index = {n: i for i, n in enumerate(have)}
    missing = [n for n in names if n not in index]
    if missing:
        raise MessageError(f"joint_state.name: missing channel(s) {missing}; message has {have}")
    out = values[[index[n] for n in names]]
    bad = [n for n, v in zip(names, out) if not np.isfinite(v)]
    if bad:
        raise MessageError(f"joint_state.{field}: non-finite value for channel(s) {bad}")
    ns = stamp_ns_of(msg)
    return ns / 1e9, out


def channels_from_joint_states(msgs: Sequence, names: Sequence[str], field: str = "position"):
    """Vectorised :func:`channels_from_joint_state`: ``(t (N,), values (N, len(names)))``."""
    n = len(msgs)
    t = np.empty(n)
    out = np.empty((n, len(names)))
    for i, msg in enumerate(msgs):
        try:
            t[i], out[i] = channels_from_joint_state(msg, names, field)
        except MessageError as exc:
            raise MessageError(f"message {i}: {exc}") from None
    return t, out


def rotor_speeds_msg(f: MsgFactory, stamp_ns: int, omega_rotors, source: str = "esc"):
    """``rotor_speeds``: rotor angular speeds Omega_1..4 (rad/s, PX4 numbering) in ``velocity``.

    ``source`` (:data:`ROTOR_SOURCES`) is carried in the joint names: :data:`ROTOR_NAMES`
    for measured speeds (ESC telemetry), :data:`ROTOR_ESTIMATED_NAMES` for speeds estimated
    from the motor outputs; ``header.frame_id`` is ``base_link`` (a frame, as TF-aware tools
    read it). Every consumer reads either (:func:`rotor_speeds_from_joint_state`).
    """
    if source not in ROTOR_SOURCES:
        raise MessageError(f"rotor_speeds: source must be one of {ROTOR_SOURCES}, got {source!r}")
    names = ROTOR_ESTIMATED_NAMES if source == "estimated" else ROTOR_NAMES
    return joint_state(f, stamp_ns, names, velocity=omega_rotors, frame_id=BASE_FRAME)


def rotor_names_of(names: Sequence[str]) -> tuple:
    """The rotor channel names a ``rotor_speeds`` message with joint names ``names`` carries:
    :data:`ROTOR_ESTIMATED_NAMES` when it has them, else :data:`ROTOR_NAMES`."""
    return ROTOR_ESTIMATED_NAMES if ROTOR_ESTIMATED_NAMES[0] in tuple(names) else ROTOR_NAMES


def rotor_speeds_from_joint_state(msg):
    """``(t, Omega(4))`` from a ``rotor_speeds`` JointState (either source)."""
    return channels_from_joint_state(msg, rotor_names_of(msg.name), field="velocity")


def rotor_source_of(msg) -> str:
    """``"estimated"`` when a ``rotor_speeds`` JointState carries estimated speeds (the
    joint names; ``header.frame_id: estimated`` in recordings before issue 24), else
    ``"esc"`` (measured)."""
    estimated = rotor_names_of(msg.name) is ROTOR_ESTIMATED_NAMES
    return "estimated" if estimated or msg.header.frame_id == ROTOR_ESTIMATED_FRAME else "esc"


def excitation_msg(f: MsgFactory, stamp_ns: int, u_e):
    """``excitation``: normalised excitation ``u_e`` (4) in ``position``."""
    return joint_state(f, stamp_ns, EXCITATION_NAMES, position=u_e)


def excitation_from_joint_state(msg):
    return channels_from_joint_state(msg, EXCITATION_NAMES, field="position")


def actuator_command_msg(f: MsgFactory, stamp_ns: int, u):
    """``actuator_command``: virtual command ``u = [ut, ua, ue, ur]`` (seed 0 Eq. 7) in
    ``position``."""
    return joint_state(f, stamp_ns, INPUT_NAMES, position=u)


def actuator_command_from_joint_state(msg):
    return channels_from_joint_state(msg, INPUT_NAMES, field="position")
