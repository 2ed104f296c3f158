"""Rate plant (PX4 rate loop inside the LPV model): model, identification, transport, gain
measurement. Oracles: hand-derived Jacobian entries, equilibrium residuals, recovery of known
coefficients from simulated data, exact MAVLink field values, analytic FIR gains."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lpv_sysid.errors import ConfigError, SafetyError
from lpv_sysid.flight.phase2 import excitation_gain, inversion_error
from lpv_sysid.ident import rate_plant as rid
from lpv_sysid.mavlink.bridge import (
    ATTITUDE_TARGET_IGNORE_ATTITUDE,
    RATE_INPUT_NAMES,
    ActuatorSetpoint,
    RateSetpointTransport,
    TransportContext,
    make_transport,
    rate_setpoint_from_attitude_target,
)
from lpv_sysid.models import rate_plant as rp

G = rp.GRAVITY
P0 = rp.RatePlantParams(
    X_u=-0.9,
    Y_v=-0.85,
    Z_w=-0.5,
    Z_T=-12.5,
    L_p=-10.0,
    L_sp=10.0,
    M_q=-12.0,
    M_sp=12.0,
    N_r=-2.0,
    N_sp=2.0,
    c_u=0.02,
    c_v=-0.03,
    c_w=-3.5,
    c_p=0.01,
    c_q=-0.02,
    c_r=0.005,
)


def test_trim_is_equilibrium_and_jacobian_matches_hand_derivation():
    v = (1.2, -0.8, 0.3)
    x0, u0 = rp.trim(v, P0)
    assert np.abs(rp.dynamics(x0, u0, P0)).max() < 1e-12
    phi, th = x0[0], x0[1]
    # pitch balances drag: g sin(theta) = X_u u + c_u
    assert G * math.sin(th) == pytest.approx(P0.X_u * 1.2 + P0.c_u, rel=1e-12)
    A, B = rp.linearize(x0, u0, P0)
    assert A[2, 1] == pytest.approx(-G * math.cos(th), rel=1e-7)  # du'/dtheta
    assert A[3, 0] == pytest.approx(G * math.cos(th) * math.cos(phi), rel=1e-7)
    assert A[4, 0] == pytest.approx(-G * math.cos(th) * math.sin(phi), rel=1e-6)
    assert A[2, 7] == pytest.approx(v[1], abs=1e-7) and A[2, 6] == pytest.approx(
        -v[2], abs=1e-7
    )  # r v - q w
    assert A[4, 6] == pytest.approx(v[0], abs=1e-7) and A[4, 5] == pytest.approx(
        -v[1], abs=1e-7
    )  # q u - p v
    assert A[0, 5] == pytest.approx(1.0) and A[1, 6] == pytest.approx(math.cos(phi), rel=1e-7)
    assert A[4, 4] == pytest.approx(P0.Z_w) and B[4, 0] == pytest.approx(P0.Z_T)
    assert B[5, 1] == pytest.approx(P0.L_sp) and B[7, 3] == pytest.approx(P0.N_sp)
    assert np.count_nonzero(np.abs(B) > 1e-9) == 4


def test_polytope_vertex_order_and_intervals():
    P = rp.RatePlantParams(
        **{k: getattr(P0, k) for k in rp.PARAM_ENTRIES}, std={"Z_T": 0.5, "L_sp": 0.2}
    )
    model, els = rp.polytope(P, [-1, -1, -0.5], [1, 1, 0.5], k_sigma=2.0)
    assert model.n_vertices == 8 and model.state_names == rp.STATE_NAMES
    assert np.allclose(model.x0[:, 2:5], model.vertices)  # trim velocity = the vertex
    zt = [e for e in els[0] if e.matrix == "B" and (e.row, e.col) == (4, 0)][0]
    assert (zt.lower, zt.upper) == pytest.approx((P0.Z_T - 1.0, P0.Z_T + 1.0))
    assert len(els[0]) == 2
    with pytest.raises(ConfigError, match="Z_T"):
        rp.RatePlantParams(**{**{k: getattr(P0, k) for k in rp.PARAM_ENTRIES}, "Z_T": 1.0})


def _simulate(P, T=40.0, fs=200.0, seed=0, noise=0.0, vtrim=(0.3, -0.2, 0.1), hold=1):
    """Nonlinear rate plant driven by random multisine setpoints around the trim at body
    velocity ``vtrim`` (default hover-ish); ``hold``: setpoints held over that many steps."""
    rng = np.random.default_rng(seed)
    x0, u0 = rp.trim(vtrim, P)
    t = np.arange(0.0, T, 1.0 / fs)
    u = np.tile(u0, (len(t), 1))
    for k, amp in enumerate((0.02, 0.15, 0.15, 0.15)):
        for f in rng.uniform(0.2, 3.0, 6):
            u[:, k] += amp / 3 * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
    if hold > 1:  # piecewise-constant commands (a setpoint stream at fs / hold)
        u = u[(np.arange(len(t)) // hold) * hold]
    x = np.zeros((len(t), 8))
    x[0] = x0
    dt = 1.0 / fs
    for i in range(len(t) - 1):  # RK4
        k1 = rp.dynamics(x[i], u[i], P)
        k2 = rp.dynamics(x[i] + dt / 2 * k1, u[i], P)
        k3 = rp.dynamics(x[i] + dt / 2 * k2, u[i], P)
        k4 = rp.dynamics(x[i] + dt * k3, u[i], P)
        x[i + 1] = x[i] + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    xs = x + noise * rng.standard_normal(x.shape)
    return t, xs, u


def _simulate_at(P, vtrim, T=40.0, fs=200.0, seed=0, noise=(0.0, 0.0, 0.0)):
    """The rate plant ``P`` around its trim at body velocity ``vtrim``, driven by multisine
    setpoints that are continuous functions of time (RK4 evaluates them at its stages: PX4's
    cascade updates its setpoints far faster than they are streamed), sampled at ``fs``;
    ``noise``: white measurement noise std of (angles [rad], velocities [m/s], rates
    [rad/s]) added to the recorded states. Returns (t, x, u)."""
    rng = np.random.default_rng(seed)
    x0, u0 = rp.trim(vtrim, P)
    comps = [
        (k, amp / 3, 2 * np.pi * f, rng.uniform(0, 2 * np.pi))
        for k, amp in enumerate((0.03, 0.2, 0.2, 0.2))
        for f in rng.uniform(0.2, 3.0, 6)
    ]

    def sp(tt):
        u = np.array(u0, dtype=float)
        for k, a, w, ph in comps:
            u[k] += a * math.sin(w * tt + ph)
        return u

    dt = 1.0 / fs
    t = np.arange(0.0, T, dt)
    x = np.zeros((len(t), 8))
    x[0] = x0
    for i in range(len(t) - 1):
        ti = t[i]
        um = sp(ti + dt / 2)
        k1 = rp.dynamics(x[i], sp(ti), P)
        k2 = rp.dynamics(x[i] + dt / 2 * k1, um, P)
        k3 = rp.dynamics(x[i] + dt / 2 * k2, um, P)
        k4 = rp.dynamics(x[i] + dt * k3, sp(ti + dt), P)
        x[i + 1] = x[i] + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    sd = np.repeat(np.asarray(noise, dtype=float), (2, 3, 3))
    u = np.array([sp(tt) for tt in t])
    return t, x + sd * rng.standard_normal(x.shape), u


def test_identification_recovers_known_rate_plant():
    t, x, u = _simulate(P0)
    # states at 100 Hz, setpoints at 50 Hz (as streamed), both from the 200 Hz simulation
    run = rid.run_from_arrays("sim", t[::2], x[::2], t[::4], u[::4])
    P, rep = rid.identify([run])
    for k in ("L_p", "M_q", "N_r", "Z_T", "X_u", "Y_v", "Z_w"):
        assert getattr(P, k) == pytest.approx(getattr(P0, k), rel=0.08), k
    assert rep["rows"]["p"]["r2"] > 0.95 and rep["rows"]["p"]["unit_dc_gain"]
    assert rep["rows"]["p"]["unconstrained"]["dc_gain"] == pytest.approx(1.0, abs=0.05)
    assert P.std["Z_T"] > 0


def test_validate_scores_the_true_model_near_one_and_a_wrong_one_lower():
    t, x, u = _simulate(P0, T=20.0, seed=3)
    run = rid.run_from_arrays("sim", t[::2], x[::2], t[::4], u[::4])
    good = rid.validate(P0, run)
    assert min(good.values()) > 0.95
    slow = rp.RatePlantParams(
        **{**{k: getattr(P0, k) for k in rp.PARAM_ENTRIES}, "L_p": -3.0, "L_sp": 3.0}
    )
    bad = rid.validate(slow, run)
    assert bad["p"] < good["p"] - 0.2 and bad["q"] == pytest.approx(good["q"])


def test_rate_row_never_takes_a_sign_flipped_fit():
    # the roll loop "follows" -p_sp (a wrong channel/sign): the fits at these delays have L_sp < 0;
    # such a fit is never taken (on one SIH flight an aliased 0.12 s delay gave R^2 0.92 with
    # M_sp = -24.9 and stopped the chain): refused with the row named
    t, x, u = _simulate(P0, T=20.0, seed=4)
    u = u.copy()
    u[:, 1] = -u[:, 1]
    cfg = rid.RateIdConfig(
        unit_dc_gain=False, delays=(0.0, 0.02)
    )  # free fit: L_sp carries the sign
    run = rid.run_from_arrays("sim", t[::2], x[::2], t[::4], u[::4], cfg)
    with pytest.raises(ConfigError, match="row p: no delay .* positive setpoint gain"):
        rid.identify([run], cfg)


def test_identification_refuses_short_or_malformed_data():
    with pytest.raises(ConfigError, match="states must be"):
        rid.run_from_arrays(
            "x", np.arange(10.0), np.zeros((10, 7)), np.arange(10.0), np.zeros((10, 4))
        )
    with pytest.raises(Exception, match="overlap only"):
        rid.run_from_arrays(
            "x",
            np.arange(0, 2, 0.01),
            np.zeros((200, 8)),
            np.arange(0, 2, 0.02),
            np.zeros((100, 4)),
        )


def test_bag_without_rate_setpoints_names_the_option_not_a_cli_flag(tmp_path):
    """The core names the missing topic and the option that records it (``record_rate_setpoints``
    of phase 1), not a command-line flag."""
    from lpv_sysid.errors import BagError
    from lpv_sysid.io import bag as bg
    from lpv_sysid.io import messages as m

    f, t0 = m.MsgFactory.rosbags(), 1_700_000_000_000_000_000
    with bg.BagWriter(tmp_path / "b") as b:
        b.add_topic("/lpv_sysid/excitation", "sensor_msgs/msg/JointState")
        for i in range(3):
            b.write("/lpv_sysid/excitation", t0 + i, m.excitation_msg(f, t0 + i, np.zeros(4)))
    with pytest.raises(BagError, match="'rate_setpoint'.*record_rate_setpoints") as exc:
        rid.read_run(tmp_path / "b")
    assert "--" not in str(exc.value)


class _Codec:
    def set_attitude_target_encode(self, *a):
        return a


def test_rate_setpoint_transport_sends_the_command_unchanged_and_clips():
    tr = make_transport("rate_setpoint", max_rate=1.5)
    assert (
        isinstance(tr, RateSetpointTransport)
        and tr.name == "attitude_rate"
        and tr.neutral() is None
    )
    ctx = TransportContext(1234, 1, 1, None, None)  # needs no telemetry (no inversion)
    (msg,) = tr.encode(_Codec(), ActuatorSetpoint((0.52, 0.1, -0.2, 0.05)), ctx)
    assert msg[:4] == (1234, 1, 1, ATTITUDE_TARGET_IGNORE_ATTITUDE)
    assert msg[5:] == pytest.approx((0.1, -0.2, 0.05, 0.52))
    (msg,) = tr.encode(_Codec(), ActuatorSetpoint((1.4, 3.0, -9.0, 0.0)), ctx)
    assert msg[5:] == pytest.approx((1.5, -1.5, 0.0, 0.95))
    with pytest.raises(SafetyError):
        tr.encode(_Codec(), ActuatorSetpoint((float("nan"), 0, 0, 0)), ctx)
    assert RATE_INPUT_NAMES == rp.INPUT_NAMES


def test_attitude_target_round_trip_through_pymavlink():
    from pymavlink.dialects.v20 import common as mav

    codec = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    (m,) = RateSetpointTransport().encode(
        codec, ActuatorSetpoint((0.61, 0.25, -0.125, 0.5)), TransportContext(5000, 1, 1)
    )
    (back,) = mav.MAVLink(None).parse_buffer(m.pack(codec))
    t, u = rate_setpoint_from_attitude_target(back)
    assert t == pytest.approx(5.0) and u == pytest.approx([0.61, 0.25, -0.125, 0.5], rel=1e-6)


def test_excitation_gain_recovers_known_fir_and_ignores_tracking_error():
    fs, T = 50.0, 60.0
    t = np.arange(0.0, T, 1.0 / fs)
    rng = np.random.default_rng(1)
    ue = np.zeros((len(t), 4))
    for k in range(4):
        for f in rng.uniform(0.5, 3.0, 20):
            ue[:, k] += np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
    ue /= math.sqrt((ue**2).sum() / fs)  # unit energy (Eq. 26)
    z = np.zeros((len(t), 3))
    d = 5  # 0.1 s delay, static gain 0.3 from ue[:,1] to z[:,0]
    z[d:, 0] = 0.3 * ue[:-d, 1]
    z[:, 1] = 0.1 * ue[:, 2]
    slow = 2.0 * np.sin(2 * np.pi * 0.05 * t)  # tracking error of the slow reference: much larger
    z[:, 0] += slow
    res = excitation_gain(t, z, ue, fs)
    # oracle: ||z_e||^2 = 0.09 ||ue_1||^2 + 0.01 ||ue_2||^2, peak singular value 0.3
    a, b = res["window"]  # rows kept (filter edges dropped)
    e1 = (ue[a - d : b - d, 1] ** 2).sum()
    e2 = (ue[a:b, 2] ** 2).sum()
    assert res["energy_ratio"] == pytest.approx(
        math.sqrt((0.09 * e1 + 0.01 * e2) / (ue[a:b] ** 2).sum()), rel=0.03
    )
    assert res["fir_peak_gain"] == pytest.approx(0.3, rel=0.03)
    raw = math.sqrt((z**2).sum() / fs)  # mixed ratio would be >> 0.3
    assert raw > 5 * res["energy_ratio"]


def test_fade_is_raised_cosine_with_zero_ends():
    """A part of a phase-2 period (``fly phase2 --duration``, excitation ``duration_s``) is
    played with the raised-cosine fades inside it: zero at both ends, 1/2 one half-ramp in."""
    from lpv_sysid.signals.excitation import ExcitationCore

    t = np.arange(0.0, 10.0 + 1e-9, 0.02)
    names = ["u_d", "v_d", "w_d", "ue_t", "ue_a", "ue_e", "ue_r"]
    u = np.column_stack([np.ones_like(t)] + [np.zeros_like(t)] * 6)
    core = ExcitationCore.phase2(t, u, names, start_time=0.0, ramp=2.0, periodic=False)
    v = core.evaluate(np.array([0.0, 1.0, 5.0, 9.0, 10.0]))[0][:, 0]
    assert core.duration == pytest.approx(10.0)
    assert v == pytest.approx([0.0, 0.5, 1.0, 0.5, 0.0], abs=1e-12)


def test_inversion_error_is_kp_times_rate_change_over_the_telemetry_age():
    # omega = A sin(2 pi f t): rms of omega(t) - omega(t - d) = A sqrt(2) |sin(pi f d)|
    t = np.arange(0.0, 20.0, 0.001)
    A, f = 0.3, 2.0
    om = np.column_stack([A * np.sin(2 * np.pi * f * t)] * 3)
    res = inversion_error(t, om, rate_p=(0.15, 0.15, 0.2), delays=(0.02,))
    expect = A * math.sqrt(2) * abs(math.sin(math.pi * f * 0.02))
    e = res["by_delay"][0]["torque_error_rms"]
    assert e[0] == pytest.approx(0.15 * expect, rel=0.01) and e[2] == pytest.approx(
        0.2 * expect, rel=0.01
    )
    s = 0.225 * math.sqrt(2) / 2
    assert res["design_torque"][0] == pytest.approx(0.01 / (4 * s))
    assert res["by_delay"][0]["ratio_to_design_torque"][0] == pytest.approx(
        e[0] / (0.01 / (4 * s))
    )


class _Msg:
    def __init__(self, mtype, src, **kw):
        self._t, self._s = mtype, src
        self.__dict__.update(kw)

    def get_type(self):
        return self._t

    def get_srcSystem(self):
        return self._s


class _Link:
    target_system = 3

    def __init__(self, batches):
        self.batches = list(batches)

    def poll(self, now, max_reads=1000):
        return self.batches.pop(0) if self.batches else []

    def send(self, msg):
        self.sent = [*getattr(self, "sent", []), msg]


def test_attitude_target_tap_passes_only_the_targets_setpoints_and_keeps_messages():
    from lpv_sysid.flight.vehicle import tap_attitude_target

    at = dict(
        time_boot_ms=1000, thrust=0.5, body_roll_rate=0.1, body_pitch_rate=-0.2, body_yaw_rate=0.3
    )
    batch = [
        _Msg("ATTITUDE_TARGET", 3, **at),
        _Msg("ATTITUDE_TARGET", 7, **at),  # foreign system
        _Msg("HEARTBEAT", 3),
        _Msg("ATTITUDE_TARGET", 3, **{**at, "thrust": float("nan")}),
    ]
    link = _Link([batch])
    got = []
    tap_attitude_target(link, lambda t, u: got.append((t, list(u))))
    msgs = link.poll(12.5)
    assert msgs == batch  # the bridge still sees every message
    assert got == [(12.5, pytest.approx([0.5, 0.1, -0.2, 0.3]))]


def test_attitude_target_tap_replaces_the_thrust_px4_repeats_in_body_rate_offboard():
    """PX4 v1.14-1.16 (src/modules/mavlink/streams/ATTITUDE_TARGET.hpp) takes the echo's rates
    from vehicle_rates_setpoint but thrust and time_boot_ms from the last
    vehicle_attitude_setpoint, which nothing publishes in body-rate OFFBOARD: the repeated
    time_boot_ms marks the thrust as stale; the thrust PX4 executes there is the one sent
    (rate-only SET_ATTITUDE_TARGET). Measured on PX4 SITL phase 2: echoed thrust std 0.0022
    against 0.038 commanded."""
    from pymavlink.dialects.v20 import common as mavlink

    from lpv_sysid.flight.vehicle import tap_attitude_target
    from lpv_sysid.mavlink.bridge import ATTITUDE_TARGET_IGNORE_ATTITUDE

    def at(ms, thrust, p):
        return _Msg(
            "ATTITUDE_TARGET",
            3,
            time_boot_ms=ms,
            thrust=thrust,
            body_roll_rate=p,
            body_pitch_rate=0.0,
            body_yaw_rate=0.0,
        )

    codec = mavlink.MAVLink(None)
    link = _Link(
        [
            [at(1000, 0.50, 0.1)],  # PX4's own attitude setpoint (HOLD): fresh
            [at(1000, 0.50, 0.2)],  # repeated time_boot_ms, nothing sent yet: dropped
            [at(1000, 0.50, 0.3)],  # repeated: the thrust sent below replaces it
            [at(1020, 0.47, 0.4)],  # an attitude setpoint again (time moved): PX4's own
        ]
    )
    got = []
    echo = tap_attitude_target(link, lambda t, u: got.append(list(u)))
    link.poll(1.0)
    link.poll(1.02)
    link.send(
        codec.set_attitude_target_encode(
            0, 3, 1, ATTITUDE_TARGET_IGNORE_ATTITUDE, [1, 0, 0, 0], 0.3, 0.0, 0.0, 0.61
        )
    )
    link.send(  # an attitude setpoint (attitude not ignored) does not set the rate thrust
        codec.set_attitude_target_encode(0, 3, 1, 0, [1, 0, 0, 0], 0.0, 0.0, 0.0, 0.9)
    )
    link.poll(1.04)
    link.poll(1.06)
    assert [g[:2] for g in got] == [
        pytest.approx([0.50, 0.1]),
        pytest.approx([0.61, 0.3]),
        pytest.approx([0.47, 0.4]),
    ]
    assert (echo.dropped, echo.replaced) == (1, 1)
    assert len(link.sent) == 2  # every message still reaches the vehicle


def test_identify_cli_builds_the_rate_plant_from_a_campaigns_bags(tmp_path, capsys):
    """``lpv-sysid identify --plant px4-rate`` (issue 21 item 2): the bags of an experiment
    directory (``bag_*``, as the data logger writes them) with state and PX4's rate setpoints
    -> vertex_models.yaml of the rate plant over the campaign box; the identified loop poles
    and thrust gain are the simulated plant's (P0) and every vertex carries them."""
    from lpv_sysid.cli.main import main as cli_main
    from lpv_sysid.configuration.defaults import config_file
    from lpv_sysid.flight.campaign import FlyConfig
    from lpv_sysid.io import bag as bg
    from lpv_sysid.io import messages as m
    from lpv_sysid.io.files import read_yaml

    f = m.MsgFactory.rosbags()
    for k, seed in enumerate((0, 1)):
        t, x, u = _simulate(P0, T=25.0, seed=seed)
        t0 = 1_000_000_000 * (100 + 50 * k)
        with bg.BagWriter(tmp_path / "exp" / f"bag_{k:04d}") as b:
            b.add_topic("/lpv_sysid/state", m.TYPES["state"])
            b.add_topic("/lpv_sysid/rate_setpoint", m.TYPES["actuator_command"])
            for i in range(0, len(t), 2):  # state 100 Hz
                ns = t0 + round(t[i] * 1e9)
                eul = [x[i, 0], x[i, 1], 0.0]
                msg = m.odometry_from_state(f, ns, [0.0, 0.0, -10.0], eul, x[i, 2:5], x[i, 5:8])
                b.write("/lpv_sysid/state", ns, msg)
            for i in range(0, len(t), 4):  # setpoints 50 Hz
                ns = t0 + round(t[i] * 1e9)
                b.write(
                    "/lpv_sysid/rate_setpoint",
                    ns,
                    m.joint_state(f, ns, rp.INPUT_NAMES, position=u[i]),
                )
    out = tmp_path / "vertex_models.yaml"
    args = ["identify", "--plant", "px4-rate", "--bags", str(tmp_path / "exp"), "--out", str(out)]
    assert cli_main(args) == 0
    printed = capsys.readouterr().out
    assert f"wrote {out}" in printed
    doc = read_yaml(str(out))
    box = FlyConfig.load(config_file("campaign_chain.yaml")).campaign
    assert doc["scheduling"]["min"] == pytest.approx(list(box.box_min))
    assert doc["scheduling"]["max"] == pytest.approx(list(box.box_max))
    assert [s["name"] for s in doc["inputs"]] == list(rp.INPUT_NAMES)
    assert doc["meta"]["design"] == rp.DESIGN and len(doc["vertices"]) == 8
    for v in doc["vertices"]:
        A, B = np.array(v["A"]), np.array(v["B"])
        assert A[5, 5] == pytest.approx(P0.L_p, rel=0.08)
        assert A[6, 6] == pytest.approx(P0.M_q, rel=0.08)
        assert A[7, 7] == pytest.approx(P0.N_r, rel=0.08)
        assert B[4, 0] == pytest.approx(P0.Z_T, rel=0.08)
    # a directory without rate setpoints: a named error, exit 2
    assert (
        cli_main(
            [
                "identify",
                "--plant",
                "px4-rate",
                "--bags",
                str(tmp_path / "nothing"),
                "--out",
                str(tmp_path / "m2.yaml"),
            ]
        )
        == 2
    )


