"""Safety supervisor core: every abort condition, latching and the safe-state action."""

import math

import pytest

from lpv_sysid.control.safety import (
    BOUND_EXCEEDED,
    EXTERNAL,
    NON_FINITE,
    OUT_OF_BOX,
    OUT_OF_ORDER,
    STALE,
    SafetyConfig,
    SafetySupervisor,
)
from lpv_sysid.errors import ConfigError, SafetyError


def make(margin=0.0):
    cfg = SafetyConfig.from_dict(
        {
            "timeouts": {"state": 0.05, "reference": 0.2},
            "box_min": [-5, -5, -2],
            "box_max": [5, 5, 2],
            "box_margin": margin,
        }
    )
    sup = SafetySupervisor(cfg)
    sup.arm(10.0)
    return sup


def feed(sup, t):
    sup.on_input("state", t, [0.0] * 12, t)
    sup.on_input("reference", t, [0.0] * 4, t)


def test_nominal_run_keeps_commanding():
    sup = make()
    for k in range(200):
        t = 10.0 + 0.004 * k
        feed(sup, t)
        sup.check_scheduling(t, [4.9, -4.9, 0.0])
        sup.check(t + 0.003)
    assert not sup.aborted
    assert sup.action.commanding and sup.action.excitation_on


def test_not_armed_is_safe_state():
    sup = SafetySupervisor(SafetyConfig(timeouts={"state": 0.1}))
    assert not sup.action.commanding and not sup.action.excitation_on


def test_stale_stream_boundary():
    sup = make()
    feed(sup, 10.0)
    sup.on_input("state", 10.19, [0.0] * 12, 10.19)
    assert sup.check(10.2) is None  # reference age exactly 0.2 s: not stale
    ev = sup.check(10.2000001)
    assert ev.reason == STALE and ev.detail.startswith("reference")
    assert not sup.action.commanding and not sup.action.excitation_on


def test_stream_never_received_after_arming():
    sup = make()
    sup.on_input("reference", 10.0, [0.0] * 4, 10.0)
    ev = sup.check(10.06)
    assert ev.reason == STALE and "state: no message" in ev.detail


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_value_names_index(bad):
    sup = make()
    x = [0.0] * 12
    x[7] = bad
    ev = sup.on_input("state", 10.0, x, 10.0)
    assert ev.reason == NON_FINITE and "indices [7]" in ev.detail


def test_out_of_order_stamp():
    sup = make()
    sup.on_input("state", 10.010, [0.0] * 12, 10.010)
    assert sup.on_input("state", 10.010, [0.0] * 12, 10.011) is None  # equal stamp allowed
    ev = sup.on_input("state", 10.006, [0.0] * 12, 10.012)
    assert ev.reason == OUT_OF_ORDER and "10.006000" in ev.detail


def test_scheduling_box_with_margin():
    sup = make(margin=0.25)
    assert sup.check_scheduling(10.0, [5.25, 0.0, 0.0]) is None
    ev = sup.check_scheduling(10.0, [0.0, 0.0, -2.26])
    assert ev.reason == OUT_OF_BOX and ev.detail.startswith("scheduling[2] = -2.26")


def test_bound_flag_and_latching_first_reason_wins():
    sup = make()
    sup.on_bound_flag(10.0, False)
    assert not sup.aborted
    sup.on_bound_flag(10.5, True, "phi = 0.61 rad > 0.6 rad")
    sup.check_scheduling(11.0, [99.0, 0.0, 0.0])
    assert sup.event.reason == BOUND_EXCEEDED and sup.event.t == 10.5
    feed(sup, 12.0)  # fresh, valid data does not clear the abort
    assert sup.aborted and not sup.action.commanding
    with pytest.raises(SafetyError, match="bound_exceeded: phi"):
        raise sup.event.as_error()
    with pytest.raises(SafetyError):
        sup.reset()  # still armed
    with pytest.raises(SafetyError):
        sup.arm(13.0)
    sup.disarm()
    sup.reset()
    sup.arm(13.0)
    assert sup.action.commanding


