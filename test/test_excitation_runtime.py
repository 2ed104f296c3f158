"""nodes/excitation_runtime directly (no rclpy, no stand-in): start, abort from every source,
the fade and the shutdown rules on a simulated node clock (ticks of 10 ms)."""

import numpy as np
import pytest

from lpv_sysid.flight.excitation import CLOCK_STALL_S, ExcitationRuntime, ExcitationSettings
from lpv_sysid.io import messages
from lpv_sysid.signals.excitation import ExcitationCore
from lpv_sysid.signals.store import load_npz, save_npz

S = 1_000_000_000  # ns
F = messages.MsgFactory.rosbags()


def table(path, channels) -> str:
    """signals.npz of ``{channel: f(t)}`` over 20 s at 50 Hz."""
    t = np.arange(0.0, 20.0, 0.02)
    save_npz(str(path), t, np.stack([f(t) for f in channels.values()], axis=1), list(channels))
    return str(path)


def sine(amplitude, hz):
    return lambda t: amplitude * np.sin(2 * np.pi * hz * t)


def zero(t):
    return 0 * t


@pytest.fixture
def signals1(tmp_path):
    """Phase 1: a 0.5 m/s 0.5 Hz sine on v_ref, 0.05 rad/s on r_ref."""
    channels = {"u_ref": zero, "v_ref": sine(0.5, 0.5), "w_ref": zero, "r_ref": sine(0.05, 0.5)}
    return table(tmp_path / "sig1.npz", channels)


@pytest.fixture
def signals2(tmp_path):
    """Phase 2: v_d = 0.8 sin(2 pi 0.2 t) on u_d, four sines of amplitude 0.5 on u_e."""
    ue = {f"ue_{c}": sine(0.5, hz) for c, hz in zip("taer", (1.3, 1.7, 2.3, 2.9))}
    return table(tmp_path / "sig2.npz", {"u_d": sine(0.8, 0.2), "v_d": zero, "w_d": zero, **ue})


def runtime(path, **settings):
    log = []
    s = ExcitationSettings(signals_file=path, **{"mode": "phase2", "ramp_s": 1.0, **settings})
    rt = ExcitationRuntime(s, F, log=lambda level, text: log.append((level, text)))
    return rt, log


def ticks(rt, t0, t1):
    """Tick every 10 ms over [t0, t1) s: times [s], v_d FRD, u_e and every output."""
    ts, v, ue, out = [], [], [], []
    for i in range(round((t1 - t0) * 100)):
        ns = round(t0 * S) + i * 10_000_000
        o = rt.on_timer(ns)
        out += o
        ref = next(m for t, m in o if t == "velocity_reference")
        exc = next(m for t, m in o if t == "excitation")
        ts.append(ns * 1e-9)
        v.append(messages.reference_from_twist(ref)[1])
        ue.append(messages.excitation_from_joint_state(exc)[1])
    return np.array(ts), np.array(v), np.array(ue), out


def status_of(msg):
    _, (st,) = messages.status_from_diagnostic_array(msg)
    return st


def test_start_plays_the_core_from_start_plus_delay(signals2):
    rt, _ = runtime(signals2, start_delay_s=0.5)
    _, v, ue, _ = ticks(rt, 1.0, 1.5)
    assert np.all(v == 0.0) and np.all(ue == 0.0)  # before start: trim (phase 2: zero)
    assert status_of(rt.status(S)).values["phase"] == "waiting_for_start"
    ok, text = rt.start(round(1.5 * S))
    oracle = ExcitationCore.phase2(*load_npz(signals2), start_time=2.0, ramp=1.0)
    assert ok and text == (
        f"phase2 excitation starts at t=2.000 s, ends at {oracle.end_time:.3f} s"
    )
    assert rt.start(round(1.6 * S)) == (False, "already started")
    ts, v, ue, _ = ticks(rt, 1.5, 4.0)
    v_exp, _, ue_exp = oracle.evaluate(ts)
    np.testing.assert_allclose(ue, ue_exp, atol=1e-12)
    np.testing.assert_allclose(v, v_exp, atol=1e-12)
    assert np.all(ue[ts <= 2.0] == 0.0) and np.abs(ue[ts > 3.0]).max() > 0.3


def test_abort_fades_within_one_ramp_and_refuses_a_restart(signals2):
    rt, log = runtime(signals2)
    assert rt.start(0)[0]
    ts0, _, _, _ = ticks(rt, 0.0, 1.5)  # last sample at 1.49 s
    out = rt.abort(round(1.5 * S), "abort service")
    st = status_of(out[0][1])
    assert [t for t, _ in out] == ["status"] and st.level == 1
    assert (st.values["phase"], st.values["abort_reason"]) == ("aborted", "abort service")
    assert log == [("warn", "excitation aborted (abort service): fading to zero within 1 s")]
    assert rt.abort(round(1.6 * S), "again") == [] and rt.abort_reason == "abort service"
    ts, _, ue, _ = ticks(rt, 1.5, 3.0)
    # oracle: the same core aborted at its last sample (1.49 s)
    oracle = ExcitationCore.phase2(*load_npz(signals2), start_time=0.0, ramp=1.0)
    for t in ts0:
        oracle.sample(t)
    assert oracle.abort() == pytest.approx(1.49, abs=1e-12)
    np.testing.assert_allclose(ue, [oracle.sample(t).u_e for t in ts], atol=1e-12)
    assert np.all(ue[ts >= 1.49 + 1.0] == 0.0)  # faded within the ramp
    assert np.abs(ue[(ts > 1.6) & (ts < 2.2)]).max() > 0.05  # a fade, not a cut
    assert rt.start(3 * S) == (False, "aborted (abort service): restart the node to run again")


