"""TRMS (seed 2, Rotondo et al. 2013): nonlinear model, quasi-LPV embedding, polytope, LPV
control."""

import math

import numpy as np
import pytest

from lpv_sysid.errors import ConfigError
from lpv_sysid.models.lpv import box_vertices
from lpv_sysid.models.trms import (
    PSI_NAMES,
    REDUCED_PSI,
    Trms,
    TrmsParams,
    bounding_box_polytope,
    euler_discrete,
    p_box,
    psi_bounds,
)
from lpv_sysid.sim.trms_closed_loop import (
    C_TRACK,
    REGION_K_DEFAULT,
    REGION_L_PAPER,
    TrmsControlConfig,
    design,
    simulate,
)
from lpv_sysid.synthesis.regions import integral_augmentation

M = Trms()
P = M.p
TV0 = P.theta_v0
TS = 0.1


@pytest.fixture(scope="module")
def des():
    return design(M, TrmsControlConfig())


# --------------------------------------------------------------------------- parameters
def test_params_from_dict_validates_and_round_trips():
    assert TrmsParams.from_dict(P.to_dict()) == P
    assert TrmsParams.from_dict({"k_oh": 0.02}).k_oh == 0.02
    with pytest.raises(ConfigError, match="unknown key"):
        TrmsParams.from_dict({"k_ohh": 1.0})
    with pytest.raises(ConfigError, match="trms.J_tr"):
        TrmsParams.from_dict({"J_tr": 0.0})
    with pytest.raises(ConfigError, match="trms.k_m"):
        TrmsParams.from_dict({"k_m": float("nan")})


def test_derived_constants_by_hand():
    # Eqs. (7)-(14) with Table 5, summed by hand: 0.01428 + 0.00028 + 0.00518 + 0.00062 + 0.01757
    # + 0.00040 + 0.01588 + 0.01006
    assert P.J_v == pytest.approx(0.0642754, abs=2e-7)
    assert P.K_A == pytest.approx((0.0075 + 0.221 + 0.119) * 0.282)
    assert P.K_C == pytest.approx(0.022 * 0.29 / 2 + 0.068 * 0.276)
    # theta_v^0: gravity moment of Eq. (5) vanishes, and the resting TRMS stays at rest (u = 0)
    assert TV0 == pytest.approx(-0.6194, abs=1e-4)
    assert (P.K_A - P.K_B) * math.cos(TV0) - P.K_C * math.sin(TV0) == pytest.approx(0.0, abs=1e-16)
    np.testing.assert_allclose(M.derivatives([0, 0, 0, 0, 0, TV0], [0, 0]), 0.0, atol=1e-15)


def test_derivatives_rejects_bad_input():
    with pytest.raises(ConfigError, match="NaN"):
        M.derivatives([0, 0, np.nan, 0, 0, 0], [0, 0])
    with pytest.raises(ConfigError, match=r"x \(6,\)"):
        M.derivatives([0, 0, 0], [0, 0])


def test_rotor_equation_steady_state_is_the_quadratic_root():
    # Eq. (1) at rest: k_a k_1 / R_a u = (B_tr + k_a^2/R_a) w + k_thp w^2 (w > 0) -> closed-form
    # root
    u = 1.3
    b = P.B_tr + P.k_a**2 / P.R_a
    w = (-b + math.sqrt(b * b + 4 * P.k_thp * P.k_a * P.k_1 / P.R_a * u)) / (2 * P.k_thp)
    assert M.derivatives([w, 0, 0, 0, 0, TV0], [u, 0])[0] == pytest.approx(0.0, abs=1e-14)


