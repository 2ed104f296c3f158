"""Phase-1 experiment simulation (seed 0 Sec. IV), trims table, CLI and bag output."""

import math
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from lpv_sysid.cli.main import main as cli_main
from lpv_sysid.control.baseline import BaselineGains
from lpv_sysid.errors import ConfigError
from lpv_sysid.io.messages import TOPIC_NAMESPACE
from lpv_sysid.models.quadrotor import Quadrotor
from lpv_sysid.sim import phase1
from lpv_sysid.sim.vehicle import SensorConfig

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "quadrotor.yaml"
Q = Quadrotor()
SCALE = 0.15  # trim 1.5 s, excitation 4.5 s, averaging 0.75 s


@pytest.fixture(scope="module")
def short_runs():
    qp, gains, sens, cfg = phase1.load_config(CONFIG)
    cfg = replace(cfg.scaled(SCALE), start="trim")
    runs = phase1.run_phase1(Quadrotor(qp), gains, sens, cfg, [8])
    return cfg, runs


def test_config_file_loads_and_matches_defaults():
    qp, gains, sens, cfg = phase1.load_config(CONFIG)
    assert qp == Q.params and gains == BaselineGains() and sens == SensorConfig()
    assert cfg == phase1.Phase1Config()
    with pytest.raises(ConfigError, match="start"):
        phase1.Phase1Config(start="cruise")
    assert (
        len(cfg.vertices()) == 8
        and cfg.vertices()[0] == (-5, -5, -5)
        and cfg.vertices()[1] == (5, -5, -5)
    )


def test_record_shapes_and_sample_rates(short_runs):
    cfg, runs = short_runs
    assert [r.name for r in runs] == ["vertex_p5_p5_p5", "hover_validation"]
    rec = runs[0]
    T = cfg.trim_s + cfg.excite_s
    assert rec.duration == pytest.approx(
        6.0
    )  # simulated record length (trim + excitation), not wall-clock time
    assert (
        rec.state_true.shape == (int(T * 250), 16) and rec.state_meas.shape == rec.state_true.shape
    )
    assert rec.imu_accel.shape == (int(T * 250), 3) and rec.rotor_meas.shape == (int(T * 100), 4)
    assert rec.command.shape == (int(T * 250), 4) and rec.reference.shape == rec.command.shape
    assert np.allclose(np.diff(rec.state_t), 1 / 250) and np.allclose(
        np.diff(rec.rotor_t), 1 / 100
    )
    # reference = vertex before the excitation, vertex + multisine after it
    pre = rec.cmd_t < rec.t_excite
    assert np.allclose(rec.reference[pre], [5, 5, 5, 0])
    assert np.all(np.abs(rec.excitation[~pre]).max(axis=0) > 0.3 * np.array(cfg.amplitudes))
    # the measured state differs from the truth by noise of the configured size
    d = rec.state_meas[:, 6:9] - rec.state_true[:, 6:9]
    assert np.std(d) == pytest.approx(SensorConfig().vel_std, rel=0.15)


def test_vertex_trim_reached_within_tolerance(short_runs):
    """Documented tolerance: |v - v_d| < 0.1 m/s, angles within 0.5 deg, delta_t within 3 rad/s."""
    cfg, runs = short_runs
    rec = runs[0]
    ach = rec.achieved_trim(cfg.trim_average_s, Q.params.arm_length)
    tr = Q.trim([5, 5, 5])
    assert np.allclose([ach["u0"], ach["v0"], ach["w0"]], [5, 5, 5], atol=0.1)
    assert ach["phi0_deg"] == pytest.approx(math.degrees(tr.x0[0]), abs=0.5)
    assert ach["theta0_deg"] == pytest.approx(math.degrees(tr.x0[1]), abs=0.5)
    assert ach["dt0"] == pytest.approx(tr.x0[8], abs=3.0)


def test_vertex_reached_from_hover_within_the_trim_segment():
    """Default flight: step from hover; after 10 s the last-5-s mean is within 0.3 m/s and
    1 deg / 5 rad/s of the model trim (the descending vertices settle slowest)."""
    cfg = replace(phase1.Phase1Config(), excite_s=3.0, hover_validation=False)
    assert cfg.start == "hover"
    rec = phase1.run_phase1(Q, BaselineGains(), SensorConfig(), cfg, [6])[0]
    assert np.allclose(rec.state_true[0, 6:9], 0.0)
    ach = rec.achieved_trim(cfg.trim_average_s, Q.params.arm_length)
    tr = Q.trim(rec.v_d)
    assert list(rec.v_d) == [5.0, -5.0, 5.0]
    assert np.allclose([ach["u0"], ach["v0"], ach["w0"]], rec.v_d, atol=0.3)
    assert ach["phi0_deg"] == pytest.approx(math.degrees(tr.x0[0]), abs=1.0)
    assert ach["theta0_deg"] == pytest.approx(math.degrees(tr.x0[1]), abs=1.0)
    assert ach["dt0"] == pytest.approx(tr.x0[8], abs=5.0)


