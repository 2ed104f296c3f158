"""Report generation from a small synthetic run directory (real YAML/npz files, real PNGs)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from lpv_sysid.cli.main import main as cli_main
from lpv_sysid.errors import ConfigError
from lpv_sysid.ident.nonlinear import (
    REGRESSOR_NAMES,
    column_correlation,
    fig10_regressors,
    virtual_actuators,
)
from lpv_sysid.models.quadrotor import TRIM_COLUMNS
from lpv_sysid.report import load_run, write_report
from lpv_sysid.signals.store import save_summary
from lpv_sysid.sim.phase1 import write_trim_table
from lpv_sysid.sim.phase2 import RunRecord, regressor_correlation_block, write_outputs

STATES = ["phi", "theta", "u", "v", "w", "p", "q", "r", "dt", "da", "de", "dr"]
TABLE1_ROW0 = (-4.99, -5.04, -4.20, -10.87, 9.28, 691.4, -36.7, 29.0, 310.5)  # seed 0 Table 1
TABLE2_ROW0 = (30.1, 39.3, 81.2, 83.2, 88.9, 95.5)  # seed 0 Table 2
TABLE3 = {
    "tic": (0.110, 0.049, 0.104, 0.274, 0.355, 0.352),  # seed 0 Table 3
    "nrmse": (0.036, 0.021, 0.035, 0.094, 0.119, 0.148),
}
AXES = ["udot", "vdot", "wdot", "pdot", "qdot", "rdot"]


def _x0(row):
    u, v, w, phi, th, dt, da, de, dr = row
    return [math.radians(phi), math.radians(th), u, v, w, 0.0, 0.0, 0.0, dt, da, de, dr]


def _write_run(d: Path) -> None:
    vertices = []
    for k, sched in enumerate([[-5, -5, -5], [5, -5, -5]]):
        row = (
            TABLE1_ROW0
            if k == 0
            else (4.95, -5.04, -4.17, -10.44, -8.05, 685.0, -34.1, -1.5, 39.2)
        )
        r2 = (
            dict(zip(AXES, [x / 100 for x in TABLE2_ROW0]))
            if k == 0
            else dict(zip(AXES, [0.5] * 6))
        )
        vertices.append(
            {
                "scheduling": sched,
                "x0": _x0(row),
                "u0": [0.5, 0, 0, 0],
                "A": np.eye(12).tolist(),
                "B": np.zeros((12, 4)).tolist(),
                "fit": {"r2": r2, "tic": dict(zip(AXES, [0.2] * 6))},
            }
        )
    models = {
        "format": "lpv_sysid/vertex_models@1",
        "time": "continuous",
        "states": [{"name": n, "unit": "x"} for n in STATES],
        "vertices": vertices,
    }
    (d / "vertex_models.yaml").write_text(yaml.safe_dump(models))
    (d / "validation.yaml").write_text(
        yaml.safe_dump({k: dict(zip(AXES, v)) for k, v in TABLE3.items()})
    )
    (d / "signals").mkdir()
    names = ["u_d", "v_d", "w_d", "ue_t", "ue_a", "ue_e", "ue_r"]
    C = np.eye(7)
    C[0, 1] = C[1, 0] = 0.0752
    # summary.yaml in the layout of lpv_sysid.signals.store.summary, written by its writer
    save_summary(
        str(d / "signals" / "summary.yaml"),
        {
            "format": "lpv_sysid/signals_summary@1",
            "duration": 30.0,
            "sample_rate": 50.0,
            "channels": [
                {
                    "name": n,
                    "group": "reference" if i < 3 else "excitation",
                    "rpf": 1.1 + 0.1 * i,
                    "n_harmonics": 10 + i,
                }
                for i, n in enumerate(names)
            ],
            "correlation": {"names": names, "matrix": C.tolist(), "max_abs_offdiagonal": 0.0752},
        },
    )
    # trims.yaml written by the phase-1 simulation's own writer
    write_trim_table(
        [
            {
                "run": "v1",
                "vertex": [-5.0, -5.0, -5.0],
                "achieved": dict(zip(TRIM_COLUMNS, TABLE1_ROW0)),
                "model_trim": dict(
                    zip(TRIM_COLUMNS, [-5.0, -5.0, -5.0, -11.5, 9.5, 690.0, -30.0, 25.0, 300.0])
                ),
            }
        ],
        d,
    )
    t = np.arange(0, 2, 0.01)
    np.savez(
        d / "signals" / "signals.npz",
        t=t,
        u=np.sin(np.outer(t, np.arange(1, 8))),
        names=np.array(names),
    )
    gains = {
        "format": "lpv_sysid/gains@1",
        "gamma": 1.0,
        "R": (0.1 * np.eye(4)).tolist(),
        "Q": (5.0 * np.eye(3)).tolist(),
        "vertices": [{"scheduling": [-5, -5, -5], "K": (2.0 * np.ones((4, 12))).tolist()}],
        "certificate": {"lmi": "seed 0 Lemma 1", "solver": "CLARABEL", "gamma_achieved": 0.9321},
    }
    (d / "gains.yaml").write_text(yaml.safe_dump(gains))
    # phase 2 through the writer of sim/phase2/outputs.py (the real producer of these files)
    tt = np.linspace(0, 3, 301)
    vd = np.column_stack([np.sin(tt), np.cos(tt), 0 * tt])
    x12 = np.zeros((tt.size, 12))
    x12[:, 2:5] = vd + 0.05 * np.sin(7 * tt)[:, None]
    x12[:, 8] = 600 + 10 * np.sin(11 * tt)
    x12[:, 9:12] = 5 * np.sin(np.outer(tt, [13, 17, 19]))
    rec = RunRecord(
        "eq33",
        tt,
        vd,
        x12,
        np.zeros((tt.size, 4)),
        np.zeros((tt.size, 4)),
        np.zeros((tt.size, 3)),
        gain=0.4321,
        z_norm=0.04321,
        ue_norm=0.1,
    )
    rec.decomposition = {
        "method": "superposition (exact: the same run with -u_e)",
        "ue_norm": 0.1,
        "total": {"z_norm": 0.04321, "ratio": 0.4321},
        "offset": {"z_norm": 0.04, "ratio": 0.4},
        "excitation": {"z_norm": 0.005, "gain": 0.05},
        "tracking": {"z_norm": 0.01, "ratio": 0.1},
    }
    block = regressor_correlation_block(tt, x12, 0.225, "eq33")
    write_outputs(
        d / "phase2",
        1.0,
        2.5,
        [rec],
        skipped={"nonlinear": "no quadrotor model"},
        regressor_block=block,
        extra={"box": {"min": [-5.0, -5.0, -5.0], "max": [5.0, 5.0, 5.0]}},
    )


def test_report_contains_expected_numbers(tmp_path):
    _write_run(tmp_path)
    out = write_report(tmp_path, tmp_path / "rep" / "report.md", verify=False)
    text = out.read_text()
    # Table 1: phi0/theta0 converted back to degrees, rotor states as stored
    assert (
        "| [-5 -5 -5] | -4.99 | -5.04 | -4.20 | -10.87 | 9.28 | 691.40 | -36.70 | 29.00 | 310.50 |"
        in text
    )
    # Table 2: R^2 stored as fractions is printed in percent
    assert "| [-5 -5 -5] | 30.1 | 39.3 | 81.2 | 83.2 | 88.9 | 95.5 |" in text
    # Table 3
    assert "| TIC | 0.110 | 0.049 | 0.104 | 0.274 | 0.355 | 0.352 |" in text
    assert "| NRMSE | 0.036 | 0.021 | 0.035 | 0.094 | 0.119 | 0.148 |" in text
    # phase-1 trims: achieved row (Table 1 values) and model trim
    assert (
        "| v1 | [-5 -5 -5] | achieved | -4.99 | -5.04 | -4.20 | -10.87 | 9.28 | 691.40 |" in text
    )
    assert (
        "| v1 | [-5 -5 -5] | model trim | -5.00 | -5.00 | -5.00 | -11.50 | 9.50 | 690.00 |" in text
    )
    # signals: worst correlation and RPF
    assert "**0.0752**" in text and "| ue_r | excitation | 16 | 1.7 |" in text
    # certificate and gain vs gamma
    assert "gamma_achieved | 0.9321" in text
    # the u_e -> z gain, not the total ratio, is what is compared with gamma; the rest named apart
    assert (
        "| LPV closed loop, Eq. (33) | 0.05 | yes | superposition | 0.4 | 0.1 | 0.4321 | "
        "completed |" in text
    )
    assert "skipped: no quadrotor model" in text
    assert "kappa = 2.5" in text
    # inputs that do not exist are named
    assert "**Input missing:** none of `verification.yaml` in the run directory." in text
    # ... so the go/no-go table says so instead of re-running the verifier
    assert (
        "| independent verification | not verified | verification.yaml, passed | NO-GO |" in text
    )
    # figures exist and are referenced
    for png in (
        "tracking_eq33.png",
        "perturbation_eq33.png",
        "regressor_correlation.png",
        "spectra.png",
        "signal_correlation.png",
        "margins_eq33.png",
    ):
        assert f"]({png})" in text
        assert (out.parent / png).stat().st_size > 1000
    # Fig. 10 table: the 'u' and 'u dt' X-axis regressors are strongly correlated here
    # (dt nearly constant), the value printed must be the recomputed correlation
    x = np.load(tmp_path / "phase2" / "eq33.npz")
    c = abs(np.corrcoef(x["v"][:, 0], x["v"][:, 0] * x["x"][:, 8])[0, 1])
    assert f"| X | 3 | {max(c, block_max(x, 'X')):.3f} |" in text


def block_max(x, axis):
    from lpv_sysid.models.quadrotor import mixer

    mix = mixer(0.225)
    Om = np.linalg.solve(mix, x["x"][:, 8:12].T).T
    d, d2 = virtual_actuators(Om, mix)
    C = np.abs(
        column_correlation(fig10_regressors(x["t"], x["v"], x["x"][:, 5:8], d, d2, 0.225)[axis])
    )
    np.fill_diagonal(C, 0)
    return float(np.nanmax(C))


def test_verification_is_read_never_recomputed_and_bad_files_are_named(tmp_path):
    """Without verification.yaml the report does not run the verifier (NO-GO: not verified); a
    hand-written file that is not the verify record is unreadable (NO-GO), not trusted."""
    _write_run(tmp_path)
    text = write_report(tmp_path).read_text()
    assert "## Go / no-go: **NO-GO**" in text and "not verified" in text
    assert "| independent verification | missing |" in text
    (tmp_path / "verification.yaml").write_text(
        yaml.safe_dump({"passed": True, "checks": [{"check": "hinf", "ok": True}]})
    )
    text = write_report(tmp_path).read_text()
    assert "| independent verification | UNREADABLE | " in text
    assert "format: expected 'lpv_sysid/verification@1'" in text
    assert "| independent verification | unreadable | verification.yaml, passed | NO-GO |" in text


def test_empty_run_dir_lists_every_missing_input(tmp_path):
    out = write_report(tmp_path)
    text = out.read_text()
    assert out == tmp_path / "report" / "report.md"
    for name in (
        "vertex_models.yaml",
        "gains.yaml",
        "phase2/summary.yaml",
        "signals/summary.yaml",
        "validation.yaml",
        "verification.yaml",
        "trims.yaml",
    ):
        assert f"`{name}`" in text
    assert text.count("**Input missing:**") >= 6
    assert "Missing or unreadable inputs:" in text


def test_malformed_input_is_named_and_strict_cli_fails(tmp_path, capsys):
    (tmp_path / "gains.yaml").write_text("gamma: [1, 2\n")
    (tmp_path / "vertex_models.yaml").write_text("- just a list\n")
    data = load_run(tmp_path)
    assert "malformed YAML" in data.problems["gains"]
    assert "expected a mapping" in data.problems["models"]
    text = write_report(tmp_path).read_text()
    assert "UNREADABLE" in text and "gains.yaml: malformed YAML" in text
    assert cli_main(["report", "--run", str(tmp_path), "--strict"]) == 2
    assert "gains.yaml: malformed YAML" in capsys.readouterr().err
    assert cli_main(["report", "--run", str(tmp_path / "nope")]) == 2
    with pytest.raises(ConfigError, match=r"\.md"):
        write_report(tmp_path, tmp_path / "report.txt")


def test_core_names_the_argument_and_the_cli_the_flag(tmp_path, capsys):
    """The report core names its argument (``run_dir``, ``out_path``), not a command-line
    flag; ``lpv-sysid report`` appends the flag that sets it."""
    with pytest.raises(ConfigError, match=r"^run_dir: .*nope is not a directory$"):
        load_run(tmp_path / "nope")
    with pytest.raises(ConfigError, match=r"^out_path: .*report\.txt must end in \.md$"):
        write_report(tmp_path, tmp_path / "report.txt")
    (tmp_path / "plain").write_text("")
    with pytest.raises(ConfigError, match=r"^out_path: cannot create .*plain"):
        write_report(tmp_path, tmp_path / "plain" / "r.md")
    assert cli_main(["report", "--run", str(tmp_path / "nope")]) == 2
    assert "nope is not a directory [--run]" in capsys.readouterr().err
    assert cli_main(["report", "--run", str(tmp_path), "--out", str(tmp_path / "r.txt")]) == 2
    assert "r.txt must end in .md [--out]" in capsys.readouterr().err


def test_cli_prints_path(tmp_path, capsys):
    _write_run(tmp_path)
    target = tmp_path / "out" / "r.md"
    assert cli_main(["report", "--run", str(tmp_path), "--out", str(target)]) == 0
    assert capsys.readouterr().out.strip() == str(target)
    assert target.is_file()


def test_regressors_match_eq6_by_hand():
    """Spot values of Eq. (6) regressors against a hand computation; dt^2 is Mix Omega^2."""
    from lpv_sysid.models.quadrotor import mixer

    ell = 0.25
    mix = mixer(ell)
    Omega = np.array([[500.0, 510.0, 490.0, 505.0], [600.0, 590.0, 610.0, 595.0]])
    t = np.array([0.0, 0.1])
    v = np.array([[1.0, 2.0, 3.0], [0.5, -1.0, 2.0]])
    om = np.array([[0.1, 0.2, 0.3], [-0.1, 0.05, 0.0]])
    d, d2 = virtual_actuators(Omega, mix)
    regs = fig10_regressors(t, v, om, d, d2, ell)
    dt, da, de, dr = d[0]
    assert d2[0, 0] == pytest.approx(np.mean(Omega[0] ** 2))
    assert regs["Z"][0, 3] == pytest.approx(4 * 3.0 * dt - 0.1 * da - 0.2 * de)
    assert regs["L"][0, 2] == pytest.approx(
        3.0 * da - 2 * ell**2 * 0.1 * dt - ell**2 * 0.2 * dr / 2
    )
    assert regs["M"][0, 6] == pytest.approx(2.0 * dr)
    assert regs["N"][0, 6] == pytest.approx((d[1, 3] - d[0, 3]) / 0.1)
    assert [regs[a].shape[1] for a in "XYZLMN"] == [len(REGRESSOR_NAMES[a]) for a in "XYZLMN"]
    C = column_correlation(np.column_stack([t, 2 * t + 1, np.ones(2)]))
    assert C[0, 1] == pytest.approx(1.0) and np.isnan(C[0, 2])


def test_table3_from_models_meta_validation(tmp_path):
    """identify stores the independent validation (Table 3) in vertex_models.yaml meta."""
    models = {
        "states": [{"name": n} for n in STATES],
        "vertices": [],
        "meta": {
            "validation": {
                "maneuver": "hover_validation",
                "tic": dict(zip(AXES, TABLE3["tic"])),
                "nrmse": dict(zip(AXES, TABLE3["nrmse"])),
            }
        },
    }
    (tmp_path / "vertex_models.yaml").write_text(yaml.safe_dump(models))
    text = write_report(tmp_path, verify=False).read_text()
    assert (
        "Independent validation maneuver `hover_validation` "
        "(from vertex_models.yaml meta.validation):" in text
    )
    assert (
        "| independent validation (Table 3) | derived | from vertex_models.yaml meta.validation |"
        in text
    )
    assert "| TIC | 0.110 | 0.049 | 0.104 | 0.274 | 0.355 | 0.352 |" in text
    assert "| metric | udot | vdot | wdot | pdot | qdot | rdot |" in text
