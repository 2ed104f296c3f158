"""The controller node's per-sample cost cut (issue 27 item 2) without changing what it
computes: the state read from the raw (serialized) subscription gives the sample, the checks
and the commands of the deserialised message bit for bit (oracle: rosbags' own CDR serializer
and the message path); one preallocated actuator_command; no 250 Hz timer beside the state
ticks. Timing is in bench/ (bench_controller_node.py), not here."""

import math

import numpy as np
import pytest
import rclpy
from lpv_test_gains import write_gains
from test_controller_safety import hover_inputs

from lpv_sysid.flight.controller import CommandBuilder, ControllerRuntime, ControllerSettings
from lpv_sysid.io import messages
from lpv_sysid.io.bag.cdr import LayoutError, odometry_record
from lpv_sysid.io.bag import jazzy_typestore
from lpv_sysid.models.quadrotor import INPUT_NAMES

TS = jazzy_typestore()
F = messages.MsgFactory.rosbags()


def odometry(stamp_ns, euler=(0.1, -0.2, 2.5), v=(1.5, -0.25, 0.125), w=(0.01, 0.02, -0.3), **kw):
    return messages.odometry_from_state(
        F,
        stamp_ns,
        (1.0, -2.0, -3.5),
        euler,
        v,
        w,
        pose_covariance=np.arange(36.0) if kw.pop("cov", False) else None,
        **kw,
    )


def cdr(msg, little_endian=True):
    return bytes(TS.serialize_cdr(msg, "nav_msgs/msg/Odometry", little_endian=little_endian))


def same_sample(a, b):
    assert (a.t, a.stamp_ns) == (b.t, b.stamp_ns)
    for k in ("pos_ned", "euler", "v_body", "omega"):
        assert getattr(a, k).tolist() == getattr(b, k).tolist(), k


@pytest.mark.parametrize(
    "frames",
    [
        {},  # odom / base_link
        {"frame_id": "o", "child_frame_id": "b"},  # 2-byte strings: padding before the doubles
        {"frame_id": "map_ned_x", "child_frame_id": "fcu_1234567"},
    ],
)
@pytest.mark.parametrize("little_endian", [True, False])
def test_odometry_record_reads_what_rosbags_serialized(frames, little_endian):
    msg = odometry(1_704_067_205_004_000_123, cov=True, **frames)
    rec = odometry_record(cdr(msg, little_endian))
    p, tw = msg.pose.pose, msg.twist.twist
    assert (rec.sec, rec.nanosec) == (msg.header.stamp.sec, msg.header.stamp.nanosec)
    assert (rec.frame_id, rec.child_frame_id) == (msg.header.frame_id, msg.child_frame_id)
    assert rec.values == (
        p.position.x,
        p.position.y,
        p.position.z,
        p.orientation.x,
        p.orientation.y,
        p.orientation.z,
        p.orientation.w,
        tw.linear.x,
        tw.linear.y,
        tw.linear.z,
        tw.angular.x,
        tw.angular.y,
        tw.angular.z,
    )
    kw = {"frame_id": None, "child_frame_id": None}
    same_sample(
        messages.state_from_odometry_cdr(cdr(msg, little_endian), **kw),
        messages.state_from_odometry(msg, **kw),
    )


def test_bytes_that_are_no_odometry_are_refused():
    good = cdr(odometry(5))
    for bad in (b"", good[:40], b"\x00\x02" + good[2:], good[:-1], cdr_of_joint_state()):
        with pytest.raises(LayoutError):
            odometry_record(bad)
        assert messages.state_from_odometry_cdr(bad) is None  # -> the validating path


def cdr_of_joint_state():
    m = messages.actuator_command_msg(F, 7, np.zeros(4))
    return bytes(TS.serialize_cdr(m, "sensor_msgs/msg/JointState"))


def test_the_validating_path_keeps_naming_the_problem():
    wrong = cdr(odometry(5, frame_id="map"))
    with pytest.raises(messages.MessageError) as a:
        messages.state_from_odometry_cdr(wrong)
    with pytest.raises(messages.MessageError) as b:
        messages.state_from_odometry(odometry(5, frame_id="map"))
    assert str(a.value) == str(b.value) == "state.header: expected frame_id 'odom', got 'map'"
    nan = odometry(5)
    nan.twist.twist.linear.y = math.nan
    assert messages.state_from_odometry_cdr(cdr(nan)) is None
    with pytest.raises(messages.MessageError, match="state.twist.twist.linear"):
        messages.state_from_odometry(nan)
    skew = odometry(5)
    skew.pose.pose.orientation.w *= 1.01
    assert messages.state_from_odometry_cdr(cdr(skew)) is None


# ------------------------------------------------------------ the runtime: same commands
@pytest.fixture(scope="module")
def gains(tmp_path_factory):
    return write_gains(tmp_path_factory.mktemp("cost") / "gains.yaml", box=2.0)