def test_output_error_scores_the_true_model_near_one_and_a_wrong_pole_lower():
    """Output error (issue 21 item 3): rows simulated from the recorded setpoints; the true
    plant reproduces the states (R^2 > 0.97 on every row), a rate loop 3x too slow or a drag
    of the wrong sign does not (the error accumulates), while the other rows keep their
    score (row-wise simulation with measured couplings)."""
    import dataclasses

    t, x, u = _simulate(P0, T=30.0, seed=5)
    run = rid.run_from_arrays("sim", t[::2], x[::2], t[::4], u[::4])
    good = rid.output_error(P0, run)
    assert good["window_s"] == rid.OUTPUT_ERROR_WINDOW_S
    for row in ("u", "v", "w", "p", "q", "r"):
        assert good[row] > 0.97, (row, good)
    slow = rid.output_error(dataclasses.replace(P0, L_p=P0.L_p / 3, L_sp=P0.L_sp / 3), run)
    assert slow["p"] < good["p"] - 0.1 and slow["q"] == good["q"]
    drag = rid.output_error(dataclasses.replace(P0, X_u=-P0.X_u), run)
    assert drag["u"] < good["u"] - 0.1 and drag["v"] == good["v"]


def _scheduled_truth(corner):
    """A rate plant whose identified coefficients depend on the vertex (drag, thrust gain
    and roll-loop bandwidth change with the flight condition; pitch and yaw loops do not):
    the known truth of the per-vertex test."""
    import dataclasses

    u, v, w = (float(c) for c in corner)
    return dataclasses.replace(
        P0,
        X_u=-0.7 - 0.05 * u,
        Y_v=-0.6 + 0.04 * v,
        Z_w=-0.5 - 0.05 * w,
        Z_T=-12.5 * (1 + 0.04 * w),
        L_p=-10.0 - 0.5 * u,
        L_sp=10.0 + 0.5 * u,
    )


