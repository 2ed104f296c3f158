"""Frame and attitude conventions: the only place NED/FRD and ENU/FLU meet.

Cores work in the seed's frames (seed 0 Sec. II): world ``F_I`` North-East-Down (NED),
body ``F_B`` Front-Right-Down (FRD). ROS topics follow REP-103: world East-North-Up (ENU,
``odom``), body Front-Left-Up (FLU, ``base_link``).

Attitude
    ``R_IB`` maps free vectors from the body to the world frame (seed 0 Eq. 1a, 1b),
    parameterised by the Euler angles ``Theta = [phi, theta, psi]`` as
    ``R_IB = Rz(psi) Ry(theta) Rx(phi)`` (seed 0, equation after Eq. 1). The Euler rates
    follow seed 0 Eq. (2): ``Theta_dot = L_IB(phi, theta) omega``.

Quaternions
    Hamilton convention, active rotation body -> world (``v_world = q v_body q*``).
    Functions in this module that take or return a quaternion without saying otherwise use
    the MAVLink/PX4 order ``(w, x, y, z)``; ROS messages (geometry_msgs/Quaternion) use
    ``(x, y, z, w)`` -- convert with :func:`xyzw_from_wxyz` / :func:`wxyz_from_xyzw`.
    Canonical quaternions returned here have ``w >= 0``.

ENU/FLU attitude (MAVROS / PX4 ros2 ``frame_transforms``)
    ``q_enu_flu = q_ned_to_enu * q_ned_frd * q_frd_to_flu``, i.e. as rotation matrices
    ``R_ENU_FLU = T_NED2ENU R_NED_FRD T_FRD2FLU`` with the (self-inverse) static transforms
    ``T_NED2ENU = [[0,1,0],[1,0,0],[0,0,-1]]`` and ``T_FRD2FLU = diag(1,-1,-1)``.
    Yaw 0 in NED (facing north) is therefore ENU yaw +90 deg.

Everything is vectorised: a vector argument may be ``(3,)`` or ``(N, 3)`` (any leading
shape), a quaternion ``(4,)`` or ``(N, 4)``, a rotation matrix ``(3, 3)`` or ``(N, 3, 3)``.
The quaternion algebra is written out here rather than delegated to
``scipy.spatial.transform.Rotation`` so that the tests can use scipy as an independent
oracle, and because the element orders and the ``w >= 0`` canonical form must be explicit.
"""

from __future__ import annotations

import math

import numpy as np

from lpv_sysid.errors import LpvSysidError


class FrameError(LpvSysidError, ValueError):
    """An array with the wrong shape, a non-finite value or an undefined conversion."""


# Static frame permutations (each is its own inverse).
T_NED_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
T_FRD_FLU = np.diag([1.0, -1.0, -1.0])


def _vec(a, n: int, what: str) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.ndim == 0 or a.shape[-1] != n:
        raise FrameError(f"{what}: expected shape (..., {n}), got {a.shape}")
    return a


def _mat3(a, what: str) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.ndim < 2 or a.shape[-2:] != (3, 3):
        raise FrameError(f"{what}: expected shape (..., 3, 3), got {a.shape}")
    return a


# --------------------------------------------------------------------------- vectors
def ned_to_enu(v) -> np.ndarray:
    """World vector NED -> ENU: ``(n, e, d) -> (e, n, -d)``."""
    v = _vec(v, 3, "ned_to_enu")
    return np.stack([v[..., 1], v[..., 0], -v[..., 2]], axis=-1)


def enu_to_ned(v) -> np.ndarray:
    """World vector ENU -> NED: ``(e, n, u) -> (n, e, -u)``."""
    v = _vec(v, 3, "enu_to_ned")
    return np.stack([v[..., 1], v[..., 0], -v[..., 2]], axis=-1)


def frd_to_flu(v) -> np.ndarray:
    """Body vector FRD -> FLU: ``(f, r, d) -> (f, -r, -d)``."""
    v = _vec(v, 3, "frd_to_flu")
    return v * np.array([1.0, -1.0, -1.0])


