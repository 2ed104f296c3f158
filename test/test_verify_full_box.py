"""`lpv-sysid verify --full-box`: empirical Monte Carlo over the full identified uncertainty box.

Plant (2 states, 2 inputs, 1 scheduling axis s in [-1, 1]): A_i = diag(a1, a2) with identified
elements a1, a2 per vertex, B = I, K_i = -I, R = I, performance output z = x2 (Q = 1,
C = [0 1]). The frozen closed loop is
diag(a1 - 1, a2 - 1) with G(s) = [0, 1 / (s + 1 - a2)], so ||G||_inf = 1 / (1 - a2) (peak at
w = 0) when both a_k < 1, and the loop is unstable otherwise.
A(s) is affine in the vertex values, so the sup over the box is attained at a scheduling vertex
with the element at its upper end: the analytic oracle.
"""

import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from support.toy_plant import write_toy_plant

from lpv_sysid.cli.main import main
from lpv_sysid.synthesis.verify import (
    full_box_intervals,
    read_verification,
    record_verification,
    verify_files,
)

K_SIGMA = 3.0


def _el(r, c, nom, std, lo=None, hi=None):
    return {
        "matrix": "A",
        "row": r,
        "col": c,
        "nominal": nom,
        "std": std,
        "lower": nom if lo is None else lo,
        "upper": nom if hi is None else hi,
    }


def _write(tmp: Path, std_v0_a2: float) -> tuple[Path, Path]:
    """vertex 0: a2 stored lower = upper = nominal (a dropped element as ident writes it) with
    std ``std_v0_a2`` -> full interval -1 +/- 3 std; vertex 1: a1 a kept corner parameter with the
    stored (widened) interval [-1.1, -0.8]; the other elements have std 0.02."""
    v0 = [_el(0, 0, -1.0, 0.02), _el(1, 1, -1.0, std_v0_a2)]
    v1 = [_el(0, 0, -1.0, 0.05, -1.1, -0.8), _el(1, 1, -1.0, 0.02)]
    return write_toy_plant(tmp, [v0, v1], k_sigma=K_SIGMA, gamma_achieved=0.9, min_margin=0.0)


def _grid_norm(Acl, Be, C):
    """Independent oracle: peak of sigma_max(C (jwI - Acl)^-1 Be) on a dense grid (0 included)."""
    w = np.concatenate([[0.0], np.logspace(-4, 3, 4000)])
    n = Acl.shape[0]
    return max(
        np.linalg.svd(C @ np.linalg.solve(1j * wk * np.eye(n) - Acl, Be), compute_uv=False)[0]
        for wk in w
    )


def test_intervals_follow_the_stored_bounds_or_k_std(tmp_path):
    _, models = _write(tmp_path, 0.1)
    boxes, k, src = full_box_intervals(yaml.safe_load(models.read_text()))
    assert k == K_SIGMA and "meta.k_sigma" in src
    # vertex 0: lower = upper = nominal with std -> nominal +/- 3 std
    assert boxes[0].lower.tolist() == pytest.approx([-1.06, -1.3]) and boxes[
        0
    ].upper.tolist() == pytest.approx([-0.94, -0.7])
    assert boxes[0].source == ("k*std", "k*std")
    # vertex 1: a1 has lower < upper -> the stored interval, not -1 +/- 0.15
    assert boxes[1].lower.tolist() == pytest.approx([-1.1, -1.06]) and boxes[
        1
    ].upper.tolist() == pytest.approx([-0.8, -0.94])
    assert boxes[1].source == ("stored", "k*std")
    boxes2, _, _ = full_box_intervals(yaml.safe_load(models.read_text()), kept="ksigma")
    assert boxes2[1].lower[0] == pytest.approx(-1.15) and boxes2[1].upper[0] == pytest.approx(
        -0.85
    )
    boxes3, k3, _ = full_box_intervals(yaml.safe_load(models.read_text()), k_sigma=1.0)
    assert k3 == 1.0 and boxes3[0].upper[1] == pytest.approx(-0.9)


