"""io/frames.py: conventions against known values and scipy.spatial.transform as oracle."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lpv_sysid.errors import LpvSysidError
from lpv_sysid.io import frames as fr

RNG = np.random.default_rng(7)
DEG = np.pi / 180


def random_euler(n):
    return np.column_stack(
        [RNG.uniform(-np.pi, np.pi, n), RNG.uniform(-1.5, 1.5, n), RNG.uniform(-np.pi, np.pi, n)]
    )


def scipy_R(euler):
    """Independent oracle: intrinsic Z-Y'-X'' = Rz(psi) Ry(theta) Rx(phi)."""
    return Rotation.from_euler("ZYX", np.asarray(euler)[..., ::-1])


def same_quat(a, b, tol=1e-12):
    a, b = np.atleast_2d(a), np.atleast_2d(b)
    d = np.minimum(np.abs(a - b).max(axis=-1), np.abs(a + b).max(axis=-1))
    return np.all(d < tol)


# ------------------------------------------------------------------ vectors
def test_vector_permutations_known_values():
    np.testing.assert_array_equal(fr.ned_to_enu([1.0, 2.0, 3.0]), [2.0, 1.0, -3.0])
    np.testing.assert_array_equal(fr.enu_to_ned([2.0, 1.0, -3.0]), [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(fr.frd_to_flu([1.0, 2.0, 3.0]), [1.0, -2.0, -3.0])
    np.testing.assert_array_equal(fr.flu_to_frd([1.0, -2.0, -3.0]), [1.0, 2.0, 3.0])
    # 1 m/s north, descending 0.5 m/s: ENU east=0, north=1, up=-0.5
    np.testing.assert_array_equal(fr.ned_to_enu([1.0, 0.0, 0.5]), [0.0, 1.0, -0.5])


def test_vector_round_trip_vectorised():
    v = RNG.normal(size=(50, 3))
    np.testing.assert_array_equal(fr.enu_to_ned(fr.ned_to_enu(v)), v)
    np.testing.assert_array_equal(fr.flu_to_frd(fr.frd_to_flu(v)), v)
    assert fr.ned_to_enu(v).shape == (50, 3)


def test_vector_wrong_shape_raises():
    with pytest.raises(LpvSysidError, match="expected shape"):
        fr.ned_to_enu([1.0, 2.0])
    with pytest.raises(ValueError):
        fr.frd_to_flu(np.zeros((4, 2)))


# --------------------------------------------------------------- rotations
def test_rotation_from_euler_matches_scipy():
    e = random_euler(40)
    np.testing.assert_allclose(fr.rotation_from_euler(e), scipy_R(e).as_matrix(), atol=1e-14)
    R = fr.rotation_from_euler(e[0])
    assert R.shape == (3, 3)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-14)


def test_rotation_elementary_axes():
    # pure yaw +90: body x (front) points east in NED
    np.testing.assert_allclose(
        fr.rotation_from_euler([0, 0, np.pi / 2]) @ [1, 0, 0], [0, 1, 0], atol=1e-15
    )
    # pure pitch +30 deg (nose up): body x has negative down component
    x = fr.rotation_from_euler([0, 30 * DEG, 0]) @ [1, 0, 0]
    np.testing.assert_allclose(x, [np.cos(30 * DEG), 0, -np.sin(30 * DEG)], atol=1e-15)
    # pure roll +30 deg (right wing down): body y has positive down component
    y = fr.rotation_from_euler([30 * DEG, 0, 0]) @ [0, 1, 0]
    np.testing.assert_allclose(y, [0, np.cos(30 * DEG), np.sin(30 * DEG)], atol=1e-15)


def test_euler_rotation_round_trip_and_gimbal_lock():
    e = random_euler(60)
    np.testing.assert_allclose(fr.euler_from_rotation(fr.rotation_from_euler(e)), e, atol=1e-12)
    # at gimbal lock the angles are not unique but the rotation is
    lock = np.array([[0.3, np.pi / 2, -0.4], [0.2, -np.pi / 2, 1.0]])
    R = fr.rotation_from_euler(lock)
    e2 = fr.euler_from_rotation(R)
    np.testing.assert_allclose(fr.rotation_from_euler(e2), R, atol=1e-12)
    assert np.all(e2[:, 0] == 0.0)


def test_quaternion_from_euler_matches_scipy():
    e = random_euler(40)
    q = fr.quaternion_from_euler(e)
    assert np.all(q[:, 0] >= 0)
    assert same_quat(fr.xyzw_from_wxyz(q), scipy_R(e).as_quat())
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-15)


def test_quaternion_rotation_round_trips():
    e = random_euler(60)
    R = fr.rotation_from_euler(e)
    q = fr.quaternion_from_rotation(R)
    assert same_quat(q, fr.quaternion_from_euler(e))
    np.testing.assert_allclose(fr.rotation_from_quaternion(q), R, atol=1e-14)
    np.testing.assert_allclose(fr.euler_from_quaternion(q), e, atol=1e-12)
    # Shepperd branches: 180 deg rotations about each axis and identity
    for R0 in (np.eye(3), np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])):
        q0 = fr.quaternion_from_rotation(R0)
        np.testing.assert_allclose(fr.rotation_from_quaternion(q0), R0, atol=1e-15)
        assert same_quat(fr.xyzw_from_wxyz(q0), Rotation.from_matrix(R0).as_quat())


