"""Column-wise message parsers: the parsers of :mod:`lpv_sysid.io.messages` for a whole
topic decoded column-wise.

Input is what :func:`lpv_sysid.io.bag.read_arrays` returns per topic (``fields``: numeric
leaf path -> (N,) or (N, k) array, ``strings``: string leaf path -> (N,) object array).
Output is the value of the per-message parser applied to every message, in the same
frames (conversions through :mod:`lpv_sysid.io.frames`), with the same checks: a failing
check raises :class:`~lpv_sysid.io.messages.MessageError` with ``row`` set to the earliest
offending message -- the one the per-message parser, applied in time order, would name
(test_dataprep_columns.py compares both on real bags).
"""

from __future__ import annotations

from typing import Callable, Mapping, Protocol, Sequence

import numpy as np

from lpv_sysid.io import frames
from lpv_sysid.io.messages.channels import (
    JOINT_STATE_FIELDS,
    ROTOR_ESTIMATED_FRAME,
    ROTOR_ESTIMATED_NAMES,
    ROTOR_NAMES,
    rotor_names_of,
)
from lpv_sysid.io.messages.factory import MessageError
from lpv_sysid.io.messages.fields import BASE_FRAME, ODOM_FRAME
from lpv_sysid.io.messages.state import ODOM_LEAVES, StateArrays, state_arrays
from lpv_sysid.models.quadrotor import EXCITATION_NAMES, INPUT_NAMES


class Columns(Protocol):
    """One topic decoded column-wise (what ``lpv_sysid.io.bag.TopicArrays`` holds)."""

    fields: Mapping[str, np.ndarray]
    strings: Mapping[str, np.ndarray]


class _FirstBad:
    """The failing check of the earliest message -- what the per-message parser, applied
    message by message in time order, raises first (for one message: the check it makes
    first). :meth:`check` registers a check (in the parser's order) by its row mask."""

    def __init__(self) -> None:
        self._order = 0
        self._best: tuple[int, int, str] | None = None

    def check(self, bad: np.ndarray, message: Callable[[int], str]) -> None:
        """``message(i)`` is made at once, for the first row ``i`` of ``bad``."""
        self._order += 1
        rows = np.flatnonzero(bad)
        if rows.size and (self._best is None or int(rows[0]) < self._best[0]):
            i = int(rows[0])
            self._best = (i, self._order, message(i))

    def raise_if_any(self) -> None:
        if self._best is not None:
            raise MessageError(self._best[2], row=self._best[0])


def _check_frames(
    bad: _FirstBad, cols: Columns, key: str, expected: str | None, what: str
) -> None:
    if expected is not None:
        have = cols.strings[key]
        bad.check(
            have != expected,
            lambda i: f"{what}[{i}]: expected frame_id {expected!r}, got {have[i]!r}",
        )


def _check_finite(bad: _FirstBad, a: np.ndarray, what: str) -> None:
    mask = ~np.isfinite(a)
    bad.check(
        mask.any(axis=1),
        lambda i: f"{what}[{i}]: non-finite value(s) at index {np.flatnonzero(mask[i]).tolist()}",
    )


def _column_stamps(bad: _FirstBad, cols: Columns, what: str) -> np.ndarray:
    """(N,) int64 nanoseconds of ``header.stamp`` (:func:`stamp_ns_from_time` per row)."""
    sec = np.asarray(cols.fields["header.stamp.sec"], dtype=np.int64)
    nsec = np.asarray(cols.fields["header.stamp.nanosec"], dtype=np.int64)
    bad.check(
        (nsec < 0) | (nsec >= 1_000_000_000),
        lambda i: f"{what}[{i}]: stamp: nanosec {nsec[i]} outside [0, 1e9)",
    )
    return sec * 1_000_000_000 + nsec


def stamps_ns_of_columns(cols: Columns, what: str = "message") -> np.ndarray:
    """(N,) int64 nanoseconds of ``header.stamp`` (:func:`stamp_ns_from_time` per row)."""
    bad = _FirstBad()
    ns = _column_stamps(bad, cols, what)
    bad.raise_if_any()
    return ns


def states_from_odometry_columns(
    cols: Columns, *, frame_id: str | None = ODOM_FRAME, child_frame_id: str | None = BASE_FRAME
) -> StateArrays:
    """:func:`state_from_odometry` of every message of ``nav_msgs/Odometry`` columns, as
    :class:`StateArrays` (the vectorised conversion of :func:`states_from_odometry`)."""
    bad = _FirstBad()
    _check_frames(bad, cols, "header.frame_id", frame_id, "state.header")
    _check_frames(bad, cols, "child_frame_id", child_frame_id, "state.child_frame_id")
    raw = np.column_stack([np.asarray(cols.fields[k], dtype=float) for k in ODOM_LEAVES])
    _check_finite(bad, raw[:, 0:3], "state.pose.pose.position")
    _check_finite(bad, raw[:, 3:7], "state.pose.pose.orientation")
    norm = np.linalg.norm(raw[:, 3:7], axis=1)
    bad.check(
        np.abs(norm - 1.0) > 1e-3,
        lambda i: (
            f"state.pose.pose.orientation[{i}]: not a unit quaternion (norm {norm[i]:.6g})"
        ),
    )
    _check_finite(bad, raw[:, 7:10], "state.twist.twist.linear")
    _check_finite(bad, raw[:, 10:13], "state.twist.twist.angular")
    ns = _column_stamps(bad, cols, "state")
    bad.raise_if_any()
    return state_arrays(ns, raw)