# --------------------------------------------------------------------------- quasi-LPV embedding
def test_embedding_reproduces_vector_field_exactly():
    rng = np.random.default_rng(2)
    lo = np.array([-2.9, -1.0, -1.7, -1.6, -0.6, TV0 - 0.5])
    hi = np.array([2.9, 1.0, 1.2, 1.6, 0.6, TV0 + 1.0])
    X = rng.uniform(lo, hi, size=(400, 6))
    # the removable singularities of Eqs. (43)-(54): omega = 0, theta_h = 0, theta_v = theta_v^0
    X[:20, 0] = 0.0
    X[20:40, 3] = 0.0
    X[40:60, 2] = 0.0
    X[60:80, 5] = TV0
    U = rng.uniform([-2.5, -2.0], [2.5, 2.0], size=(400, 2))
    worst = 0.0
    for x, u in zip(X, U):
        A, B = M.lpv_matrices(x)
        f = M.derivatives(x, u)
        worst = max(
            worst, float(np.max(np.abs(A @ M.shift(x) + B @ u - f)) / (1.0 + np.max(np.abs(f))))
        )
    assert worst < 1e-13


def test_embedding_with_nonzero_k_t_couples_tail_into_pitch():
    m = Trms(TrmsParams(k_t=0.01))
    x = np.array([1.2, 0.3, 0.4, 0.9, -0.2, TV0 + 0.3])
    u = np.array([1.0, 0.5])
    A, B = m.lpv_matrices(x)
    np.testing.assert_allclose(A @ m.shift(x) + B @ u, m.derivatives(x, u), rtol=0, atol=1e-14)
    assert B[4, 0] != 0.0


def test_reference_equilibrium_zeroes_the_dynamics():
    # Eqs. (107)-(112) against Eqs. (1)-(6): all rates vanish; with Omega^r != 0 only the angles
    # move
    for th, dv, Wh, Wv in [
        (0.5, 0.2, 0.0, 0.0),
        (-0.6, -0.2, 0.0, 0.0),
        (1.0, 0.6, 0.1, -0.05),
        (-1.2, 0.1, -0.2, 0.1),
    ]:
        x, u = M.reference_equilibrium(th, TV0 + dv, Wh, Wv)
        f = M.derivatives(x, u)
        np.testing.assert_allclose(f[[0, 1, 3, 4]], 0.0, atol=1e-12)
        assert f[2] == pytest.approx(Wh) and f[5] == pytest.approx(Wv)


# --------------------------------------------------------------------------- bounding box, Table 8
def _discrete_bounds(gaps=None):
    lo, hi, _ = psi_bounds(M, *p_box(P), gaps=gaps)
    dlo, dhi = lo * TS, hi * TS
    for k in (0, 2, 7):  # psi_1d, psi_3d, psi_8d carry the identity (Eq. 60)
        dlo[k] += 1.0
        dhi[k] += 1.0
    return dict(zip(PSI_NAMES, zip(dlo, dhi)))


def test_table8_bounds_reproduced_from_the_model():
    b = _discrete_bounds()
    table8 = {
        "a22": (0.9122, 0.9697),
        "a23": (-0.0750, -0.0182),
        "a24": (-0.0041, -0.0003),
        "a25": (-0.0019, 0.0019),
        "a26": (-0.1336, 0.1148),
        "a44": (0.8837, 0.9896),
        "a54": (0.0, 0.2339),
    }
    for name, (lo, hi) in table8.items():
        assert b[name][0] == pytest.approx(lo, abs=6e-5), name
        assert b[name][1] == pytest.approx(hi, abs=6e-5), name
    # upper ends only (the lower ends of a21 / a56 need the paper's unprinted Eq. (69) gaps)
    for name, hi in {"a11": 0.8534, "a21": 0.1124, "a56": -0.3464}.items():
        assert b[name][1] == pytest.approx(hi, abs=6e-5), name
    # a11 lower: Eq. (67) takes max(k_thp w_max, -k_thn w_min) -> 0.7157; Table 8's 0.7207 is the
    # k_thp branch
    assert b["a11"][0] == pytest.approx(0.7157, abs=6e-5)
    k_thp_only = 1 - TS / P.J_tr * (P.k_a**2 / P.R_a + P.B_tr + P.k_thp * 2.9)
    assert k_thp_only == pytest.approx(0.7207, abs=6e-5)


def test_gaps_lift_the_input_gains_off_zero():
    b = _discrete_bounds({"omega_h": (-0.5, 0.5), "omega_v": (-0.5, 0.5)})
    assert b["a54"][0] == pytest.approx(
        TS * P.l_m * P.k_fvn * 0.5 / P.J_v, rel=1e-12
    )  # k_fvn < k_fvp
    assert b["a21"][0] > 0.0
    with pytest.raises(ConfigError, match="unknown variable"):
        psi_bounds(M, *p_box(P), gaps={"omega": (-1, 1)})


