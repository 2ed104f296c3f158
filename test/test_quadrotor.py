"""Seed 0 quadrotor model: Eqs. (2), (3), (6)-(8), trims (Table 1) and Jacobians (Eqs. 10-16)."""

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from lpv_sysid.errors import ConfigError, SolverError
from lpv_sysid.models.quadrotor import (
    DEFAULT_K,
    K_NAMES,
    Quadrotor,
    QuadrotorParams,
    full_state,
    mixer,
    reduced_state,
)

Q = Quadrotor()
P = Q.params
# PX4 quad-X rotor positions (FRD) and spin directions: 1 FR CCW, 2 RL CCW, 3 FL CW, 4 RR CW
S = P.arm_length / math.sqrt(2)
POS = np.array([[S, S, 0], [-S, -S, 0], [S, -S, 0], [-S, S, 0]])
CCW = np.array([1, 1, -1, -1])


def test_mixer_matches_rotor_geometry_and_inverts():
    M = mixer(P.arm_length)
    assert np.allclose(M[0], 0.25)
    assert np.allclose(M @ Q.mix_inv, np.eye(4), atol=1e-12)
    # roll moment of thrusts T_i along -z at r_i: (r x F)_x = -y_i T_i -> delta_a row
    T = np.array([1.0, 2.0, 3.0, 4.0])
    moment = np.cross(POS, np.c_[np.zeros(4), np.zeros(4), -T]).sum(axis=0)
    assert M[1] @ T == pytest.approx(moment[0])
    assert M[2] @ T == pytest.approx(moment[1])
    assert np.allclose(M[3], CCW)


def test_hover_forces_from_independent_rotor_sum():
    Om = np.array([600.0, 610.0, 590.0, 605.0])
    F, Mo = Q.forces_moments([0, 0, 0], [0, 0, 0], Om)
    # delta_t^2 = mean(Omega^2), so F_z = K_zT0 mean(Omega^2) at zero airspeed
    assert F[2] == pytest.approx(P.K["z_T0"] * np.mean(Om**2))
    # roll/pitch moments of the independent rotor sum with per-rotor thrust K_lT0 Omega^2
    thrust = P.K["l_T0"] * Om**2
    mom = np.cross(POS, np.c_[np.zeros(4), np.zeros(4), -thrust]).sum(axis=0)
    assert Mo[0] == pytest.approx(mom[0], rel=1e-12)
    assert Mo[1] == pytest.approx(mom[1], rel=1e-12)
    assert Mo[2] == pytest.approx(P.K["n_Q0"] * (CCW @ Om**2), rel=1e-12)


def test_gravity_and_position_kinematics_frames():
    x = np.zeros(16)
    x[3:6] = [0.3, -0.2, math.pi / 2]
    x[6:9] = [1.0, 0.0, 0.0]
    xd = Q.derivatives(x, np.zeros(4))
    R = Rotation.from_euler("ZYX", [math.pi / 2, -0.2, 0.3]).as_matrix()  # R_IB
    assert np.allclose(xd[0:3], R @ [1.0, 0.0, 0.0], atol=1e-12)
    # nose north->east after +90 deg yaw: moving forward goes east in NED
    assert xd[1] == pytest.approx(math.cos(-0.2))
    # rotors stopped: gravity in body R^T g e3 plus the u-dependent terms of Eq. (6a, 6c)
    g_body = R.T @ [0, 0, P.g]
    aero = np.array([P.K["x_mu0"], 0.0, P.K["z_mu"]]) / P.mass
    assert np.allclose(xd[6:9], g_body + aero, atol=1e-12)
    x[6:9] = 0.0
    assert np.allclose(Q.derivatives(x, np.zeros(4))[6:9], g_body, atol=1e-12)


def test_euler_kinematics_eq2_against_rotation_derivative():
    phi, th, psi = 0.4, -0.3, 1.0
    om = np.array([0.3, -0.5, 0.7])
    x = np.zeros(16)
    x[3:6] = [phi, th, psi]
    x[9:12] = om
    x[12:16] = P.omega_min
    rates = Q.derivatives(x, Q.mix @ np.full(4, P.a_omega * P.omega_min / P.b_omega))[3:6]
    h = 1e-6
    R0 = Rotation.from_euler("ZYX", [psi, th, phi])
    R1 = R0 * Rotation.from_rotvec(om * h)  # R-dot = R [omega x] (Eq. 1b)
    ypr = R1.as_euler("ZYX")
    assert np.allclose((np.array([ypr[2], ypr[1], ypr[0]]) - [phi, th, psi]) / h, rates, atol=1e-5)


