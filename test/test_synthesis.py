"""synthesis/hinf/norm.py and synthesis/hinf/synthesize.py (seed 0 Lemma 1, Eqs. 29-31) against
analytic oracles."""

import numpy as np
import pytest

from lpv_sysid.errors import ConfigError, SolverError
from lpv_sysid.synthesis.example_models import (
    first_order_min_gain,
    first_order_plant,
    quadrotor_like_polytope,
    uncontrollable_disturbance_plant,
)
from lpv_sysid.synthesis.hinf import (
    HinfOptions,
    certificate_margins,
    eq30_matrix,
    excitation_R,
    hinf_norm,
    hinf_norm_sweep,
    output_Q,
    performance_matrix,
    solve_lemma1,
    synthesize_hinf,
)
from lpv_sysid.synthesis.scaling import choose_scaling


# ------------------------------------------------------------------ H-inf norm (independent check)
def test_hinf_norm_first_order_and_resonance_analytic():
    a = 3.0
    h = hinf_norm(np.array([[-a]]), np.array([[2.0]]), np.array([[1.5]]))
    assert h.stable and abs(h.value - 1.0) < 1e-5  # |1.5 * 2 / a| at w = 0
    for zeta in (0.05, 0.2, 0.5):
        wn = 7.0
        A = np.array([[0.0, 1.0], [-(wn**2), -2 * zeta * wn]])
        B = np.array([[0.0], [wn**2]])
        C = np.array([[1.0, 0.0]])
        peak = 1.0 / (2 * zeta * np.sqrt(1 - zeta**2))
        h = hinf_norm(A, B, C)
        assert abs(h.value - peak) < 2e-6 * peak
        assert abs(h.frequency - wn * np.sqrt(1 - 2 * zeta**2)) < 1e-3 * wn


def test_hinf_norm_matches_dense_sweep_on_random_mimo():
    rng = np.random.default_rng(7)
    w = np.concatenate([[0.0], np.logspace(-3, 3, 6000)])
    for _ in range(6):
        n = 4
        A = rng.normal(size=(n, n))
        A -= (np.max(np.linalg.eigvals(A).real) + 0.05 + rng.random()) * np.eye(
            n
        )  # lightly damped
        B = rng.normal(size=(n, 2))
        C = rng.normal(size=(3, n))
        h = hinf_norm(A, B, C)
        s, _ = hinf_norm_sweep(A, B, C, w)
        assert s <= h.value * (1 + 1e-9)  # the grid can only under-estimate
        assert h.lower <= s * (1 + 2e-3) and h.value >= s  # and gets within 0.2% on a dense grid


def test_hinf_norm_badly_scaled_12_state_matches_sweep_with_and_without_balancing():
    model = quadrotor_like_polytope(0)
    R = excitation_R([0.1] * 4, 100.0)
    C = performance_matrix(output_Q([5.0] * 3, 100.0), 12, (2, 3, 4))
    # any stabilising gain will do; take the LQR gain (Riccati, independent of Lemma 1)
    from scipy.linalg import solve_continuous_are

    A, B = model.A[0], model.B[0]
    P = solve_continuous_are(A, B, np.eye(12), 1e6 * np.eye(4))
    K = -np.linalg.solve(1e6 * np.eye(4), B.T @ P)
    Acl = A + B @ K
    assert np.max(np.linalg.eigvals(Acl).real) < 0
    h1 = hinf_norm(Acl, B @ R, C)
    h0 = hinf_norm(Acl, B @ R, C, balanced=False)
    s, _ = hinf_norm_sweep(Acl, B @ R, C, np.concatenate([[0.0], np.logspace(-3, 4, 4000)]))
    assert abs(h1.value - h0.value) < 1e-5 * h1.value
    assert s <= h1.value * (1 + 1e-9) and h1.lower <= s * (1 + 2e-3)


def test_hinf_norm_unstable_is_inf():
    assert hinf_norm(np.array([[0.1]]), np.eye(1), np.eye(1)).value == np.inf


