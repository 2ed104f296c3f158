"""Vehicle safety of the phase-2 controller path (issue 12 items 1-6) on the pure cores:
ControllerRuntime (node and replay), the settings declaration, the gains start-up checks,
the reference limiter and the supervisor's stamp checks. No rclpy: the node-level wiring
of the same faults is in test_nodes_controller.py."""

import math
import os

import numpy as np
import pytest
import yaml
from lpv_test_gains import design_for, write_gains

from lpv_sysid.cli.main import main
from lpv_sysid.control.law import LpvControllerConfig, ReferenceLimiter
from lpv_sysid.control.safety import check_closed_loop
from lpv_sysid.errors import ConfigError
from lpv_sysid.flight.controller import ControllerRuntime, ControllerSettings
from lpv_sysid.io import messages
from lpv_sysid.io.formats import GainSchedule, load_certified_systems
from lpv_sysid.models.quadrotor import Quadrotor, mixer

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLES = os.path.join(ROOT, "msg_samples")
SAMPLE_GAINS = os.path.join(SAMPLES, "gains.yaml")
P2 = os.path.join(SAMPLES, "phase2_sim")


@pytest.fixture(scope="module")
def gains2(tmp_path_factory):
    return write_gains(tmp_path_factory.mktemp("g2") / "gains.yaml", box=2.0)


@pytest.fixture(scope="module")
def gains5(tmp_path_factory):
    return write_gains(tmp_path_factory.mktemp("g5") / "gains.yaml", box=5.0)


def with_feedforward(d):
    """Add the reference feedforward (synthesis/feedforward.py) of the trim linearisations."""
    from lpv_sysid.models.quadrotor import STATE_NAMES
    from lpv_sysid.synthesis.feedforward import FeedforwardLayout, vertex_feedforward

    quad = Quadrotor()
    lins = [quad.linearize(quad.trim(np.array(v["scheduling"]))) for v in d["vertices"]]
    layout = FeedforwardLayout()
    F, Fj = vertex_feedforward(
        np.array([a for a, _ in lins]), np.array([b for _, b in lins]), STATE_NAMES, layout
    )
    d["feedforward"] = layout.to_dict()
    for i, v in enumerate(d["vertices"]):
        v["F_ff"], v["F_jerk"] = F[i].tolist(), Fj[i].tolist()


@pytest.fixture(scope="module")
def gains5ff(tmp_path_factory):
    return write_gains(
        tmp_path_factory.mktemp("g5ff") / "gains.yaml", box=5.0, edit=with_feedforward
    )


def runtime(gains, **kw):
    return ControllerRuntime(
        ControllerSettings(gains_file=str(gains), **kw), messages.MsgFactory.rosbags()
    )


def hover_inputs(rt):
    """State, rotor speeds and excitation holding the box-centre trim (v_d = 0)."""
    gs = rt.schedule
    x0 = gs.x0.mean(axis=0)  # multilinear weights at the centre: 1/8 each
    return x0[:8], np.linalg.solve(rt.mix, x0[8:])


def feed(rt, t_now, *, stamp=None, v_d=(0.0, 0.0, 0.0), u_e=(0.0, 0.0, 0.0, 0.0), streams=None):
    """One message of every input stream received at ``t_now`` stamped ``stamp``."""
    x8, om = hover_inputs(rt)
    st = t_now if stamp is None else stamp
    vals = {
        "state": x8,
        "rotor_speeds": om,
        "velocity_reference": np.append(v_d, 0.0),
        "excitation": np.asarray(u_e, float),
    }
    for topic in streams or vals:
        rt.on_sample(topic, st, vals[topic], t_now)


def fly(rt, t0, seconds, dt=0.004, stamp_offset=0.0, **kw):
    """Feed all streams and tick at 250 Hz for ``seconds``; returns the commands."""
    cmds = []
    for k in range(int(round(seconds / dt))):
        t = t0 + k * dt
        feed(rt, t, stamp=t + stamp_offset, **kw)
        cmds += [m for topic, m in rt.tick(t) if topic == "actuator_command"]
        if rt.supervisor.aborted:
            break
    return cmds


