"""Issue 20 item 4: the certified box holds ALL identified elements at once with a stated joint
probability (Sidak), not each element marginally at 3 sigma.

Oracles: the defining equation of the Sidak half-width ((1 - 2 tail(k))^p = P, normal and
Student-t), a Monte Carlo of correlated Gaussian estimates, and half-widths computed by hand from
the raw models file."""

from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.stats import norm, t

from lpv_sysid.errors import ConfigError
from lpv_sysid.ident.equation_error import t_factor
from lpv_sysid.ident.vertex import DEFAULT_JOINT_PROBABILITY, joint_k
from lpv_sysid.models.quadrotor import QuadrotorParams
from lpv_sysid.studies.coverage import AirframeCoverage, VertexCoverage
from lpv_sysid.synthesis.uncertainty_set import load_models
from lpv_sysid.synthesis.verify import VerifyReport
from lpv_sysid.synthesis.verify.box import _sidak_stored_k, check_joint_claim


def test_sidak_half_width_solves_its_defining_equation():
    assert DEFAULT_JOINT_PROBABILITY == 0.95
    for p in (1, 51, 408):
        k = joint_k(p, 0.95)  # normal, stored std = raw std (t_factor(3, None) = 1)
        assert (2 * norm.cdf(k) - 1) ** p == pytest.approx(0.95, abs=1e-9)
    assert joint_k(408, 0.95) == pytest.approx(3.8347, abs=1e-3)
    # marginal 3 sigma on 408 elements: all at once only with ~33 % (the number)
    assert (2 * norm.cdf(3.0) - 1) ** 408 == pytest.approx(0.332, abs=2e-3)
    # Student-t: the stored std is s * t_factor(3, nu); the half-width in raw s is k * t_factor
    for nu in (27.0, 58.0):
        k = joint_k(408, 0.95, nu, 3.0)
        q = k * t_factor(3.0, nu)
        assert (1 - 2 * t.sf(q, nu)) ** 408 == pytest.approx(0.95, abs=1e-9)
        assert k > joint_k(408, 0.95)  # heavier tails, wider
    with pytest.raises(ConfigError):
        joint_k(10, 1.0)


def test_verifier_sidak_width_is_scipy_stats_bit_for_bit():
    """The verifier's own Sidak half-width (scipy.special, no scipy.stats import) is the
    scipy.stats formula exactly, also where a quantile reaches the end of the support."""
    for p in (1, 6, 528, 10**6):
        for prob in (0.5, 0.95, 0.999, 1 - 1e-17):
            for dof in (None, 0.5, 5.0, 58.0, 1e5, np.inf):
                for k in (1.0, 3.0, 9.0):  # norm.cdf(9) == 1: t.ppf = inf
                    a = 1.0 - prob ** (1.0 / p)
                    if dof is None:
                        want = float(norm.isf(a / 2.0))
                    else:
                        with np.errstate(invalid="ignore"):  # inf / inf at a = 0
                            want = float(t.isf(a / 2.0, dof) / (t.ppf(norm.cdf(k), dof) / k))
                    got = _sidak_stored_k(p, prob, dof, k)
                    assert got == want or (np.isnan(got) and np.isnan(want)), (p, prob, dof, k)


def test_sidak_holds_for_correlated_gaussian_estimates():
    """Monte Carlo: 40 estimates with pairwise correlation 0.6, all inside +/- joint_k with
    probability >= 0.95 (Sidak's inequality); the marginal 3 sigma covers them far less often."""
    rng = np.random.default_rng(1)
    p, n = 40, 20000
    S = 0.6 * np.ones((p, p)) + 0.4 * np.eye(p)
    Z = rng.standard_normal((n, p)) @ np.linalg.cholesky(S).T
    k = joint_k(p, 0.95)
    all_in = np.mean(np.all(np.abs(Z) <= k, axis=1))
    assert all_in >= 0.95 - 3 * np.sqrt(0.95 * 0.05 / n)
    Z_ind = rng.standard_normal((n, p))
    ind = np.mean(np.all(np.abs(Z_ind) <= k, axis=1))
    assert ind == pytest.approx(0.95, abs=4 * np.sqrt(0.95 * 0.05 / n))
    assert np.mean(np.all(np.abs(Z_ind) <= 3.0, axis=1)) < 0.92


def _models(path: Path, dof=None) -> Path:
    """Two vertices of a 2-state plant: 3 A elements with a std (two stored at 3 std, one stored
    at 6 std: wider than the joint interval) and one fixed element."""
    verts = []
    for s in (-1.0, 1.0):
        A = [[-1.0 + 0.1 * s, 0.5], [0.2, -2.0]]
        B = [[1.0], [0.5]]
        unc = [
            {"matrix": "A", "row": 0, "col": 0, "nominal": A[0][0], "std": 0.01},
            {"matrix": "A", "row": 0, "col": 1, "nominal": 0.5, "std": 0.02},
            {"matrix": "A", "row": 1, "col": 0, "nominal": 0.2, "std": 0.01, "k": 6.0},
        ]
        for e in unc:
            k = e.pop("k", 3.0)
            e["lower"], e["upper"] = e["nominal"] - k * e["std"], e["nominal"] + k * e["std"]
        verts.append(
            {"scheduling": [s], "x0": [0.0, 0.0], "u0": [0.0], "A": A, "B": B, "uncertain": unc}
        )
    meta: dict = {"k_sigma": 3.0}
    if dof is not None:
        meta["std"] = {"dof": [dof, dof], "t_factor": [t_factor(3.0, dof)] * 2}
    doc = {
        "format": "lpv_sysid/vertex_models@2",
        "time": "continuous",
        "states": [{"name": "x1", "unit": "1"}, {"name": "x2", "unit": "1"}],
        "inputs": [{"name": "u1", "unit": "1"}],
        "scheduling": {"names": ["s"], "min": [-1.0], "max": [1.0]},
        "vertices": verts,
        "meta": meta,
    }
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def _half(box, i, r, c):
    rows, cols, half = box.arrays(i)
    sel = (rows == r) & (cols == c)
    return float(half[sel][0])


