"""`lpv-sysid synthesize` -> `lpv-sysid verify` round trip, tampering, and the verifier's
checks."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from lpv_sysid.cli.main import main
from lpv_sysid.io.formats import GainSchedule, certify_law
from lpv_sysid.synthesis.hinf import hinf_norm
from lpv_sysid.synthesis.uncertainty_set import load_models
from lpv_sysid.synthesis.verify import verify_files


def _models(path: Path, a=1.0, b=1.0):
    """x' = a x + b u (scalar, unstable), 1-axis box; z = Q^-1 x."""
    verts = [
        {"scheduling": [s], "x0": [0.0], "u0": [0.0], "A": [[a]], "B": [[b]], "uncertain": []}
        for s in (-1.0, 1.0)
    ]
    doc = {
        "format": "lpv_sysid/vertex_models@1",
        "time": "continuous",
        "states": [{"name": "x", "unit": "m/s"}],
        "inputs": [{"name": "u", "unit": "1"}],
        "scheduling": {"names": ["s"], "min": [-1.0], "max": [1.0]},
        "vertices": verts,
    }
    path.write_text(yaml.safe_dump(doc))
    return path


def _config(path: Path, region: bool):
    # T = 2, Delta_in = 1 -> R = sqrt(1*2/2) = 1 (Eq. 27); Delta_out = 1/sqrt(2) -> Q = 1 (Eq. 28)
    hinf = {"gamma": 0.5, "solver": "CLARABEL", "fallback": "SCS"}
    if region:
        hinf["region"] = {"strip": {"min": -2.5, "max": -1.0}}
    cfg = {
        "hinf": hinf,
        "weights": {"T": 2.0, "input_magnitudes": [1.0], "output_magnitudes": [2**-0.5]},
        "velocity_states": ["x"],
        "verify": {"n_random": 5, "seed": 1},
    }
    path.write_text(yaml.safe_dump(cfg))
    return path


@pytest.fixture()
def synthesized(tmp_path, capsys):
    models = _models(tmp_path / "vertex_models.yaml")
    cfg = _config(tmp_path / "synthesis.yaml", region=True)
    out = tmp_path / "out" / "gains.yaml"
    rc = main(["synthesize", "--models", str(models), "--config", str(cfg), "--out", str(out)])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert f"wrote {out}" in text and (out.parent / "gains.cert.npz").is_file()
    return models, out


def test_synthesize_writes_certified_gains_and_verify_passes(synthesized, capsys):
    models, out = synthesized
    g = GainSchedule.load(out, auto_layout=True)
    k = g.K[0, 0, 0]
    # analytic: ||G||_inf = 1 / |1 + k| <= 0.5 needs 1 + k <= -2; region strip needs 1 + k > -2.5
    assert -2.5 < 1 + k <= -2.0 + 1e-6
    assert g.certificate.gamma_achieved <= 0.5 and g.certificate.min_margin > 0
    assert g.certificate.to_dict()["region"] == {"strip": {"min": -2.5, "max": -1.0}}
    rc = main(["verify", "--gains", str(out), "--models", str(models)])
    text = capsys.readouterr().out
    assert rc == 0 and "PASS" in text and "0 failed" in text


def test_tampered_gain_breaks_the_bound_and_fails_verify(synthesized, capsys):
    models, out = synthesized
    d = yaml.safe_load(out.read_text())
    k = d["vertices"][0]["K"][0][0]
    d["vertices"][0]["K"][0][0] = 0.8 * k  # one entry changed by 20%
    # re-hashed and re-sealed (anyone can: certify_law is public, the seal unkeyed): the
    # file checks, only the independent verification can catch the broken bound
    d = certify_law(d, layout=None)
    out.write_text(yaml.safe_dump(d, sort_keys=False))
    # the bound is really broken at that vertex (independent oracle: 1 / |1 + 0.8 k| > 0.5)
    assert 1.0 / abs(1 + 0.8 * k) > 0.5
    assert hinf_norm(np.array([[1 + 0.8 * k]]), np.eye(1), np.eye(1)).value > 0.5
    rc = main(["verify", "--gains", str(out), "--models", str(models)])
    text = capsys.readouterr().out
    assert rc == 1 and "FAIL" in text
    rep = verify_files(out, models, n_random=3)
    failed = {r.check for r in rep.rows if not r.ok}
    assert {"hinf", "K = S H^-1", "gamma claim"} <= failed
    assert not [
        r for r in rep.rows if r.check == "hinf" and r.where.startswith("vertex 1") and not r.ok
    ]