# ----------------------------------------------------------------- item 1: one validation
@pytest.mark.parametrize(
    "params, needle",
    [
        ({"u_esc_min": 0.9, "u_esc_max": 0.1}, "u_esc_min < u_esc_max"),
        ({"rate_limit": [-1.0, 1.0, 1.0, 1.0]}, "rate_limit' entry [0] must be >= 0.01"),
        ({"rate_limit": [0.0, 1.0, 1.0, 1.0]}, "rate_limit' entry [0] must be >= 0.01"),
        ({"rate_limit": [1.0, math.nan, 1.0, 1.0]}, "rate_limit' entry [1] must be finite"),
        ({"rate_limit": [1.0, 1.0]}, "rate_limit' needs 0 or 4 entries"),
        ({"monitor_margin": 0.0}, "monitor_margin' must be >= 1"),
        ({"state_timeout_s": 1e9}, "state_timeout_s' must be <= 1"),
        ({"box_margin": 100.0}, "box_margin' must be <= 1"),
        ({"rate_hz": 10.0}, "state_timeout_s 0.02 s is shorter than one control period"),
        ({"stamp_tolerance_s": 0.05}, "stamp_tolerance_s 0.05 s exceeds the shortest timeout"),
        ({"monitor_window_s": 0.5}, "monitor_window_s must be 0 (running) or >= 1 s"),
        ({"feedforward": 1}, "feedforward' must be true or false"),
        ({"rate_hz": 250}, None),  # an int for a double is fine off-ROS
        ({"bogus": 1.0}, "unknown parameter(s) ['bogus']"),
    ],
)
def test_settings_validate_every_rule(params, needle):
    d = {"gains_file": "g.yaml", **params}
    if needle is None:
        assert ControllerSettings.from_dict(d).rate_hz == 250.0
        return
    with pytest.raises(ConfigError, match="lpv_controller") as exc:
        ControllerSettings.from_dict(d)
    assert needle in str(exc.value)


def test_direct_construction_is_validated_too():
    """The library path (dataclasses built directly) runs the same checks: before, the
    runtime built LpvControllerConfig directly and its checks never ran."""
    with pytest.raises(ConfigError, match="u_esc_min < u_esc_max"):
        ControllerSettings(gains_file="g.yaml", u_esc_min=0.9, u_esc_max=0.1)
    with pytest.raises(ConfigError, match="u_esc_min < u_esc_max"):
        LpvControllerConfig(u_esc_min=0.9, u_esc_max=0.1)
    for bad in ((-1.0,) * 4, (0.0,) * 4, (math.nan,) * 4, (math.inf,) * 4):
        with pytest.raises(ConfigError, match="rate_limit"):
            LpvControllerConfig(rate_limit=bad)
    with pytest.raises(ConfigError, match="monitor_margin"):
        LpvControllerConfig(monitor_margin=0.0)
    with pytest.raises(ConfigError, match="gains_file"):
        ControllerSettings()


def test_esc_limits_must_contain_every_trim(gains2):
    """u_esc_max 0.3 < the hover trim ESC command (~0.53): every command would be clamped
    (thrust 0.3 instead of the trim); refused at load naming the trim."""
    trims = np.linalg.solve(mixer(0.225), GainSchedule.load(gains2).u0.T).T
    assert trims.max() > 0.5 and trims.min() > 0.3  # the oracle: hover needs ~0.53 per motor
    with pytest.raises(ConfigError, match=r"do not contain the trim ESC commands .* of vertex 0"):
        runtime(gains2, u_esc_max=0.3)
    rt = runtime(gains2, u_esc_min=0.1, u_esc_max=0.9)  # consistent limits fly
    assert rt.law.cfg.u_esc_max == 0.9


def test_box_margin_bounded_by_the_box(gains2):
    with pytest.raises(ConfigError, match="box_margin 0.5 m/s exceeds 0.1 of the narrowest"):
        runtime(gains2, box_margin=0.5)  # box [-2, 2]: at most 0.4
    assert runtime(gains2, box_margin=0.4).supervisor.config.box_margin == 0.4