def flu_to_frd(v) -> np.ndarray:
    """Body vector FLU -> FRD: ``(f, l, u) -> (f, -l, -u)``."""
    v = _vec(v, 3, "flu_to_frd")
    return v * np.array([1.0, -1.0, -1.0])


# ----------------------------------------------------------------------- quaternions
def xyzw_from_wxyz(q) -> np.ndarray:
    """MAVLink order ``(w, x, y, z)`` -> ROS order ``(x, y, z, w)``."""
    q = _vec(q, 4, "xyzw_from_wxyz")
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def wxyz_from_xyzw(q) -> np.ndarray:
    """ROS order ``(x, y, z, w)`` -> MAVLink order ``(w, x, y, z)``."""
    q = _vec(q, 4, "wxyz_from_xyzw")
    return np.concatenate([q[..., 3:], q[..., :3]], axis=-1)


def quaternion_normalize(q) -> np.ndarray:
    """Unit quaternion ``(w, x, y, z)`` with ``w >= 0``; raises FrameError on a zero/NaN norm."""
    q = _vec(q, 4, "quaternion_normalize")
    n = np.sqrt(np.einsum("...i,...i->...", q, q))[..., None]
    if not np.isfinite(n).all() or (n < 1e-12).any():
        raise FrameError("quaternion_normalize: quaternion has zero or non-finite norm")
    q = q / n
    return np.where(q[..., :1] < 0.0, -q, q)


def quaternion_conjugate(q) -> np.ndarray:
    """Conjugate (= inverse for unit quaternions) of ``(w, x, y, z)``."""
    q = _vec(q, 4, "quaternion_conjugate")
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quaternion_multiply(a, b) -> np.ndarray:
    """Hamilton product ``a * b`` of ``(w, x, y, z)`` quaternions (rotation b, then a)."""
    a = _vec(a, 4, "quaternion_multiply(a)")
    b = _vec(b, 4, "quaternion_multiply(b)")
    aw, ax, ay, az = (a[..., i] for i in range(4))
    bw, bx, by, bz = (b[..., i] for i in range(4))
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quaternion_rotate(q, v) -> np.ndarray:
    """Rotate vector(s) ``v`` by the unit quaternion(s) ``q`` (``(w,x,y,z)``): ``q v q*``."""
    return np.einsum(
        "...ij,...j->...i", rotation_from_quaternion(q), _vec(v, 3, "quaternion_rotate")
    )


# ----------------------------------------------------------- Euler / rotation matrix
def rotation_from_euler(euler) -> np.ndarray:
    """``R_IB = Rz(psi) Ry(theta) Rx(phi)`` (seed 0, after Eq. 1) from ``[phi, theta, psi]``."""
    e = _vec(euler, 3, "rotation_from_euler")
    cf, sf = np.cos(e[..., 0]), np.sin(e[..., 0])
    ct, st = np.cos(e[..., 1]), np.sin(e[..., 1])
    cp, sp = np.cos(e[..., 2]), np.sin(e[..., 2])
    R = np.empty(e.shape[:-1] + (3, 3))
    R[..., 0, 0] = ct * cp
    R[..., 0, 1] = sf * st * cp - cf * sp
    R[..., 0, 2] = cf * st * cp + sf * sp
    R[..., 1, 0] = ct * sp
    R[..., 1, 1] = sf * st * sp + cf * cp
    R[..., 1, 2] = cf * st * sp - sf * cp
    R[..., 2, 0] = -st
    R[..., 2, 1] = sf * ct
    R[..., 2, 2] = cf * ct
    return R