def test_verify_refuses_other_models_and_tampered_sidecar(synthesized, capsys):
    models, out = synthesized
    other = _models(models.parent / "other.yaml", a=1.3)
    rep = verify_files(out, other, n_random=2)
    assert not rep.passed and any(r.check == "models hash" and not r.ok for r in rep.rows)
    side = out.parent / "gains.cert.npz"
    z = dict(np.load(side))
    z["H"] = z["H"] * 1.01
    np.savez(side, **z)
    rep = verify_files(out, models, n_random=2)
    assert any(r.check == "sidecar" and not r.ok for r in rep.rows)


def test_bad_input_exit_2(tmp_path, capsys):
    bad = tmp_path / "m.yaml"
    bad.write_text("format: [unclosed\n")
    cfg = _config(tmp_path / "c.yaml", region=False)
    rc = main(
        [
            "synthesize",
            "--models",
            str(bad),
            "--config",
            str(cfg),
            "--out",
            str(tmp_path / "g.yaml"),
        ]
    )
    assert rc == 2
    assert "m.yaml" in capsys.readouterr().err


def test_vertex_dependent_B_is_caught_in_the_interior(tmp_path, capsys):
    # B changes sign between the vertices: Lemma 1 finds vertex gains (S_i per vertex), but the
    # interpolated law fails in the interior (B(v_d) K(v_d) = 0 at s = 0): the verifier catches it
    models = _models(tmp_path / "vertex_models.yaml")
    d = yaml.safe_load(models.read_text())
    d["vertices"][1]["B"] = [[-1.0]]
    models.write_text(yaml.safe_dump(d))
    cfg = _config(tmp_path / "c.yaml", region=False)
    c = yaml.safe_load(cfg.read_text())
    c["uncertainty"] = {"common_b": False}  # the old per-vertex B structure (not the default)
    cfg.write_text(yaml.safe_dump(c))
    rc = main(
        [
            "synthesize",
            "--models",
            str(models),
            "--config",
            str(cfg),
            "--out",
            str(tmp_path / "g.yaml"),
        ]
    )
    out = capsys.readouterr().out
    assert rc == 1 and "B differs between scheduling vertices" in out and "FAIL" in out
    rep = verify_files(tmp_path / "g.yaml", models, n_random=20)
    assert all(r.ok for r in rep.rows if r.check == "hinf")  # vertices certified
    assert any(not r.ok for r in rep.rows if r.check == "hinf interior")  # interior is not


def test_infeasible_request_explains_remedy(tmp_path, capsys):
    # uncertain B in [-1, 1] contains B = 0 with an unstable A: no gain stabilises all of Eq. (23)
    models = _models(tmp_path / "vertex_models.yaml")
    d = yaml.safe_load(models.read_text())
    for v in d["vertices"]:
        v["uncertain"] = [
            {
                "matrix": "B",
                "row": 0,
                "col": 0,
                "nominal": 0.0,
                "std": 0.5,
                "lower": -1.0,
                "upper": 1.0,
            }
        ]
        v["B"] = [[0.0]]
    models.write_text(yaml.safe_dump(d))
    cfg = _config(tmp_path / "c.yaml", region=False)
    rc = main(
        [
            "synthesize",
            "--models",
            str(models),
            "--config",
            str(cfg),
            "--out",
            str(tmp_path / "g.yaml"),
        ]
    )
    err = capsys.readouterr().err
    assert rc == 2 and "Lemma 1" in err and "reduce the uncertainty" in err
    assert not (tmp_path / "g.yaml").exists()


def test_load_models_corner_enumeration(tmp_path):
    models = _models(tmp_path / "vertex_models.yaml")
    d = yaml.safe_load(models.read_text())
    for v in d["vertices"]:
        v["uncertain"] = [
            {
                "matrix": "A",
                "row": 0,
                "col": 0,
                "nominal": 1.0,
                "std": 0.1,
                "lower": 0.8,
                "upper": 1.2,
            }
        ]
    models.write_text(yaml.safe_dump(d))
    m, _ = load_models(models)
    assert [len(s) for s in m.systems] == [2, 2]
    assert sorted(a[0, 0] for a, _ in m.systems[0]) == [0.8, 1.2]


def test_written_gains_load_with_io_formats_and_drive_the_runtime_law(synthesized):
    from lpv_sysid.control.law import LpvController, LpvControllerConfig
    from lpv_sysid.io.formats import GainSchedule

    models, out = synthesized
    gs = GainSchedule.load(
        out, models_path=models, layout=None
    )  # checks hash, names, box, equilibria
    ctl = LpvController(gs, LpvControllerConfig(velocity_index=(0,)))
    u, info = ctl.step(0.0, np.array([0.2]), np.array([0.3]), np.array([0.5]))
    k = 0.35 * gs.K[0, 0, 0] + 0.65 * gs.K[1, 0, 0]  # s = 0.3 in [-1, 1]: alpha = (0.35, 0.65)
    np.testing.assert_allclose(u, [k * 0.2 + 1.0 * 0.5], rtol=1e-12)  # u0 = 0, x0 = 0, R = 1
