"""The safe start order of a phase (issue 24 item 4): flight/sequencer.py, ROS-free (its
shell against the rclpy stand-in: test_sequencer_node.py; under real ROS 2:
test_ros_real.py's phase-2 launch)."""

import pytest

from lpv_sysid.errors import ConfigError
from lpv_sysid.flight.sequencer import (
    ABORTED,
    PHASE1_STEPS,
    PHASE2_STEPS,
    RUNNING,
    SequencerRuntime,
    SequencerSettings,
)
from lpv_sysid.io import messages

F = messages.MsgFactory.rosbags()
NS = "/lpv_sysid"


def status(node, level="OK", message="", **values):
    st = messages.diagnostic_status(F, level, f"{NS}/{node}", message, values)
    return messages.diagnostic_array(F, 0, [st])


def runtime(steps=PHASE2_STEPS, ready=lambda n, w: True, **kw):
    s = SequencerSettings(steps=steps, **kw)
    return SequencerRuntime(s, F, f"{NS}/sequencer", ready)


def calls(out):
    return [payload for key, payload in out if key == "call"]


def test_phase2_runs_bridge_ready_controller_armed_offboard_excitation_in_order():
    rt = runtime()
    ok, msg, out = rt.start(0.0)
    assert ok and calls(out) == []  # the bridge's link is not up yet: nothing is started
    assert calls(rt.on_status(status("mavlink_bridge", link_up="False", state="IDLE"), 0.1)) == []
    assert calls(rt.on_timer(0.2)) == []
    rt.on_status(status("mavlink_bridge", link_up="True", state="IDLE"), 0.3)
    assert calls(rt.on_timer(0.4)) == [("lpv_controller", "start")]
    assert calls(rt.on_timer(0.5)) == []  # not armed yet
    rt.on_status(status("lpv_controller", armed="false"), 0.6)
    assert calls(rt.on_timer(0.7)) == []
    rt.on_status(status("lpv_controller", armed="true"), 0.8)
    assert calls(rt.on_timer(0.9)) == [("mavlink_bridge", "start")]
    for state in ("PRESTREAM", "SWITCHING"):  # OFFBOARD not confirmed yet: excitation waits
        rt.on_status(status("mavlink_bridge", link_up="True", state=state), 1.0)
        assert calls(rt.on_timer(1.1)) == []
    rt.on_status(status("mavlink_bridge", link_up="True", state="OFFBOARD_ACTIVE"), 2.0)
    assert calls(rt.on_timer(2.1)) == [("excitation", "start")]
    rt.on_status(status("excitation", phase="waiting_for_start"), 2.2)
    assert rt.on_timer(2.3) == [] and rt.state != RUNNING
    rt.on_status(status("excitation", phase="fade_in"), 2.4)
    rt.on_timer(2.5)
    assert rt.state == RUNNING and rt.started == ["lpv_controller", "mavlink_bridge", "excitation"]
    (st,) = messages.status_from_diagnostic_array(rt.status(2.6)[0][1])[1]
    assert st.values["phase"] == "running" and st.name == f"{NS}/sequencer"


def test_a_start_not_confirmed_in_time_aborts_every_started_node_in_reverse():
    rt = runtime(step_timeout_s=10.0)
    rt.start(0.0)
    rt.on_status(status("mavlink_bridge", link_up="True", state="IDLE"), 0.0)
    rt.on_timer(0.0)
    rt.on_status(status("lpv_controller", armed="true"), 0.1)
    assert calls(rt.on_timer(0.2)) == [("mavlink_bridge", "start")]
    rt.on_status(status("mavlink_bridge", link_up="True", state="SWITCHING"), 1.0)
    assert calls(rt.on_timer(10.1)) == []  # 9.9 s after the call
    out = rt.on_timer(10.3)
    assert calls(out) == [("mavlink_bridge", "abort"), ("lpv_controller", "abort")]
    assert rt.state == ABORTED
    assert rt.reason == (
        "mavlink_bridge not confirmed within 10 s (waiting for: PX4 in OFFBOARD with "
        "setpoints streaming (MAVROS: streaming); state: SWITCHING)"
    )
    assert calls(rt.on_timer(20.0)) == []  # nothing more is started