def test_hover_trim_is_level_with_equal_rotors():
    tr = Q.trim([0, 0, 0])
    om_h = math.sqrt(P.mass * P.g / -P.K["z_T0"])  # z_mu0 = 0 in the defaults
    assert tr.x0[0] == pytest.approx(0, abs=1e-9) and tr.x0[1] == pytest.approx(0, abs=1e-9)
    assert np.allclose(tr.full_state[12:], om_h, rtol=1e-8)
    assert 580 < om_h < 630
    assert np.allclose(tr.u0, [P.a_omega * om_h / P.b_omega, 0, 0, 0], atol=1e-9)
    assert np.max(np.abs(Q.derivatives(tr.full_state, tr.u0)[3:])) < 1e-8


@pytest.mark.parametrize("axis", [0, 1])
def test_trim_symmetry(axis):
    v = np.zeros(3)
    v[axis] = 5.0
    a, b = Q.trim(v), Q.trim(-v)
    ang = 1 if axis == 0 else 0  # u -> theta, v -> phi
    assert a.x0[ang] == pytest.approx(-b.x0[ang], rel=1e-7)
    assert abs(a.x0[ang]) > math.radians(2)
    assert a.x0[8] == pytest.approx(b.x0[8], rel=1e-9)
    # forward flight pitches nose down, flight to the right rolls right
    assert (a.x0[1] < 0) if axis == 0 else (a.x0[0] > 0)


SEED_TABLE1 = {  # vertex -> (phi0, theta0 [deg], delta_t0 [rad/s]) of seed 0 Table 1
    (-5, -5, -5): (-10.87, 9.28, 691.4),
    (5, -5, -5): (-10.44, -8.05, 685.0),
    (-5, 5, -5): (8.55, 8.11, 689.0),
    (5, 5, -5): (8.04, -8.98, 679.5),
    (-5, -5, 5): (-5.00, 3.17, 554.9),
    (5, -5, 5): (-5.14, -4.08, 521.8),
    (-5, 5, 5): (3.80, 3.00, 546.9),
    (5, 5, 5): (3.85, -4.83, 525.8),
}


@pytest.mark.parametrize("vertex", list(SEED_TABLE1))
def test_vertex_trims_resemble_seed_table1(vertex):
    tr = Q.trim(vertex)
    assert np.max(np.abs(Q.derivatives(tr.full_state, tr.u0)[3:])) < 1e-7
    phi, th, dt0 = SEED_TABLE1[vertex]
    assert math.degrees(tr.x0[0]) == pytest.approx(phi, abs=2.0)
    assert math.degrees(tr.x0[1]) == pytest.approx(th, abs=1.5)
    assert tr.x0[8] == pytest.approx(dt0, abs=25.0)
    assert np.all(tr.full_state[12:] < P.omega_max)


def test_yaw_rate_trim_is_a_steady_turn():
    tr = Q.trim([4, 1, -1], yaw_rate=0.4)
    xd = Q.derivatives(tr.full_state, tr.u0)
    assert np.max(np.abs(xd[3:5])) < 1e-9 and np.max(np.abs(xd[6:])) < 1e-7
    assert xd[5] == pytest.approx(0.4, rel=1e-9)  # psi-dot, Eq. (2)


def test_trim_outside_rotor_limits_raises():
    with pytest.raises(SolverError, match="rotor"):
        Q.trim([0, 0, -25])


def _fd_jacobians(x, u):
    A = np.zeros((12, 12))
    B = np.zeros((12, 4))
    for j in range(12):
        h = 1e-6 * max(1.0, abs(x[j]))
        e = np.zeros(12)
        e[j] = h
        A[:, j] = (Q.derivatives12(x + e, u) - Q.derivatives12(x - e, u)) / (2 * h)
    for j in range(4):
        e = np.zeros(4)
        e[j] = 1e-7
        B[:, j] = (Q.derivatives12(x, u + e) - Q.derivatives12(x, u - e)) / 2e-7
    return A, B


