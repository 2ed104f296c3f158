"""`lpv-sysid identify` / `identify-nonlinear` end to end through real rosbag2 files.

Bags are written with io/messages + io/bag (ENU/FLU on the wire) from data with a known
truth: the linearised quadrotor under LQR + excitation (vertex maneuvers, the excitation on
its own topic) and the nonlinear quadrotor (for Eq. 6).
"""

import numpy as np
import pytest
import yaml

from lpv_sysid.cli.main import main
from lpv_sysid.io import messages
from lpv_sysid.io.bag import BagWriter
from lpv_sysid.io.formats import VertexModels
from lpv_sysid.models.lpv import box_vertices
from lpv_sysid.models.quadrotor import Quadrotor, mixer
from lpv_sysid.sim import synthetic as syn

RATE = 50.0
NOISE = np.array([2e-3, 2e-3, 0.02, 0.02, 0.02, 5e-3, 5e-3, 5e-3, 2.0, 0.02, 0.02, 2.0])


def write_bag(path, t, states, u, v_d, exc, arm):
    """Topics state, rotor_speeds, actuator_command, velocity_reference, excitation."""
    f = messages.MsgFactory.rosbags()
    mix_inv = np.linalg.inv(mixer(arm))
    with BagWriter(str(path)) as w:
        for name in (
            "state",
            "rotor_speeds",
            "actuator_command",
            "velocity_reference",
            "excitation",
        ):
            w.add_topic(f"/lpv_sysid/{name}", messages.TYPES[name])
        for k, tk in enumerate(t):
            ns = int(round(tk * 1e9))
            x = states[k]
            w.write(
                "/lpv_sysid/state",
                ns,
                messages.odometry_from_state(f, ns, [0, 0, 0], [x[0], x[1], 0.0], x[2:5], x[5:8]),
            )
            w.write(
                "/lpv_sysid/rotor_speeds", ns, messages.rotor_speeds_msg(f, ns, mix_inv @ x[8:12])
            )
            w.write("/lpv_sysid/actuator_command", ns, messages.actuator_command_msg(f, ns, u[k]))
            w.write(
                "/lpv_sysid/velocity_reference", ns, messages.twist_reference_msg(f, ns, v_d, 0.0)
            )
            w.write("/lpv_sysid/excitation", ns, messages.excitation_msg(f, ns, exc[k]))
    return path


@pytest.fixture(scope="module")
def phase1_bags(tmp_path_factory):
    d = tmp_path_factory.mktemp("bags")
    q = Quadrotor()
    rng = np.random.default_rng(8)
    t = np.arange(0, 22, 1 / RATE)
    on = t >= 6.0
    truths = {}
    Qw = np.diag([10, 10, 1, 1, 1, 1, 1, 1, 1e-6, 1e-4, 1e-4, 1e-6])
    Rw = np.diag([1e2, 1e4, 1e4, 1e2])
    for i, c in enumerate(list(box_vertices([-5] * 3, [5] * 3)) + [np.zeros(3)]):
        tr = q.trim(c)
        A, B = q.linearize(tr)
        e = np.zeros((t.size, 4))
        e[on] = syn.multisine(t[on], 4, (0.2, 3.0), 1.0, rng) * np.array(
            [0.03, 0.002, 0.002, 0.03]
        )
        dd, _ = syn.closed_loop(A, B, t, e, Qw, Rw)
        x = tr.x0 + dd.x + NOISE * rng.normal(size=dd.x.shape)
        name = "hover" if i == 8 else f"v{i}"
        write_bag(
            d / name,
            t,
            x,
            tr.u0 + dd.u,
            c,
            e / np.array([0.03, 0.002, 0.002, 0.03]),
            q.params.arm_length,
        )
        truths[tuple(c)] = (A, B)
    cfg = d / "ident.yaml"
    cfg.write_text(
        yaml.safe_dump(
            {
                "identification": {
                    "model": "appendix_b",
                    "sample_rate": RATE,
                    "trim_duration": 6.0,
                    "trim_average": 4.0,
                    "uncertainty": {"p_max": 3},
                }
            }
        )
    )
    return d, cfg, truths