def test_quaternion_multiply_matches_scipy_composition():
    a, b = random_euler(20), random_euler(20)
    qa, qb = fr.quaternion_from_euler(a), fr.quaternion_from_euler(b)
    qab = fr.quaternion_multiply(qa, qb)
    oracle = (scipy_R(a) * scipy_R(b)).as_quat()
    assert same_quat(fr.xyzw_from_wxyz(qab), oracle)
    v = RNG.normal(size=(20, 3))
    np.testing.assert_allclose(
        fr.quaternion_rotate(qab, v), (scipy_R(a) * scipy_R(b)).apply(v), atol=1e-13
    )
    inv = fr.quaternion_multiply(qa, fr.quaternion_conjugate(qa))
    np.testing.assert_allclose(inv, np.tile([1.0, 0, 0, 0], (20, 1)), atol=1e-15)


def test_quaternion_order_conversion():
    q = np.array([0.1, 0.2, 0.3, 0.4])
    np.testing.assert_array_equal(fr.xyzw_from_wxyz(q), [0.2, 0.3, 0.4, 0.1])
    np.testing.assert_array_equal(fr.wxyz_from_xyzw(fr.xyzw_from_wxyz(q)), q)


def test_quaternion_normalize_rejects_zero_and_nan():
    with pytest.raises(LpvSysidError, match="norm"):
        fr.quaternion_normalize([0.0, 0, 0, 0])
    with pytest.raises(LpvSysidError):
        fr.rotation_from_quaternion([np.nan, 0, 0, 1])


# ----------------------------------------------------------- NED/FRD <-> ENU/FLU
def test_static_transform_quaternions():
    s = np.sqrt(0.5)
    assert same_quat(fr.Q_NED_TO_ENU, [0.0, s, s, 0.0])
    assert same_quat(fr.Q_FRD_TO_FLU, [0.0, 1.0, 0.0, 0.0])


def test_yaw_zero_ned_is_enu_yaw_plus_90():
    q = fr.ros_orientation_from_euler([0.0, 0.0, 0.0])
    r = Rotation.from_quat(q)  # scipy uses (x, y, z, w) like ROS
    np.testing.assert_allclose(r.as_euler("ZYX"), [np.pi / 2, 0, 0], atol=1e-14)
    # heading east in NED (psi = +90 deg) -> ENU yaw 0; heading west -> 180
    r = Rotation.from_quat(fr.ros_orientation_from_euler([0.0, 0.0, np.pi / 2]))
    np.testing.assert_allclose(r.as_euler("ZYX"), [0, 0, 0], atol=1e-14)


def test_enu_yaw_equals_90_minus_ned_yaw():
    for psi in np.linspace(-3, 3, 13):
        r = Rotation.from_quat(fr.ros_orientation_from_euler([0.0, 0.0, psi]))
        assert fr.wrap_angle(r.as_euler("ZYX")[0] - (np.pi / 2 - psi)) == pytest.approx(
            0, abs=1e-12
        )


def test_nose_up_and_right_wing_down_survive_conversion():
    # physical meaning: body forward axis points up in ENU for a nose-up pitch
    th = 20 * DEG
    r = Rotation.from_quat(fr.ros_orientation_from_euler([0.0, th, 0.4]))
    fwd = r.apply([1.0, 0, 0])  # FLU x in ENU
    assert fwd[2] == pytest.approx(np.sin(th), abs=1e-14)
    # ROS pitch about the left axis: nose up is negative pitch
    assert r.as_euler("ZYX")[1] == pytest.approx(-th, abs=1e-14)
    # right wing down (phi > 0): the FLU left axis points up
    ph = 15 * DEG
    r = Rotation.from_quat(fr.ros_orientation_from_euler([ph, 0.0, 0.0]))
    assert r.apply([0, 1.0, 0])[2] == pytest.approx(np.sin(ph), abs=1e-14)
    assert r.as_euler("ZYX")[2] == pytest.approx(ph, abs=1e-14)


def test_enu_flu_attitude_maps_vectors_consistently():
    # v_enu = R_ENU_FLU v_flu must equal ned_to_enu(R_NED_FRD flu_to_frd(v_flu))
    e = random_euler(30)
    v_flu = RNG.normal(size=(30, 3))
    r = Rotation.from_quat(fr.ros_orientation_from_euler(e))
    expected = fr.ned_to_enu(fr.body_to_world(fr.flu_to_frd(v_flu), e))
    np.testing.assert_allclose(r.apply(v_flu), expected, atol=1e-13)