def test_abort_before_start_fades_the_trim_offset(signals1):
    rt, _ = runtime(signals1, mode="phase1", vertex_frd=(2.0, 0.0, 0.0))
    ts, v, _, _ = ticks(rt, 0.0, 0.5)
    assert np.all(v == [2.0, 0.0, 0.0])  # before start: the vertex (trim) reference
    rt.abort(round(0.5 * S), "abort service")
    ts, v, _, _ = ticks(rt, 0.5, 2.0)
    assert v[0, 0] == 2.0  # continuous: the fade starts from the trim value at 0.5 s
    assert v[50, 0] == pytest.approx(1.0, abs=1e-12)  # raised cosine half way (1.0 s)
    assert np.all(v[ts >= 1.5] == 0.0) and np.all(v[ts < 1.5, 0] > 0.0)


@pytest.mark.parametrize(
    "sender, values, fades",
    [
        ("/lpv_sysid/lpv_controller", {"aborted": True}, True),
        ("/lpv_sysid/mavlink_bridge", {"state": "HANDBACK"}, True),
        ("/lpv_sysid/campaign", {"phase": "failed"}, True),
        ("/lpv_sysid/mavlink_bridge", {"state": "OFFBOARD_ACTIVE"}, False),  # no abort
        ("/lpv_sysid/sim_vehicle", {"aborted": True}, False),  # not watched
    ],
)
def test_abort_on_the_status_of_a_watched_node(signals2, sender, values, fades):
    rt, _ = runtime(signals2)
    rt.start(0)
    ticks(rt, 0.0, 1.5)
    st = messages.diagnostic_status(F, "ERROR", sender, "link lost", values)
    out = rt.on_status(messages.diagnostic_array(F, round(1.5 * S), [st]), round(1.5 * S))
    assert rt.aborted == fades and len(out) == int(fades)
    if fades:
        assert rt.abort_reason == f"{sender}: link lost"
    ts, _, ue, _ = ticks(rt, 1.5, 3.0)
    assert (np.abs(ue[ts >= 2.5]).max() == 0.0) == fades


def test_clock_going_back_aborts_and_fades_on_rebased_time(signals2):
    rt, _ = runtime(signals2)
    rt.start(0)
    ticks(rt, 0.0, 3.0)  # last at 2.99 s
    out = rt.on_timer(round(0.99 * S))  # the node clock went back 2 s
    assert [t for t, _ in out] == ["status", "velocity_reference", "excitation"]
    assert rt.abort_reason == "node clock went back by 2.000 s"
    ts, _, ue, _ = ticks(rt, 1.0, 2.5)
    assert np.abs(ue[:10]).max() > 0  # fading, not cut
    assert np.all(ue[ts >= 0.99 + 1.0 + 0.01] == 0.0)  # one ramp of the re-based time


def test_shutdown_final_status_once_the_fade_is_over(signals2):
    rt, log = runtime(signals2)
    rt.start(0)
    ticks(rt, 0.0, 2.0)
    out = rt.begin_shutdown(2 * S, wall_s=100.0)
    assert status_of(out[0][1]).values["abort_reason"] == "shutdown"
    assert rt.shutdown_state(round(2.25 * S)) == "fading out (0.75 s of the 1 s ramp left)"
    _, _, ue, out = ticks(rt, 2.0, 3.0)  # up to 2.99 s: the fade (to 3.0 s) not over
    assert not rt.shutdown_done and [t for t, _ in out if t == "status"] == []
    out = rt.on_timer(3 * S)
    assert [t for t, _ in out] == ["velocity_reference", "excitation", "status"]
    assert rt.shutdown_done and log[-1] == ("info", "excitation faded out: shutdown")
    assert messages.excitation_from_joint_state(out[1][1])[1].tolist() == [0.0] * 4
    assert rt.on_timer(round(3.01 * S))[2:] == []  # the final status once


def test_shutdown_stops_waiting_when_the_node_clock_stalls(signals2):
    rt, log = runtime(signals2)
    rt.start(0)
    ticks(rt, 0.0, 2.0)
    rt.begin_shutdown(2 * S, wall_s=100.0)
    assert rt.poll_shutdown(2 * S, 100.0 + CLOCK_STALL_S - 0.1) == []
    assert rt.poll_shutdown(round(2.01 * S), 100.45) == []  # the clock moved: wait again
    assert rt.poll_shutdown(round(2.01 * S), 100.45 + CLOCK_STALL_S - 0.01) == []
    out = rt.poll_shutdown(round(2.01 * S), 100.45 + CLOCK_STALL_S + 0.01)
    assert [t for t, _ in out] == ["status"] and rt.shutdown_done
    assert log[-1] == (
        "info",
        "excitation node clock stopped at 2.010 s before the fade ended: shutdown",
    )
    assert rt.poll_shutdown(round(2.01 * S), 200.0) == []


def test_its_own_status_never_aborts_it(signals2):
    rt, _ = runtime(signals2, abort_on_status_from=("excitation",))
    rt.start(0)
    for sender, fades in (("/lpv_sysid/excitation", False), ("/other/excitation", True)):
        st = messages.diagnostic_status(F, "WARN", sender, "aborted", {"aborted": True})
        rt.on_status(messages.diagnostic_array(F, S, [st]), S)
        assert rt.aborted == fades