def test_excitation_moves_the_vehicle_and_stays_bounded(short_runs):
    cfg, runs = short_runs
    rec = runs[1]  # hover validation
    on = rec.state_t >= rec.t_excite
    ref = np.stack(
        [np.interp(rec.state_t[on], rec.cmd_t, rec.reference[:, i]) for i in range(4)], 1
    )
    v = rec.state_true[on][:, [6, 7, 8, 11]]
    # the PX4-like loop lags above ~0.5 Hz (docs/quadrotor_model.md), but every excited
    # axis responds with a sizeable share of the reference and nothing runs away
    assert np.all(v.std(axis=0) > 0.3 * ref.std(axis=0))
    assert np.max(np.abs(v[:, :3])) < 3.0
    assert np.all(np.abs(rec.command[:, 0] - 0.54) < 0.3)
    assert np.max(np.abs(rec.state_true[:, 3:5])) < math.radians(35)


def test_phase1_excitation_is_the_designed_multisine_orthogonal_and_in_band():
    """The phase-1 excitation is the signals/ design (seed 0 Sec. IV): 4 channels, peaks as
    configured (before taper), mutually orthogonal over one period, energy only in 0.2-2 Hz."""
    cfg = phase1.Phase1Config(taper_s=0.0, amplitudes=(1.0, 2.0, 3.0, 0.5))
    sig = phase1.design_excitation(cfg)
    fs = 100.0
    t = np.arange(int(cfg.excite_s * fs)) / fs
    u = phase1.excitation_signal(cfg, t, sig)
    assert u.shape == (t.size, 4)
    # peaks within 2 % of the configured amplitude (dense evaluation vs 50 Hz design grid)
    assert np.allclose(np.max(np.abs(u), axis=0), cfg.amplitudes, rtol=0.02)
    G = u.T @ u / len(t)
    off = G - np.diag(np.diag(G))
    assert np.max(np.abs(off)) < 1e-9 * np.max(np.diag(G))
    spec = np.abs(np.fft.rfft(u, axis=0)) ** 2
    f = np.fft.rfftfreq(len(t), 1 / fs)
    inband = (f >= 0.2 - 1e-9) & (f <= 2.0 + 1e-9)
    assert np.all(spec[~inband].sum(axis=0) < 1e-9 * spec.sum(axis=0))
    # no two channels share a harmonic
    owners = spec[inband] > 1e-9 * spec.max()
    assert np.all(owners.sum(axis=1) <= 1)
    # phase optimisation: relative peak factor well below Schroeder-only phases
    assert np.all(sig.rpf < sig.rpf_schroeder)


def test_phase1_taper_starts_and_ends_at_zero():
    cfg = phase1.Phase1Config()
    t = np.array([0.0, cfg.excite_s])
    assert np.allclose(phase1.excitation_signal(cfg, t), 0.0, atol=1e-12)


def test_trim_table_files_round_trip(short_runs, tmp_path):
    cfg, runs = short_runs
    rows = phase1.trim_table(runs, cfg, Q.params.arm_length)
    y, m = phase1.write_trim_table(rows, tmp_path)
    d = yaml.safe_load(y.read_text())
    assert d["format"] == "lpv_sysid/phase1_trims@1" and len(d["runs"]) == 2
    assert d["runs"][0]["seed0_table1"]["dt0"] == 525.8
    assert d["runs"][0]["achieved"] == rows[0]["achieved"]
    text = m.read_text()
    assert "| [+5 +5 +5] | seed0_table1 |" in text and "| [+0 +0 +0] | achieved |" in text