@pytest.mark.parametrize(
    "line, needle",
    [
        ("monitor_margin: 0.0", "monitor_margin' must be >= 1"),
        ("state_timeout_s: 1.0e+9", "state_timeout_s' must be <= 1"),
        ("box_margin: 100.0", "box_margin' must be <= 1"),
        ("u_esc_min: 0.9", "u_esc_min < u_esc_max"),
    ],
)
def test_replay_refuses_what_the_node_refuses(tmp_path, capsys, line, needle):
    params = tmp_path / "ctl.yaml"
    params.write_text(
        f"/**/lpv_controller:\n  ros__parameters:\n    u_esc_max: 0.5\n    {line}\n"
        if line.startswith("u_esc_min")
        else f"/**/lpv_controller:\n  ros__parameters:\n    {line}\n"
    )
    code = main(
        [
            "replay",
            "--bag",
            P2,
            "--node",
            "lpv_controller",
            "--params",
            str(params),
            "--gains",
            SAMPLE_GAINS,
            "--out",
            str(tmp_path / "out"),
        ]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and needle in err[0]
    assert not (tmp_path / "out").exists()


# --------------------------------------------------------------- item 2: gains on load
def _tamper(path, edit):
    d = yaml.safe_load(open(path))
    edit(d)
    with open(path, "w") as fh:
        yaml.safe_dump(d, fh)


def test_law_hash_and_stability_of_the_sample_gains():
    """msg_samples/gains.yaml (the LQR test law) passes honestly: its law hashes to its
    certificate, and A + B K is Hurwitz at every vertex on trim linearisations computed
    here afresh (independent of the sidecar)."""
    gs = GainSchedule.load(SAMPLE_GAINS)
    gs.check_law_sha256()
    quad = Quadrotor()
    worst = -np.inf
    for vx in gs.vertices:
        a, b = quad.linearize(quad.trim(vx.scheduling))
        worst = max(worst, np.linalg.eigvals(a + b @ vx.K).real.max())
    assert worst < 0
    systems = load_certified_systems(SAMPLE_GAINS, gs.certificate, 12, 4)
    assert check_closed_loop(gs.K, systems) == pytest.approx(worst, rel=1e-6)


def test_tampered_gains_are_refused(tmp_path):
    """K edited after certification (certificate unchanged): refused before any command."""
    g = write_gains(tmp_path / "gains.yaml", box=2.0)
    _tamper(g, lambda d: d["vertices"][3].update(K=(-np.array(d["vertices"][3]["K"])).tolist()))
    with pytest.raises(ConfigError, match=r"gains_sha256: \w+ does not match the gains"):
        runtime(g)
    g2 = write_gains(tmp_path / "g2.yaml", box=2.0)
    _tamper(
        g2, lambda d: d["vertices"][0]["K"][0].__setitem__(2, d["vertices"][0]["K"][0][2] + 1e-9)
    )
    with pytest.raises(ConfigError, match="changed after certification"):
        runtime(g2)


def test_gains_without_hash_are_refused_with_the_remedy(tmp_path):
    g = write_gains(tmp_path / "gains.yaml", box=2.0)
    _tamper(g, lambda d: d["certificate"].pop("gains_sha256"))
    with pytest.raises(ConfigError, match=r"gains_sha256: missing.*re-run `lpv-sysid synthesize`"):
        runtime(g)


def test_negated_gains_with_a_recomputed_hash_fail_the_stability_recheck(tmp_path):
    """Even a law whose hash was recomputed (e.g. a certifying tool fed the wrong K) must
    stabilise the certified systems: K -> -K makes A + B K unstable (oracle: the eigen-
    values of the fresh linearisation), refused naming the vertex."""

    def negate(d):
        for v in d["vertices"]:
            v["K"] = (-np.array(v["K"])).tolist()

    g = write_gains(tmp_path / "neg.yaml", box=2.0, edit=negate)
    gs = GainSchedule.load(g)
    quad = Quadrotor()
    abscissa = [
        np.linalg.eigvals(a + b @ vx.K).real.max()
        for vx in gs.vertices
        for a, b in [quad.linearize(quad.trim(vx.scheduling))]
    ]
    worst = int(np.argmax(abscissa))
    assert min(abscissa) > 0
    msg = (
        rf"unstable at vertex {worst}, certified system 0 "
        rf"\(max Re\(eig\) = {abscissa[worst]:.4g}"
    )
    with pytest.raises(ConfigError, match=msg):
        runtime(g)


def test_sidecar_missing_or_changed_is_refused(tmp_path):
    g = write_gains(tmp_path / "gains.yaml", box=2.0)
    side = tmp_path / "gains.cert.npz"
    data = dict(np.load(side))
    data["A_sys"] = data["A_sys"] * 0.5
    with open(side, "wb") as fh:
        np.savez(fh, **data)
    with pytest.raises(ConfigError, match="sidecar.sha256"):
        runtime(g)
    side.unlink()
    with pytest.raises(ConfigError, match="not found"):
        runtime(g)


def test_gains_without_design_envelope_are_refused(tmp_path):
    g = write_gains(
        tmp_path / "gains.yaml", box=2.0, edit=lambda d: d["certificate"].pop("design")
    )
    with pytest.raises(ConfigError, match=r"certificate.design missing.*summary.yaml of the"):
        runtime(g)


def test_synthesize_writes_the_hash_and_the_certified_systems(tmp_path, capsys):
    """The one writer (lpv-sysid synthesize): gains_sha256 equals the hash of the law it
    wrote, and the sidecar's systems are the polytope it certified
    (uncertainty_set.load_models)."""
    from test_verify import _config, _models

    from lpv_sysid.synthesis.uncertainty_set import load_models

    models = _models(tmp_path / "vertex_models.yaml")
    cfg = _config(tmp_path / "synthesis.yaml", region=False)
    out = tmp_path / "gains.yaml"
    assert (
        main(
            [
                "synthesize",
                "--models",
                str(models),
                "--config",
                str(cfg),
                "--out",
                str(out),
                "--no-verify",
            ]
        )
        == 0
    )
    assert "no phase-2 signals summary" in capsys.readouterr().out
    gs = GainSchedule.load(out, layout=None)
    assert gs.certificate.gains_sha256 == gs.law_sha256() and gs.certificate.design is None
    model, _ = load_models(models, gs.certificate.extra["uncertainty"])
    got = load_certified_systems(out, gs.certificate, model.n_x, model.n_u)
    assert [len(s) for s in got] == [len(s) for s in model.systems]
    for mine, theirs in zip(got, model.systems):
        for (a, b), (a2, b2) in zip(mine, theirs):
            np.testing.assert_array_equal(a, a2)
            np.testing.assert_array_equal(b, b2)


# ----------------------------------------------------------- item 3: excitation bound
@pytest.mark.parametrize("value", [50.0, 1e150])
def test_excitation_beyond_the_design_aborts(gains2, value):
    """|u_e| = 50 or 1e150: before, no abort (and the monitor ratio shrank to ~1e-153)."""
    rt = runtime(gains2)
    feed(rt, 100.0)
    assert rt.start(100.0)[0]
    assert fly(rt, 100.004, 0.2)
    cmds = fly(rt, 100.2, 0.2, u_e=(0.0, value, 0.0, 0.0))
    ev = rt.supervisor.event
    assert ev.reason == "excitation_bound" and ev.detail.startswith(f"excitation[1] = {value:.4g}")
    assert "designed bound 1.5" in ev.detail  # design peak 1 x envelope_margin 1.5
    assert cmds == []  # aborted on receipt, before the tick


def test_excitation_gain_counts_against_the_design(gains2):
    rt = runtime(gains2, excitation_gain=4.0)
    feed(rt, 100.0)
    rt.start(100.0)
    fly(rt, 100.004, 0.1, u_e=(0.3, 0.0, 0.0, 0.0))  # kappa u_e = 1.2 <= 1.5: flies
    assert rt.supervisor.event is None
    fly(rt, 100.2, 0.1, u_e=(0.4, 0.0, 0.0, 0.0))  # 1.6 > 1.5
    assert rt.supervisor.event.reason == "excitation_bound"


def test_signals_file_with_huge_amplitude_is_refused(tmp_path):
    from lpv_sysid.signals.store import load_npz, save_npz

    t = np.arange(0.0, 1.0, 0.02)
    path = str(tmp_path / "s.npz")
    save_npz(path, t, np.stack([1e308 * np.sin(t), 0 * t], axis=1), ["ue_t", "u_d"])
    with pytest.raises(ConfigError, match=r"channel\(s\) \['ue_t'\] too large"):
        load_npz(path)


def test_signal_table_checked_against_the_design():
    from lpv_sysid.io.formats import DesignEnvelope
    from lpv_sysid.signals.excitation import check_design

    d = design_for(2.0)
    env = DesignEnvelope(
        tuple(d["reference_peak"]),
        tuple(d["reference_rate"]),
        tuple(d["reference_accel"]),
        d["knot_interval_s"],
        d["fade_s"],
        tuple(d["excitation_peak"]),
    )
    t = np.arange(0.0, 20.0, 0.02)
    names = ["u_d", "v_d", "w_d", "ue_t", "ue_a", "ue_e", "ue_r"]
    ok = np.stack(
        [0.8 * np.sin(2 * np.pi * 0.2 * t), 0 * t, 0 * t] + [0.5 * np.sin(3 * t)] * 4, axis=1
    )
    check_design(t, ok, names, env, ramp=1.0)
    big = ok.copy()
    big[:, 4] *= 3.0  # ue_a peak 1.5 > design 1
    with pytest.raises(ConfigError, match="ue_a peak 1.5 exceeds the design excitation peak 1"):
        check_design(t, big, names, env, ramp=1.0)
    with pytest.raises(ConfigError, match="ramp_s 0.5 s is shorter than the fade"):
        check_design(t, ok, names, env, ramp=0.5)
    fast = ok.copy()
    fast[:, 0] = 1.7 * np.sin(2 * np.pi * 2.0 * t)  # 21 m/s^2 > the design rate
    with pytest.raises(ConfigError, match="u_d changes at"):
        check_design(t, fast, names, env, ramp=1.0)


# --------------------------------------------------------------- item 4: header stamps
def _started(gains):
    rt = runtime(gains)
    feed(rt, 100.0)
    assert rt.start(100.0)[0]
    fly(rt, 100.004, 0.5)
    assert rt.supervisor.event is None and rt.commands > 100
    return rt


def test_frozen_stamp_aborts(gains2):
    """The same header stamp repeated while messages keep arriving on time: before, never
    flagged (receipt time only). Now stale once the stamp is older than timeout + tolerance
    (state: 0.02 + 0.01 s)."""
    rt = _started(gains2)
    t0 = 100.5
    for k in range(250):  # 1 s
        t = t0 + 0.004 * k
        feed(rt, t, streams=["rotor_speeds", "velocity_reference", "excitation"])
        rt.on_sample("state", t0, hover_inputs(rt)[0], t)  # frozen stamp
        rt.tick(t)
        if rt.supervisor.aborted:
            break
    ev = rt.supervisor.event
    assert ev.reason == "stale" and ev.detail.startswith("state: stamp frozen at 100.500000 s")
    assert 0.03 < ev.t - t0 <= 0.03 + 0.004 + 1e-9


def test_frozen_stamp_of_a_silent_stream_ages_at_the_tick(gains2):
    """The tick check judges the newest stamp too (a stream whose last message carried an
    old stamp, then nothing): stale by stamp age before its receipt timeout."""
    rt = runtime(gains2)
    feed(rt, 100.0, stamp=100.0 - 0.025)
    assert rt.start(100.0)[0]
    fly(rt, 100.004, 0.5, stamp_offset=-0.025)  # latency 25 ms: inside 0.02 + 0.01 s
    assert rt.supervisor.event is None and rt.commands > 100
    t = 100.6
    feed(rt, t, stamp=t - 0.025)
    rt.tick(t + 0.006)  # receipt age 6 ms, stamp age 31 ms
    ev = rt.supervisor.event
    assert ev.reason == "stale" and ev.detail.startswith("state: newest stamp")


def test_every_stream_stamped_in_the_past_aborts(gains2):
    """Every stream stamped 10 s in the past but arriving on time: before, no abort."""
    rt = runtime(gains2)
    feed(rt, 100.0, stamp=90.0)
    assert rt.start(100.0)[0]
    cmds = fly(rt, 100.004, 0.1, stamp_offset=-10.0)
    ev = rt.supervisor.event
    assert ev.reason == "stale" and ev.detail == (
        "state: stamp 10.000 s old at receipt (timeout 0.02 s + tolerance 0.01 s)"
    )
    assert cmds == [] and ev.t == pytest.approx(100.004)


def test_stamps_from_another_clock_source_abort(gains2):
    """Node on sim time (t ~ 100 s), a publisher stamping with the wall clock (~1.7e9 s):
    refused as from the future, naming the clock-source mismatch."""
    rt = _started(gains2)
    feed(rt, 100.6, stamp=1.7e9, streams=["rotor_speeds"])
    ev = rt.supervisor.event
    assert ev.reason == "future_stamp" and "ahead of the node clock" in ev.detail
    assert "use_sim_time" in ev.detail


def test_small_latency_is_tolerated(gains2):
    rt = _started(gains2)
    for k in range(100):
        t = 100.6 + 0.004 * k
        feed(rt, t, stamp=t - 0.008)  # 8 ms transport latency
        rt.tick(t)
    feed(rt, 101.0, stamp=101.0 + 0.009)  # a 9 ms lead (clock offset)
    assert rt.supervisor.event is None


def test_start_refused_while_sim_clock_not_running(gains2):
    rt = runtime(gains2)
    ok, msg = rt.start(0.0)
    assert not ok and "use_sim_time" in msg and not rt.supervisor.armed


# ---------------------------------------------------------- item 6: reference envelope
def test_reference_step_aborts_before_a_feedforward_spike(gains5ff):
    """0 -> 4.9 m/s in one message: before, the law followed it (a_ff = 94 m/s^2, saturated
    commands); now the incoming rate exceeds the design envelope x margin: abort."""
    rt = runtime(gains5ff)
    assert rt.law.has_ff
    feed(rt, 100.0)
    rt.start(100.0)
    fly(rt, 100.004, 0.5)
    n = rt.commands
    cmds = fly(rt, 100.504, 0.5, v_d=(4.9, 0.0, 0.0))
    ev = rt.supervisor.event
    assert ev.reason == "reference_envelope" and "reference[0] changes at 1225 m/s^2" in ev.detail
    assert cmds == [] and rt.commands == n
    assert np.abs(rt.law.a_filt).max() < 1e-9  # the law never saw the step


def test_reference_within_margin_is_rate_limited(gains5ff):
    """A reference 1.3 x faster than the design rate (inside the abort margin 1.5) is
    followed at the design rate: the limited v_d and the law's feedforward acceleration
    never exceed R1 (Bernstein + fade bound of the design, independently recomputed)."""
    rt = runtime(gains5ff)
    d = rt.schedule.certificate.design
    P, f, r = 4.5, 0.2, 1.0
    R1 = 2 * np.pi * f * P + np.pi * P / (2 * r)
    assert d.reference_rate[0] == pytest.approx(R1, rel=1e-12)
    feed(rt, 100.0)
    rt.start(100.0)
    # 0 -> 4 m/s at 1.3 R1, the slope changing over 50 ms at each end
    tt = np.arange(0.0, 1.6, 0.004)
    T_ramp = 4.0 / (1.3 * R1)
    w_in = 1.3 * R1 * np.clip(np.minimum(tt / 0.05, (T_ramp + 0.05 - tt) / 0.05), 0.0, 1.0)
    v_in = np.concatenate([[0.0], np.cumsum(0.5 * (w_in[1:] + w_in[:-1]) * 0.004)])
    a_max = 0.0
    for k in range(1, tt.size):
        t = 100.0 + tt[k]
        feed(rt, t, v_d=(v_in[k], 0.0, 0.0))
        rt.tick(t)
        a_max = max(a_max, abs(rt.law.a_filt[0]))
    assert rt.supervisor.event is None
    assert rt.limiter.limited > 50
    assert a_max <= R1 * (1 + 1e-9) and a_max > 0.9 * R1
    assert v_in[-1] == pytest.approx(4.0, abs=0.05)
    assert rt.v_d[0] == v_in[-1]  # caught up once the ramp ended


def test_limiter_passes_a_design_signal_unchanged():
    """The played phase-2 signal (band-limited table at 50 Hz, linear interpolation, 1 s
    raised-cosine fades, abort fade included) at 100 Hz with stamp jitter: followed bit for
    bit (the bounds are rigorous for it)."""
    from lpv_sysid.signals.excitation import ExcitationCore

    d = design_for(5.0)
    t = np.arange(0.0, 100.0, 0.02)
    rng = np.random.default_rng(3)
    cols = []
    for _ in range(3):  # multisines up to 0.2 Hz scaled to peak 4.5
        s = sum(
            rng.uniform(0.2, 1) * np.sin(2 * np.pi * 0.01 * h * t + rng.uniform(0, 6.3))
            for h in range(1, 21)
        )
        cols.append(4.5 * s / np.abs(s).max())
    u = np.stack(cols + [0 * t] * 4, axis=1)
    core = ExcitationCore.phase2(
        t, u, ["u_d", "v_d", "w_d", "ue_t", "ue_a", "ue_e", "ue_r"], start_time=1.0, ramp=1.0
    )
    lim = ReferenceLimiter(d["reference_rate"], d["reference_accel"], d["knot_interval_s"], 1.5)
    ts = np.sort(np.arange(0.0, 60.0, 0.01) + rng.uniform(-0.003, 0.003, 6000))
    for tk in ts:
        if tk > 40.0 and not core.aborted:
            core.abort(tk)
        v = core.sample(tk).velocity
        y, excess = lim.update(tk, v)
        assert excess is None and np.array_equal(y, v)
    assert lim.limited == 0


def test_limiter_step_response_respects_the_bounds():
    lim = ReferenceLimiter([2.0], [4.0], 0.02, 1e9)
    ys, ws = [], []
    for k in range(600):
        t = 0.01 * k
        y, _ = lim.update(t, [0.0 if t < 0.5 else 3.0])
        ys.append(float(y[0]))
        ws.append(float(lim.w[0]))
    ys, ws = np.array(ys), np.array(ws)
    assert np.abs(ws).max() <= 2.0 + 1e-12  # rate bound
    # slope change over any window W <= R2 (W + 2 T + 2 dt) (class docstring)
    for lag in range(1, 150):
        dw = np.abs(ws[lag:] - ws[:-lag]).max()
        assert dw <= 4.0 * (0.01 * lag + 2 * 0.02 + 2 * 0.01) + 1e-12
    assert ys.max() <= 3.0 + 2.0 * 0.01 and ys[-1] == 3.0  # no overshoot beyond one step
    # time-optimal-ish: 3 m at 2 m/s plus the ramp up/down at 4 m/s^3 is ~2 s
    assert 1.9 < 0.01 * np.argmax(ys >= 3.0) - 0.5 < 2.3


def test_box_abort_on_a_slow_ramp_out_of_the_box(gains2):
    """out_of_box on a reference leaving the box inside the rate envelope."""
    rt = runtime(gains2)
    feed(rt, 100.0)
    rt.start(100.0)
    for k in range(1, 2000):
        t = 100.0 + 0.004 * k
        feed(rt, t, v_d=(1.0 * (t - 100.0), 0.0, 0.0))
        rt.tick(t)
        if rt.supervisor.aborted:
            break
    ev = rt.supervisor.event
    assert ev.reason == "out_of_box" and ev.detail.startswith("scheduling[0] = 2.00")


# ------------------------------------------------------------- issue 11: core log lines
def test_abort_line_is_handed_to_the_shell(gains2, caplog):
    rt = _started(gains2)
    rt.take_log()
    with caplog.at_level("DEBUG"):
        rt.abort(101.0, "test")
        rt.tick(101.0)
    lines = rt.take_log()
    assert lines == [("error", "safety abort: external: test; actuator commands stopped")]
    assert not [r for r in caplog.records if r.name.startswith("lpv_sysid.nodes")]


def test_design_envelope_from_a_phase2_summary(tmp_path):
    """certificate.design from the signals summary that synthesize reads: peaks and highest
    harmonics of the reference, Bernstein + fade bounds (oracle: the played signal of a
    real phase-2 design stays inside them), excitation peaks, table interval."""
    from lpv_sysid.signals.excitation import ExcitationCore, design_envelope
    from lpv_sysid.signals.multisine import SignalsConfig, design
    from lpv_sysid.signals.store import summary, write_signal_set
    from lpv_sysid.synthesis.gains import design_from_summary

    cfg = yaml.safe_load(open(os.path.join(ROOT, "config", "signals_phase2.yaml")))
    cfg["duration"] = 20.0
    cfg["groups"][0]["band"] = [0.05, 0.2]
    cfg["groups"][1]["band"] = [0.55, 2.0]
    cfg["optimisation"] = {"p_stages": [4, 16], "max_iter": 20, "clip_iter": 10}
    sig = design(SignalsConfig.from_dict(cfg, where="test"))
    _, path = write_signal_set(str(tmp_path / "sig"), sig)
    env = design_envelope(summary(sig), fade_s=2.0)
    got = design_from_summary(path)
    assert got["reference_rate"] == env["reference_rate"] and "summary.yaml" in got["source"]
    assert design_from_summary("Eqs. (27)-(28)") is None
    assert env["knot_interval_s"] == pytest.approx(1.0 / cfg["sample_rate"])
    assert env["excitation_peak"] == pytest.approx(np.abs(sig.u[:, 3:]).max(axis=0).tolist())
    P = np.abs(sig.u[:, :3]).max(axis=0)
    core = ExcitationCore.phase2(sig.t, sig.u, sig.names, start_time=0.0, ramp=2.0)
    tt = np.arange(0.0, core.duration, 0.001)
    v = core.evaluate(tt)[0]
    rate = np.abs(np.diff(v, axis=0)).max(axis=0) / 0.001
    R1 = np.array(env["reference_rate"])
    assert np.all(rate <= R1) and np.all(rate > 0.3 * R1)
    assert np.all(np.array(env["reference_peak"]) == P)


# ------------------------------------------------- issue 25 item 6: absurd inputs abort
def _absurd_state(rt, index, value):
    x8, _ = hover_inputs(rt)
    x8 = x8.copy()
    x8[index] = value
    return x8


@pytest.mark.parametrize(
    "topic, index, value, needle",
    [
        ("state", 2, 1e6, "body speed 1e+06 m/s beyond max_body_speed 30"),  # u = 1e6 m/s
        ("state", 4, -31.0, "body speed 31 m/s beyond max_body_speed 30"),
        ("state", 0, 3.0, "roll 3 rad / pitch"),  # roll 3 rad
        ("state", 1, -1.3, "pitch -1.3 rad beyond max_tilt 1.2"),
        ("state", 6, 25.0, "body rate 25 rad/s beyond max_body_rate 20"),
        ("rotor_speeds", 2, -1000.0, "rotor_speeds[2] = -1000 rad/s outside [0, 5000]"),
        ("rotor_speeds", 0, 1e7, "rotor_speeds[0] = 1e+07 rad/s outside"),
    ],
)
def test_absurd_inputs_abort_the_controller(gains2, topic, index, value, needle):
    rt = runtime(gains2)
    feed(rt, 100.0)
    assert rt.start(100.0)[0]
    assert fly(rt, 100.004, 0.1)
    x8, om = hover_inputs(rt)
    if topic == "state":
        bad = _absurd_state(rt, index, value)
    else:
        bad = om.copy()
        bad[index] = value
    rt.on_sample(topic, 100.2, bad, 100.2)
    ev = rt.supervisor.event
    assert ev is not None and ev.reason == "input_bound" and needle in ev.detail
    assert [m for tp, m in rt.tick(100.2) if tp == "actuator_command"] == []


def test_plausible_inputs_near_the_bounds_fly(gains2):
    rt = runtime(gains2, max_tilt=0.5, max_body_speed=5.0)
    feed(rt, 100.0)
    assert rt.start(100.0)[0]
    x8, _ = hover_inputs(rt)
    x8 = x8.copy()
    x8[0], x8[2] = 0.49, 4.9  # inside the declared bounds: no abort (the law may saturate)
    rt.on_sample("state", 100.004, x8, 100.004)
    assert rt.supervisor.event is None
    with pytest.raises(ConfigError, match="max_body_speed"):
        ControllerSettings(gains_file=str(gains2), max_body_speed=1e9)
    with pytest.raises(ConfigError, match="max_tilt"):
        ControllerSettings(gains_file=str(gains2), max_tilt=3.5)
