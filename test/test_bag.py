"""io/bag: rosbag2 round trips (mcap, sqlite3) of every topic type, metadata, rates,
out-of-order stamps, truncated / metadata-less / crashed bags and write errors."""

import errno
import sqlite3

import numpy as np
import pytest
import yaml

from lpv_sysid.errors import BagError
from lpv_sysid.io import bag as bg
from lpv_sysid.io import messages as m
from lpv_sysid.mavlink.bridge import RATE_INPUT_NAMES

F = m.MsgFactory.rosbags()
T0 = 1_700_000_000_000_000_000
RNG = np.random.default_rng(11)

TOPICS = {f"/lpv_sysid/{k}": v for k, v in m.TYPES.items()}


def sample_set(i):
    """Values and messages for every topic of DESIGN.md at sample i."""
    ns = T0 + i * 10_000_000
    vals = {
        "state": (
            RNG.normal(size=3),
            np.array([0.1, -0.2, 0.3]) * RNG.uniform(-1, 1, 3),
            RNG.normal(size=3),
            RNG.normal(size=3),
        ),
        "rotor_speeds": RNG.uniform(300, 900, 4),
        "imu": (RNG.normal(size=3), RNG.normal(size=3)),
        "velocity_reference": (RNG.normal(size=3), float(RNG.normal())),
        "excitation": RNG.uniform(-1, 1, 4),
        "actuator_command": RNG.normal(size=4),
        "status": ("WARN", f"node{i}", "msg", {"k": float(i) / 3}),
        "rate_setpoint": RNG.normal(size=4),
    }
    msgs = {
        "state": m.odometry_from_state(F, ns, *vals["state"]),
        "rotor_speeds": m.rotor_speeds_msg(F, ns, vals["rotor_speeds"]),
        "imu": m.imu_msg(F, ns, *vals["imu"]),
        "velocity_reference": m.twist_reference_msg(F, ns, *vals["velocity_reference"]),
        "excitation": m.excitation_msg(F, ns, vals["excitation"]),
        "actuator_command": m.actuator_command_msg(F, ns, vals["actuator_command"]),
        "status": m.diagnostic_array(F, ns, [m.diagnostic_status(F, *vals["status"])]),
        "rate_setpoint": m.joint_state(F, ns, RATE_INPUT_NAMES, position=vals["rate_setpoint"]),
    }
    return ns, vals, msgs


def check_sample(name, msg, val):
    if name == "state":
        s = m.state_from_odometry(msg)
        for a, b in zip((s.pos_ned, s.euler, s.v_body, s.omega), val):
            np.testing.assert_allclose(a, b, atol=1e-12)
    elif name == "rotor_speeds":
        np.testing.assert_array_equal(m.rotor_speeds_from_joint_state(msg)[1], val)
    elif name == "imu":
        s = m.imu_from_msg(msg)
        np.testing.assert_array_equal(s.specific_force, val[0])
        np.testing.assert_array_equal(s.omega, val[1])
    elif name == "velocity_reference":
        _, v, r = m.reference_from_twist(msg)
        np.testing.assert_array_equal(v, val[0])
        assert r == val[1]
    elif name == "excitation":
        np.testing.assert_array_equal(m.excitation_from_joint_state(msg)[1], val)
    elif name == "actuator_command":
        np.testing.assert_array_equal(m.actuator_command_from_joint_state(msg)[1], val)
    elif name == "rate_setpoint":
        assert list(msg.name) == list(RATE_INPUT_NAMES)
        np.testing.assert_array_equal(np.asarray(msg.position), val)
    else:
        _, st = m.status_from_diagnostic_array(msg)
        assert (st[0].level, st[0].name, st[0].values) == (1, val[1], {"k": repr(val[3]["k"])})


def write_all(path, storage, n=5, **kw):
    samples = [sample_set(i) for i in range(n)]
    with bg.BagWriter(path, storage=storage, **kw) as b:
        for t, ty in TOPICS.items():
            b.add_topic(t, ty)
        for ns, _, msgs in samples:
            for k, msg in msgs.items():
                b.write(f"/lpv_sysid/{k}", ns, msg)
    return samples