def test_a_refused_start_aborts_and_an_abort_on_status_aborts_the_rest():
    rt = runtime(steps=PHASE1_STEPS)
    assert calls(rt.start(0.0)[2]) == [("mavlink_bridge", "start")]  # the first step at once
    out = rt.on_answer("mavlink_bridge", "start", False, "link down", 0.1)
    assert calls(out) == [("mavlink_bridge", "abort")] and rt.reason.endswith("link down")

    rt = runtime(steps=PHASE1_STEPS)
    rt.start(0.0)
    rt.on_status(status("mavlink_bridge", state="OFFBOARD_ACTIVE"), 0.5)
    assert calls(rt.on_timer(0.6)) == [("excitation", "start")]
    rt.on_status(status("excitation", phase="playing"), 0.7)
    rt.on_timer(0.8)
    assert rt.state == RUNNING
    # the bridge hands back (envelope): the sequencer aborts the excitation, then the bridge
    out = rt.on_status(status("mavlink_bridge", "ERROR", "geofence", state="HANDBACK"), 5.0)
    assert calls(out) == [("excitation", "abort"), ("mavlink_bridge", "abort")]
    assert "geofence" in rt.reason


def test_services_not_up_yet_are_waited_for_without_timeout():
    up = set()
    rt = runtime(steps=PHASE1_STEPS, ready=lambda n, w: n in up, step_timeout_s=1.0)
    rt.start(0.0)
    assert calls(rt.on_timer(100.0)) == []  # the bridge's service is not there yet
    up.add("mavlink_bridge")
    assert calls(rt.on_timer(101.0)) == [("mavlink_bridge", "start")]
    assert rt.start(102.0)[:2] == (False, "sequence already starting")


def test_settings_refuse_unknown_or_repeated_steps():
    with pytest.raises(ConfigError, match=r"unknown step\(s\) \['controller'\]"):
        SequencerSettings(steps=("controller",))
    with pytest.raises(ConfigError, match="listed twice"):
        SequencerSettings(steps=("excitation", "excitation"))
    with pytest.raises(ConfigError, match="at least one"):
        SequencerSettings(steps=())
    assert SequencerSettings().steps == PHASE2_STEPS


def _running(rt):
    rt.start(0.0)
    rt.on_status(status("mavlink_bridge", link_up="True", state="IDLE"), 0.1)
    rt.on_timer(0.2)
    rt.on_status(status("lpv_controller", armed="true"), 0.3)
    rt.on_timer(0.4)
    rt.on_status(status("mavlink_bridge", link_up="True", state="OFFBOARD_ACTIVE"), 0.5)
    rt.on_timer(0.6)
    rt.on_status(status("excitation", phase="running"), 0.7)
    rt.on_timer(0.8)
    assert rt.state == RUNNING


def test_a_signal_played_to_its_end_hands_back_first_then_stops_the_rest():
    """Issue 21: the graph's phase 2 ends like ``fly phase2``: the excitation's phase
    ``done`` -> the bridge hands back (while the controller still commands), then the
    controller and the excitation stop; a later hand-back status is no abort."""
    from lpv_sysid.flight.sequencer import COMPLETE

    rt = runtime()
    _running(rt)
    assert calls(rt.on_status(status("excitation", phase="ramp_out"), 30.0)) == []
    out = rt.on_status(status("excitation", phase="done"), 31.0)
    assert calls(out) == [
        ("mavlink_bridge", "abort"),
        ("excitation", "abort"),
        ("lpv_controller", "abort"),
    ]
    assert rt.state == COMPLETE and rt.reason == "signal complete"
    # the bridge's HANDBACK that follows is the expected end, not a new abort
    assert calls(rt.on_status(status("mavlink_bridge", state="HANDBACK"), 31.5)) == []
    (st,) = messages.status_from_diagnostic_array(rt.status(32.0)[0][1])[1]
    assert st.values["phase"] == COMPLETE and st.level == 0  # OK
    # off: the nodes are left running (the operator ends the flight)
    rt2 = runtime(hand_back_when_done=False)
    _running(rt2)
    assert calls(rt2.on_status(status("excitation", phase="done"), 31.0)) == []
    assert rt2.state == RUNNING
