"""State, input and channel layouts of the seed 0 quadrotor and the map between them.

Frames: NED world frame F_I, FRD body frame F_B (seed 0 Sec. II).

Full state (16, ``FULL_STATE_NAMES``): position NED, Euler angles, body velocity, body
rates, rotor speeds Omega_1..4 (PX4 quad-X numbering: 1 front-right CCW, 2 rear-left CCW,
3 front-left CW, 4 rear-right CW). Controller state (12, ``STATE_NAMES``, seed 0 Eq. 14
without position and yaw) replaces Omega by the virtual actuators delta = Mix Omega
(:func:`mixer`, Eq. 7; its first row is 1/4 [1 1 1 1], the seed's pdf shows a fifth
entry, a typo). The rigid-body part of the controller state is its first 8 entries
(phi, theta, u, v, w, p, q, r).
"""

from __future__ import annotations

import math

import numpy as np

from lpv_sysid.models.quadrotor.params import QuadrotorParams

STATE_NAMES = ("phi", "theta", "u", "v", "w", "p", "q", "r", "dt", "da", "de", "dr")
STATE_UNITS = (
    "rad",
    "rad",
    "m/s",
    "m/s",
    "m/s",
    "rad/s",
    "rad/s",
    "rad/s",
    "rad/s",
    "m*rad/s",
    "m*rad/s",
    "rad/s",
)
INPUT_NAMES = ("ut", "ua", "ue", "ur")
INPUT_UNITS = ("1", "m", "m", "1")
FULL_STATE_NAMES = (
    "x",
    "y",
    "z",
    "phi",
    "theta",
    "psi",
    "u",
    "v",
    "w",
    "p",
    "q",
    "r",
    "Omega1",
    "Omega2",
    "Omega3",
    "Omega4",
)
SCHEDULING_NAMES = ("u_d", "v_d", "w_d")
EXCITATION_NAMES = ("ue_t", "ue_a", "ue_e", "ue_r")
#: sqrt(2) / 2: the arm's projection on the body axes of the quad-X frame (Eq. 7)
HALF_SQRT2 = math.sqrt(2.0) / 2.0
# Indices into the 12-entry controller state (STATE_NAMES).
I_PHI, I_THETA, I_U, I_V, I_W, I_P, I_Q, I_R, I_DT, I_DA, I_DE, I_DR = range(12)


def mixer(arm_length: float) -> np.ndarray:
    """Mix of seed 0 Eq. (7) for the PX4 quad-X rotor numbering."""
    s = arm_length * HALF_SQRT2
    return np.array(
        [[0.25, 0.25, 0.25, 0.25], [-s, s, s, -s], [s, -s, s, -s], [1.0, 1.0, -1.0, -1.0]]
    )


def reduced_state(x16: np.ndarray, arm_length: float = QuadrotorParams.arm_length) -> np.ndarray:
    """x16 (FULL_STATE_NAMES) -> controller state (STATE_NAMES), delta = Mix Omega (Eq. 7)."""
    x16 = np.asarray(x16, dtype=float)
    if x16.shape[-1] != 16:
        raise ValueError(f"reduced_state: expected 16 states, got shape {x16.shape}")
    delta = x16[..., 12:16] @ mixer(arm_length).T
    return np.concatenate([x16[..., 3:5], x16[..., 6:12], delta], axis=-1)


def full_state(
    controller_state: np.ndarray,
    pos_ned=0.0,
    psi: float = 0.0,
    arm_length: float = QuadrotorParams.arm_length,
) -> np.ndarray:
    """Controller state (STATE_NAMES) -> x16 with the given NED position and yaw;
    Omega = Mix^-1 delta."""
    controller_state = np.asarray(controller_state, dtype=float)
    if controller_state.shape != (12,):
        raise ValueError(f"full_state: expected 12 states, got shape {controller_state.shape}")
    out = np.zeros(16)
    out[0:3] = np.broadcast_to(np.asarray(pos_ned, dtype=float), (3,))
    out[3:5] = controller_state[0:2]
    out[5] = psi
    out[6:12] = controller_state[2:8]
    out[12:16] = np.linalg.solve(mixer(arm_length), controller_state[8:12])
    return out