def _flown_at(P, corner):
    """The FRD body velocity at which the rate plant ``P`` flies the campaign vertex
    ``corner`` (commanded in the heading frame, ``body_ned``): the fixed point of
    v_body = R(phi, theta)^T corner with (phi, theta) the trim attitude at v_body."""
    corner = np.asarray(corner, dtype=float)
    vb = corner.copy()
    for _ in range(50):
        x0, _ = rp.trim(tuple(vb), P)
        x = np.r_[x0[:2], vb, np.zeros(3)][None, :]
        # level = R vb (orthonormal R): R^T corner from the level image of the unit vectors
        R = np.column_stack(
            [rid.level_velocity(np.r_[x0[:2], e, np.zeros(3)][None, :])[0] for e in np.eye(3)]
        )
        vb = R.T @ corner
    assert np.allclose(rid.level_velocity(x)[0], corner, atol=1e-6)
    return tuple(vb)


def test_per_vertex_identification_recovers_each_vertex_within_its_intervals(tmp_path):
    """Issue 22 item 2: each corner of a +-4/+-4/+-2 m/s box is flown (simulated) with its own
    true coefficients and measurement noise (0.003 rad, 0.02 m/s, 0.01 rad/s); the per-vertex
    fit recovers every vertex's drag, thrust gain and loop poles within 3 of its own standard
    deviations (56 coefficients), detects the coefficients whose truth depends on the vertex
    (spread > 3 combined std) and not those that do not, and the pooled fit of all runs is
    outside the 3-sigma interval of some vertex (pooling would assume what is identified).
    A hover run belongs to no corner; a corner without runs takes the pooled fit and says
    so; vertex_models.yaml carries each vertex's own coefficients."""
    from lpv_sysid.io.files import read_yaml, save_yaml
    from lpv_sysid.models.lpv import box_vertices

    vmin, vmax = [-4.0, -4.0, -2.0], [4.0, 4.0, 2.0]
    corners = box_vertices(vmin, vmax)
    noise = (0.003, 0.02, 0.01)
    runs = []
    for k, c in enumerate(corners):
        P = _scheduled_truth(c)
        t, x, u = _simulate_at(P, _flown_at(P, c), T=30.0, seed=k, noise=noise)
        runs.append(rid.run_from_arrays(f"vertex_{k + 1}", t[::2], x[::2], t[::4], u[::4]))
    t, x, u = _simulate_at(P0, (0.0, 0.0, 0.0), T=20.0, seed=20, noise=noise)
    hover = rid.run_from_arrays("hover", t[::2], x[::2], t[::4], u[::4])
    assert rid.assign_vertex(hover, vmin, vmax) is None
    assert [rid.assign_vertex(r, vmin, vmax) for r in runs] == list(range(8))
    fits, pooled, rep = rid.identify_vertices([*runs, hover], vmin, vmax)
    assert rep["unassigned_runs"] == ["hover"]
    names = ("X_u", "Y_v", "Z_w", "Z_T", "L_p", "M_q", "N_r")
    worst = 0.0
    for f in fits:
        assert f.source == "vertex" and f.runs == (f"vertex_{f.index + 1}",)
        truth = _scheduled_truth(f.vertex)
        for n in names:
            z = abs(getattr(f.params, n) - getattr(truth, n)) / f.params.std[n]
            assert z < 3.0, (f.index, n, getattr(f.params, n), getattr(truth, n), z)
            worst = max(worst, z)
    assert worst > 0.5  # the intervals are not vacuous
    sch = rep["scheduling"]
    for n in ("X_u", "Y_v", "Z_T", "L_p"):
        assert sch[n]["max_difference_sigmas"] > 3.0, (n, sch[n])
    for n in ("M_q", "N_r"):
        assert sch[n]["max_difference_sigmas"] < 3.0, (n, sch[n])
    assert (
        max(abs(pooled.X_u - f.params.X_u) / f.params.std["X_u"] for f in fits) > 3.0
    )  # the pooled drag misses a vertex's
    # vertex_models.yaml: each corner's A/B carry that corner's own fit
    doc = rid.models_document([f.params for f in fits], vmin, vmax, 2.0, rep)
    save_yaml(doc, tmp_path / "m.yaml")
    doc = read_yaml(str(tmp_path / "m.yaml"))
    assert "per-vertex" in doc["meta"]["identification"]["method"]
    for f, v in zip(fits, doc["vertices"]):
        A, B = np.array(v["A"]), np.array(v["B"])
        assert A[2, 2] == pytest.approx(f.params.X_u) and B[4, 0] == pytest.approx(f.params.Z_T)
        assert A[5, 5] == pytest.approx(f.params.L_p)
    # corners without data: the pooled fit, said per vertex
    fits2, pooled2, rep2 = rid.identify_vertices([runs[0], runs[7], hover], vmin, vmax)
    src = [f.source for f in fits2]
    assert src == ["vertex"] + ["pooled"] * 6 + ["vertex"]
    assert fits2[3].params == pooled2 and fits2[3].reason == "no run at this vertex"
    assert rep2["vertices"][3]["source"] == "pooled"
    assert rep2["scheduling"]["vertices_pooled"] == 6
    short = rid.run_from_arrays("short", *_short(runs[2]))
    fits3, _, _ = rid.identify_vertices([runs[0], short], vmin, vmax)
    assert fits3[2].source == "pooled" and "s of data" in fits3[2].reason


