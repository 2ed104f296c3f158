"""Common input matrix for Lemma 1 (models.lpv input_hull / product_systems, synthesis with
``uncertainty.common_b``): hull on hand numbers, the interior identity of the product weights, and
a 2-state plant whose per-vertex certificate fails inside the box while the common-B one holds."""

import numpy as np
import pytest
import yaml

from lpv_sysid.cli.main import main
from lpv_sysid.errors import ConfigError, SolverError
from lpv_sysid.io.formats import GainSchedule
from lpv_sysid.models.lpv import (
    CommonInputSet,
    PolytopicModel,
    UncertainElement,
    common_input_deviation,
    input_hull,
    multilinear_weights,
    product_systems,
)
from lpv_sysid.synthesis.hinf import HinfOptions, hinf_norm, solve_lemma1
from lpv_sysid.synthesis.hinf.synthesize import _shrunk_model
from lpv_sysid.synthesis.uncertainty_set import load_models
from lpv_sysid.synthesis.verify import verify_files, verify_gains

# 2 states, 1 input, 1-axis box [-1, 1], z = x1: B turns from (0.4, 0.2) to (1.1, 2.9) across the
# box. With per-vertex B the solution at gamma = 3 (Clarabel and SCS alike) certifies both vertices
# but B(s) K(s) is bilinear and the interpolated loop is unstable inside the box; the common-B
# polytope is feasible (gamma_min ~ 1.75) and holds everywhere.
A2 = np.array([[[-2.5, -1.8], [-1.2, -1.4]], [[0.2, 0.3], [2.9, 1.5]]])
B2 = np.array([[[0.4], [0.2]], [[1.1], [2.9]]])
GAMMA = 3.0


def _write_models(path, A=A2, B=B2, uncertain=None):
    verts = [
        {
            "scheduling": [s],
            "x0": [0.0, 0.0],
            "u0": [0.0],
            "A": A[i].tolist(),
            "B": B[i].tolist(),
            "uncertain": (uncertain or [[], []])[i],
        }
        for i, s in enumerate((-1.0, 1.0))
    ]
    doc = {
        "format": "lpv_sysid/vertex_models@1",
        "time": "continuous",
        "states": [{"name": "x1", "unit": "m/s"}, {"name": "x2", "unit": "m/s"}],
        "inputs": [{"name": "u", "unit": "1"}],
        "scheduling": {"names": ["s"], "min": [-1.0], "max": [1.0]},
        "vertices": verts,
    }
    path.write_text(yaml.safe_dump(doc))
    return path


def _write_config(path, common_b, gamma=GAMMA):
    # T = 2, Delta_in = 1 -> R = 1 (Eq. 27); Delta_out = 1/sqrt(2) with n_z = 1 -> Q = 1 (Eq. 28)
    cfg = {
        "hinf": {"gamma": gamma, "solver": "CLARABEL", "fallback": "SCS"},
        "weights": {"T": 2.0, "input_magnitudes": [1.0], "output_magnitudes": [2**-0.5]},
        "velocity_states": ["x1"],
        "verify": {"n_random": 10, "seed": 3},
        "uncertainty": {"common_b": common_b, "p_max": 4, "p_max_b": 2, "output_states": [0, 1]},
    }
    path.write_text(yaml.safe_dump(cfg))
    return path


def _loop_norm(A, B, K):
    return hinf_norm(A + B @ K, B, np.array([[1.0, 0.0]])).value  # R = 1, z = Q^-1 x1, Q = 1


