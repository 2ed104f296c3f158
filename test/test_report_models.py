"""The report's view of the identified models (issue 23 item 3): open-loop poles and time to
double per vertex (oracle: the eigenvalues placed in A by construction) and the parameter
table with intervals and significance."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import yaml
from test_formats import models_dict

from lpv_sysid.report import write_report
from lpv_sysid.report.sections_models import parameter_rows, pole_rows


def _with_poles(doc):
    rng = np.random.default_rng(2)
    for k, v in enumerate(doc["vertices"]):
        # eigenvalues: +2.1 (vertex 0 only, else -2.1), 0.5 +/- 2j, the rest stable
        lam = [2.1 if k == 0 else -2.1, -1.0, -3.0, -4.0, -5.0, -6.0, -7.0, -8.0, -9.0, -10.0]
        J = np.zeros((12, 12))
        J[:10, :10] = np.diag(lam)
        J[10:, 10:] = [[0.5, 2.0], [-2.0, 0.5]]
        T = rng.normal(size=(12, 12)) + 5 * np.eye(12)
        v["A"] = (T @ J @ np.linalg.inv(T)).tolist()
    return doc


def test_poles_and_time_to_double():
    doc = _with_poles(copy.deepcopy(models_dict()))
    rows = pole_rows(doc)
    assert len(rows) == 8
    assert rows[0][2] == pytest.approx(2.1, rel=1e-9)
    assert rows[0][3] == pytest.approx(math.log(2) / 2.1, rel=1e-9)  # 0.33 s
    assert rows[0][1].startswith("+2.1, +0.5+2j")
    for r in rows[1:]:
        assert r[2] == pytest.approx(0.5) and r[1] == "+0.5+2j"
        assert r[3] == pytest.approx(math.log(2) / 0.5)


def test_parameter_table_intervals_and_significance():
    doc = copy.deepcopy(models_dict())
    e = doc["vertices"][0]["uncertain"][0]
    e.update(nominal=-0.41, std=0.03, lower=-0.50, upper=-0.32)
    e2 = doc["vertices"][1]["uncertain"][0]
    e2.update(nominal=0.02, std=0.03, lower=-0.07, upper=0.11)
    header, rows = parameter_rows(doc)
    assert header[0] == "element" and len(header) == 9
    row = next(r for r in rows if r[0] == "A[u, phi]")  # row 2 = u, col 0 = phi
    assert row[1] == "-0.41 [-0.5, -0.32] 13.7*"
    assert row[2] == "+0.02 [-0.07, +0.11] 0.7"  # interval holds zero: not significant
    assert all(r[0] != "B[dr, ur]" for r in rows)  # std 0: known, not identified


def test_report_shows_the_views(tmp_path):
    doc = _with_poles(copy.deepcopy(models_dict()))
    axes = ("u", "v", "w", "p", "q", "r")
    doc.setdefault("meta", {})["validation"] = {
        "maneuver": "hover",
        "tic": {a + "dot": 0.1 for a in axes},
        "nrmse": {a + "dot": 0.1 for a in axes},
        "output_error": {
            "horizon_s": 1.0,
            "tic": dict.fromkeys(axes, 0.05),
            "nrmse": {a: 0.01 * (k + 1) for k, a in enumerate(axes)},
        },
    }
    (tmp_path / "vertex_models.yaml").write_text(yaml.safe_dump(doc))
    text = write_report(tmp_path).read_text()
    assert "restarted from the measured state every 1.00 s" in text
    assert "| NRMSE | 0.010 | 0.020 | 0.030 | 0.040 | 0.050 | 0.060 |" in text
    assert "## Identified models: open-loop stability and parameters" in text
    assert "shortest: **0.33 s**" in text


def test_data_source_labels_sitl_apart_from_flown(tmp_path):
    from lpv_sysid.report import load_run, provenance

    for kind, meta in (
        ("SITL", {"vehicle": {"kind": "SITL"}}),
        ("SIMULATED", {"vehicle": {"kind": "SIMULATED"}}),
        ("HITL", {"provenance": {"vehicle_kind": "HITL", "source": {"kind": "px4_ulog"}}}),
        ("FLOWN", {"status": "closed_cleanly"}),  # an older record: kind not recorded
    ):
        run = tmp_path / kind
        run.mkdir()
        (run / "experiment.yaml").write_text(yaml.safe_dump(meta))
        src = provenance(load_run(run, verify=False))
        assert src[0].dataset == "phase-1 flights" and src[0].label == kind


def test_loop_margins_of_an_unstable_first_order_loop():
    """Four decoupled loops L = k / (s - 1) (plant 1/(s-1), du = -k dx): analytic margins
    gm = 1/k, pm = atan(sqrt(k^2 - 1)); balanced disk margin 2/(1 + k) at w = 0 for k >= 1."""
    pytest.importorskip("control")
    from lpv_sysid.report.sections_models import loop_margins

    k = np.array([2.0, 3.0, 1.5, 4.0])
    A = -2.0 * np.eye(12)
    A[:4, :4] = np.eye(4)
    B = np.zeros((12, 4))
    B[:4, :4] = np.eye(4)
    K = np.zeros((4, 12))
    K[:4, :4] = -np.diag(k)
    res = loop_margins(A, B, K)
    for (gm_db, pm, dm, _, _), ki in zip(res["channels"], k):
        assert gm_db == pytest.approx(20 * math.log10(1 / ki), abs=1e-6)
        assert pm == pytest.approx(math.degrees(math.atan(math.sqrt(ki**2 - 1))), abs=1e-3)
        # |0.5 (S - T)| = 0.5 |(1 - L) / (1 + L)| peaks at w = 0, L(0) = -k: (1 + k) / 2 (k - 1)
        assert dm == pytest.approx(2 * (ki - 1) / (ki + 1), rel=1e-3)
    assert res["closed_loop_stable"]
    # decoupled loops: the unstructured MIMO margin is the smallest channel's
    assert res["mimo_disk_margin"] == pytest.approx(min(d[2] for d in res["channels"]), rel=1e-3)


def test_chain_directory_gets_the_run_report(tmp_path):
    """A chain directory (phase1/ flown on PX4 SITL) gets report/report.md beside its own
    summary, go/no-go first, the data labelled SITL."""
    from lpv_sysid.flight.chain.report import _full_report

    (tmp_path / "phase1").mkdir()
    (tmp_path / "phase1" / "experiment.yaml").write_text(
        yaml.safe_dump({"vehicle": {"kind": "SITL"}, "status": "closed_cleanly"})
    )
    rel = _full_report(tmp_path)
    assert str(rel) == "report/report.md"
    text = (tmp_path / rel).read_text()
    first = [ln for ln in text.splitlines() if ln.startswith("## ")][0]
    assert first.startswith("## Go / no-go:") and "(on SITL data only)" in first
    assert "| phase-1 flights | SITL |" in text


def test_nonlinear_identification_table(tmp_path):
    doc = {
        "K": {"C_T": 1.2e-5, "C_D": 3.0e-3},
        "std": {"C_T": 2.0e-7, "C_D": 4.0e-3},
        "refined": {"K": {"C_T": 1.21e-5, "C_D": 2.5e-3}, "std": {"C_T": 1.0e-7}},
    }
    (tmp_path / "nonlinear_model.yaml").write_text(yaml.safe_dump(doc))
    text = write_report(tmp_path).read_text()
    assert "## Nonlinear identification (seed 0 Eq. 6)" in text
    assert "| C_T | 1.2e-05 | 2e-07 | 60 | 1.21e-05 | 1e-07 |" in text
    assert "| C_D | 0.003 | 0.004 | 0.75 | 0.0025 | - |" in text