def euler_from_rotation(R) -> np.ndarray:
    """Inverse of :func:`rotation_from_euler`: ``[phi, theta, psi]`` with ``theta`` in
    ``[-pi/2, pi/2]`` and ``phi, psi`` in ``(-pi, pi]``.

    At gimbal lock (``|theta| = pi/2``) only ``psi -/+ phi`` is defined; ``phi = 0`` is
    returned then.
    """
    R = _mat3(R, "euler_from_rotation")
    s = np.clip(-R[..., 2, 0], -1.0, 1.0)
    theta = np.arcsin(s)
    lock = np.abs(s) > 1.0 - 1e-12
    phi = np.where(lock, 0.0, np.arctan2(R[..., 2, 1], R[..., 2, 2]))
    psi = np.where(
        lock, np.arctan2(-R[..., 0, 1], R[..., 1, 1]), np.arctan2(R[..., 1, 0], R[..., 0, 0])
    )
    return np.stack([phi, theta, psi], axis=-1)


def rotation_from_quaternion(q) -> np.ndarray:
    """Rotation matrix of the unit quaternion ``(w, x, y, z)`` (normalised first)."""
    q = quaternion_normalize(q)
    w, x, y, z = (q[..., i] for i in range(4))
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def quaternion_from_rotation(R) -> np.ndarray:
    """Unit quaternion ``(w, x, y, z)``, ``w >= 0``, of a rotation matrix.

    Shepperd's method: the largest of ``w^2, x^2, y^2, z^2`` (read off the diagonal) is
    computed first, which keeps the division well conditioned for every rotation.
    """
    R = _mat3(R, "quaternion_from_rotation")
    m = R.reshape(-1, 3, 3)
    m00, m01, m02 = m[:, 0, 0], m[:, 0, 1], m[:, 0, 2]
    m10, m11, m12 = m[:, 1, 0], m[:, 1, 1], m[:, 1, 2]
    m20, m21, m22 = m[:, 2, 0], m[:, 2, 1], m[:, 2, 2]
    k = np.argmax(np.stack([m00 + m11 + m22, m00, m11, m22], axis=1), axis=1)
    # 4 * (largest component) from the diagonal; the other components from the
    # off-diagonal sums/differences divided by it (each branch is well conditioned).
    big = 0.5 * np.sqrt(
        np.maximum(
            np.choose(
                k,
                [
                    1.0 + m00 + m11 + m22,
                    1.0 + m00 - m11 - m22,
                    1.0 - m00 + m11 - m22,
                    1.0 - m00 - m11 + m22,
                ],
            ),
            1e-300,
        )
    )
    f = 0.25 / big
    d21, d02, d10 = m21 - m12, m02 - m20, m10 - m01
    s01, s02, s12 = m01 + m10, m02 + m20, m12 + m21
    q = np.stack(
        [
            np.choose(k, [big, d21 * f, d02 * f, d10 * f]),
            np.choose(k, [d21 * f, big, s01 * f, s02 * f]),
            np.choose(k, [d02 * f, s01 * f, big, s12 * f]),
            np.choose(k, [d10 * f, s02 * f, s12 * f, big]),
        ],
        axis=1,
    )
    return quaternion_normalize(q).reshape(R.shape[:-2] + (4,))


def quaternion_from_euler(euler) -> np.ndarray:
    """``q = q_z(psi) * q_y(theta) * q_x(phi)`` (``(w, x, y, z)``, ``w >= 0``) -- the
    quaternion of ``R_IB`` of seed 0 Eq. (1)."""
    e = _vec(euler, 3, "quaternion_from_euler")
    cf, sf = np.cos(e[..., 0] / 2), np.sin(e[..., 0] / 2)
    ct, st = np.cos(e[..., 1] / 2), np.sin(e[..., 1] / 2)
    cp, sp = np.cos(e[..., 2] / 2), np.sin(e[..., 2] / 2)
    q = np.stack(
        [
            cp * ct * cf + sp * st * sf,
            cp * ct * sf - sp * st * cf,
            cp * st * cf + sp * ct * sf,
            sp * ct * cf - cp * st * sf,
        ],
        axis=-1,
    )
    return np.where(q[..., :1] < 0.0, -q, q)


def euler_from_quaternion(q) -> np.ndarray:
    """``[phi, theta, psi]`` (seed 0 Eq. 1 parameterisation) of the quaternion ``(w,x,y,z)``."""
    return euler_from_rotation(rotation_from_quaternion(q))


