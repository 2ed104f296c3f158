"""One reading of gains.yaml: `verify` checks the arrays the runtime law flies (issue 14 item 2).

Both paths load the file through io.formats.GainSchedule: verify_files (its verify_gains gets
K, R, gamma) and LpvController (what the vehicle flies). A file whose vertices are listed in
another corner order is valid (io.formats re-orders it); the former second parser of
the synthesis reader (synthesis/uncertainty_set.py) refused it in verify while the vehicle
flew it.
"""

from pathlib import Path

import numpy as np
import pytest
import yaml

from lpv_sysid.cli.main import main
from lpv_sysid.control.law import LpvController, LpvControllerConfig
from lpv_sysid.errors import ConfigError
from lpv_sysid.io.formats import GainSchedule, seal_document
from lpv_sysid.synthesis.verify import checker as V


def _models(path: Path) -> Path:
    """x' = a(s) x + u, a = 1 at s = -1 and 2 at s = +1 (two different vertex gains)."""
    verts = [
        {"scheduling": [s], "x0": [0.0], "u0": [0.0], "A": [[a]], "B": [[1.0]], "uncertain": []}
        for s, a in ((-1.0, 1.0), (1.0, 2.0))
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


@pytest.fixture()
def files(tmp_path, capsys):
    models = _models(tmp_path / "vertex_models.yaml")
    cfg = tmp_path / "synthesis.yaml"
    cfg.write_text(
        yaml.safe_dump(
            {
                "hinf": {"gamma": 0.5, "solver": "CLARABEL", "fallback": "SCS"},
                "weights": {"T": 2.0, "input_magnitudes": [1.0], "output_magnitudes": [2**-0.5]},
                "velocity_states": ["x"],
            }
        )
    )
    out = tmp_path / "out" / "gains.yaml"
    rc = main(["synthesize", "--models", str(models), "--config", str(cfg), "--out", str(out)])
    assert rc == 0, capsys.readouterr().out
    return models, out


def _verify_arrays(monkeypatch, gains: Path, models: Path) -> dict:
    """The K, R, gamma verify_files hands to its independent checks."""
    seen: dict = {}
    real = V.verify_gains

    def spy(model, K, R, C, gamma, *a, **kw):
        seen.update(K=np.array(K), R=np.array(R), gamma=gamma)
        return real(model, K, R, C, gamma, *a, **kw)

    monkeypatch.setattr(V, "verify_gains", spy)
    rep = V.verify_files(gains, models, n_random=2)
    assert seen, "verify_files did not reach verify_gains"
    seen["passed"] = rep.passed
    return seen


def _flown(gains: Path, x: float, s: float, ue: float) -> float:
    ctl = LpvController(
        GainSchedule.load(gains, auto_layout=True), LpvControllerConfig(velocity_index=(0,))
    )
    u, _ = ctl.step(0.0, np.array([x]), np.array([s]), np.array([ue]))
    return float(u[0])


def test_verify_and_controller_get_identical_arrays(files, monkeypatch):
    models, gains = files
    got = _verify_arrays(monkeypatch, gains, models)
    gs = GainSchedule.load(gains, auto_layout=True)
    assert got["passed"]
    assert np.array_equal(got["K"], gs.K) and np.array_equal(got["R"], gs.R)
    assert got["gamma"] == gs.gamma
    assert got["K"][0, 0, 0] != got["K"][1, 0, 0]  # two vertex gains: the order matters
    # what the law flies at each vertex (alpha = e_i; x0 = u0 = 0): u = K_i x + R u_e
    for i, s in enumerate((-1.0, 1.0)):
        expected = got["K"][i, 0, 0] * 0.3 + got["R"][0, 0] * 0.5
        assert _flown(gains, 0.3, s, 0.5) == pytest.approx(expected, rel=1e-14, abs=1e-15)


def test_reordered_vertices_are_read_the_same_on_both_paths(files, monkeypatch):
    models, gains = files
    before = _verify_arrays(monkeypatch, gains, models)
    u_before = _flown(gains, 0.3, 1.0, 0.5)
    d = yaml.safe_load(gains.read_text())
    d["vertices"] = d["vertices"][::-1]  # same corners, other order: a valid file
    d = seal_document(d)  # as a tool writing this order would seal it (any edit breaks a seal)
    gains.write_text(yaml.safe_dump(d, sort_keys=False))
    after = _verify_arrays(monkeypatch, gains, models)  # the old second parser refused this
    assert after["passed"]
    assert np.array_equal(after["K"], before["K"])
    assert _flown(gains, 0.3, 1.0, 0.5) == u_before


@pytest.mark.parametrize(
    "edit, message",
    [
        (
            lambda d: d["vertices"][1].update(K=[[1.0, 2.0]]),
            "gains.yaml: vertices[1].K: expected shape 1x1, got 1x2",
        ),
        (
            lambda d: d["vertices"][0]["K"][0].__setitem__(0, "fast"),
            "gains.yaml: vertices[0].K[0][0]: expected a number, got string 'fast'",
        ),
        (
            lambda d: d["vertices"][1].update(scheduling=[-1.0]),
            "gains.yaml: vertices[1].scheduling: corner [-1.0] already given by vertices[0]",
        ),
        (
            lambda d: d["vertices"][0].update(F_ff=[[1.0], [2.0]]),
            "gains.yaml: vertices[0].F_ff: given but the file has no top-level 'feedforward'",
        ),
    ],
)
def test_hand_edited_gains_are_refused_identically(files, edit, message):
    models, gains = files
    d = yaml.safe_load(gains.read_text())
    edit(d)
    gains.write_text(yaml.safe_dump(d, sort_keys=False))
    with pytest.raises(ConfigError) as by_verify:
        V.verify_files(gains, models, n_random=2)
    with pytest.raises(ConfigError) as by_vehicle:
        LpvController(GainSchedule.load(gains, auto_layout=True))
    assert str(by_verify.value) == str(by_vehicle.value) == message


def test_controller_refuses_a_feedforward_layout_that_is_not_the_file_format():
    """The law takes the io.formats FeedforwardSpec only (no raw mapping: a second reading)."""
    from types import SimpleNamespace

    sched = SimpleNamespace(
        K=np.zeros((2, 1, 2)),
        x0=np.zeros((2, 2)),
        u0=np.zeros((2, 1)),
        R=np.eye(1),
        Q=np.eye(1),
        gamma=1.0,
        vmin=np.array([-1.0]),
        vmax=np.array([1.0]),
        F_ff=np.zeros((2, 2, 1)),
        F_jerk=None,
        feedforward={"free_states": ["a"], "accelerated_states": ["b"], "held_states": ["a"]},
        state_names=("a", "b"),
    )
    with pytest.raises(ConfigError, match="feedforward must be the io.formats FeedforwardSpec"):
        LpvController(sched, LpvControllerConfig(velocity_index=(1,)))
