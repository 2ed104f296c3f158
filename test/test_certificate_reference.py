"""Issue 20 item 5: gamma bounds u_e -> z only; the reference-driven part is covered for
references within the design envelope's rate AND acceleration, and a table beyond either is
refused before flight by the one load check (signals.excitation.check_design, used by the
excitation runtime at load).

Oracle: a sinusoid a sin(w t) has peak rate a w and peak acceleration a w^2; time-scaling it by
s multiplies them by s and s^2."""

import numpy as np
import pytest

from lpv_sysid.errors import ConfigError
from lpv_sysid.io.formats import DesignEnvelope
from lpv_sysid.signals.excitation import check_design, envelope_dict

NAMES = ["u_d", "v_d", "w_d", "ue_t", "ue_a", "ue_e", "ue_r"]


def _env():
    d = envelope_dict([1.8] * 3, [0.2] * 3, 0.01, [1.0] * 4, fade_s=1.0)
    return DesignEnvelope(
        tuple(d["reference_peak"]),
        tuple(d["reference_rate"]),
        tuple(d["reference_accel"]),
        d["knot_interval_s"],
        d["fade_s"],
        tuple(d["excitation_peak"]),
    )


def _table(a, w, t_end=60.0, dt=0.01):
    t = np.arange(0.0, t_end, dt)
    u = np.zeros((t.size, 7))
    u[:, 0] = a * np.sin(w * t)
    u[:, 3:] = 0.5 * np.sin(3.0 * t)[:, None]
    return t, u


def test_references_beyond_the_recorded_acceleration_are_refused_before_flight():
    env = _env()
    R1, R2 = env.reference_rate[0], env.reference_accel[0]
    # a reference whose rate is within the design but whose acceleration is not (small
    # amplitude, high frequency): refused by the acceleration bound alone
    w = 1.5 * R2 / R1
    a = 0.9 * R1 / w  # peak rate 0.9 R1, peak accel 0.9 R1 w = 1.35 R2
    assert a * w <= R1 and a * w**2 > R2
    t, u = _table(a, w)
    with pytest.raises(ConfigError, match="u_d accelerates at .* beyond the design acceleration"):
        check_design(t, u, NAMES, env, ramp=1.0)
    # at the bound (rate and acceleration 0.99 of it): accepted
    w1 = R2 / R1
    a1 = 0.99 * R1 / w1
    assert a1 * w1 <= R1 and a1 * w1**2 <= R2 and a1 <= env.reference_peak[0]
    t, u = _table(a1, w1)
    check_design(t, u, NAMES, env, ramp=1.0)
    # the same reference played 2x-5x faster: refused (rate x s, acceleration x s^2)
    for s in (2.0, 3.0, 5.0):
        t, u = _table(a1, s * w1)
        with pytest.raises(ConfigError, match="beyond the design"):
            check_design(t, u, NAMES, env, ramp=1.0)


# ------------------------------------------------- the same refusal on the live flight path
def _runtime_with_reference(tmp_path, scale):
    """The flight controller's runtime (the one path of lpv_controller_node, ``fly phase2``
    and the chain) fed v_d = a (1 - cos(s w t)) at 250 Hz against the LQR test law whose
    certificate.design records R1 = 12.72 m/s^2, R2 = 47.08 m/s^3: at s = 1 the acceleration
    is 0.99 R2 and the rate 0.79 R1 (at the bound); s = 2..5 multiplies them by s and s^2.
    Returns the runtime after 3 s (or at its abort)."""
    from lpv_test_gains import write_gains

    from lpv_sysid.flight.controller import ControllerRuntime, ControllerSettings
    from lpv_sysid.io import messages

    g = write_gains(tmp_path / "gains.yaml", box=5.0)
    rt = ControllerRuntime(ControllerSettings(gains_file=g), messages.MsgFactory.rosbags())
    d = rt.schedule.certificate.design
    R1, R2 = d.reference_rate[0], d.reference_accel[0]
    a = 2.2
    w = np.sqrt(0.99 * R2 / a)
    assert a * w <= 0.8 * R1 and 2 * a < 5.0
    x0 = rt.schedule.x0.mean(axis=0)
    x8, om = x0[:8], np.linalg.solve(rt.mix, x0[8:])

    def feed(t, v):
        for topic, val in (
            ("state", x8),
            ("rotor_speeds", om),
            ("velocity_reference", np.array([v, 0.0, 0.0, 0.0])),
            ("excitation", np.zeros(4)),
        ):
            rt.on_sample(topic, t, val, t)

    feed(100.0, 0.0)
    assert rt.start(100.0)[0]
    for k in range(1, 750):
        t = 100.0 + 0.004 * k
        feed(t, a * (1.0 - np.cos(scale * w * 0.004 * k)))
        rt.tick(t)
        if rt.supervisor.aborted:
            break
    return rt, a * w * scale / R1


@pytest.mark.parametrize("scale", [0.5, 1.0, 2.0, 3.0, 5.0])
def test_the_flight_runtime_refuses_references_faster_than_the_certificate(tmp_path, scale):
    """Within the recorded envelope (0.5x, 1x = at the acceleration bound): followed, no abort,
    the law's reference is the incoming one bit for bit. 2x-5x: the runtime aborts with
    ``reference_envelope`` before the law follows it (what gamma does not cover is not flown)."""
    rt, rate_ratio = _runtime_with_reference(tmp_path, scale)
    if scale <= 1.0:
        assert rt.supervisor.event is None and rt.limiter.limited == 0
        assert rt.commands > 700
    else:
        assert rate_ratio > 1.5  # beyond the abort margin of the rate alone
        ev = rt.supervisor.event
        assert ev is not None and ev.reason == "reference_envelope"
        assert "reference[0]" in ev.detail