def _short(run):
    """(t, x, t, u) of the first 8 s of a run (less than min_vertex_s after trimming)."""
    k = int(8.0 * 50)
    return run.t[:k], run.x[:k], run.t[:k], run.u_raw[:k]


def _write_rate_bag(path, t, x, u, t0_ns):
    """A phase-1 run bag as `fly phase1 --record-rate-setpoints` writes it: state at 100 Hz,
    PX4's rate setpoints at 50 Hz (from a 200 Hz simulation)."""
    from lpv_sysid.io import bag as bg
    from lpv_sysid.io import messages as m

    f = m.MsgFactory.rosbags()
    with bg.BagWriter(path) as b:
        b.add_topic("/lpv_sysid/state", m.TYPES["state"])
        b.add_topic("/lpv_sysid/rate_setpoint", m.TYPES["actuator_command"])
        for i in range(0, len(t), 2):
            ns = t0_ns + round(t[i] * 1e9)
            eul = [x[i, 0], x[i, 1], 0.0]
            msg = m.odometry_from_state(f, ns, [0.0, 0.0, -30.0], eul, x[i, 2:5], x[i, 5:8])
            b.write("/lpv_sysid/state", ns, msg)
        for i in range(0, len(t), 4):
            ns = t0_ns + round(t[i] * 1e9)
            b.write(
                "/lpv_sysid/rate_setpoint", ns, m.joint_state(f, ns, rp.INPUT_NAMES, position=u[i])
            )