@pytest.mark.parametrize(
    "vd,yaw_rate,pert",
    [
        ([0, 0, 0], 0.0, 0.0),
        ([5, -5, -5], 0.0, 0.0),
        ([-5, 5, 5], 0.0, 1.0),
        ([3, 1, -2], 0.3, 1.0),
    ],
)
def test_analytic_jacobians_match_finite_differences(vd, yaw_rate, pert):
    tr = Q.trim(vd, yaw_rate=yaw_rate)
    x = tr.x0 + pert * np.r_[0.05, -0.03, 0.2, -0.1, 0.1, 0.1, -0.2, 0.15, 5, 3, -2, 8]
    A, B = Q.linearize(x)
    An, Bn = _fd_jacobians(x, tr.u0)
    # per element: relative 1e-6 against the row scale (the rows mix 1e0 and 1e4 entries)
    for M, Mn in ((A, An), (B, Bn)):
        scale = np.maximum(np.max(np.abs(Mn), axis=1, keepdims=True), 1e-3)
        assert np.all(np.abs(M - Mn) <= 1e-6 * scale + 1e-9), np.max(np.abs(M - Mn) / scale)


def test_linearize_actuator_rows_and_trim_equilibrium():
    tr = Q.trim([5, 5, 5])
    A, B = Q.linearize(tr)
    assert np.allclose(A[8:, 8:], -P.a_omega * np.eye(4))
    assert np.allclose(B[8:], P.b_omega * np.eye(4))
    assert np.allclose(A[8:, :8], 0)
    assert np.max(np.abs(Q.derivatives12(tr.x0, tr.u0))) < 1e-7


def test_unknown_masks_structure():
    mA, mB = Q.unknown_masks()
    assert not mA[0:2].any() and not mA[8:].any()  # kinematics, motors known
    assert not mA[2:5, 0:2].any()  # gravity known
    assert mA[2, 2] and mA[3, 3] and mA[4, 4] and mA[4, 8]  # drag, inflow, thrust
    assert not mA[2, 3] and not mA[2, 7]  # Coriolis only (v r, no aero)
    assert mA[5, 9] and mA[6, 10] and mA[7, 11]  # control effectiveness
    assert mB.sum() == 1 and mB[7, 3]  # J_z delta_r-dot only
    # an element outside the mask does not change when all K are perturbed
    Kp = {k: v * 1.3 + 1e-6 for k, v in DEFAULT_K.items()}
    Q2 = Quadrotor(QuadrotorParams(K=Kp, j_rotor=P.j_rotor * 1.3))
    x = Q.trim([5, -5, 5]).x0
    A1, B1 = Q.linearize(x)
    A2, B2 = Q2.linearize(x)
    assert np.allclose(A1[~mA], A2[~mA]) and np.allclose(B1[~mB], B2[~mB])
    changed = ~np.isclose(A1, A2)
    assert not (changed & ~mA).any() and changed[mA].sum() > 0.8 * mA.sum()


def test_motor_step_time_constant():
    """Rotor speed after a u_ESC step follows exp(-a t) (Eq. 8): 63.2 % at t = 1/a."""
    tr = Q.trim([0, 0, 0])
    u_esc = np.full(4, 0.6)
    sol = solve_ivp(
        lambda t, x: Q.derivatives(x, Q.mix @ u_esc),
        (0, 1 / P.a_omega),
        tr.full_state,
        rtol=1e-10,
        atol=1e-8,
    )
    om0 = tr.full_state[12]
    om_ss = P.b_omega * 0.6 / P.a_omega
    frac = (sol.y[12, -1] - om0) / (om_ss - om0)
    assert frac == pytest.approx(1 - math.exp(-1), abs=1e-6)


def test_u_esc_clipped_and_rotor_limits():
    assert np.allclose(Q.u_esc([2.0, 0, 0, 0]), 1.0)
    x = Q.trim([0, 0, 0]).full_state
    x[12:] = P.omega_max
    assert np.all(Q.derivatives(x, [1.0, 0, 0, 0])[12:] == 0.0)


def test_state_conversions_round_trip():
    controller_state = Q.trim([1, 2, -1]).x0
    assert np.allclose(reduced_state(full_state(controller_state, psi=0.4)), controller_state)


def test_params_validation_names_the_field():
    with pytest.raises(ConfigError, match="K"):
        QuadrotorParams.from_dict({"K": {"x_bogus": 1.0}})
    with pytest.raises(ConfigError, match="mass"):
        QuadrotorParams.from_dict({"mass": -1.0})
    with pytest.raises(ConfigError, match="inertia"):
        QuadrotorParams.from_dict({"inertia": [[1, 0], [0, 1]]})
    with pytest.raises(ConfigError, match="unknown key"):
        QuadrotorParams.from_dict({"masss": 1.0})
    p = QuadrotorParams.from_dict(QuadrotorParams().to_dict())
    assert p == QuadrotorParams() and set(p.K) == set(K_NAMES)