def test_small_intervals_pass_and_worst_norm_matches_the_oracles(tmp_path, capsys):
    gains, models = _write(tmp_path, 0.1)
    rep = verify_files(gains, models, n_random=4, seed=3, full_box=40)
    assert rep.passed, rep.table()
    fb = rep.full_box
    assert fb.passed and fb.fraction_ok == 1.0 and fb.all_stable and fb.n == 40 + 4
    # analytic sup over the box: vertex 0 (s = -1) with a2 = -1 + 3 * 0.1 = -0.7 -> 1 / 1.7; the
    # first-order worst corner finds it exactly
    assert fb.worst.norm == pytest.approx(1 / 1.7, rel=1e-5)
    assert fb.worst.v_d.tolist() == [-1.0] and "vertex 0 worst-norm corner" in fb.worst.where
    Acl = fb.worst_A + fb.worst_B @ fb.worst_K
    assert np.allclose(Acl, np.diag([Acl[0, 0], -1.7]))
    assert fb.worst.norm == pytest.approx(
        _grid_norm(Acl, fb.worst_B, np.array([[0.0, 1.0]])), rel=1e-5
    )
    # no sample exceeds the analytic sup (hinf_norm returns the bracket's upper end, +2e-6 rel)
    assert all(s.norm <= 1 / 1.7 * (1 + 1e-5) for s in fb.samples)
    assert all(s.norm >= 1 / (1 + 1.3) * (1 - 1e-9) for s in fb.samples)  # a2 >= -1.3 everywhere
    assert fb.max_abscissa == pytest.approx(-1.7, abs=1e-9)
    rows = {r.check: r for r in rep.rows if r.check.startswith("full-box")}
    assert set(rows) == {"full-box hinf", "full-box frac", "full-box stab"} and all(
        r.ok for r in rows.values()
    )
    rc = main(
        [
            "verify",
            "--gains",
            str(gains),
            "--models",
            str(models),
            "--full-box",
            "20",
            "--random",
            "2",
        ]
    )
    out = capsys.readouterr().out
    assert rc == 0 and "PASS" in out and "WARN" not in out
    worst = float(re.search(r"worst norm ([0-9.eE+-]+) vs gamma 1 at v_d \[-1.0\]", out).group(1))
    assert worst == pytest.approx(1 / 1.7, rel=1e-5)


def test_destabilising_interval_is_found_and_warns_unless_strict(tmp_path, capsys):
    # vertex 0: a2 in -1 +/- 3 * 1.0 = [-4, 2]: closed loop a2 - 1 unstable for a2 > 1
    gains, models = _write(tmp_path, 1.0)
    rep = verify_files(gains, models, n_random=4, seed=0, full_box=60)
    fb = rep.full_box
    assert rep.passed  # the certificate's own checks still hold
    assert not fb.passed and 0.0 < fb.fraction_ok < 1.0 and not fb.all_stable
    assert fb.max_abscissa == pytest.approx(1.0, abs=1e-9)  # analytic: a2 = 2 at s = -1
    assert fb.worst.v_d.tolist() == [-1.0] or fb.worst.norm == np.inf
    unstable = [s for s in fb.samples if s.abscissa >= 0]
    assert unstable and all(s.norm == np.inf and not s.ok for s in unstable)
    warn = [r for r in rep.rows if r.check.startswith("full-box") and not r.ok]
    assert warn and all(r.advisory and r.result == "WARN" for r in warn)
    assert "WARN" in rep.table() and "0 failed" in rep.table()
    args = [
        "verify",
        "--gains",
        str(gains),
        "--models",
        str(models),
        "--full-box",
        "30",
        "--random",
        "2",
    ]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "WARN" in out and "PASS" in out
    assert main(args + ["--strict-full-box"]) == 1
    out = capsys.readouterr().out
    assert "FAIL" in out and "full-box frac" in out
    assert main(args[:-4] + ["--full-box", "-1"]) == 2 and "--full-box" in capsys.readouterr().err
    strict = verify_files(gains, models, n_random=2, full_box=30, strict_full_box=True)
    assert not strict.passed and any(
        r.check == "full-box frac" and r.result == "FAIL" for r in strict.rows
    )