def test_external_abort():
    sup = make()
    assert sup.abort(10.0, EXTERNAL, "operator").reason == EXTERNAL
    assert not sup.action.excitation_on


@pytest.mark.parametrize(
    "cfg, field",
    [
        ({"timeouts": {"state": 0.0}}, "timeouts.state"),
        ({"timeouts": {"state": 0.1}, "box_min": [1], "box_max": [0]}, "box_min"),
        ({"timeouts": {"state": 0.1}, "bogus": 1}, "bogus"),
        ({"timeout": {}}, "timeout"),
    ],
)
def test_bad_config_names_field(cfg, field):
    with pytest.raises(ConfigError, match=field):
        SafetyConfig.from_dict(cfg)


# ----------------------------------------------- header stamps against the node clock
def make_tol(tol=0.01):
    sup = SafetySupervisor(SafetyConfig(timeouts={"state": 0.05}, stamp_tolerance=tol))
    sup.arm(10.0)
    return sup


def test_future_stamp_beyond_tolerance():
    from lpv_sysid.control.safety import FUTURE_STAMP

    sup = make_tol()
    assert sup.on_input("state", 10.01, [0.0], 10.0) is None  # at the tolerance
    ev = sup.on_input("state", 10.0201, [0.0], 10.01)
    assert ev.reason == FUTURE_STAMP and "0.010 s ahead of the node clock 10.010000 s" in ev.detail


def test_stamp_age_at_receipt_and_at_the_tick():
    sup = make_tol()
    assert sup.on_input("state", 9.96, [0.0], 10.0) is None  # 40 ms latency < 50 + 10
    assert sup.check(10.0) is None
    ev = sup.on_input("state", 9.9399, [0.0], 10.0)
    assert ev.reason == OUT_OF_ORDER  # went back: first reason
    sup = make_tol()
    sup.on_input("state", 10.0, [0.0], 10.0)
    sup.on_input("state", 10.0, [0.0], 10.05)  # frozen, 50 ms
    assert sup.check(10.05) is None
    ev = sup.on_input("state", 10.0, [0.0], 10.0601)  # 60.1 ms > 50 + 10
    assert ev.reason == STALE and ev.detail.startswith("state: stamp frozen at 10.000000 s")
    sup = make_tol()
    sup.on_input("state", 10.0, [0.0], 10.0)
    sup.on_input("state", 10.0, [0.0], 10.04)
    ev = sup.check(10.0601)  # receipt 20 ms, stamp 60 ms
    assert ev.reason == STALE and ev.detail.startswith("state: newest stamp 10.000000 s is 0.060")


def test_stamp_checks_only_while_armed():
    sup = SafetySupervisor(SafetyConfig(timeouts={"state": 0.05}, stamp_tolerance=0.01))
    assert sup.on_input("state", 1e9, [0.0], 0.0) is None  # before /clock, sim time
    with pytest.raises(ConfigError, match="stamp_tolerance"):
        SafetyConfig(timeouts={"state": 0.05}, stamp_tolerance=-1.0)


def test_excitation_bound_and_closed_loop_check():
    import numpy as np

    from lpv_sysid.control.safety import EXCITATION_BOUND, check_closed_loop

    sup = make()
    assert sup.check_excitation(10.0, [0.1, -0.2, 0.0, 0.0], [0.2, 0.2, 0.2, 0.2]) is None
    ev = sup.check_excitation(10.0, [0.1, -0.3, 0.0, math.nan], [0.2] * 4)
    assert ev.reason == EXCITATION_BOUND and ev.detail.startswith("excitation[1] = -0.3")
    A = np.array([[0.0, 1.0], [0.0, 0.0]])  # double integrator
    B = np.array([[0.0], [1.0]])
    K_ok = np.array([[-1.0, -2.0]])  # s^2 + 2 s + 1: poles -1, -1
    assert check_closed_loop(K_ok[None], [[(A, B)]]) == pytest.approx(-1.0, abs=1e-6)
    with pytest.raises(ConfigError, match="unstable at vertex 1"):
        check_closed_loop(np.stack([K_ok, -K_ok]), [[(A, B)], [(A, B)]])