def test_identify_cli_takes_the_bags_of_several_flights_per_vertex(tmp_path, capsys):
    """``identify --plant px4-rate --bags FLIGHT1 FLIGHT2`` (issue 22 items 1-2: a campaign
    over two batteries, ``fly phase1 --resume``): three corners of the +-4/+-4/+-1.0 box of
    config/campaign_px4_box.yaml flown over two flights get their own fits (their drag is
    the simulated truth of each corner), the other five the pooled fit, and the printed
    table and vertex_models.yaml say which."""
    from lpv_sysid.cli.main import main as cli_main
    from lpv_sysid.configuration.defaults import config_file
    from lpv_sysid.io.files import read_yaml
    from lpv_sysid.models.lpv import box_vertices

    vmin, vmax = [-4.0, -4.0, -1.0], [4.0, 4.0, 1.0]
    corners = box_vertices(vmin, vmax)
    flown = {0: "flight1", 7: "flight1", 2: "flight2"}
    for n, (k, flight) in enumerate(flown.items()):
        c = corners[k]
        P = _scheduled_truth(c)
        t, x, u = _simulate_at(P, _flown_at(P, c), T=25.0, seed=40 + k)
        _write_rate_bag(tmp_path / flight / f"bag_{n:04d}", t, x, u, 10**9 * (100 + 60 * n))
    out = tmp_path / "vertex_models.yaml"
    args = ["identify", "--plant", "px4-rate", "--bags", str(tmp_path / "flight1")]
    args += [str(tmp_path / "flight2"), "--out", str(out)]
    args += ["--campaign", str(config_file("campaign_px4_box.yaml"))]
    assert cli_main(args) == 0
    printed = capsys.readouterr().out
    rows = [ln.split() for ln in printed.splitlines() if ln.strip().startswith(tuple("12345678"))]
    assert [r[0] for r in rows] == [str(k) for k in range(1, 9)]
    assert [r[4] for r in rows] == ["vertex" if k in flown else "pooled" for k in range(8)]
    assert printed.count("(no run at this vertex)") == 5
    (tmp_path / "printed.txt").write_text(printed)
    doc = read_yaml(str(out))
    ident = doc["meta"]["identification"]
    assert [v["source"] for v in ident["vertices"]] == [
        "vertex" if k in flown else "pooled" for k in range(8)
    ]
    for k in flown:
        A = np.array(doc["vertices"][k]["A"])
        assert A[2, 2] == pytest.approx(_scheduled_truth(corners[k]).X_u, rel=0.05)
        assert A[5, 5] == pytest.approx(_scheduled_truth(corners[k]).L_p, rel=0.05)


def test_level_velocity_rotates_body_velocity_by_roll_and_pitch():
    """Hand values: pitch 30 deg nose up, body u = 1 -> level (cos 30, 0, -sin 30); roll 90
    deg right, body w = 1 (down in the body) -> level v = -1 (the body's down points left);
    the norm is kept."""
    th = math.radians(30.0)
    x = np.array([[0.0, th, 1.0, 0.0, 0.0, 0, 0, 0], [math.pi / 2, 0.0, 0.0, 0.0, 1.0, 0, 0, 0]])
    lv = rid.level_velocity(x)
    assert lv[0] == pytest.approx([math.cos(th), 0.0, -math.sin(th)], abs=1e-12)
    assert lv[1] == pytest.approx([0.0, -1.0, 0.0], abs=1e-12)