def joint_bag(path, n, storage="mcap", step=10_000_000, **kw):
    """n excitation messages at 1/step GHz; value i in every channel."""
    with bg.BagWriter(path, storage=storage, **kw) as b:
        b.add_topic("/e", "sensor_msgs/msg/JointState")
        for i in range(n):
            b.write("/e", T0 + i * step, m.excitation_msg(F, T0 + i * step, np.full(4, float(i))))


def values(contents, topic="/e"):
    return [m.excitation_from_joint_state(msg)[1][0] for _, msg in contents[topic]]


# ----------------------------------------------------------------- round trips
@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_round_trip_every_topic(tmp_path, storage):
    samples = write_all(tmp_path / "b", storage)
    data = bg.read_bag(tmp_path / "b")
    assert data.problems == []
    assert data.types == TOPICS
    for k in m.TYPES:
        got = data[f"/lpv_sysid/{k}"]
        assert [ns for ns, _ in got] == [s[0] for s in samples]
        for (ns, msg), (ns0, vals, _) in zip(got, samples):
            assert m.stamp_ns_of(msg) == ns0
            check_sample(k, msg, vals[k])


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_metadata_definitions_and_qos(tmp_path, storage):
    with bg.BagWriter(tmp_path / "b", storage=storage) as b:
        b.add_topic("/s", "nav_msgs/msg/Odometry", qos={"reliability": "best_effort", "depth": 5})
        b.add_topic("/j", "sensor_msgs/msg/JointState")
        b.write("/j", 7, m.rotor_speeds_msg(F, 7, np.ones(4)))
    meta = yaml.safe_load((tmp_path / "b" / "metadata.yaml").read_text())[
        "rosbag2_bagfile_information"
    ]
    assert meta["version"] == 9
    assert meta["storage_identifier"] == storage
    assert meta["message_count"] == 1
    ts = bg.jazzy_typestore()
    tops = {t["topic_metadata"]["name"]: t for t in meta["topics_with_message_count"]}
    assert tops["/s"]["message_count"] == 0 and tops["/j"]["message_count"] == 1
    assert tops["/s"]["topic_metadata"]["type_description_hash"] == ts.hash_rihs01(
        "nav_msgs/msg/Odometry"
    )
    assert tops["/s"]["topic_metadata"]["serialization_format"] == "cdr"
    qos = tops["/s"]["topic_metadata"]["offered_qos_profiles"][0]
    assert (qos["reliability"], qos["depth"], qos["durability"]) == ("best_effort", 5, "volatile")
    qos = tops["/j"]["topic_metadata"]["offered_qos_profiles"][0]
    assert (qos["reliability"], qos["depth"], qos["history"]) == ("reliable", 10, "keep_last")
    from rosbags.rosbag2 import Reader

    with Reader(tmp_path / "b") as r:
        for c in r.connections:
            assert c.msgdef.data == ts.generate_msgdef(c.msgtype, ros_version=2)[0]


def test_bad_qos(tmp_path):
    with bg.BagWriter(tmp_path / "b") as b:
        with pytest.raises(BagError, match=r"qos.reliability: unknown value 'sometimes'"):
            b.add_topic("/s", "nav_msgs/msg/Odometry", qos={"reliability": "sometimes"})
        with pytest.raises(BagError, match=r"qos: unknown key\(s\) \['speed'\]"):
            b.add_topic("/s", "nav_msgs/msg/Odometry", qos={"speed": 1})


def test_counts_and_rates(tmp_path):
    joint_bag(tmp_path / "b", 101, step=10_000_000)  # 100 Hz for exactly 1 s
    info = bg.topic_info(tmp_path / "b")
    s = info["/e"]
    assert s.msgtype == "sensor_msgs/msg/JointState"
    assert s.count == 101
    assert s.duration_s == pytest.approx(1.0, abs=1e-12)
    assert s.rate_hz == pytest.approx(100.0, rel=1e-12)
    joint_bag(tmp_path / "c", 1)
    assert bg.topic_info(tmp_path / "c")["/e"].rate_hz == 0.0