def test_config_errors_name_the_problem(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("quadrotor: {mass: [1, 2}\n")
    with pytest.raises(ConfigError, match="malformed YAML"):
        phase1.load_config(bad)
    bad.write_text("phase1: {trim_s: -1}\n")
    with pytest.raises(ConfigError, match="trim_s"):
        phase1.load_config(bad)
    bad.write_text("simulation: {}\n")
    with pytest.raises(ConfigError, match="unknown section"):
        phase1.load_config(bad)
    with pytest.raises(ConfigError, match="vertex index"):
        phase1.run_phase1(Q, BaselineGains(), SensorConfig(), phase1.Phase1Config(), [9])


def test_cli_phase1_writes_trims(tmp_path, capsys):
    out = tmp_path / "p1"
    rc = cli_main(
        [
            "simulate",
            "phase1",
            "--config",
            str(CONFIG),
            "--out",
            str(out),
            "--duration-scale",
            "0.1",
            "--vertices",
            "1",
            "--no-hover",
            "--no-bags",
        ]
    )
    assert rc == 0
    d = yaml.safe_load((out / "trims.yaml").read_text())
    assert d["runs"][0]["vertex"] == [-5.0, -5.0, -5.0]
    assert f"wrote {out / 'trims.yaml'}" in capsys.readouterr().out


def test_cli_bad_config_exits_2(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("controller: {tilt_max_deg: 120}\n")
    rc = cli_main(["simulate", "phase1", "--config", str(bad), "--out", str(tmp_path / "o")])
    assert rc == 2
    assert "tilt_max_deg" in capsys.readouterr().err


def test_run_bag_round_trip(short_runs, tmp_path):
    pytest.importorskip("lpv_sysid.io.bag")
    from lpv_sysid.io import messages
    from lpv_sysid.io.bag import read_bag

    cfg, runs = short_runs
    rec = runs[0]
    path = phase1.write_run_bag(rec, tmp_path / rec.name)
    data = read_bag(str(path))
    ns = TOPIC_NAMESPACE
    assert len(data[f"{ns}/state"]) == len(rec.state_t)
    assert len(data[f"{ns}/rotor_speeds"]) == len(rec.rotor_t)
    assert len(data[f"{ns}/imu"]) == len(rec.imu_t)
    assert len(data[f"{ns}/actuator_command"]) == len(rec.cmd_t)
    # one status per simulated second of the record (rec.duration: simulated, not wall time)
    assert len(data[f"{ns}/status"]) == math.ceil(rec.duration)
    stamp, msg = data[f"{ns}/state"][100]
    s = messages.state_from_odometry(msg)
    assert stamp == round(rec.state_t[100] * 1e9)
    assert np.allclose(s.v_body, rec.state_meas[100, 6:9]) and np.allclose(
        s.euler, rec.state_meas[100, 3:6]
    )
    _, msg = data[f"{ns}/velocity_reference"][-1]
    _, v_d, r_d = messages.reference_from_twist(msg)
    assert np.allclose(v_d, rec.reference[-1, :3]) and r_d == pytest.approx(rec.reference[-1, 3])
    shutil.rmtree(path)


def test_phase1_bag_read_independently_with_rosbags_anyreader(short_runs, tmp_path):
    """Issue 2 acceptance, without io/bag: the bag opens with rosbags' AnyReader, carries the
    Jazzy message types with their definitions, and each topic arrives at its configured rate
    (state and imu 250 Hz, rotor_speeds 100 Hz, velocity_reference at the 250 Hz control rate)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    cfg, runs = short_runs
    rec = runs[0]
    path = phase1.write_run_bag(rec, tmp_path / rec.name)
    ns = TOPIC_NAMESPACE
    expected = {
        f"{ns}/state": ("nav_msgs/msg/Odometry", 250.0),
        f"{ns}/imu": ("sensor_msgs/msg/Imu", 250.0),
        f"{ns}/rotor_speeds": ("sensor_msgs/msg/JointState", 100.0),
        f"{ns}/velocity_reference": ("geometry_msgs/msg/TwistStamped", 250.0),
    }
    with AnyReader([Path(path)], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        conns = {c.topic: c for c in reader.connections}
        for topic, (msgtype, hz) in expected.items():
            c = conns[topic]
            assert c.msgtype == msgtype and c.msgdef.data.strip()  # definition stored in the bag
            stamps = np.array([t for _, t, _ in reader.messages(connections=[c])], dtype=np.int64)
            period = np.diff(stamps) * 1e-9
            assert np.median(period) == pytest.approx(1.0 / hz, rel=1e-6), topic
            assert stamps[-1] - stamps[0] == pytest.approx(
                (rec.duration - 1.0 / hz) * 1e9, rel=1e-3
            )
    shutil.rmtree(path)