# ------------------------------------------------------------------ hull and product on hand
# numbers
def test_input_hull_on_hand_numbers():
    B = np.array([[[1.0, 0.0], [0.0, 2.0]], [[1.0, 0.0], [0.5, 3.0]]])
    els = [
        [UncertainElement("B", 1, 1, 1.8, 2.2, 2.0), UncertainElement("A", 0, 0, -1.0, 1.0)],
        [UncertainElement("B", 1, 1, 2.5, 3.5, 3.0), UncertainElement("B", 0, 0, 0.9, 1.1, 1.0)],
    ]
    base, hull, nlo, nhi = input_hull(B, els)
    # B[0,0]: {1} u [0.9, 1.1]; B[1,0]: nominals 0 and 0.5; B[1,1]: [1.8, 2.2] u [2.5, 3.5];
    # B[0,1] = 0 fixed
    assert [(e.row, e.col) for e in hull] == [(0, 0), (1, 0), (1, 1)]
    assert [(e.lower, e.upper) for e in hull] == [(0.9, 1.1), (0.0, 0.5), (1.8, 3.5)]
    assert [e.nominal for e in hull] == [1.0, 0.25, 2.5]  # mean of the vertex nominals
    np.testing.assert_array_equal(base, [[1.0, 0.0], [0.25, 2.5]])
    np.testing.assert_array_equal(nlo, [[1.0, 0.0], [0.0, 2.0]])
    np.testing.assert_array_equal(nhi, [[1.0, 0.0], [0.5, 3.0]])
    A = np.zeros((2, 2, 2))
    m = PolytopicModel.from_common_input([0.0], [1.0], A, B, None, None, els)
    c = m.common_input
    assert c.M == 8 and m.input_structure == {
        "B": "common",
        "M": [16, 8],
        "M_A": [2, 1],
        "M_B": 8,
        "B_method": "box",
    }
    got = sorted((b[0, 0], b[1, 0], b[1, 1], b[0, 1]) for b in c.corners)
    want = sorted((x, y, z, 0.0) for x in (0.9, 1.1) for y in (0.0, 0.5) for z in (1.8, 3.5))
    assert got == want
    # product order j = a * M_B + b: vertex 0 has two A corners (A[0,0] = -1, +1)
    for i, lst in enumerate(m.systems):
        for j, (Aj, Bj) in enumerate(lst):
            a, b = divmod(j, 8)
            np.testing.assert_array_equal(Bj, c.corners[b])
            if i == 0:
                assert Aj[0, 0] == (-1.0, 1.0)[a]
    assert common_input_deviation(m, 8) == (0.0, 0.0)
    with pytest.raises(ConfigError, match="outside shape"):
        input_hull(B, [[UncertainElement("B", 2, 0, 0.0, 1.0)], []])


def test_shrunk_common_set_is_hull_of_shrunk_intervals():
    # vertex nominals 1 and 2 with [0.5, 1.5], [1.5, 2.5]: hull [0.5, 2.5], nominal hull [1, 2];
    # shrinking the widths by rho = 0.5 gives [0.75, 1.25] u [1.75, 2.25] -> hull [0.75, 2.25]
    B = np.array([[[1.0]], [[2.0]]])
    els = [
        [UncertainElement("B", 0, 0, 0.5, 1.5, 1.0)],
        [UncertainElement("B", 0, 0, 1.5, 2.5, 2.0)],
    ]
    m = PolytopicModel.from_common_input([0.0], [1.0], -np.ones((2, 1, 1)), B, None, None, els)
    np.testing.assert_allclose(sorted(m.common_input.corners.ravel()), [0.5, 2.5])
    s = _shrunk_model(m, 0.5)
    np.testing.assert_allclose(sorted(s.common_input.corners.ravel()), [0.75, 2.25])
    assert common_input_deviation(s, 2) == (0.0, 0.0)
    np.testing.assert_allclose(
        sorted(_shrunk_model(m, 0.0).common_input.corners.ravel()), [1.0, 2.0]
    )