# ------------------------------------------------------------------ Lemma 1
def test_lemma1_gamma_min_equals_analytic_bound():
    # u cannot reach x1: ||w -> z||_inf = 1/a1 for every stabilising K (example_models docstring)
    model, Be, C, gmin = uncontrollable_disturbance_plant(a1=2.0, a2=1.0)
    res = solve_lemma1(model, None, C, HinfOptions(minimize_gamma=True), Be=Be)
    assert abs(res.gamma_solver - gmin) < 2e-3 * gmin
    for i in range(2):
        Acl = model.A[i] + model.B[i] @ res.K[i]
        assert np.max(np.linalg.eigvals(Acl).real) < 0
        assert abs(hinf_norm(Acl, Be, C).value - gmin) < 1e-4


def test_lemma1_infeasible_below_gamma_min_reports_remedy_factor():
    model, Be, C, gmin = uncontrollable_disturbance_plant(a1=2.0, a2=1.0)
    with pytest.raises(SolverError) as ei:
        synthesize_hinf(model, None, C, HinfOptions(gamma=0.8 * gmin), Be=Be)
    rem = ei.value.remedy
    assert abs(rem.excitation_shrink - 1.25) < 5e-3  # gamma_min / gamma_req
    assert abs(rem.output_grow - 1.25) < 5e-3
    assert "reduce the excitation magnitudes" in str(ei.value)


def test_gamma_min_scales_linearly_with_excitation():
    # the homogeneity the remedy uses: B_e -> c B_e gives gamma_min -> c gamma_min
    model, Be, C, _ = uncontrollable_disturbance_plant(a1=1.0, a2=0.5)
    g1 = solve_lemma1(model, None, C, HinfOptions(minimize_gamma=True), Be=Be).gamma_solver
    g3 = solve_lemma1(model, None, C, HinfOptions(minimize_gamma=True), Be=3 * Be).gamma_solver
    assert abs(g3 / g1 - 3.0) < 5e-3


def test_lemma1_first_order_feasible_gain_satisfies_analytic_condition():
    a, b, r, c, gamma = 1.0, 2.0, 0.5, 1.0, 0.4
    model = first_order_plant(a, b, r * b)
    res = solve_lemma1(model, np.array([[r]]), np.array([[c]]), HinfOptions(gamma=gamma))
    k = res.K[0, 0, 0]
    assert (
        k <= first_order_min_gain(a, b, r * b, c, gamma) + 1e-9
    )  # analytic feasibility condition
    assert abs(c * r * b) / abs(a + b * k) <= gamma  # closed-loop DC gain = H-inf norm
    assert res.gamma_certified <= gamma and res.min_margin > 0


def test_eq30_numeric_matrix_is_symmetric_and_certificate_detects_tampering():
    model, Be, C, gmin = uncontrollable_disturbance_plant(a1=2.0, a2=1.0)
    res = solve_lemma1(model, None, C, HinfOptions(gamma=1.0), Be=Be)
    M = eq30_matrix(model.A[0], model.B[0], Be, C, res.X[0][0], res.S[0], res.H, 1.0)
    np.testing.assert_allclose(M, M.T, atol=1e-12)
    g, margin = certificate_margins(model, None, C, res.X, res.S, res.H, res.scaling, 1.0, Be=Be)
    assert g <= 1.0 and margin > 0
    bad_X = [[-x for x in row] for row in res.X]
    g2, margin2 = certificate_margins(model, None, C, bad_X, res.S, res.H, res.scaling, 1.0, Be=Be)
    assert margin2 < 0


def test_quadrotor_like_12_state_certified_by_independent_norm():
    model = quadrotor_like_polytope(0)  # 8 vertices, M = 1
    R = excitation_R([0.1] * 4, 100.0)
    C = performance_matrix(output_Q([5.0] * 3, 100.0), 12, (2, 3, 4))
    res = solve_lemma1(model, R, C, HinfOptions(gamma=1.0, solver="SCS"))
    assert res.size.eq30_block_dim == 31 and res.size.lmi_blocks == 16
    assert res.gamma_certified <= 1.0
    # the scaling (b = 1.4e4) is undone exactly: K = S H^-1 in the original coordinates
    np.testing.assert_allclose(
        res.K[3],
        np.linalg.solve(res.H.T, res.S[3].T).T,
        rtol=1e-6,
        atol=1e-9 * np.abs(res.K[3]).max(),
    )
    for i, lst in enumerate(model.systems):
        for A, B in lst:
            Acl = A + B @ res.K[i]
            assert np.max(np.linalg.eigvals(Acl).real) < 0
            assert hinf_norm(Acl, B @ R, C).value <= 1.0
    # and the open loop is unstable (the certificate is not trivial)
    assert np.max(np.linalg.eigvals(model.A[0]).real) > 0


