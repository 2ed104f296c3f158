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