def channels_from_joint_state_columns(
    cols: Columns, names: Sequence[str], field: str = "position", pick=None
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`channels_from_joint_states` of ``sensor_msgs/JointState`` columns:
    ``(t (N,), values (N, len(names)))``; the channel order may differ between messages.
    ``pick(have)``: the channel names to read from messages whose names are ``have``
    (same count as ``names``; default: ``names``)."""
    if field not in JOINT_STATE_FIELDS:
        raise MessageError(
            f"joint_state: field must be one of {JOINT_STATE_FIELDS}, got {field!r}"
        )
    values = np.asarray(cols.fields[field], dtype=float)
    col_names = cols.strings["name"]
    n = col_names.size
    out = np.full((n, len(names)), np.nan)
    bad = _FirstBad()
    rest = np.arange(n)
    while rest.size:  # one pass per distinct name list (one, normally)
        cell = np.empty(1, dtype=object)
        cell[0] = have = tuple(col_names[rest[0]])
        hit = col_names[rest] == cell
        rows, rest = rest[hit], rest[~hit]
        in_group = np.zeros(n, bool)
        in_group[rows] = True
        index = {c: k for k, c in enumerate(have)}
        want = tuple(names) if pick is None else pick(have)
        missing = [c for c in want if c not in index]
        if values.shape[1] != len(have):
            bad.check(
                in_group,
                lambda i: (
                    f"message {i}: joint_state.{field}: {values.shape[1]} values for "
                    f"{len(have)} names {list(have)}"
                ),
            )
        elif missing:
            bad.check(
                in_group,
                lambda i: (
                    f"message {i}: joint_state.name: missing channel(s) {missing}; "
                    f"message has {list(have)}"
                ),
            )
        else:
            out[rows] = values[rows][:, [index[c] for c in want]]
            mask = in_group[:, None] & ~np.isfinite(out)
            bad.check(
                mask.any(axis=1),
                lambda i: (
                    f"message {i}: joint_state.{field}: non-finite value for channel(s) "
                    f"{[c for c, b in zip(names, mask[i]) if b]}"
                ),
            )
    ns = _column_stamps(bad, cols, "joint_state")
    bad.raise_if_any()
    return ns / 1e9, out


def rotor_speeds_from_joint_state_columns(cols: Columns) -> tuple[np.ndarray, np.ndarray]:
    """``(t, Omega (N, 4))`` of ``rotor_speeds`` columns (either source)."""
    return channels_from_joint_state_columns(
        cols, ROTOR_NAMES, field="velocity", pick=rotor_names_of
    )


def rotor_sources_of_columns(cols: Columns) -> np.ndarray:
    """(N,) :func:`rotor_source_of` of every message of ``rotor_speeds`` columns."""
    by_name = np.array(
        [rotor_names_of(n) is ROTOR_ESTIMATED_NAMES for n in cols.strings["name"]], dtype=bool
    ).reshape(-1)
    estimated = by_name | (cols.strings["header.frame_id"] == ROTOR_ESTIMATED_FRAME)
    return np.where(estimated, "estimated", "esc")


def excitation_from_joint_state_columns(cols: Columns) -> tuple[np.ndarray, np.ndarray]:
    return channels_from_joint_state_columns(cols, EXCITATION_NAMES, field="position")


def actuator_command_from_joint_state_columns(cols: Columns) -> tuple[np.ndarray, np.ndarray]:
    return channels_from_joint_state_columns(cols, INPUT_NAMES, field="position")


def reference_from_twist_columns(
    cols: Columns, *, frame_id: str | None = BASE_FRAME
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`reference_from_twist` of ``velocity_reference`` columns:
    ``(t (N,), v_d_frd (N, 3), r_d_frd (N,))``."""
    bad = _FirstBad()
    _check_frames(bad, cols, "header.frame_id", frame_id, "velocity_reference.header")
    lin = np.column_stack([cols.fields[f"twist.linear.{c}"] for c in "xyz"]).astype(float)
    ang = np.column_stack([cols.fields[f"twist.angular.{c}"] for c in "xyz"]).astype(float)
    _check_finite(bad, lin, "velocity_reference.twist.linear")
    _check_finite(bad, ang, "velocity_reference.twist.angular")
    ns = _column_stamps(bad, cols, "velocity_reference")
    bad.raise_if_any()
    return ns / 1e9, frames.flu_to_frd(lin), frames.flu_to_frd(ang)[:, 2]