def test_polytope_vertices_and_interpolation_reproduce_the_lpv_matrix():
    poly = bounding_box_polytope(M, REDUCED_PSI, ts=TS)
    assert poly.A.shape == (256, 6, 6)
    rng = np.random.default_rng(5)
    plo, phi = p_box(P)
    for _ in range(20):
        x = np.zeros(6)
        x[[2, 5, 0, 3, 1]] = rng.uniform(plo, phi)
        assert poly.contains(x)
        A_lpv, _ = M.lpv_matrices(x)
        psi = poly.psi_full(x)
        A_red, _ = euler_discrete(M.A_of_psi(psi), np.zeros((6, 2)), TS)
        np.testing.assert_allclose(poly.A_at(x), A_red, atol=1e-12)
        # scheduled entries are exactly the embedding's, frozen ones are the LS constants
        for k in poly.index:
            r, c = [
                (0, 0),
                (1, 0),
                (1, 1),
                (1, 2),
                (1, 3),
                (1, 4),
                (1, 5),
                (3, 3),
                (4, 1),
                (4, 3),
                (4, 5),
            ][k]
            assert A_red[r, c] == pytest.approx((r == c) + TS * A_lpv[r, c], abs=1e-12)


def test_vertex_order_follows_box_vertices():
    poly = bounding_box_polytope(M, ("a21", "a54"), ts=None)
    verts = box_vertices(poly.lo, poly.hi)
    for Ai, v in zip(poly.A, verts):
        assert (Ai[1, 0], Ai[4, 3]) == (v[0], v[1])


def test_without_gaps_the_pitch_integrator_is_uncontrollable_at_a_vertex():
    # a54 = 0 at omega_v = 0 (Table 8 lower bound 0): PBH rank of the augmented pair (Eq. 129) at
    # z = 1
    poly = bounding_box_polytope(M, ("a21", "a54"), ts=TS, gaps=None)
    Aa, Ba = integral_augmentation(poly.A[0], poly.B, C_TRACK, ts=TS)  # a21 = a54 = 0
    s = np.linalg.svd(np.hstack([Aa - np.eye(8), Ba]), compute_uv=False)
    assert s[-1] / s[0] < 1e-3
    Aa, Ba = integral_augmentation(poly.A[3], poly.B, C_TRACK, ts=TS)  # both at their maximum
    s = np.linalg.svd(np.hstack([Aa - np.eye(8), Ba]), compute_uv=False)
    assert s[-1] / s[0] > 1e-3


# --------------------------------------------------------------------------- LPV control
def test_vertex_closed_loops_in_region(des):
    assert des.K.shape == (32, 2, 8) and des.L.shape == (32, 6, 4)
    ev = des.controller_eigs()
    assert np.all(REGION_K_DEFAULT.contains(ev))
    ev_open = [np.linalg.eigvals(a) for a, _ in des.augmented_vertices()]
    assert not np.all(REGION_K_DEFAULT.contains(np.array(ev_open)))  # integrators at z = 1
    assert np.all(REGION_L_PAPER.contains(des.observer_eigs()))


def test_observer_error_contracts_for_any_scheduling_sequence(des):
    # quadratic D_L-stability (disk |z| < 0.7) of the dual (Eq. 131) with the common X gives
    # M^T X M < 0.7^2 X for M = A + L C (Schur form affine in M): e^T X e shrinks by 0.7^2 per step
    # for every convex combination of the vertices, i.e. for arbitrarily fast scheduling.
    Xl = des.result_L.X
    rng = np.random.default_rng(7)
    from lpv_sysid.sim.trms_closed_loop import C_MEAS

    e = rng.normal(size=6)
    for _ in range(40):
        w = rng.dirichlet(np.full(len(des.K), 0.2))
        Acl = np.tensordot(w, des.poly.A, axes=1) + np.tensordot(w, des.L, axes=1) @ C_MEAS
        e_next = Acl @ e
        assert e_next @ Xl @ e_next <= 0.7**2 * (e @ Xl @ e) * (1 + 1e-7)
        e = e_next