def test_product_weights_make_the_B_part_vertex_independent():
    """The algebra of the models.lpv docstring, numerically: with beta_i^(a,b) = beta_i^a beta^b,
    sum_i alpha_i sum_(a,b) beta U_i^(a,b) = A(v,theta) H + B(theta) S(v); with per-vertex B the
    same weighted sum is not B(v) S(v) (the cross terms alpha_i alpha_k B_i S_k are missing)."""
    rng = np.random.default_rng(5)
    n, m_, MA, MB = 3, 2, 2, 4
    Ac = [rng.normal(size=(MA, n, n)) for _ in range(2)]
    common = CommonInputSet(rng.normal(size=(MB, n, m_)))
    systems = product_systems(Ac, common)
    H = rng.normal(size=(n, n))
    S = rng.normal(size=(2, m_, n))
    alpha = np.array([0.3, 0.7])
    beta_a = [rng.dirichlet(np.ones(MA)) for _ in range(2)]
    beta_b = rng.dirichlet(np.ones(MB))
    lhs = sum(
        alpha[i] * np.kron(beta_a[i], beta_b)[j] * (Aj @ H + Bj @ S[i])
        for i in range(2)
        for j, (Aj, Bj) in enumerate(systems[i])
    )
    A_v = sum(alpha[i] * np.tensordot(beta_a[i], Ac[i], axes=1) for i in range(2))
    B_t = np.tensordot(beta_b, common.corners, axes=1)
    np.testing.assert_allclose(
        lhs, A_v @ H + B_t @ (alpha[0] * S[0] + alpha[1] * S[1]), atol=1e-12
    )
    # per-vertex B_i: the weighted sum differs from B(v) S(v) by -alpha_0 alpha_1 (B_0 - B_1)(S_0
    # - S_1)
    Bv = rng.normal(size=(2, n, m_))
    lhs_pv = sum(alpha[i] * Bv[i] @ S[i] for i in range(2))
    rhs_pv = (alpha[0] * Bv[0] + alpha[1] * Bv[1]) @ (alpha[0] * S[0] + alpha[1] * S[1])
    np.testing.assert_allclose(
        lhs_pv - rhs_pv, alpha[0] * alpha[1] * (Bv[0] - Bv[1]) @ (S[0] - S[1]), atol=1e-12
    )
    assert np.max(np.abs(lhs_pv - rhs_pv)) > 1e-3


# ------------------------------------------------------------------ synthesis: per-vertex vs
# common B
def test_per_vertex_B_fails_inside_while_common_B_certifies_the_interior(tmp_path, capsys):
    models = _write_models(tmp_path / "vertex_models.yaml")
    # old structure: vertices certified, the interpolated law breaks the bound inside the box
    rc = main(
        [
            "synthesize",
            "--models",
            str(models),
            "--config",
            str(_write_config(tmp_path / "pv.yaml", False)),
            "--out",
            str(tmp_path / "pv" / "gains.yaml"),
        ]
    )
    out = capsys.readouterr().out
    assert rc == 1 and "B differs between scheduling vertices" in out
    g = GainSchedule.load(tmp_path / "pv" / "gains.yaml", auto_layout=True)
    assert g.certificate.extra["input_structure"]["B"] == "per_vertex"
    for i in range(2):
        assert _loop_norm(A2[i], B2[i], g.K[i]) <= GAMMA  # vertices: certified
    worst = 0.0
    for s in np.linspace(-1, 1, 41):
        a, _ = multilinear_weights([s], [-1.0], [1.0])
        worst = max(
            worst,
            _loop_norm(np.tensordot(a, A2, 1), np.tensordot(a, B2, 1), np.tensordot(a, g.K, 1)),
        )
    assert worst > GAMMA  # interior: violated (true model)
    rep = verify_files(tmp_path / "pv" / "gains.yaml", models, n_random=20)
    assert any(not r.ok for r in rep.rows if r.check == "hinf interior")

    # common input set: B in the hull of the vertex B's for every vertex -> the interior is covered
    out_c = tmp_path / "cb" / "gains.yaml"
    rc = main(
        [
            "synthesize",
            "--models",
            str(models),
            "--config",
            str(_write_config(tmp_path / "cb.yaml", True)),
            "--out",
            str(out_c),
        ]
    )
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "M_i = M_A x M_B = [1, 1] x 4 = [4, 4]" in out and "covers the whole box" in out
    g = GainSchedule.load(out_c, auto_layout=True)
    st = g.certificate.extra["input_structure"]
    assert st["B"] == "common" and st["M_B"] == 4 and st["M_A"] == [1, 1]
    assert [(h["lower"], h["upper"]) for h in st["B_hull"]] == [(0.4, 1.1), (0.2, 2.9)]
    assert g.certificate.extra["uncertainty"]["common_b"] is True
    # independent oracle: frozen loops on a grid of s and of the B hull (corners + true B(s))
    corners = [np.array([[b0], [b1]]) for b0 in (0.4, 1.1) for b1 in (0.2, 2.9)]
    rng = np.random.default_rng(0)
    worst = 0.0
    for s in np.linspace(-1, 1, 21):
        a, _ = multilinear_weights([s], [-1.0], [1.0])
        A, K = np.tensordot(a, A2, 1), np.tensordot(a, g.K, 1)
        Bs = (
            corners
            + [np.tensordot(a, B2, 1)]
            + [np.tensordot(rng.dirichlet(np.ones(4)), np.array(corners), 1) for _ in range(3)]
        )
        worst = max(worst, max(_loop_norm(A, B, K) for B in Bs))
    assert worst <= GAMMA * (1 + 1e-6)
    rep = verify_files(out_c, models, n_random=10)
    assert rep.passed, rep.table()
    assert {r.check for r in rep.rows} >= {
        "common B",
        "product A",
        "B hull",
        "structure",
        "hinf interior",
    }
    # re-verifying the common-B certificate against a per-vertex rebuild is refused (structure +
    # LMIs)
    rep = verify_files(out_c, models, n_random=2, uncertainty={"common_b": False})
    assert {r.check for r in rep.rows if not r.ok} >= {"structure", "lmi"}