def test_scaling_is_powers_of_two_and_balances_motor_rows():
    model = quadrotor_like_polytope(0)
    R = excitation_R([0.1] * 4, 100.0)
    C = performance_matrix(output_Q([5.0] * 3, 100.0), 12, (2, 3, 4))
    sc = choose_scaling(list(model.A), list(model.B), [b @ R for b in model.B], C)
    for v in np.concatenate([sc.t, sc.s_u]):
        assert np.log2(v) == round(np.log2(v))
    assert np.abs(sc.Bc(model.B[0])).max() < 1e-2 * np.abs(model.B[0]).max()


def test_options_validation():
    with pytest.raises(ConfigError, match="unknown"):
        HinfOptions.from_dict({"gama": 1})
    with pytest.raises(ConfigError, match="solver"):
        HinfOptions.from_dict({"solver": "CVX"})
    with pytest.raises(ConfigError):
        excitation_R([0.1, -1], 10.0)
    np.testing.assert_allclose(
        excitation_R([0.1] * 4, 50.0), np.sqrt(4 * 50 / 2) * 0.1 * np.eye(4)
    )  # Eq. 27
    np.testing.assert_allclose(
        output_Q([5.0] * 3, 50.0), np.sqrt(3 * 50) * 5 * np.eye(3)
    )  # Eq. 28


def test_uncertainty_reduction_remedy_by_bisection_matches_analytic_shrink():
    # x1' = -a1 x1 + w with a1 in [2 - 1, 2 + 1]: gamma_min = 1 / a1_lower. Shrinking the interval
    # by rho gives a1_lower = 2 - rho, so gamma = 0.6 needs rho <= 2 - 1/0.6 = 1/3 (analytic).
    from lpv_sysid.models.lpv import PolytopicModel, UncertainElement
    from lpv_sysid.synthesis.hinf import remedy_analysis

    base, Be, C, _ = uncontrollable_disturbance_plant(a1=2.0, a2=1.0)
    el = [UncertainElement("A", 0, 0, -3.0, -1.0, -2.0)]
    model = PolytopicModel.from_uncertain_elements(
        base.vmin, base.vmax, base.A, base.B, base.x0, base.u0, [el, el]
    )
    rem = remedy_analysis(model, None, C, HinfOptions(gamma=0.6, remedy_bisection_steps=7), Be=Be)
    assert abs(rem.gamma_min - 1.0) < 2e-3  # 1 / a1_lower = 1 / 1
    assert abs(rem.excitation_shrink - 1.0 / 0.6) < 5e-3
    assert abs(rem.nominal_gamma_min - 0.5) < 2e-3
    assert 1 / 3 - 0.02 < rem.uncertainty_shrink <= 1 / 3 + 1e-3
    assert "33" in rem.message() or "32" in rem.message()


def test_auto_solver_order():
    from lpv_sysid.synthesis.hinf.synthesize import _solver_order

    auto = HinfOptions.from_dict({"solver": "auto"})
    assert _solver_order(auto, 8, {"CLARABEL", "SCS"}) == ["CLARABEL", "SCS"]
    assert _solver_order(auto, 128, {"CLARABEL", "SCS"}) == ["SCS", "CLARABEL"]
    assert _solver_order(auto, 128, {"CLARABEL", "SCS", "MOSEK"})[0] == "MOSEK"
    assert _solver_order(HinfOptions(solver="SCS", fallback="CLARABEL"), 8, set()) == [
        "SCS",
        "CLARABEL",
    ]