def test_out_of_order_writes_read_back_sorted(tmp_path):
    stamps = [T0 + 30, T0 + 10, T0 + 20, T0 + 10]
    with bg.BagWriter(tmp_path / "b") as b:
        b.add_topic("/e", "sensor_msgs/msg/JointState")
        for k, ns in enumerate(stamps):
            b.write("/e", ns, m.excitation_msg(F, ns, np.full(4, float(k))))
    data = bg.read_bag(tmp_path / "b")
    assert [ns for ns, _ in data["/e"]] == sorted(stamps)
    assert values(data) == [1.0, 3.0, 2.0, 0.0]  # equal stamps keep write order
    meta = yaml.safe_load((tmp_path / "b" / "metadata.yaml").read_text())[
        "rosbag2_bagfile_information"
    ]
    assert meta["starting_time"]["nanoseconds_since_epoch"] == T0 + 10
    assert meta["duration"]["nanoseconds"] == 20


def test_write_raw_and_bare_file(tmp_path):
    msg = m.excitation_msg(F, 5, [1.0, 2.0, 3.0, 4.0])
    raw = bg.jazzy_typestore().serialize_cdr(msg, "sensor_msgs/msg/JointState")
    with bg.BagWriter(tmp_path / "b") as b:
        b.add_topic("/e", "sensor_msgs/msg/JointState")
        b.write_raw("/e", 5, raw)
    data = bg.read_bag(tmp_path / "b" / "b.mcap")
    np.testing.assert_array_equal(m.excitation_from_joint_state(data["/e"][0][1])[1], [1, 2, 3, 4])


def test_topics_filter(tmp_path):
    write_all(tmp_path / "b", "mcap", n=2)
    data = bg.read_bag(tmp_path / "b", topics=["/lpv_sysid/imu"])
    assert list(data) == ["/lpv_sysid/imu"] and len(data["/lpv_sysid/imu"]) == 2
    with pytest.raises(BagError, match=r"topic\(s\) \['/nope'\] not in bag"):
        bg.read_bag(tmp_path / "b", topics=["/nope"])
    data = bg.read_bag(tmp_path / "b", topics=["/nope"], strict=False)
    assert data["/nope"] == [] and "not in bag" in data.problems[0]


# --------------------------------------------------------------- damaged bags
def test_truncated_mcap(tmp_path):
    joint_bag(tmp_path / "b", 200, chunk_bytes=2000)
    f = tmp_path / "b" / "b.mcap"
    raw = f.read_bytes()
    f.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(BagError, match=r"bag .*b: cannot be read .*strict=False"):
        bg.read_bag(tmp_path / "b")
    data = bg.read_bag(tmp_path / "b", strict=False)
    got = values(data)
    assert 20 < len(got) < 200
    assert got == [float(i) for i in range(len(got))]  # an exact prefix
    assert any("truncated record" in p for p in data.problems)
    assert bg.topic_info(tmp_path / "b", strict=False)["/e"].count == len(got)


def test_missing_metadata(tmp_path):
    joint_bag(tmp_path / "b", 30)
    (tmp_path / "b" / "metadata.yaml").unlink()
    with pytest.raises(BagError, match="missing metadata.yaml"):
        bg.read_bag(tmp_path / "b")
    data = bg.read_bag(tmp_path / "b", strict=False)
    assert values(data) == [float(i) for i in range(30)]
    assert data.types == {"/e": "sensor_msgs/msg/JointState"}
    assert "missing metadata.yaml" in data.problems[0]


def test_missing_metadata_sqlite(tmp_path):
    joint_bag(tmp_path / "b", 12, storage="sqlite3")
    (tmp_path / "b" / "metadata.yaml").unlink()
    data = bg.read_bag(tmp_path / "b", strict=False)
    assert values(data) == [float(i) for i in range(12)]


def test_truncated_sqlite(tmp_path):
    joint_bag(tmp_path / "b", 400, storage="sqlite3")
    f = tmp_path / "b" / "b.db3"
    raw = f.read_bytes()
    f.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(BagError, match="cannot be read"):
        bg.read_bag(tmp_path / "b")
    data = bg.read_bag(tmp_path / "b", strict=False)
    assert any("truncated" in p for p in data.problems)
    got = values(data)
    assert 20 < len(got) < 400
    assert got == [float(i) for i in range(len(got))]  # an exact prefix


