"""ident.dataprep reads bags column-wise (io.bag.read_arrays + the column parsers of
io.message_columns, issue 15 "identify"): the streams must equal those of the per-message path
(read_bag + the per-message parsers) -- bit for bit, the attitude within 1e-12 rad (the
column path converts quaternions with the vectorised io.frames functions, the per-message
path with their scalar twin) -- on a phase-1 bag written by the package, on a bag with
out-of-order and duplicated stamps, permuted channel lists and estimated rotor speeds, and
on bags the column reader refuses (then the per-message path is used)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lpv_sysid.control.baseline import BaselineGains
from lpv_sysid.errors import BagError
from lpv_sysid.ident import dataprep as dp
from lpv_sysid.ident.dataprep import streams as rs
from lpv_sysid.io import bag as bg
from lpv_sysid.io import messages as m
from lpv_sysid.io.messages import columns as mc
from lpv_sysid.models.quadrotor import EXCITATION_NAMES, INPUT_NAMES, Quadrotor
from lpv_sysid.sim import phase1 as p1
from lpv_sysid.sim.vehicle import SensorConfig

F = m.MsgFactory.rosbags()
T0 = 1_700_000_000_000_000_000
ARRAYS = ("t_state", "euler", "v", "omega", "t_rotor", "Omega", "t_cmd", "u", "t_ref", "ref")


def per_message(path):
    info = bg.topic_info(path)
    wanted = [t for t in (rs._topic_for(list(info), s) for s in dp.TOPICS) if t is not None]
    return rs._streams_from_messages(path, wanted)


def assert_same(a: dp.Streams, b: dp.Streams) -> None:
    for f in dataclasses.fields(dp.Streams):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            assert x is not None and y is not None, f.name
            assert x.shape == y.shape and x.dtype == y.dtype, (f.name, x.shape, y.shape)
            if f.name == "euler":
                np.testing.assert_allclose(x, y, rtol=0, atol=1e-12, err_msg=f.name)
            else:
                np.testing.assert_array_equal(x, y, err_msg=f.name)
        else:
            assert x == y, f.name


@pytest.fixture(scope="module")
def phase1_bag(tmp_path_factory):
    cfg = p1.Phase1Config(trim_s=2.0, excite_s=3.0)
    rec = p1.simulate_run(
        Quadrotor(), BaselineGains(), SensorConfig(), cfg, (5.0, -5.0, 5.0), "r", seed=3
    )
    return p1.write_run_bag(rec, tmp_path_factory.mktemp("p1") / "r")


def test_phase1_bag_columns_equal_messages(phase1_bag, monkeypatch):
    cols = dp.streams_from_bag(phase1_bag)
    assert_same(cols, per_message(phase1_bag))
    assert cols.t_state.size == 1250 and cols.t_rotor.size == 500
    # the default path is the column reader: it works without the per-message one
    monkeypatch.setattr(rs, "_streams_from_messages", None)
    assert_same(dp.streams_from_bag(phase1_bag), cols)
    # the attitude is a real rotation (not all zeros): the 1e-12 comparison means something
    assert np.ptp(cols.euler[:, 0]) > 1e-3


def odom(ns, k, q=None):
    msg = m.odometry_from_state(
        F, ns, [0.1 * k, 0, -1], [0.02 * k, -0.01 * k, 0.3 + 0.001 * k], [1, 2 + k, 3], [0.1, 0, k]
    )
    if q is not None:
        o = msg.pose.pose.orientation
        o.x, o.y, o.z, o.w = q
    return msg


def write_odd_bag(path, *, bad_state_at=None, nan_state_at=None, long_excitation_at=None):
    """Stamps out of order and duplicated; rotor channels in two orders; estimated rotors."""
    stamps = [0, 10, 20, 20, 15, 30, 40, 40, 50, 35, 60, 70]  # ms
    with bg.BagWriter(path) as w:
        for name in ("state", "rotor_speeds", "actuator_command", "velocity_reference"):
            w.add_topic(f"/v/lpv_sysid/{name}", m.TYPES[name])
        w.add_topic("/v/lpv_sysid/excitation", m.TYPES["excitation"])
        for k, ms in enumerate(stamps):
            ns = T0 + ms * 1_000_000
            q = (0.0, 0.0, 0.0, 2.0) if k == bad_state_at else None
            msg = odom(ns, k, q)
            if k == nan_state_at:
                msg.twist.twist.linear.x = float("nan")
            w.write("/v/lpv_sysid/state", ns, msg)
            omega = np.array([700.0, 710, 720, 730]) + k
            if k % 3 == 1:  # the same speeds, channels listed in another order
                order = [2, 0, 3, 1]
                msg = m.joint_state(
                    F,
                    ns,
                    [m.ROTOR_NAMES[i] for i in order],
                    velocity=omega[order],
                    frame_id=m.ROTOR_ESTIMATED_FRAME,
                )
            else:
                msg = m.rotor_speeds_msg(F, ns, omega, source="esc")
            w.write("/v/lpv_sysid/rotor_speeds", ns, msg)
            w.write(
                "/v/lpv_sysid/actuator_command",
                ns,
                m.actuator_command_msg(F, ns, [0.5 + 0.01 * k, 0.001 * k, -0.002, 0.0]),
            )
            w.write(
                "/v/lpv_sysid/velocity_reference",
                ns,
                m.twist_reference_msg(F, ns, [1.0, -2.0, 0.5 * k], 0.1 * k),
            )
            names = list(EXCITATION_NAMES) + (["extra"] if k == long_excitation_at else [])
            w.write(
                "/v/lpv_sysid/excitation",
                ns,
                m.joint_state(F, ns, names, position=np.arange(len(names)) * 0.1 * k),
            )
    return path


def test_out_of_order_duplicated_and_permuted_columns_equal_messages(tmp_path):
    path = write_odd_bag(tmp_path / "odd")
    cols = dp.streams_from_bag(path)
    assert_same(cols, per_message(path))
    # independent oracle: rotor channels back in PX4 order whatever the message order was,
    # stamps as written (sorted by the bag, stable), source "estimated" detected
    np.testing.assert_array_equal(cols.Omega[:, 1] - cols.Omega[:, 0], np.full(12, 10.0))
    assert cols.rotor_estimated
    np.testing.assert_array_equal(
        np.round((cols.t_state - T0 / 1e9) * 1e3), [0, 10, 15, 20, 20, 30, 35, 40, 40, 50, 60, 70]
    )
    assert INPUT_NAMES == ("ut", "ua", "ue", "ur")
    # dataprep's cleaning then sorts and drops the duplicates identically
    a = dp.resample(cols, 100.0, max_gap=1.0)
    b = dp.resample(per_message(path), 100.0, max_gap=1.0)
    for k in ("t", "Omega", "u", "ref"):
        np.testing.assert_array_equal(a[k], b[k])
    np.testing.assert_allclose(a["state"], b["state"], rtol=0, atol=1e-12)


def test_topic_of_mixed_structure_falls_back_to_messages(tmp_path, monkeypatch):
    path = write_odd_bag(tmp_path / "mixed", long_excitation_at=4)
    with pytest.raises(BagError, match="different structure"):
        bg.read_arrays(path, topics=["/v/lpv_sysid/excitation"])
    calls = []
    orig = rs._streams_from_messages
    monkeypatch.setattr(rs, "_streams_from_messages", lambda *a: calls.append(a) or orig(*a))
    got = dp.streams_from_bag(path)
    assert calls
    # message k = 4 (stamp 15 ms: row 2 in time order) has a fifth channel; the four read
    np.testing.assert_array_equal(got.exc[2], np.arange(4) * 0.4)


@pytest.mark.parametrize(
    "bad, first_ms, what",
    [
        ({"bad_state_at": 5}, 30, "not a unit quaternion"),
        # a later NaN velocity (a check made before the norm's) is not the first error
        ({"bad_state_at": 5, "nan_state_at": 8}, 30, "not a unit quaternion"),
        ({"bad_state_at": 8, "nan_state_at": 5}, 30, "twist.twist.linear"),
    ],
)
def test_bad_message_names_topic_and_time_as_the_message_path(tmp_path, bad, first_ms, what):
    path = write_odd_bag(tmp_path / "bad", **bad)
    with pytest.raises(BagError) as cols:
        dp.streams_from_bag(path)
    with pytest.raises(BagError) as msgs:
        per_message(path)
    for exc in (cols.value, msgs.value):
        text = str(exc)
        assert "topic '/v/lpv_sysid/state'" in text and what in text, text
    at = str(msgs.value).split(" s: ")[0].rsplit(" at ", 1)[1]
    assert f" at {at} s: " in str(cols.value)
    assert at == f"{(T0 + first_ms * 1_000_000) * 1e-9:.3f}"


def test_column_parsers_check_what_the_message_parsers_check():
    class Cols:
        def __init__(self, fields, strings):
            self.fields, self.strings = fields, strings

    names = np.empty(2, dtype=object)
    names[:] = [("rotor_1", "rotor_2"), ("rotor_1", "rotor_2")]
    js = Cols(
        {
            "header.stamp.sec": np.array([1, 2], np.int32),
            "header.stamp.nanosec": np.array([5, 1_000_000_000], np.uint32),
            "velocity": np.ones((2, 2)),
        },
        {"name": names, "header.frame_id": np.array(["base_link"] * 2, dtype=object)},
    )
    with pytest.raises(m.MessageError, match="nanosec 1000000000") as exc:
        mc.channels_from_joint_state_columns(js, ["rotor_1"], "velocity")
    assert exc.value.row == 1
    js.fields["header.stamp.nanosec"] = np.array([5, 6], np.uint32)
    with pytest.raises(m.MessageError, match="missing channel"):
        mc.rotor_speeds_from_joint_state_columns(js)
    js.fields["velocity"][1, 1] = np.nan
    with pytest.raises(m.MessageError, match=r"non-finite value for channel\(s\) \['rotor_2'\]"):
        mc.channels_from_joint_state_columns(js, ["rotor_2", "rotor_1"], "velocity")
    t, v = mc.channels_from_joint_state_columns(js, ["rotor_1"], "velocity")
    assert t.tolist() == [1.000000005, 2.000000006] and v.tolist() == [[1.0], [1.0]]
