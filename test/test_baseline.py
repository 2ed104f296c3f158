"""PX4-like baseline velocity controller around the seed 0 quadrotor."""

import math

import numpy as np
import pytest

from lpv_sysid.control.baseline import BaselineController, BaselineGains
from lpv_sysid.errors import ConfigError, SafetyError
from lpv_sysid.models.quadrotor import Quadrotor, reduced_state
from lpv_sysid.sim.vehicle import SensorConfig, SimVehicle

Q = Quadrotor()
HOVER = Q.trim([0, 0, 0])
NOISELESS = SensorConfig(
    pos_std=0,
    att_std_deg=0,
    vel_std=0,
    rate_std=0,
    accel_std=0,
    gyro_std=0,
    rotor_std=0,
    vib_accel=0,
    vib_accel_blade=0,
    vib_gyro=0,
)


def _fly(ref, r_ref=0.0, seconds=8.0, x0=None, sensors=NOISELESS, warm=True):
    veh = SimVehicle(Q, sensors, HOVER.full_state if x0 is None else x0)
    c = BaselineController(BaselineGains(hover_thrust=float(HOVER.u0[0])))
    if warm:
        c.warm_start(HOVER.x0, HOVER.u0, [0, 0, 0])
    n = int(seconds * 500)
    log = np.empty((n // 2, 12))
    u = HOVER.u0
    for k in range(n):
        if k % 2 == 0:
            u = c.step(k / 500, reduced_state(veh.measure_state()), ref, r_ref)
            esc = Q.mix_inv @ u
            assert np.all(esc >= -1e-9) and np.all(esc <= 1 + 1e-9)  # mixer desaturation
            log[k // 2] = veh.x[3:12] + [0.0, 0.0, 0.0]
        veh.step(u)
    return np.array(veh.x), log


@pytest.mark.parametrize("ref", [[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0], [0, 0, 1.0]])
def test_unit_velocity_steps_converge(ref):
    x, _ = _fly(ref, seconds=8.0)
    assert np.allclose(x[6:9], ref, atol=0.03)
    assert np.all(np.abs(x[9:12]) < 0.02)


def test_vertex_reference_reached_from_hover():
    x, log = _fly([5.0, -5.0, -5.0], seconds=12.0)
    assert np.allclose(x[6:9], [5, -5, -5], atol=0.1)
    tr = Q.trim([5, -5, -5])
    assert x[3] == pytest.approx(tr.x0[0], abs=math.radians(1.0))
    assert x[4] == pytest.approx(tr.x0[1], abs=math.radians(1.0))
    # tilt limit respected throughout
    assert np.max(np.arccos(np.cos(log[:, 0]) * np.cos(log[:, 1]))) < math.radians(40)


def test_yaw_rate_reference_tracked():
    x, _ = _fly([0, 0, 0], r_ref=0.5, seconds=6.0)
    assert x[11] == pytest.approx(0.5, abs=0.02)


def test_attitude_disturbance_recovers():
    x0 = HOVER.full_state.copy()
    x0[3], x0[4], x0[9] = 0.4, -0.3, 1.0
    x, _ = _fly([0, 0, 0], seconds=6.0, x0=x0)
    assert abs(x[3]) < math.radians(1) and abs(x[4]) < math.radians(1)
    assert np.allclose(x[6:9], 0, atol=0.05)


def test_hover_with_noise_and_vibration_stays_close():
    x, log = _fly([0, 0, 0], seconds=5.0, sensors=SensorConfig(seed=3))
    assert np.allclose(x[6:9], 0, atol=0.2)
    assert np.max(np.abs(log[:, 0:2])) < math.radians(3)


def test_warm_start_reproduces_trim_command():
    tr = Q.trim([-5, 5, 5])
    c = BaselineController(BaselineGains(hover_thrust=float(HOVER.u0[0])))
    c.warm_start(tr.x0, tr.u0, [-5, 5, 5])
    u = c.step(0.0, tr.x0, [-5, 5, 5], 0.0)
    assert np.allclose(u, tr.u0, atol=1e-9)


def test_linearised_closed_loop_at_hover_is_stable():
    """Eigenvalues of the closed loop linearised numerically about hover (true state)."""
    g = BaselineGains(
        hover_thrust=float(HOVER.u0[0]),
        velocity_rate_hz=250.0,
        rate_d_roll=0.0,
        rate_d_pitch=0.0,
        vel_d_xy=0.0,
    )
    # the static part of the cascade at hover (no integrators, no filters): u = K dx
    K = np.zeros((4, 12))
    eps = 1e-6
    for j in range(8):
        dx = np.zeros(12)
        dx[j] = eps
        up, um = [], []
        for sgn, out in ((1, up), (-1, um)):
            c = BaselineController(g)
            c.warm_start(HOVER.x0, HOVER.u0, [0, 0, 0])
            c._rate_prev = list(HOVER.x0[5:8] + sgn * dx[5:8])
            out.append(c.step(0.0, HOVER.x0 + sgn * dx, [0, 0, 0], 0.0))
        K[:, j] = (up[0] - um[0]) / (2 * eps)
    A, B = Q.linearize(HOVER)
    eig = np.linalg.eigvals(A + B @ K)
    assert np.max(eig.real) < -0.05
    assert np.max(np.linalg.eigvals(A).real) >= 0  # open loop is not asymptotically stable


def test_gains_validation():
    with pytest.raises(ConfigError, match="unknown"):
        BaselineGains.from_dict({"vel_p": 1.0})
    with pytest.raises(ConfigError, match="hover_thrust"):
        BaselineGains.from_dict({"hover_thrust": 0.95})
    assert BaselineGains.from_dict(BaselineGains().to_dict()) == BaselineGains()


def test_non_finite_measurement_or_reference_raises_safety_error():
    c = BaselineController(BaselineGains())
    x = HOVER.x0.copy()
    x[6] = np.nan
    with pytest.raises(SafetyError, match="q"):
        c.step(0.0, x, [0, 0, 0], 0.0)
    with pytest.raises(SafetyError, match="w_d"):
        c.step(0.0, HOVER.x0, [0, 0, np.inf], 0.0)


def test_vehicle_divergence_raises_safety_error():
    veh = SimVehicle(Q, NOISELESS, HOVER.full_state)
    veh.x[6] = np.nan
    with pytest.raises(SafetyError, match="diverged"):
        veh.step(HOVER.u0)


def test_mixer_desaturation_priorities():
    c = BaselineController(BaselineGains())
    mi = c.mix_inv
    # feasible commands pass unchanged
    cmd, sat = c._desaturate(0.5, 0.01, -0.01, 0.1)
    assert np.allclose(cmd, [0.5, 0.01, -0.01, 0.1]) and not any(sat)
    # too much yaw at high collective: yaw is reduced first, roll/pitch kept
    cmd, sat = c._desaturate(0.8, 0.02, 0.0, 1.0)  # motors 0.8 +- 0.031 +- 0.25
    esc = mi @ np.array(cmd)
    assert sat[2] and not sat[0] and cmd[1] == pytest.approx(0.02) and cmd[3] < 1.0
    assert esc.max() == pytest.approx(1.0) and esc.min() >= 0
    # roll demand beyond the collective margin: collective shifts, roll kept
    cmd, sat = c._desaturate(0.9, 0.1, 0.0, 0.0)
    esc = mi @ np.array(cmd)
    assert cmd[1] == pytest.approx(0.1) and cmd[0] < 0.9 and esc.max() == pytest.approx(1.0)
    # impossible roll demand: scaled to the full [0, 1] spread
    cmd, sat = c._desaturate(0.5, 1.0, 0.0, 0.0)
    esc = mi @ np.array(cmd)
    assert (
        all(sat) and esc.min() == pytest.approx(0.0, abs=1e-12) and esc.max() == pytest.approx(1.0)
    )