# ------------------------------------------------------------- NED/FRD <-> ENU/FLU
Q_NED_TO_ENU = quaternion_from_rotation(T_NED_ENU)  # (0, sqrt(2)/2, sqrt(2)/2, 0)
Q_FRD_TO_FLU = quaternion_from_rotation(T_FRD_FLU)  # (0, 1, 0, 0)


def _left_matrix(a) -> np.ndarray:
    """4x4 matrix of ``q -> a * q`` (Hamilton product, ``(w,x,y,z)``)."""
    return np.stack([quaternion_multiply(a, e) for e in np.eye(4)], axis=1)


def _right_matrix(b) -> np.ndarray:
    """4x4 matrix of ``q -> q * b``."""
    return np.stack([quaternion_multiply(e, b) for e in np.eye(4)], axis=1)


# q -> q_ned_to_enu * q * q_frd_to_flu is linear in q: a constant orthogonal 4x4 matrix.
# Both static rotations are 180 deg turns (their own inverses up to sign), so the same
# matrix maps ENU/FLU back to NED/FRD (M @ M = I).
_M_ATTITUDE = _left_matrix(Q_NED_TO_ENU) @ _right_matrix(Q_FRD_TO_FLU)


def quaternion_enu_flu_from_ned_frd(q_ned_frd) -> np.ndarray:
    """Attitude NED/FRD -> ENU/FLU (both ``(w,x,y,z)``):
    ``q_enu_flu = q_ned_to_enu * q_ned_frd * q_frd_to_flu``."""
    q = _vec(q_ned_frd, 4, "quaternion_enu_flu_from_ned_frd")
    return quaternion_normalize(q @ _M_ATTITUDE.T)


def quaternion_ned_frd_from_enu_flu(q_enu_flu) -> np.ndarray:
    """Attitude ENU/FLU -> NED/FRD (both ``(w,x,y,z)``):
    ``q_ned_frd = q_ned_to_enu^-1 * q_enu_flu * q_frd_to_flu^-1``; the static transforms
    are 180 deg rotations, whose inverses equal them up to the sign of the quaternion."""
    q = _vec(q_enu_flu, 4, "quaternion_ned_frd_from_enu_flu")
    return quaternion_normalize(q @ _M_ATTITUDE.T)


def ros_orientation_from_euler(euler_ned) -> np.ndarray:
    """ROS ``geometry_msgs/Quaternion`` ``(x, y, z, w)`` of the ENU/FLU attitude from the
    seed's NED/FRD Euler angles ``[phi, theta, psi]``."""
    return xyzw_from_wxyz(quaternion_enu_flu_from_ned_frd(quaternion_from_euler(euler_ned)))


def euler_from_ros_orientation(q_xyzw) -> np.ndarray:
    """NED/FRD Euler angles ``[phi, theta, psi]`` from a ROS ENU/FLU ``(x, y, z, w)``."""
    return euler_from_quaternion(quaternion_ned_frd_from_enu_flu(wxyz_from_xyzw(q_xyzw)))


def odometry_ned_frd_from_ros_scalar(pos_enu, q_xyzw, v_flu, w_flu):
    """Scalar fast path of the Odometry conversion (one message at the controller's state
    rate): ENU position -> NED, ROS ENU/FLU orientation ``(x, y, z, w)`` -> NED/FRD Euler
    angles, FLU body velocity and rates -> FRD. Same conventions as :func:`enu_to_ned`,
    :func:`euler_from_ros_orientation` and :func:`flu_to_frd` (checked against them in
    test_frames.py); plain floats because numpy's per-call overhead dominates for 3-vectors.
    Returns four float tuples ``(pos_ned, euler, v_frd, w_frd)``."""
    e, n, u = pos_enu
    x, y, z, w = q_xyzw
    qw, qx, qy, qz = (float(c) for c in _attitude_map_scalar(w, x, y, z))
    norm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    _R, euler = rotation_euler_from_quaternion_scalar(qw / norm, qx / norm, qy / norm, qz / norm)
    return (
        (n, e, -u),
        tuple(euler.tolist()),
        (v_flu[0], -v_flu[1], -v_flu[2]),
        (w_flu[0], -w_flu[1], -w_flu[2]),
    )


