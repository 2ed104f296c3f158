"""Safety supervisor core: every abort condition, latching and the safe-state action."""

import math

import pytest

from lpv_sysid.control.safety import (
    BOUND_EXCEEDED, EXTERNAL, NON_FINITE, OUT_OF_BOX, OUT_OF_ORDER, STALE, SafetyConfig,
    SafetySupervisor)
from lpv_sysid.errors import ConfigError, SafetyError


def make(margin=0.0):
    cfg = SafetyConfig.from_dict({"timeouts": {"state": 0.05, "reference": 0.2},
                                  "box_min": [-5, -5, -2], "box_max": [5, 5, 2],
                                  "box_margin": margin})
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
    assert sup.check(10.2) is None          # reference age exactly 0.2 s: not stale
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
    feed(sup, 12.0)   # fresh, valid data does not clear the abort
    assert sup.aborted and not sup.action.commanding
    with pytest.raises(SafetyError, match="bound_exceeded: phi"):
        raise sup.event.as_error()
    with pytest.raises(SafetyError):
        sup.reset()   # still armed
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


@pytest.mark.parametrize("cfg, field", [
    ({"timeouts": {"state": 0.0}}, "timeouts.state"),
    ({"timeouts": {"state": 0.1}, "box_min": [1], "box_max": [0]}, "box_min"),
    ({"timeouts": {"state": 0.1}, "bogus": 1}, "bogus"),
    ({"timeout": {}}, "timeout"),
])
def test_bad_config_names_field(cfg, field):
    with pytest.raises(ConfigError, match=field):
        SafetyConfig.from_dict(cfg)