def flight(rt, raw):
    """2 s at 250 Hz, tick_source state; the state as bytes (``raw``) or as a message."""
    x8, om = hover_inputs(rt)
    rng = np.random.default_rng(7)
    out = []

    def inputs(t, ns):
        rt.on_sample("rotor_speeds", t, om, t)
        rt.on_sample("velocity_reference", t, np.array([0.1, 0.0, 0.0, 0.0]), t)
        rt.on_sample("excitation", t, np.array([0.05, -0.02, 0.0, 0.01]), t)
        msg = odometry(
            ns,
            euler=(x8[0] + 0.01 * rng.standard_normal(), x8[1], 0.3),
            v=tuple(x8[2:5] * np.array([1, -1, -1]) + 0.01 * rng.standard_normal(3)),
            w=tuple(0.001 * rng.standard_normal(3)),
        )
        if raw:
            return rt.on_state_cdr(cdr(msg), t + 0.001, lambda d: None)
        return rt.on_input("state", msg, t + 0.001)

    inputs(10.0, 10_000_000_000)
    assert rt.start(10.0005)[0]
    for k in range(1, 501):
        ns = 10_000_000_000 + 4_000_000 * k
        for topic, m in inputs(ns / 1e9, ns):
            if topic == "actuator_command":
                out.append((m.header.stamp.sec, m.header.stamp.nanosec, list(m.position)))
    return out


def test_raw_state_gives_the_commands_of_the_message_bit_for_bit(gains):
    def rt():
        s = ControllerSettings(gains_file=gains, tick_source="state")
        return ControllerRuntime(s, F)

    a, b = flight(rt(), raw=True), flight(rt(), raw=False)
    assert len(a) == 500 and a == b
    assert len({tuple(c[2]) for c in a}) > 400  # the commands move with the noisy state


def test_raw_state_that_needs_the_validating_path_is_deserialised(gains):
    rt = ControllerRuntime(ControllerSettings(gains_file=gains, tick_source="state"), F)
    nan = odometry(5_000_000_000)
    nan.twist.twist.angular.z = math.inf
    seen = []

    def deserialize(data):
        seen.append(data)
        return TS.deserialize_cdr(data, "nav_msgs/msg/Odometry")

    assert rt.on_state_cdr(cdr(nan), 5.0, deserialize) == []
    assert len(seen) == 1  # the message path, which rejects it by name (not started: a warning)
    assert rt.take_log()[-1] == (
        "warn",
        "state rejected before start: state.twist.twist.angular: non-finite value(s) at index [2]",
    )


# ------------------------------------------------------------ the preallocated command
@pytest.mark.parametrize("kind", ["rosbags", "rclpy"])
def test_reused_command_message_equals_a_new_one(kind):
    f = messages.MsgFactory.rosbags() if kind == "rosbags" else messages.MsgFactory.rclpy()
    new, reused = CommandBuilder(f), CommandBuilder(f, reuse=True)
    first = reused(1, np.zeros(4))
    for stamp, u in ((1_704_067_205_004_000_000, [0.51, -0.012, 0.034, 1e-3]), (7, [1, 2, 3, 4])):
        a, b = new(stamp, np.array(u, float)), reused(stamp, np.array(u, float))
        assert b is first  # one message, filled per tick
        assert (b.header.stamp.sec, b.header.stamp.nanosec, b.header.frame_id) == (
            a.header.stamp.sec,
            a.header.stamp.nanosec,
            a.header.frame_id,
        )
        assert list(b.name) == list(a.name) == list(INPUT_NAMES)
        for field in ("position", "velocity", "effort"):
            assert type(getattr(a, field)) is type(getattr(b, field))
            assert list(getattr(a, field)) == list(getattr(b, field))


# ------------------------------------------------------------ the node: timers, subscription
@pytest.mark.parametrize("tick_source, period_ns", [("timer", 4_000_000), ("state", 10_000_000)])
def test_node_timer_ticks_on_the_timer_only_and_state_is_raw(gains, tick_source, period_ns):
    from lpv_sysid.nodes.lpv_controller_node import LpvControllerNode

    s = ControllerSettings(gains_file=gains, tick_source=tick_source)
    assert s.timer_period_s == pytest.approx(period_ns * 1e-9)
    rclpy.init()
    try:
        node = LpvControllerNode(
            parameter_overrides=[
                rclpy.parameter.Parameter("gains_file", value=gains),
                rclpy.parameter.Parameter("tick_source", value=tick_source),
            ]
        )
        periods = sorted(t.timer_period_ns for t in node.timers)
        assert periods == sorted([period_ns, 500_000_000])  # the tick/watch and status 2 Hz
        raw = {s.topic_name.rsplit("/", 1)[-1]: s.raw for s in node.subscriptions}
        assert raw == {
            "state": True,
            "rotor_speeds": False,
            "velocity_reference": False,
            "excitation": False,
        }
        node.destroy_node()
    finally:
        rclpy.shutdown()