def test_nonlinear_step_tracking_zero_steady_state_error(des):
    x0, _ = M.reference_equilibrium(0.9, TV0 + 0.25)
    ref = lambda t: (0.9, TV0 + 0.25) if t < 1.0 else (1.1, TV0 + 0.30)  # noqa: E731
    run = simulate(des, ref, x0, t_end=40.0)
    err = run.x[:, [2, 5]] - run.r
    assert np.max(np.abs(err[-1])) < 1e-4  # integral action: no offset
    assert np.max(np.abs(err[run.t > 30.0])) < 1e-3
    assert np.max(np.abs(err[run.t > 2.0, 0])) > 0.05  # it did have to move (not trivially 0)
    assert run.in_box.all() and not run.saturated.any()
    x_end, u_end = M.reference_equilibrium(1.1, TV0 + 0.30)
    np.testing.assert_allclose(run.u[-1], u_end, atol=1e-3)  # settles on the Eq. (111)-(112) input


def test_observer_converges_in_closed_loop(des):
    x0, _ = M.reference_equilibrium(0.9, TV0 + 0.25)
    x_hat0 = x0 + np.array([0.2, 0.1, 0.1, 0.2, 0.05, 0.05])
    run = simulate(des, (1.0, TV0 + 0.25), x0, x_hat0, t_end=30.0)
    e = run.x_hat - run.x
    assert np.max(np.abs(e[0])) == pytest.approx(0.2)
    # the unmeasured rates converge; the residual on omega is the Euler/frozen-parameter model
    # mismatch
    assert np.max(np.abs(e[-1, [1, 4]])) < 1e-3
    assert np.max(np.abs(e[-1])) < 0.1
    assert np.max(np.abs(run.x[-1, [2, 5]] - run.r[-1])) < 1e-3


def test_control_config_validation():
    with pytest.raises(ConfigError, match="unknown key"):
        TrmsControlConfig.from_dict({"tau": 1.0})
    with pytest.raises(ConfigError, match="unit disk"):
        TrmsControlConfig.from_dict({"region_K": {"disk": {"centre": 0.5, "radius": 0.9}}})
    cfg = TrmsControlConfig.from_dict(
        {"tau_h": 2.0, "region_L": {"disk": {"centre": 0.0, "radius": 0.6}}}
    )
    assert cfg.tau_h == 2.0 and cfg.region_L.disk_r == 0.6
    with pytest.raises(ConfigError, match="tau_v"):
        TrmsControlConfig(tau_v=-1.0)


def test_yaw_second_order_identification_formulas_match_the_model():
    # Eqs. (72)-(81), (87): with u_v = 0 (theta_v = theta_v^0) the yaw subsystem is
    # K_p / (1 + 2 xi_p T_p s + T_p^2 s^2) from omega_h^2 to theta_h; check against the Jacobian
    # of Eq. (2)
    D0 = P.K_D * math.cos(TV0) ** 2 + P.K_E * math.sin(TV0) ** 2 + P.K_F
    Tp2 = D0 / P.k_chp  # Eq. (80)
    two_xi_T = P.k_oh / P.k_chp  # Eq. (78)
    Kp = P.l_t * P.k_fhp * math.cos(TV0) / P.k_chp  # Eq. (76)
    wh = 0.8
    A, _ = M.jacobian(np.array([wh, 0.0, 0.3, 0.0, 0.0, TV0]), np.zeros(2))
    assert A[1, 2] == pytest.approx(-1.0 / Tp2, rel=1e-7)
    assert A[1, 1] == pytest.approx(-two_xi_T / Tp2, rel=1e-7)
    assert A[1, 0] == pytest.approx(Kp / Tp2 * 2 * wh, rel=1e-7)
    # Eq. (87): steady state theta_h / omega_h^2 = K_p (equilibrium of Eqs. 107-112 at theta_v^0)
    x, _ = M.reference_equilibrium(0.4, TV0)
    assert x[2] / x[0] ** 2 == pytest.approx(Kp, rel=1e-12)