def test_common_B_refuses_what_no_gain_can_do(tmp_path, capsys):
    # B flips sign across the box (x' = x + b(s) u): per-vertex Lemma 1 certifies both vertices,
    # but b(0) = 0 leaves x' = x unstable for every gain (oracle). The common hull [-1, 1] contains
    # b = 0: the common-B LMI is infeasible, i.e. nothing is certified that cannot hold.
    A = np.array([[[1.0]], [[1.0]]])
    B = np.array([[[1.0]], [[-1.0]]])
    model_pv = PolytopicModel.from_uncertain_elements([-1.0], [1.0], A, B, None, None, [[], []])
    res = solve_lemma1(model_pv, np.eye(1), np.eye(1), HinfOptions(gamma=0.5))
    rep = verify_gains(model_pv, res.K, np.eye(1), np.eye(1), 0.5, n_random=20)
    assert all(r.ok for r in rep.rows if r.check == "hinf")
    assert any(not r.ok for r in rep.rows if r.check == "hinf interior")
    model_cb = PolytopicModel.from_common_input([-1.0], [1.0], A, B, None, None, [[], []])
    assert sorted(model_cb.common_input.corners.ravel()) == [-1.0, 1.0]
    with pytest.raises(SolverError):
        solve_lemma1(model_cb, np.eye(1), np.eye(1), HinfOptions(gamma=0.5, minimize_gamma=True))
    # the CLI refuses with exit 2, writes nothing and names the option
    models = tmp_path / "flip.yaml"
    doc = {
        "format": "lpv_sysid/vertex_models@1",
        "time": "continuous",
        "states": [{"name": "x", "unit": "m/s"}],
        "inputs": [{"name": "u", "unit": "1"}],
        "scheduling": {"names": ["s"], "min": [-1.0], "max": [1.0]},
        "vertices": [
            {
                "scheduling": [s],
                "x0": [0.0],
                "u0": [0.0],
                "A": [[1.0]],
                "B": [[b]],
                "uncertain": [],
            }
            for s, b in ((-1.0, 1.0), (1.0, -1.0))
        ],
    }
    models.write_text(yaml.safe_dump(doc))
    cfg = {
        "hinf": {"gamma": 0.5, "solver": "CLARABEL"},
        "velocity_states": ["x"],
        "weights": {"T": 2.0, "input_magnitudes": [1.0], "output_magnitudes": [2**-0.5]},
        "uncertainty": {"common_b": True},
    }
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
    rc = main(
        [
            "synthesize",
            "--models",
            str(models),
            "--config",
            str(tmp_path / "c.yaml"),
            "--out",
            str(tmp_path / "g.yaml"),
        ]
    )
    err = capsys.readouterr().err
    assert (
        rc == 2 and "common_b" in err and "Lemma 1" in err and not (tmp_path / "g.yaml").exists()
    )


