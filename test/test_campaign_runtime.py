"""flight/campaign/runtime.py directly: no rclpy, no stand-in.

The message-level behaviour of campaign_node: its settings, the LAND -> HOLD rule, start
refused while the bridge services are missing, the bridge service calls the campaign
asks for, the auto start on the bridge's first status, the status content, a recording
failure logged once and aborting; on rosbags messages and explicit clock values.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
import yaml

from lpv_sysid.configuration import parameters
from lpv_sysid.control import campaign
from lpv_sysid.errors import ConfigError, LpvSysidError
from lpv_sysid.flight.campaign import PARSERS, CampaignNodeSettings, CampaignRuntime
from lpv_sysid.io import messages
from lpv_sysid.signals.excitation import phase1_signals
from lpv_sysid.signals.store import save_npz

F = messages.MsgFactory.rosbags()
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
NAME, BRIDGE = "/lpv_sysid/campaign", "/lpv_sysid/mavlink_bridge"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("campaign_runtime")
    s = phase1_signals(duration=6.0, peaks=(0.4, 0.4, 0.2, 0.3))
    save_npz(str(d / "sig.npz"), s.t, s.u, tuple(s.names))
    (d / "campaign.yaml").write_text(
        yaml.safe_dump(
            {
                "bridge_config": os.path.join(ROOT, "config", "mavlink_bridge.yaml"),
                "campaign": {"vertices": [2], "finish": "LAND"},
            }
        )
    )
    return d


def make(files, ready=("start", "abort"), **kw):
    settings = CampaignNodeSettings(
        campaign_file=str(files / "campaign.yaml"), signals_file=str(files / "sig.npz"), **kw
    )
    return CampaignRuntime(settings, F, NAME, BRIDGE, lambda which: which in ready)


def status_of(out):
    (msg,) = [m for k, m in out if k == "status"]
    _, (st,) = messages.status_from_diagnostic_array(msg)
    return st


def bridge_status(name, state):
    values = {"state": state, "vehicle_mode": "HOLD", "armed": "False"}
    st = messages.diagnostic_status(F, "OK", name, state, values)
    return messages.diagnostic_array(F, 10**9, [st])


def test_settings_are_the_one_declaration_of_the_parameters():
    assert list(parameters.specs(CampaignNodeSettings)) == [
        "campaign_file",
        "signals_file",
        "out_dir",
        "bridge_node",
        "rate_hz",
        "status_rate_hz",
        "auto_start",
    ]
    s = CampaignNodeSettings()
    assert (s.campaign_file, s.bridge_node, s.rate_hz, s.auto_start) == (
        "campaign.yaml",
        "mavlink_bridge",
        100.0,
        False,
    )
    with pytest.raises(ConfigError, match="rate_hz"):
        CampaignNodeSettings(rate_hz=5.0)


def test_land_is_flown_as_hold_and_the_plan_is_logged(files):
    rt = make(files)
    assert rt.campaign.plan.config.finish == "HOLD"
    (warn, info) = rt.take_log()
    assert warn[0] == "warn" and "finish LAND" in warn[1]
    assert info[0] == "info" and info[1].startswith("2 runs planned")  # vertex 2 + hover
    assert f"bridge {BRIDGE}" in info[1]


def test_start_is_refused_while_a_bridge_service_is_missing(files):
    rt = make(files, ready=("start",))
    rt.take_log()
    ok, message, out = rt.start(1.0)
    assert not ok and out == [] and rt.campaign.phase == campaign.IDLE
    assert message == (f"not started: the bridge services {BRIDGE}/start|abort are not available")
    assert rt.take_log() == [("info", f"start: {message}")]


def test_start_calls_the_bridge_and_status_names_the_phase(files):
    rt = make(files)
    rt.take_log()
    ok, message, out = rt.start(1.0)
    assert ok and message == "campaign started: 2 runs"
    assert out[0] == ("call", "start")
    st = status_of(out)
    assert (st.level, st.name, st.message) == (0, NAME, f"campaign {campaign.STARTING}")
    assert st.values == {
        "phase": campaign.STARTING,
        "run": "",
        "runs_done": "0",
        "runs": "2",
        "reason": rt.campaign.reason,
    }
    assert ("info", f"{campaign.STARTING}: 2 runs planned; starting offboard") in rt.take_log()
    assert rt.start(1.1)[:2] == (True, f"already {campaign.STARTING}")


def test_abort_requests_the_hand_back_on_the_next_step(files):
    rt = make(files)
    rt.start(1.0)
    rt.on_status(bridge_status(BRIDGE, "PRESTREAM"))
    rt.take_log()
    ok, message, out = rt.abort(1.2)
    assert ok and out == [] and message.endswith(": excitation off, handing back")
    assert rt.take_log() == [("warn", message)]
    out = rt.on_timer(1.21)
    assert ("call", "abort") in out
    assert not rt.shutdown_complete()


def test_auto_start_waits_for_the_bridge_status(files):
    rt = make(files, auto_start=True)
    assert rt.on_timer(1.0) == [] and rt.campaign.phase == campaign.IDLE
    rt.on_status(bridge_status("/lpv_sysid/other", "STREAMING"))  # not the bridge: ignored
    assert rt.bridge_values == {} and rt.on_timer(1.01) == []
    rt.on_status(bridge_status(BRIDGE, "IDLE"))
    assert rt.bridge_values["state"] == "IDLE"
    rt.take_log()
    out = rt.on_timer(1.02)
    assert out[0] == ("call", "start") and rt.campaign.phase != campaign.IDLE
    assert ("info", "auto start: campaign started: 2 runs") in rt.take_log()
    assert rt.on_timer(1.03).count(("call", "start")) == 0  # once


class FailingRecorder:
    active = "bag_0000"

    def state(self, *args):
        raise LpvSysidError("disk full")


def test_a_recording_failure_is_logged_once_and_aborts(files):
    rt = make(files)
    rt.start(1.0)
    rt.rec = FailingRecorder()
    rt.take_log()
    state = messages.odometry_from_state(F, 10**9, [0.0] * 3, [0.0] * 3, [0.0] * 3, [0.0] * 3)
    sample = PARSERS["state"](state)
    rt.on_sample("state", sample, 1.1)
    rt.on_sample("state", sample, 1.2)
    assert rt.take_log() == [("error", "recording failed: disk full")]
    assert rt.campaign.state is sample  # the sample reached the campaign before the bag
    rt.on_status(bridge_status(BRIDGE, "PRESTREAM"))
    assert ("call", "abort") in rt.on_timer(1.3)


def test_rotor_speeds_parser_keeps_the_source():
    msg = messages.rotor_speeds_msg(F, 2 * 10**9, [600.0, 610.0, 620.0, 630.0], "estimated")
    t, omega, source = PARSERS["rotor_speeds"](msg)
    assert t == 2.0 and source == "estimated"
    np.testing.assert_array_equal(omega, [600.0, 610.0, 620.0, 630.0])


def test_imu_is_only_wanted_while_a_run_is_recorded(files):
    rt = make(files)
    assert rt.wants("state") and rt.wants("rotor_speeds") and not rt.wants("imu")
    rt.rec = FailingRecorder()
    assert rt.wants("imu")


def test_the_bridge_status_from_before_the_start_call_is_no_refusal(files):
    """Under real Jazzy the bridge's start answer and its next 2 Hz status came 0.9-1.4 s
    after the call: the IDLE it still showed aborted the campaign ("offboard start failed:
    bridge IDLE"). IDLE counts as a refusal only START_ANSWER_S after the call."""
    from lpv_sysid.flight.campaign.runtime import START_ANSWER_S

    rt = make(files)
    rt.on_status(bridge_status(BRIDGE, "IDLE"))
    rt.start(1.0)
    for t in (1.5, 2.5, 1.0 + START_ANSWER_S - 0.1):
        rt.on_timer(t)
        assert rt.campaign.phase == campaign.STARTING, rt.campaign.reason
    rt.on_timer(1.0 + START_ANSWER_S + 0.1)  # still IDLE: the bridge did not start
    assert rt.campaign.phase != campaign.STARTING
    assert "offboard start failed: bridge IDLE" in rt.campaign.reason


def test_the_bridges_vehicle_record_goes_into_the_runs_experiment_yaml(files, tmp_path):
    """A vehicle_record received before the start is written when the recording opens, a
    newer one replaces it (the bridge re-publishes on material changes); a bad one is
    logged and changes nothing."""
    rt = make(files, out_dir=str(tmp_path / "runs"))
    first = {"kind": "SITL", "px4_parameters": {"SYS_AUTOSTART": 10040}}
    rt.on_vehicle_record(messages.vehicle_record_msg(F, first, "utc"))
    rt.start(1.0)
    meta = yaml.safe_load((tmp_path / "runs" / "experiment.yaml").read_text())
    assert meta["vehicle"] == first
    newer = {"kind": "SITL", "px4_parameters": {"SYS_AUTOSTART": 10040, "COM_OBL_RC_ACT": 5}}
    rt.on_vehicle_record(messages.vehicle_record_msg(F, newer, "utc"))
    rt.take_log()
    rt.on_vehicle_record(F("std_msgs/msg/String", data="{not json"))
    ((level, text),) = rt.take_log()
    assert level == "warn" and text.startswith("vehicle_record ignored: vehicle_record: data is")
    meta = yaml.safe_load((tmp_path / "runs" / "experiment.yaml").read_text())
    assert meta["vehicle"] == newer