def test_ros_orientation_round_trip():
    e = random_euler(60)
    q = fr.ros_orientation_from_euler(e)
    assert q.shape == (60, 4)
    np.testing.assert_allclose(fr.euler_from_ros_orientation(q), e, atol=1e-12)
    qn = fr.quaternion_from_euler(e)
    assert same_quat(
        fr.quaternion_ned_frd_from_enu_flu(fr.quaternion_enu_flu_from_ned_frd(qn)), qn
    )


# ------------------------------------------------------------------ kinematics
def test_kinematics_matrix_is_inverse_of_rate_map():
    # Independent derivation: omega = W(phi, theta) Theta_dot with
    # W = [[1, 0, -sin th], [0, cos ph, sin ph cos th], [0, -sin ph, cos ph cos th]]
    for phi, th in [(0.3, -0.4), (-1.0, 1.2), (2.5, 0.1)]:
        W = np.array(
            [
                [1, 0, -np.sin(th)],
                [0, np.cos(phi), np.sin(phi) * np.cos(th)],
                [0, -np.sin(phi), np.cos(phi) * np.cos(th)],
            ]
        )
        np.testing.assert_allclose(fr.kinematics_matrix(phi, th) @ W, np.eye(3), atol=1e-13)
    L = fr.kinematics_matrix(np.array([0.1, 0.2]), np.array([0.3, 0.4]))
    assert L.shape == (2, 3, 3)


def test_euler_rates_match_finite_difference_of_R():
    # Eq. (1b): R_dot = R [omega x]; integrate one tiny step and compare Theta_dot
    e = np.array([0.3, -0.5, 1.1])
    w = np.array([0.4, -0.2, 0.7])
    h = 1e-6
    skew = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    R = fr.rotation_from_euler(e)
    Rp = R @ Rotation.from_rotvec(w * h).as_matrix()
    Rm = R @ Rotation.from_rotvec(-w * h).as_matrix()
    fd = (fr.euler_from_rotation(Rp) - fr.euler_from_rotation(Rm)) / (2 * h)
    np.testing.assert_allclose(fr.euler_rates(e, w), fd, atol=1e-7)
    np.testing.assert_allclose((Rp - Rm) / (2 * h), R @ skew, atol=1e-7)


def test_kinematics_matrix_gimbal_lock_raises():
    with pytest.raises(LpvSysidError, match="singular"):
        fr.kinematics_matrix(0.0, np.pi / 2)


def test_body_world_velocity():
    e = random_euler(25)
    v = RNG.normal(size=(25, 3))
    np.testing.assert_allclose(fr.body_to_world(v, e), scipy_R(e).apply(v), atol=1e-13)
    np.testing.assert_allclose(fr.world_to_body(fr.body_to_world(v, e), e), v, atol=1e-13)
    # forward flight at 5 m/s with yaw 90 deg: moving east
    np.testing.assert_allclose(
        fr.body_to_world([5.0, 0, 0], [0, 0, np.pi / 2]), [0, 5.0, 0], atol=1e-14
    )


def test_body_forward_frd_is_flu_x():
    np.testing.assert_array_equal(fr.frd_to_flu([3.0, 0.0, 0.0]), [3.0, 0.0, 0.0])
    # yaw rate: positive r (FRD, nose right) is negative FLU z rate
    np.testing.assert_array_equal(fr.frd_to_flu([0.0, 0.0, 0.5]), [0.0, 0.0, -0.5])


def test_wrap_angle():
    np.testing.assert_allclose(
        fr.wrap_angle([3 * np.pi, -np.pi, 0.5, -7.0]),
        [np.pi, np.pi, 0.5, -7.0 + 2 * np.pi],
        atol=1e-14,
    )


def test_scalar_quaternion_rotation_matches_vectorised_and_scipy():
    """The hot-path scalar closed form equals the vectorised functions and scipy."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(7)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        R, euler = fr.rotation_euler_from_quaternion_scalar(*map(float, q))
        np.testing.assert_allclose(np.array(R), fr.rotation_from_quaternion(q), atol=1e-12)
        np.testing.assert_allclose(
            np.array(R), Rotation.from_quat(q[[1, 2, 3, 0]]).as_matrix(), atol=1e-12
        )
        np.testing.assert_allclose(euler, fr.euler_from_quaternion(q), atol=1e-9)


def test_scalar_odometry_conversion_matches_the_vectorised_functions():
    rng = np.random.default_rng(11)
    for _ in range(50):
        pos, v, w = rng.normal(size=(3, 3))
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        pos_ned, euler, v_frd, w_frd = fr.odometry_ned_frd_from_ros_scalar(
            pos.tolist(), q.tolist(), v.tolist(), w.tolist()
        )
        np.testing.assert_allclose(pos_ned, fr.enu_to_ned(pos), atol=1e-15)
        np.testing.assert_allclose(euler, fr.euler_from_ros_orientation(q), atol=1e-9)
        np.testing.assert_allclose(v_frd, fr.flu_to_frd(v), atol=1e-15)
        np.testing.assert_allclose(w_frd, fr.flu_to_frd(w), atol=1e-15)
