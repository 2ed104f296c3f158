"""control/lpv_controller.py: the runtime law of seed 0 Eqs. (17), (31) on hand-computed numbers."""

from types import SimpleNamespace

import numpy as np
import pytest

from lpv_sysid.control.lpv_controller import LpvController, LpvControllerConfig
from lpv_sysid.errors import ConfigError, SafetyError
from lpv_sysid.models.quadrotor import mixer


def _schedule(gamma=1.0):
    # vertex i: K_i = i * E (E = ones), x0_i = i * 0.1 * ones(12), u0_i = (i, 0, 0, 0) * 0.01 + 0.5
    K = np.array([i * np.ones((4, 12)) * 1e-3 for i in range(8)])
    x0 = np.array([i * 0.1 * np.ones(12) for i in range(8)])
    u0 = np.array([[0.5 + 0.01 * i, 0.0, 0.0, 0.0] for i in range(8)])
    return SimpleNamespace(
        K=K,
        x0=x0,
        u0=u0,
        R=np.diag([0.1, 0.2, 0.3, 0.4]),
        Q=np.diag([2.0, 4.0, 5.0]),
        gamma=gamma,
        vmin=np.array([-5.0, -5.0, -5.0]),
        vmax=np.array([5.0, 5.0, 5.0]),
    )


def test_law_equals_formula_on_hand_computed_numbers():
    ctl = LpvController(_schedule())
    # v_d = (0, -5, 5): t = (0.5, 0, 1) -> weights nonzero only at vertices (b=0, c=1): i = 1 and 5,
    # alpha_1 = (1-0.5)*1*1 = 0.5, alpha_5 = 0.5 -> K = 3e-3 * ones, x0 = 0.3 * ones, u0 = (0.53, 0, 0, 0)
    x = np.full(12, 1.3)
    u_e = np.array([1.0, -1.0, 2.0, 0.5])
    u, info = ctl.step(0.0, x, np.array([0.0, -5.0, 5.0]), u_e)
    # K (x - x0) = 3e-3 * 12 * 1.0 = 0.036 per channel; R u_e = (0.1, -0.2, 0.6, 0.2)
    np.testing.assert_allclose(
        u, [0.53 + 0.036 + 0.1, 0.036 - 0.2, 0.036 + 0.6, 0.036 + 0.2], rtol=1e-14
    )
    assert not info["clamped"] and not info["saturated"]


def test_weights_match_models_lpv():
    from lpv_sysid.models.lpv import multilinear_weights

    ctl = LpvController(_schedule())
    rng = np.random.default_rng(2)
    for _ in range(20):
        vd = rng.uniform(-5, 5, 3)
        np.testing.assert_allclose(
            ctl.weights(vd)[0],
            multilinear_weights(vd, -5 * np.ones(3), 5 * np.ones(3))[0],
            atol=1e-15,
        )


def test_mixer_saturation_clips_per_motor_commands():
    mix = mixer(0.225)
    ctl = LpvController(_schedule(), mix=mix)
    u, info = ctl.step(
        0.0, np.zeros(12), np.zeros(3), np.array([20.0, 0.0, 0.0, 0.0])
    )  # huge thrust
    esc = np.linalg.solve(mix, u)
    assert info["saturated"]
    assert np.all(esc <= 1.0 + 1e-12) and np.all(esc >= -1e-12)
    unsat = LpvController(_schedule()).step(
        0.0, np.zeros(12), np.zeros(3), np.array([20.0, 0, 0, 0])
    )[0]
    np.testing.assert_allclose(u, mix @ np.clip(np.linalg.solve(mix, unsat), 0, 1), rtol=1e-12)


def test_clamp_nan_time_and_shape_errors():
    ctl = LpvController(_schedule())
    u_out, info = ctl.step(0.0, np.zeros(12), np.array([9.0, 0.0, 0.0]), np.zeros(4))
    assert info["clamped"]
    u_edge, _ = LpvController(_schedule()).step(
        0.0, np.zeros(12), np.array([5.0, 0.0, 0.0]), np.zeros(4)
    )
    np.testing.assert_allclose(u_out, u_edge)
    with pytest.raises(SafetyError, match="x"):
        ctl.step(0.1, np.full(12, np.nan), np.zeros(3), np.zeros(4))
    with pytest.raises(SafetyError, match="u_e"):
        ctl.step(0.1, np.zeros(12), np.zeros(3), np.array([0, np.inf, 0, 0]))
    with pytest.raises(SafetyError, match="backwards"):
        ctl.step(-1.0, np.zeros(12), np.zeros(3), np.zeros(4))
    with pytest.raises(SafetyError, match="shapes"):
        ctl.step(1.0, np.zeros(11), np.zeros(3), np.zeros(4))


def test_rate_limit():
    ctl = LpvController(_schedule(), LpvControllerConfig(rate_limit=(1.0, 1.0, 1.0, 1.0)))
    u0, _ = ctl.step(0.0, np.zeros(12), np.zeros(3), np.zeros(4))
    u1, info = ctl.step(
        0.01, np.zeros(12), np.zeros(3), np.array([1.0, 0, 0, 0])
    )  # wants +0.1 in ut
    assert info["rate_limited"]
    np.testing.assert_allclose(u1 - u0, [0.01, 0, 0, 0], atol=1e-15)


def test_bound_monitor_gain_and_flag_only_after_enough_energy():
    # constant z: v - v_d = (2, 0, 0) -> z = Q^-1 dv = (1, 0, 0); |u_e| = 0.5 -> gain = 1 / 0.5 = 2
    ctl = LpvController(
        _schedule(gamma=1.0), LpvControllerConfig(monitor_margin=1.5, monitor_min_energy=0.1)
    )
    x = np.zeros(12)
    x[2] = 2.0
    ue = np.array([0.5, 0.0, 0.0, 0.0])
    dt = 0.01
    flags = []
    for k in range(100):
        _, info = ctl.step(k * dt, x, np.zeros(3), ue)
        flags.append((info["bound_judged"], info["bound_exceeded"]))
    assert abs(ctl.gain() - 2.0) < 1e-12
    # energy of u_e reaches 0.1 after 0.1 / 0.25 = 0.4 s = 40 steps (the first step has dt = 0)
    first_judged = [f[0] for f in flags].index(True)
    assert first_judged == 40
    assert not any(f[1] for f in flags[:first_judged]) and flags[-1][1]
    ok = LpvController(
        _schedule(gamma=1.5), LpvControllerConfig(monitor_margin=1.5, monitor_min_energy=0.1)
    )
    for k in range(100):
        _, info = ok.step(k * dt, x, np.zeros(3), ue)
    assert not info["bound_exceeded"]  # 2 < 1.5 * 1.5


def test_config_validation():
    with pytest.raises(ConfigError):
        LpvControllerConfig.from_dict({"margin": 1})
    with pytest.raises(ConfigError):
        LpvController(_schedule(), mix=np.eye(3))