def test_verifier_flags_a_broken_common_structure():
    A = np.array([[[-1.0]], [[-2.0]]])
    B = np.array([[[1.0]], [[2.0]]])
    m = PolytopicModel.from_common_input([-1.0], [1.0], A, B, None, None, [[], []])
    K = np.array([[[-1.0]], [[-1.0]]])
    rep = verify_gains(m, K, np.eye(1), np.eye(1), 10.0, n_random=3)
    assert [r.ok for r in rep.rows if r.check in ("common B", "product A")] == [True, True]
    # vertex 1 claims the common set but its second corner was altered by 1e-9
    bad = [list(m.systems[0]), [m.systems[1][0], (m.systems[1][1][0], m.systems[1][1][1] + 1e-9)]]
    m_bad = PolytopicModel(
        vmin=m.vmin,
        vmax=m.vmax,
        A=m.A,
        B=m.B,
        x0=None,
        u0=None,
        systems=bad,
        common_input=m.common_input,
    )
    dB, dA = common_input_deviation(m_bad, 2)
    assert abs(dB - 1e-9) < 1e-15 and dA == 0.0
    rep = verify_gains(m_bad, K, np.eye(1), np.eye(1), 10.0, n_random=3)
    assert [r.ok for r in rep.rows if r.check == "common B"] == [False]
    assert common_input_deviation(m_bad, 3) == (float("inf"), float("inf"))


def test_load_models_budget_and_config_errors(tmp_path):
    unc = [
        [
            {
                "matrix": "A",
                "row": 0,
                "col": 0,
                "nominal": -2.5,
                "std": 0.1,
                "lower": -2.6,
                "upper": -2.4,
            },
            {
                "matrix": "A",
                "row": 1,
                "col": 1,
                "nominal": -1.4,
                "std": 0.1,
                "lower": -1.5,
                "upper": -1.3,
            },
        ],
        [
            {
                "matrix": "B",
                "row": 1,
                "col": 0,
                "nominal": 2.9,
                "std": 0.1,
                "lower": 2.8,
                "upper": 3.0,
            }
        ],
    ]
    models = _write_models(tmp_path / "m.yaml", uncertain=unc)
    m, _ = load_models(models, {"common_b": True, "p_max": 4, "output_states": [0, 1]})
    # B hull: B[0,0] in [0.4, 1.1], B[1,0] in [0.2, 3.0] -> M_B = 4; A: 2 free elements at vertex 0
    assert m.input_structure["M_B"] == 4 and m.input_structure["M_A"] == [4, 1]
    assert sorted({round(float(b[1, 0]), 12) for b in m.common_input.corners}) == [0.2, 3.0]
    # budget p_max = 3: the A part keeps 3 - 2 = 1 corner parameter (influence reduction)
    m3, _ = load_models(models, {"common_b": True, "p_max": 3, "output_states": [0, 1]})
    assert m3.input_structure["M_A"] == [2, 1] and m3.input_structure["M"] == [8, 4]
    # more B hull elements than p_max_b: reduction of ident.uncertainty on the hull (once, not per
    # vertex)
    mi, _ = load_models(
        models, {"common_b": True, "p_max": 4, "p_max_b": 1, "output_states": [0, 1]}
    )
    assert mi.input_structure["M_B"] == 2 and mi.input_structure["B_method"] == "influence"
    assert mi.input_structure["M_A"] == [4, 1]  # budget 4 - 1 = 3 >= 2 free
    assert common_input_deviation(mi, 2) == (0.0, 0.0)
    mh, _ = load_models(
        models,
        {"common_b": True, "p_max": 4, "p_max_b": 1, "method": "hybrid", "output_states": [0, 1]},
    )
    c = mh.common_input.corners  # 2 box corners x 2 simplex vertices
    assert mh.input_structure["M_B"] == 4 and mh.input_structure["M_A"] == [4, 1]
    tol = 1e-12  # midpoint +- half-width rounding
    assert c[:, 0, 0].min() <= 0.4 + tol and c[:, 0, 0].max() >= 1.1 - tol
    assert c[:, 1, 0].min() <= 0.2 + tol and c[:, 1, 0].max() >= 3.0 - tol
    mp, _ = load_models(models, {"common_b": False, "p_max": 4})
    assert mp.common_input is None and [len(s) for s in mp.systems] == [4, 2]
    with pytest.raises(ConfigError, match="common_b"):
        load_models(models, {"common_b": "yes"})
    with pytest.raises(ConfigError, match="p_max"):
        load_models(models, {"common_b": True, "p_max_b": -1})