@pytest.mark.parametrize("dof", [None, 30.0])
def test_full_box_uses_the_simultaneous_half_width(tmp_path, dof):
    models = _models(tmp_path / "vm.yaml", dof)
    # default 0.95 over 6 elements: Sidak k 2.63 < 3 -> the stored (wider) 3-std intervals stay
    model, _ = load_models(models, {"set": "full_box", "box_inflation": None})
    assert _half(model.box, 0, 0, 0) == pytest.approx(0.03, rel=1e-9)
    assert model.box.coverage["probability"] == 0.95 and model.box.coverage["widened"] == 0
    model, _ = load_models(
        models, {"set": "full_box", "joint_probability": 0.999, "box_inflation": None}
    )
    box = model.box
    p = 6  # elements with a std over both vertices
    a = 1 - 0.999 ** (1 / p)
    q = norm.isf(a / 2) if dof is None else t.isf(a / 2, dof)  # in raw std
    s_raw = 1.0 if dof is None else 1.0 / t_factor(3.0, dof)  # stored std = raw * t_factor
    k = q * s_raw
    assert k > 3.0
    for i in range(2):
        assert _half(box, i, 0, 0) == pytest.approx(k * 0.01, rel=1e-9)
        assert _half(box, i, 0, 1) == pytest.approx(k * 0.02, rel=1e-9)
        assert _half(box, i, 1, 0) == pytest.approx(6.0 * 0.01, rel=1e-9)  # stored, wider
    assert box.coverage["probability"] == 0.999 and box.coverage["elements"] == p
    assert box.coverage["widened"] == 4
    # marginal (the earlier meaning): the stored 3-std intervals
    marg, _ = load_models(
        models, {"set": "full_box", "joint_probability": None, "box_inflation": None}
    )
    assert _half(marg.box, 0, 0, 0) == pytest.approx(0.03) and marg.box.coverage is None
    # the stated margin (issue 20 item 6, default 5 %): every half-width x 1.05, same centre
    infl, _ = load_models(models, {"set": "full_box", "joint_probability": None})
    assert _half(infl.box, 0, 0, 0) == pytest.approx(0.03 * 1.05, rel=1e-12)
    assert np.array_equal(infl.box.A_centre, marg.box.A_centre)
    assert infl.box.coverage == {"box_inflation": 0.05}
    with pytest.raises(ConfigError, match="joint_probability"):
        load_models(models, {"set": "full_box", "joint_probability": 1.5})


def test_verifier_recomputes_the_joint_claim(tmp_path):
    models = _models(tmp_path / "vm.yaml")
    model, raw = load_models(
        models, {"set": "full_box", "joint_probability": 0.999, "box_inflation": None}
    )
    box = model.box
    bx = {
        "Ac": np.asarray(box.A_centre),
        "Bc": np.asarray(box.B_centre),
        "rows": [box.arrays(i)[0] for i in range(2)],
        "cols": [box.arrays(i)[1] for i in range(2)],
        "half": [box.arrays(i)[2] for i in range(2)],
    }
    cert = {"certified_set": {"joint_coverage": dict(box.coverage)}}
    rep = VerifyReport()
    check_joint_claim(rep, model, raw, cert, bx)
    assert [r.ok for r in rep.rows] == [True]
    # the marginal box does not carry the claim: the verifier fails it
    bx_m = dict(bx)
    bx_m["half"] = [h * 3.0 / joint_k(6, 0.999) for h in bx["half"]]
    rep = VerifyReport()
    check_joint_claim(rep, model, raw, cert, bx_m)
    assert [r.ok for r in rep.rows] == [False]
    # a claim over fewer elements than the file has fails too
    cert_few = {"certified_set": {"joint_coverage": {**box.coverage, "elements": 2}}}
    rep = VerifyReport()
    check_joint_claim(rep, model, raw, cert_few, bx)
    assert [r.ok for r in rep.rows] == [False]


def test_coverage_study_reports_the_joint_rate():
    """An airframe is jointly covered only when every |z| <= the Sidak k of its element count
    (never below the stored 3: the box keeps a wider stored interval)."""
    P = 0.9999
    k = joint_k(4, P)
    assert k > 3.0

    def af(zs):
        v = [VertexCoverage(f"v{j}", (0.0, 0.0, 0.0), dict(z), 3.0) for j, z in enumerate(zs)]
        return AirframeCoverage(1, QuadrotorParams(), v)

    inside = af([{"a": 2.9, "b": -3.1}, {"a": 0.0, "b": k - 1e-6}])
    outside = af([{"a": 2.9, "b": -3.1}, {"a": 0.0, "b": k + 1e-6}])
    assert inside.covered == 2  # marginal 3 sigma misses two
    assert inside.jointly_covered(P) and not outside.jointly_covered(P)
    assert outside.worst_joint_ratio(P) == pytest.approx((k + 1e-6) / k)
    # at 0.95 the Sidak k of 4 elements is 2.49 < 3: the stored 3 applies, -3.1 is outside
    assert inside.joint_k(0.95) == [3.0, 3.0] and not inside.jointly_covered(0.95)
