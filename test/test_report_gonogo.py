"""The report's go/no-go table: values against independent reads of verification.yaml, the
certificate and the logs; NO-GO rules; margins against hand-built logs; data provenance."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from support.toy_plant import write_toy_plant

from lpv_sysid.io.files import sha256_file
from lpv_sysid.models.quadrotor import QuadrotorParams, mixer
from lpv_sysid.report import (
    FLOWN,
    NO_GO,
    SIMULATED,
    go_no_go,
    limits_from_summary,
    load_run,
    provenance,
    run_margins,
    write_report,
)
from lpv_sysid.synthesis.verify import read_verification, record_verification


def _write_pair(tmp: Path) -> tuple[Path, Path]:
    """Two-state, two-vertex model x' = -x + u with small element intervals and K = -I: the
    frozen closed loop -2 I has H-inf norm 0.5 (u_e -> x2) < gamma 1 everywhere."""
    el = {"matrix": "A", "row": 0, "col": 0, "nominal": -1.0, "std": 0.01}
    el = {**el, "lower": -1.02, "upper": -0.98}
    return write_toy_plant(tmp, [[el], [el]], k_sigma=3.0, gamma_achieved=0.6, min_margin=0.01)


def _table(text: str) -> dict[str, list[str]]:
    """item -> [value, limit, verdict, note] of the go/no-go table."""
    head = text.index("## Go / no-go")
    rows = {}
    for line in text[head:].splitlines()[3:]:
        if not line.startswith("| "):
            if rows:
                break
            continue
        cells = [c.strip() for c in line.strip("|").split(" | ")]
        if cells[0] not in ("item", "---"):
            rows[cells[0]] = cells[1:]
    return rows


@pytest.fixture()
def verified(tmp_path):
    gains, models = _write_pair(tmp_path)
    rep, path = record_verification(gains, models, n_random=3, full_box=10)
    assert rep.passed
    return tmp_path, gains, models, path


def test_table_values_equal_the_recorded_numbers(verified):
    run, gains, models, path = verified
    raw = yaml.safe_load(path.read_text())  # independent read of the record
    assert raw["gains"]["sha256"] == sha256_file(gains) and raw["tool_version"].startswith(
        "lpv_sysid "
    )
    # the analytic oracle: frozen closed loop -2 I +- 0.02, norm u_e -> x2 = 1 / 2 exactly
    assert raw["numbers"]["worst_hinf"] == pytest.approx(0.5, rel=1e-4)
    assert raw["numbers"]["max_real_eig"] == pytest.approx(-1.98, abs=1e-9)
    assert raw["numbers"]["n_failed"] == 0 and raw["passed"] is True
    text = write_report(run).read_text()
    t = _table(text)
    assert text.count("## Go / no-go: **GO**") == 1
    n = raw["numbers"]
    assert t["verified H-inf / LMI"][0].startswith(f"worst frozen H-inf {n['worst_hinf']:.4g}")
    assert t["independent verification"][:3] == [
        f"passed: {len(raw['checks'])} checks, 0 failed, 0 warnings",
        "0 failed",
        "GO",
    ]
    cert = yaml.safe_load(gains.read_text())["certificate"]
    assert t["certificate (gains.yaml)"][:3] == [
        f"gamma_achieved {cert['gamma_achieved']:.4g}, min margin {cert['min_margin']:.4g}",
        "gamma 1, margin > 0",
        "GO",
    ]
    assert t["verified gains.yaml = this run's"][2] == "GO"
    assert f"sha256 {raw['gains']['sha256'][:12]}..." == t["verified gains.yaml = this run's"][0]


def test_no_go_when_missing_failed_or_for_other_gains(verified):
    run, gains, models, path = verified
    # 1. a failed check recorded (written by the record's own writer, one row flipped)
    v = read_verification(path)
    raw = yaml.safe_load(path.read_text())
    raw["checks"][0]["ok"] = False
    raw["passed"] = False
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    t = _table(write_report(run).read_text())
    assert t["independent verification"][2] == NO_GO
    assert t["independent verification"][0].startswith(f"FAILED: {len(v.checks)} checks, 1 failed")
    # a file that claims passed with a failing row is not trusted either
    raw["passed"] = True
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    t = _table(write_report(run).read_text())
    assert t["independent verification"][:1] == ["unreadable"]
    assert t["independent verification"][2] == NO_GO
    # 2. the gains file changed after verification (one comment line: other bytes)
    record_verification(gains, models, n_random=3, full_box=0)
    assert _table(write_report(run).read_text())["verified gains.yaml = this run's"][2] == "GO"
    gains.write_text("# edited after verify\n" + gains.read_text())
    text = write_report(run).read_text()
    t = _table(text)
    assert t["verified gains.yaml = this run's"][2] == NO_GO
    assert "## Go / no-go: **NO-GO**" in text
    # 3. no verification.yaml at all: not verified, and the report does not create one
    path.unlink()
    t = _table(write_report(run).read_text())
    assert t["independent verification"][:3] == [
        "not verified",
        "verification.yaml, passed",
        NO_GO,
    ]
    assert not path.exists()


def _summary(box=(-5.0, 5.0), gamma=0.8, **limits):
    s = {"gamma": gamma, "box": {"min": [box[0]] * 3, "max": [box[1]] * 3}}
    if limits:
        s["limits"] = limits
    return s


def test_margins_of_a_hand_built_log():
    """Known extremes: tilt peak 30 deg (theta) at t = 2, ESC command 0.9 on motor 3 at t = 3
    (headroom 0.1), u = 5.4 m/s at t = 4 (0.4 outside the +-5 box), z = 0.5 ue (ratio 0.5)."""
    t = np.arange(0.0, 6.0 + 1e-9, 0.01)
    N = t.size
    x = np.zeros((N, 12))
    x[:, 0] = np.radians(10.0) * np.sin(t)  # phi at most 10 deg
    x[:, 1] = np.radians(30.0) * np.exp(-((t - 2.0) ** 2) / 0.1)  # theta peaks at 30 deg at t = 2
    x[:, 2] = 5.4 * np.exp(-((t - 4.0) ** 2) / 0.1)  # u = 5.4 at t = 4
    esc = np.full((N, 4), 0.5)
    esc[:, 2] = 0.5 + 0.4 * np.exp(-((t - 3.0) ** 2) / 0.1)  # 0.9 at t = 3
    u = esc @ mixer(QuadrotorParams.arm_length).T
    ue = np.column_stack([np.sin(3 * t), np.cos(3 * t), np.zeros(N), np.zeros(N)])
    z = 0.5 * ue[:, :3]
    arrays = {"t": t, "x": x, "u": u, "z": z, "ue": ue}
    lim = limits_from_summary(_summary(max_tilt_deg=45.0))
    m = run_margins("nonlinear", arrays, lim)
    ex = m.extremes()
    assert ex["tilt_deg"] == pytest.approx((30.0, 2.0), abs=1e-9)
    assert ex["esc_headroom"] == pytest.approx((0.1, 3.0), abs=1e-9)
    assert ex["box_distance"] == pytest.approx((-0.4, 4.0), abs=1e-9)
    # |z|^2 / |ue|^2 = 0.25 sample by sample -> every judged running ratio is 0.5
    judged = m.monitor_ratio[np.isfinite(m.monitor_ratio)]
    assert judged.size > 0 and np.allclose(judged, 0.5, rtol=1e-12)
    # judged once E_e = sum |ue|^2 dt (= 0.01 per sample after the first) reaches min_energy
    first = int(np.flatnonzero(np.isfinite(m.monitor_ratio))[0])
    assert first == math.ceil(round(lim.monitor_min_energy / 0.01, 9))
    assert lim.monitor_limit == pytest.approx(0.8 * lim.monitor_margin)
    assert lim.source["max_tilt_deg"] == "phase2 summary limits"
    assert "default" in lim.source["box_margin"]


def _sim_run(run: Path, arrays: dict) -> None:
    (run / "phase2").mkdir(parents=True)
    np.savez(run / "phase2" / "nonlinear.npz", **arrays)
    s = {"format": "lpv_sysid/phase2_summary@2", **_summary(), "safety_events": []}
    s["nonlinear"] = {"completed": True, "monitor_window_s": None}
    (run / "phase2" / "summary.yaml").write_text(yaml.safe_dump(s))


def test_simulated_data_is_labelled_and_the_flown_one_too(tmp_path):
    t = np.linspace(0, 2, 201)
    N = t.size
    x = np.zeros((N, 12))
    x[:, 1] = np.radians(70.0) * np.sin(np.pi * t / 2) ** 2  # 70 deg > the 60 deg default
    u = np.full((N, 4), 0.5) @ mixer(QuadrotorParams.arm_length).T
    arrays = {"t": t, "x": x, "u": u, "z": np.zeros((N, 3)), "ue": np.ones((N, 4))}
    sim = tmp_path / "sim"
    _sim_run(sim, arrays)
    (sim / "phase1").mkdir()
    d = load_run(sim)
    labels = {p.dataset: p.label for p in provenance(d)}
    assert labels == {"phase-1 flights": SIMULATED, "phase-2 nonlinear": SIMULATED}
    text = write_report(sim).read_text()
    assert "## Go / no-go: **NO-GO** (on SIMULATED data only)" in text
    t_row = _table(text)["max tilt (nonlinear)"]
    assert t_row[:3] == ["70.0 deg at t = 1.0 s", "60 deg", NO_GO]
    assert "| phase-2 nonlinear | SIMULATED |" in text and "flight data" not in text
    # a phase-1 directory with the flight recorder's experiment.yaml was flown
    flown = tmp_path / "flown"
    (flown / "phase1").mkdir(parents=True)
    (flown / "phase1" / "experiment.yaml").write_text(
        yaml.safe_dump({"format": "lpv_sysid/experiment@1", "description": "fly phase1"})
    )
    (flown / "phase1" / "campaign_summary.yaml").write_text(
        yaml.safe_dump({"connect": "udpin:0.0.0.0:14540", "handback": {"confirmed": None}})
    )
    d = load_run(flown)
    p1 = provenance(d)[0]
    assert (p1.label, "udpin:0.0.0.0:14540" in p1.evidence) == (FLOWN, True)
    rows, overall = go_no_go(d, None)
    hb = {r.item: r for r in rows}["hand-back confirmed (phase 1)"]
    assert hb.verdict == NO_GO and overall == NO_GO
    # the chain's broken-loop run: listed as a data set of the same vehicle, and its hand-back
    # judged like every flight's (HOLD confirmed: GO; FAILED: NO-GO)
    (flown / "broken_loop").mkdir()
    for state, verdict in (("DONE", "GO"), ("FAILED", NO_GO)):
        (flown / "broken_loop" / "broken_loop_summary.yaml").write_text(
            yaml.safe_dump(
                {
                    "ok": state == "DONE",
                    "reason": "run complete",
                    "handback": {"state": state, "mode": "HOLD"},
                }
            )
        )
        d = load_run(flown)
        src = {p.dataset: p for p in provenance(d)}
        assert src["broken-loop run"].label == FLOWN
        assert "run complete" in src["broken-loop run"].evidence
        assert "broken_loop/broken_loop_summary.yaml" in src["broken-loop run"].evidence
        rows, _ = go_no_go(d, None)
        hb = {r.item: r for r in rows}["hand-back confirmed (broken-loop run)"]
        assert (hb.value, hb.verdict) == (f"state {state}", verdict)


def test_loop_delay_row_judges_the_configured_loop_verify_checked(verified):
    """A certificate whose bound (0.1 s, the toy plant) is below the loop the controller will fly
    is NO-GO on the first page: measured on a PX4 SITL chain, the report said GO while phase 2
    was refused for a 60 ms loop against a 52.8 ms bound."""
    run, gains, models, path = verified
    t = _table(write_report(run).read_text())
    assert t["loop delay (certificate)"][2] == "GO"
    assert "no configured loop checked" in t["loop delay (certificate)"][3]
    record_verification(gains, models, n_random=3, full_box=0, loop_delay_s=0.06)
    t = _table(write_report(run).read_text())
    assert t["loop delay (certificate)"][:3] == [
        "configured loop 60.00 ms; bound 100.00 ms; margins: gamma kept up to 700.00 ms, "
        "stable up to 1000.00 ms",
        "configured loop delay <= bound",
        "GO",
    ]
    record_verification(gains, models, n_random=3, full_box=0, loop_delay_s=0.12)
    text = write_report(run).read_text()
    t = _table(text)
    assert t["loop delay (certificate)"][0].startswith("configured loop 120.00 ms; bound 100.00")
    assert t["loop delay (certificate)"][2] == NO_GO
    assert "refuses these gains" in t["loop delay (certificate)"][3]
    assert "## Go / no-go: **NO-GO**" in text