def test_identify_cli_writes_valid_models(phase1_bags, tmp_path, capsys):
    d, cfg, truths = phase1_bags
    out = tmp_path / "vertex_models.yaml"
    assert main(["identify", "--bags", str(d), "--config", str(cfg), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "seed 0 Table 1" in text and "seed 0 Table 2" in text and "seed 0 Table 3" in text
    assert f"wrote {out}" in text
    assert (tmp_path / "vertex_models_validation.png").stat().st_size > 1000
    vm = VertexModels.load(out)  # strict format check
    assert vm.meta["uncertainty"]["M"] == [8] * 8
    z = []
    for vx_ in vm.vertices:
        A, B = truths[tuple(vx_.scheduling)]
        assert len(vx_.uncertain) == 43
        for e in vx_.uncertain:
            truth = (A if e.matrix == "A" else B)[e.row, e.col]
            z.append((e.nominal - truth) / e.std)
    assert np.mean(np.abs(np.array(z)) < 3) >= 0.95
    assert set(vm.meta["validation"]["tic"]) == {"udot", "vdot", "wdot", "pdot", "qdot", "rdot"}
    # format @2: the whole box nominal +/- k std of every identified element (k = meta.k_sigma)
    assert vm.format_version == 2 and vm.meta["k_sigma"] == 3.0
    for e in vm.vertices[0].uncertain:
        assert e.upper - e.nominal == pytest.approx(
            3.0 * e.std
        ) and e.nominal - e.lower == pytest.approx(3.0 * e.std)
    assert "uncertainty box of Eq. (22): every identified element" in text


def test_identify_cli_errors(phase1_bags, tmp_path, capsys):
    d, cfg, _ = phase1_bags
    out = tmp_path / "m.yaml"
    bad = tmp_path / "bad.yaml"
    bad.write_text("identification: {k_sigmaa: 3}\n")
    assert main(["identify", "--bags", str(d), "--config", str(bad), "--out", str(out)]) == 2
    assert "unknown key" in capsys.readouterr().err
    bad.write_text("identification: [1, 2\n")
    assert main(["identify", "--bags", str(d), "--config", str(bad), "--out", str(out)]) == 2
    assert "malformed YAML" in capsys.readouterr().err
    # one vertex missing
    import shutil

    partial = tmp_path / "partial"
    partial.mkdir()
    for name in ("v0", "v1", "hover"):
        shutil.copytree(d / name, partial / name)
    assert main(["identify", "--bags", str(partial), "--config", str(cfg), "--out", str(out)]) == 2
    assert "no maneuver for vertex" in capsys.readouterr().err
    assert not out.exists()  # nothing half-written
    assert main(["identify", "--bags", str(tmp_path / "none"), "--out", str(out)]) == 2


def test_identify_nonlinear_cli(tmp_path, capsys):
    q = Quadrotor()
    rng = np.random.default_rng(2)
    t = np.arange(0, 24, 0.01)
    v_ref = np.stack(
        [
            3 * np.sin(2 * np.pi * 0.05 * t),
            3 * np.sin(2 * np.pi * 0.07 * t + 1),
            2 * np.sin(2 * np.pi * 0.03 * t + 2),
        ],
        axis=1,
    )
    amp = np.array([0.05, 0.003, 0.003, 0.05])
    e = syn.multisine(t, 4, (0.5, 4.0), 1.0, rng) * amp
    X, U, _ = syn.nonlinear_flight(q, t, v_ref, e)
    states = np.concatenate(
        [X[:, 3:5], X[:, 6:12], X[:, 12:16] @ mixer(q.params.arm_length).T], axis=1
    )
    states[:, 2:8] += 0.01 * rng.normal(size=(t.size, 6))
    write_bag(tmp_path / "phase2", t, states, U, [0, 0, 0], e / amp, q.params.arm_length)
    out = tmp_path / "nl.yaml"
    assert (
        main(
            [
                "identify-nonlinear",
                "--bags",
                str(tmp_path / "phase2"),
                "--out",
                str(out),
                "--plot",
                str(tmp_path / "fig10.png"),
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    assert "Fig. 10" in text and "z_T0" in text
    doc = yaml.safe_load(out.read_text())
    z = [(doc["K"][k] - q.params.K[k]) / doc["std"][k] for k in q.params.K]
    assert np.mean(np.abs(np.array(z)) < 3) >= 0.9
    assert doc["K"]["z_T0"] == pytest.approx(q.params.K["z_T0"], rel=0.02)
    assert np.shape(doc["axes"]["L"]["correlation"]) == (7, 7)
    assert (tmp_path / "fig10.png").stat().st_size > 1000
    assert (
        main(
            [
                "identify-nonlinear",
                "--bags",
                str(tmp_path / "phase2"),
                "--out",
                str(out),
                "--fix",
                "nonsense=1",
            ]
        )
        == 2
    )