def test_seed_reproduces_the_samples(tmp_path):
    gains, models = _write(tmp_path, 1.0)
    a = verify_files(gains, models, n_random=1, seed=7, full_box=30).full_box
    b = verify_files(gains, models, n_random=1, seed=7, full_box=30).full_box
    c = verify_files(gains, models, n_random=1, seed=8, full_box=30).full_box
    key = lambda fb: [(s.where, s.v_d.tolist(), s.norm, s.abscissa) for s in fb.samples]  # noqa: E731
    assert key(a) == key(b) and a.summary() == b.summary()
    assert key(a) != key(c)


def test_report_verification_carries_the_full_box(tmp_path):
    """verify writes the Monte Carlo into verification.yaml; the report renders it from there
    (reduced-polytope certificate: a miss is a WARNING naming that set, not a failure)."""
    from lpv_sysid.report import write_report

    gains, models = _write(tmp_path, 1.0)
    _, path = record_verification(gains, models, n_random=2, full_box=20)
    assert path == tmp_path / "verification.yaml"
    v = read_verification(path)
    raw = yaml.safe_load(path.read_text())
    assert v.passed and raw["full_box"]["samples"] == 20 + 2 * 2
    assert raw["full_box"]["fraction_ok"] < 1
    assert any(c.get("advisory") and not c["ok"] for c in raw["checks"])
    text = write_report(tmp_path, tmp_path / "rep" / "report.md").read_text()
    assert "Full identified uncertainty box (empirical Monte Carlo)" in text
    assert "advisory warnings" in text
    assert "**WARNING:** samples outside the bound -- this certificate covers the reduced" in text


def test_element_sensitivities_match_finite_differences():
    """The analytic first-order sensitivities that pick the worst corners vs central differences
    of the Hamiltonian-bisection norm and of numpy's eigenvalues (3 states, 2 inputs, A and B
    elements)."""
    from lpv_sysid.synthesis.hinf import hinf_norm
    from lpv_sysid.synthesis.verify import ElementBox, element_sensitivities

    rng = np.random.default_rng(4)
    A = np.array([[-1.0, 2.0, 0.0], [-2.0, -0.5, 1.0], [0.0, 0.3, -2.0]])
    B = rng.normal(size=(3, 2))
    K = -0.3 * B.T
    R = np.diag([0.7, 1.2])
    C = np.array([[1.0, 0.0, 0.5]])
    box = ElementBox(
        np.array([True, True, False, False]),
        np.array([0, 1, 2, 0]),
        np.array([1, 1, 0, 1]),
        np.zeros(4),
        np.full(4, -1.0),
        np.full(4, 1.0),
        ("stored",) * 4,
    )
    theta = np.array([A[0, 1], A[1, 1], B[2, 0], B[0, 1]])
    (n1, g_norm), (n2, g_abs) = element_sensitivities(A, B, K, R, C, box, theta)
    assert n1 == "worst-norm corner" and n2 == "worst-abscissa corner"

    def f(th):
        Ap, Bp = box.apply(A, B, th)
        Acl = Ap + Bp @ K
        return hinf_norm(Acl, Bp @ R, C, tol=1e-10).lower, float(
            np.max(np.linalg.eigvals(Acl).real)
        )

    h = 1e-6
    for k in range(4):
        e = np.zeros(4)
        e[k] = h
        (np_, ap), (nm, am) = f(theta + e), f(theta - e)
        assert g_norm[k] == pytest.approx((np_ - nm) / (2 * h), rel=1e-3, abs=1e-6)
        assert g_abs[k] == pytest.approx((ap - am) / (2 * h), rel=1e-3, abs=1e-6)