_M_ATTITUDE_LIST = _M_ATTITUDE.tolist()


def _attitude_map_scalar(w: float, x: float, y: float, z: float):
    """``_M_ATTITUDE @ (w, x, y, z)`` on floats (the ENU/FLU <-> NED/FRD attitude map)."""
    return [r[0] * w + r[1] * x + r[2] * y + r[3] * z for r in _M_ATTITUDE_LIST]


# ------------------------------------------------------------------------ kinematics
def rotation_euler_from_quaternion_scalar(w: float, x: float, y: float, z: float):
    """R_IB (nested lists) and (phi, theta, psi) of a unit quaternion (w, x, y, z), on floats.

    Same convention as :func:`rotation_from_quaternion` / :func:`euler_from_rotation`
    (seed 0 Eq. 1), without validation or vectorisation: a hot path (one call per MAVLink
    attitude message) where the numpy versions cost ~40 us and this closed form ~3 us.
    test_mavlink_core.py checks it against the vectorised functions and scipy.
    """
    R = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    euler = np.array(
        [
            math.atan2(R[2][1], R[2][2]),
            math.asin(max(-1.0, min(1.0, -R[2][0]))),
            math.atan2(R[1][0], R[0][0]),
        ]
    )
    return R, euler


def kinematics_matrix(phi, theta) -> np.ndarray:
    """``L_IB(phi, theta)`` of seed 0 Eq. (2): ``Theta_dot = L_IB omega``.

    Shape ``(3, 3)`` for scalars, ``(N, 3, 3)`` for arrays. Undefined at
    ``cos(theta) = 0`` (gimbal lock): raises :class:`FrameError`.
    """
    phi = np.asarray(phi, dtype=float)
    theta = np.asarray(theta, dtype=float)
    phi, theta = np.broadcast_arrays(phi, theta)
    ct = np.cos(theta)
    if np.any(np.abs(ct) < 1e-9):
        raise FrameError("kinematics_matrix: L_IB (seed 0 Eq. 2) is singular at |theta| = pi/2")
    sf, cf, tt = np.sin(phi), np.cos(phi), np.tan(theta)
    L = np.zeros(phi.shape + (3, 3))
    L[..., 0, 0] = 1.0
    L[..., 0, 1] = sf * tt
    L[..., 0, 2] = cf * tt
    L[..., 1, 1] = cf
    L[..., 1, 2] = -sf
    L[..., 2, 1] = sf / ct
    L[..., 2, 2] = cf / ct
    return L


def euler_rates(euler, omega) -> np.ndarray:
    """``Theta_dot = L_IB(phi, theta) omega`` (seed 0 Eq. 2 / 3b); ``omega`` FRD body rates."""
    e = _vec(euler, 3, "euler_rates(euler)")
    w = _vec(omega, 3, "euler_rates(omega)")
    return np.einsum("...ij,...j->...i", kinematics_matrix(e[..., 0], e[..., 1]), w)


def body_to_world(v_body, euler) -> np.ndarray:
    """``q_dot = R_IB v`` (seed 0 Eq. 1a): FRD body vector -> NED world vector."""
    R = rotation_from_euler(euler)
    return np.einsum("...ij,...j->...i", R, _vec(v_body, 3, "body_to_world"))


def world_to_body(v_world, euler) -> np.ndarray:
    """``v = R_IB^T q_dot``: NED world vector -> FRD body vector."""
    R = rotation_from_euler(euler)
    return np.einsum("...ji,...j->...i", R, _vec(v_world, 3, "world_to_body"))


def wrap_angle(a) -> np.ndarray:
    """Wrap angle(s) to ``(-pi, pi]``."""
    a = np.asarray(a, dtype=float)
    w = np.mod(a + np.pi, 2 * np.pi) - np.pi
    return np.where(w == -np.pi, np.pi, w)