def test_truncated_sqlite_large_rows_never_zero_filled(tmp_path):
    # 8 kB messages span sqlite overflow pages; a row reaching into the missing half must
    # be reported, never returned with zeros in place of the lost bytes
    names = [f"c{k}" for k in range(1000)]
    with bg.BagWriter(tmp_path / "b", storage="sqlite3") as b:
        b.add_topic("/big", "sensor_msgs/msg/JointState")
        for i in range(30):
            b.write("/big", i, m.joint_state(F, i, names, position=np.arange(1000) + 1.0 + i))
    f = tmp_path / "b" / "b.db3"
    raw = f.read_bytes()
    f.write_bytes(raw[: len(raw) // 2])
    data = bg.read_bag(tmp_path / "b", strict=False)
    got = data["/big"]
    assert 0 < len(got) < 30
    for i, (ns, msg) in enumerate(got):
        assert ns == i
        np.testing.assert_array_equal(
            m.channels_from_joint_state(msg, names)[1], np.arange(1000) + 1.0 + i
        )


def test_crash_before_close_keeps_flushed_messages(tmp_path):
    b = bg.BagWriter(tmp_path / "b").open()
    b.add_topic("/e", "sensor_msgs/msg/JointState")
    for i in range(40):
        b.write("/e", T0 + i, m.excitation_msg(F, T0 + i, np.full(4, float(i))))
    b.flush(fsync=True)
    for i in range(40, 50):
        b.write("/e", T0 + i, m.excitation_msg(F, T0 + i, np.full(4, float(i))))
    b._writer.storage.bio.close()  # process dies: no footer, no metadata.yaml
    data = bg.read_bag(tmp_path / "b", strict=False)
    assert values(data) == [float(i) for i in range(40)]


def test_nonexistent_and_not_a_bag(tmp_path):
    with pytest.raises(BagError, match="does not exist"):
        bg.read_bag(tmp_path / "nothing")
    (tmp_path / "x.txt").write_text("hi")
    with pytest.raises(BagError, match="not a bag directory"):
        bg.read_bag(tmp_path / "x.txt")
    (tmp_path / "bad.mcap").write_bytes(b"garbage!" * 10)
    data = bg.read_bag(tmp_path / "bad.mcap", strict=False)
    assert dict(data) == {} and any("bad magic" in p for p in data.problems)


# --------------------------------------------------------------- write errors
class _FullDisk:
    """File wrapper: writes fail with ENOSPC once ``full`` is set."""

    def __init__(self, bio):
        self.bio, self.full = bio, False

    def write(self, data):
        if self.full:
            raise OSError(errno.ENOSPC, "No space left on device")
        return self.bio.write(data)

    def __getattr__(self, name):
        return getattr(self.bio, name)


def test_disk_full_mcap(tmp_path):
    b = bg.BagWriter(tmp_path / "b").open()
    b.add_topic("/e", "sensor_msgs/msg/JointState")
    for i in range(25):
        b.write("/e", T0 + i, m.excitation_msg(F, T0 + i, np.full(4, float(i))))
    b.flush()
    disk = _FullDisk(b._writer.storage.bio)
    b._writer.storage.bio = disk
    for i in range(25, 30):
        b.write("/e", T0 + i, m.excitation_msg(F, T0 + i, np.full(4, float(i))))
    disk.full = True
    with pytest.raises(BagError, match=r"bag .*b: flush failed \(ENOSPC"):
        b.flush()
    assert not b.is_open
    with pytest.raises(BagError, match=r"not open \(after error: flush failed"):
        b.write("/e", T0, m.excitation_msg(F, T0, np.zeros(4)))
    # the recovery saved the 5 messages still in memory and indexed the file: it opens
    # strictly (footer + metadata.yaml), nothing written is lost
    data = bg.read_bag(tmp_path / "b")
    assert values(data) == [float(i) for i in range(30)]
    assert b.durable_counts == {"/e": 30}


def test_disk_full_sqlite_closes_readable(tmp_path):
    b = bg.BagWriter(tmp_path / "b", storage="sqlite3").open()
    b.add_topic("/e", "sensor_msgs/msg/JointState")
    for i in range(10):
        b.write("/e", T0 + i, m.excitation_msg(F, T0 + i, np.full(4, float(i))))

    class FullCursor:
        def execute(self, *a):
            raise sqlite3.OperationalError("database or disk is full")

    b._writer.storage.cursor = FullCursor()
    with pytest.raises(
        BagError,
        match=r"writing '/e' failed \(OperationalError: database or "
        r"disk is full\); closed; all 10 message\(s\) written are readable",
    ):
        b.write("/e", T0 + 10, m.excitation_msg(F, T0 + 10, np.zeros(4)))
    assert not b.is_open
    data = bg.read_bag(tmp_path / "b")  # committed (not rolled back), metadata.yaml written
    assert values(data) == [float(i) for i in range(10)]
    assert b.durable_counts == {"/e": 10}


def test_transient_write_error_closes_bag_cleanly(tmp_path):
    b = bg.BagWriter(tmp_path / "b").open()
    b.add_topic("/e", "sensor_msgs/msg/JointState")
    b.write("/e", 1, m.excitation_msg(F, 1, np.ones(4)))
    real = b._writer.write

    def fail_once(*a):
        b._writer.write = real
        raise OSError(errno.EIO, "Input/output error")

    b._writer.write = fail_once
    with pytest.raises(BagError, match=r"writing '/e' failed \(EIO: Input/output error\); closed"):
        b.write("/e", 2, m.excitation_msg(F, 2, np.ones(4)))
    data = bg.read_bag(tmp_path / "b")  # strict: footer and metadata present
    assert len(data["/e"]) == 1


def test_exception_in_with_block_still_closes(tmp_path):
    with pytest.raises(RuntimeError):
        with bg.BagWriter(tmp_path / "b") as b:
            b.add_topic("/e", "sensor_msgs/msg/JointState")
            b.write("/e", 1, m.excitation_msg(F, 1, np.zeros(4)))
            raise RuntimeError("node crashed")
    assert len(bg.read_bag(tmp_path / "b")["/e"]) == 1


def test_writer_errors(tmp_path):
    joint_bag(tmp_path / "b", 1)
    with pytest.raises(BagError, match=r"bag .*b: cannot create: .*exists"):
        bg.BagWriter(tmp_path / "b").open()
    with pytest.raises(BagError, match="storage must be one of"):
        bg.BagWriter(tmp_path / "c", storage="rosbag1")
    with bg.BagWriter(tmp_path / "c") as b:
        with pytest.raises(BagError, match=r"unknown message type 'foo/msg/Bar'"):
            b.add_topic("/x", "foo/msg/Bar")
        b.add_topic("/e", "sensor_msgs/msg/JointState")
        b.add_topic("/e", "sensor_msgs/msg/JointState")  # idempotent
        with pytest.raises(BagError, match="already registered as sensor_msgs/msg/JointState"):
            b.add_topic("/e", "nav_msgs/msg/Odometry")
        with pytest.raises(BagError, match=r"topic '/y' was not added"):
            b.write("/y", 1, m.excitation_msg(F, 1, np.zeros(4)))
        with pytest.raises(
            BagError, match=r"has type sensor_msgs/msg/JointState, got a nav_msgs/msg/Odometry"
        ):
            b.write("/e", 1, m.odometry_from_state(F, 1, *np.zeros((4, 3))))
        with pytest.raises(BagError, match=r"stamp -5 ns outside"):
            b.write("/e", -5, m.excitation_msg(F, 1, np.zeros(4)))
        with pytest.raises(BagError, match="cannot serialise"):
            b.write("/e", 1, "not a message")
        b.write("/e", 1, m.excitation_msg(F, 1, np.zeros(4)))
    assert b.counts == {"/e": 1}
    with pytest.raises(BagError, match="not open"):
        b.write("/e", 2, m.excitation_msg(F, 2, np.zeros(4)))
    assert len(bg.read_bag(tmp_path / "c")["/e"]) == 1
