"""io/bag fast paths: the CDR block codec, the chunk/index readers (read_bag, read_arrays,
topic_info) and bulk writing (write_many, encode_block), each against rosbags itself."""

import itertools

import numpy as np
import pytest
import yaml

from lpv_sysid.errors import BagError
from lpv_sysid.io import bag as bg
from lpv_sysid.io import messages as m
from lpv_sysid.io.bag.cdr import layout
from lpv_sysid.io.bag.mcap import index as mcap_index

F = m.MsgFactory.rosbags()
TS = bg.jazzy_typestore()
T0 = 1_700_000_000_000_000_000
TOPICS = {f"/lpv_sysid/{k}": v for k, v in m.TYPES.items()}


def sample_msgs(i, rng):
    ns = T0 + i * 10_000_000
    return ns, {
        "state": m.odometry_from_state(
            F,
            ns,
            rng.normal(size=3),
            rng.uniform(-1, 1, 3) * 0.3,
            rng.normal(size=3),
            rng.normal(size=3),
        ),
        "rotor_speeds": m.rotor_speeds_msg(
            F, ns, rng.uniform(300, 900, 4), source="estimated" if i % 3 == 0 else "esc"
        ),
        "imu": m.imu_msg(
            F,
            ns,
            rng.normal(size=3),
            rng.normal(size=3),
            None if i % 2 else rng.uniform(-1, 1, 3) * 0.3,
        ),
        "velocity_reference": m.twist_reference_msg(
            F, ns, rng.normal(size=3), float(rng.normal())
        ),
        "excitation": m.excitation_msg(F, ns, rng.uniform(-1, 1, 4)),
        "actuator_command": m.actuator_command_msg(F, ns, rng.normal(size=4)),
        "status": m.diagnostic_array(
            F,
            ns,
            [
                m.diagnostic_status(
                    F,
                    "WARN" if i % 2 else "OK",
                    f"node{i % 4}",
                    "x" * (i % 5),
                    {"k": i / 3, "n": i},
                )
            ],
        ),
    }


def write_all(path, storage="mcap", n=40, **kw):
    rng = np.random.default_rng(3)
    with bg.BagWriter(path, storage=storage, **kw) as b:
        for t, ty in TOPICS.items():
            b.add_topic(t, ty)
        b.add_topic("/empty", "sensor_msgs/msg/Imu")
        # out-of-order and equal stamps on one topic
        for i in itertools.chain(range(n), [n // 2, 3]):
            ns, msgs = sample_msgs(i, rng)
            for k, msg in msgs.items():
                b.write(f"/lpv_sysid/{k}", ns, msg)


def reference(path, topics=None):
    """What rosbags gives: AnyReader's records deserialised one by one, per topic sorted by
    stamp (stable)."""
    from rosbags.highlevel import AnyReader

    out = {}
    p = path if not path.is_dir() else path
    with AnyReader([p], default_typestore=TS) as r:
        for c in r.connections:
            if topics is None or c.topic in topics:
                out.setdefault(c.topic, [])
        conns = [c for c in r.connections if topics is None or c.topic in topics]
        for c, ns, data in r.messages(connections=conns):
            out[c.topic].append((ns, TS.deserialize_cdr(data, c.msgtype)))
    for v in out.values():
        v.sort(key=lambda it: it[0])
    return out


def same(a, b):
    """Deep equality of rosbags messages, including value types and array dtypes."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (
            type(a) is type(b)
            and a.dtype == b.dtype
            and a.shape == b.shape
            and np.array_equal(a, b, equal_nan=True)
        )
    if hasattr(a, "__dataclass_fields__"):
        return type(a) is type(b) and all(
            same(getattr(a, f), getattr(b, f))
            for f in a.__dataclass_fields__
            if f != "__msgtype__"
        )
    if isinstance(a, list):
        return isinstance(b, list) and len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    if isinstance(a, float) and isinstance(b, float) and np.isnan(a) and np.isnan(b):
        return True
    return type(a) is type(b) and a == b


def leaf(msg, path):
    return layout._get_path(msg, path)


# ------------------------------------------------------------------ read_bag / arrays
@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_read_bag_equals_rosbags_deserialisation(tmp_path, storage):
    write_all(tmp_path / "b", storage)
    ref = reference(tmp_path / "b")
    got = bg.read_bag(tmp_path / "b")
    assert set(got) == set(ref) and got.problems == []
    for t in ref:
        assert [ns for ns, _ in got[t]] == [ns for ns, _ in ref[t]], t
        assert all(same(a, b) for (_, a), (_, b) in zip(got[t], ref[t])), t
    msg = got["/lpv_sysid/rotor_speeds"][0][1]
    assert not msg.velocity.flags.writeable  # read-only like rosbags' arrays
    sub = bg.read_bag(tmp_path / "b", topics=["/lpv_sysid/state"], optional=["/nope"])
    assert set(sub) == {"/lpv_sysid/state"}
    assert all(
        same(a, b) for (_, a), (_, b) in zip(sub["/lpv_sysid/state"], ref["/lpv_sysid/state"])
    )


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_read_arrays_equal_rosbags_values(tmp_path, storage):
    write_all(tmp_path / "b", storage)
    ref = reference(tmp_path / "b")
    arr = bg.read_arrays(
        tmp_path / "b", topics=[t for t in TOPICS if not t.endswith("status")] + ["/empty"]
    )
    for t, rows in ref.items():
        if t.endswith("status"):
            continue
        a = arr[t]
        assert a.msgtype == TOPICS.get(t, "sensor_msgs/msg/Imu")
        assert a.log_time.tolist() == [ns for ns, _ in rows]
        for path, col in a.fields.items():
            want = [leaf(msg, path) for _, msg in rows]
            assert col.shape[0] == len(rows)
            for x, y in zip(col, want):
                assert np.array_equal(np.asarray(x), np.asarray(y)), (t, path)
                if isinstance(y, np.ndarray):
                    assert x.dtype == y.dtype, (t, path)
                else:  # a scalar: same Python type
                    assert type(x.item()) is type(y), (t, path)
        for path, col in a.strings.items():
            want = [leaf(msg, path) for _, msg in rows]
            assert [tuple(x) if isinstance(x, tuple) else x for x in col] == [
                tuple(y) if isinstance(y, list) else y for y in want
            ], (t, path)
    odom = arr["/lpv_sysid/state"]
    assert set(odom.strings) == {"header.frame_id", "child_frame_id"}
    assert odom.fields["pose.covariance"].shape == (len(odom), 36)
    assert len(arr["/empty"]) == 0
    with pytest.raises(BagError, match="not in bag"):
        bg.read_arrays(tmp_path / "b", topics=["/nope"])


def test_read_arrays_mixed_layouts_and_irregular_topics(tmp_path):
    """Several layouts on one topic (joint names differ) stack; a topic whose sequence
    lengths differ has no common shape and says so (read_bag still reads it)."""
    with bg.BagWriter(tmp_path / "b") as b:
        b.add_topic("/r", "sensor_msgs/msg/JointState")
        b.add_topic("/j", "sensor_msgs/msg/JointState")
        for i in range(30):
            b.write(
                "/r",
                i,
                m.rotor_speeds_msg(
                    F, i, np.full(4, i + 0.5), source="estimated" if i % 4 == 1 else "esc"
                ),
            )
            b.write(
                "/j",
                i,
                m.joint_state(
                    F,
                    i,
                    [f"a{k}" for k in range(1 + i % 3)],
                    position=np.arange(1 + i % 3, dtype=float),
                ),
            )
    a = bg.read_arrays(tmp_path / "b", topics=["/r"])["/r"]
    assert a.fields["velocity"][:, 0].tolist() == [i + 0.5 for i in range(30)]
    # the rotor-speed source is in the joint names, the frame is base_link (REP-105)
    assert a.strings["header.frame_id"].tolist() == ["base_link"] * 30
    with pytest.raises(BagError, match="different structure"):
        bg.read_arrays(tmp_path / "b", topics=["/j"])
    lax = bg.read_arrays(tmp_path / "b", strict=False)
    assert "/j" not in lax and any("different structure" in p for p in lax.problems)
    assert [len(msg.name) for _, msg in bg.read_bag(tmp_path / "b")["/j"]] == [
        1 + i % 3 for i in range(30)
    ]


def test_block_decode_of_odd_bytes_matches_rosbags():
    """Bool bytes other than 0/1, signed ``byte``, unsigned ``char``: as rosbags reads them."""
    for msgtype, raw in (
        ("std_msgs/msg/Bool", b"\x00\x01\x00\x00\x02"),
        ("std_msgs/msg/Byte", b"\x00\x01\x00\x00\xf0"),
        ("std_msgs/msg/Char", b"\x00\x01\x00\x00\xf0"),
    ):
        lay = layout._LAYOUTS.for_record(TS, msgtype, raw)
        assert lay is not None
        got = lay.decode(np.frombuffer(raw, np.uint8).reshape(1, -1))["data"][0]
        want = TS.deserialize_cdr(raw, msgtype).data
        assert got == want and type(got.item()) is type(want), msgtype


def test_layout_probe_catches_a_wrong_offset():
    msg = m.odometry_from_state(F, 5, np.ones(3), np.zeros(3), np.ones(3), np.ones(3))
    lay = bg.CdrLayout.from_message(TS, "nav_msgs/msg/Odometry", msg)
    lay.probe(TS)  # the real layout passes
    leaves = list(lay.leaves.values())
    k = next(i for i, lf in enumerate(leaves) if lf.path == "twist.twist.linear.y")
    leaves[k] = layout._Leaf(leaves[k].path, leaves[k].offset + 8, leaves[k].rostype, None)
    broken = bg.CdrLayout(
        lay.msgtype, lay.template, leaves, lay.strings, lay.struct_index, lay.counts
    )
    with pytest.raises(bg.LayoutError, match="disagrees with rosbags"):
        broken.probe(TS)


# ------------------------------------------------------------------------ topic_info
def test_topic_info_from_index_equals_records(tmp_path):
    write_all(tmp_path / "b", chunk_bytes=3000, flush_messages=17)
    ref = reference(tmp_path / "b")
    info = bg.topic_info(tmp_path / "b")
    assert set(info) == set(ref)
    for t, rows in ref.items():
        s = info[t]
        stamps = [ns for ns, _ in rows]
        assert (s.count, s.start_ns, s.end_ns) == (
            len(rows),
            min(stamps, default=None),
            max(stamps, default=None),
        )
        assert s.msgtype == (TOPICS.get(t) or "sensor_msgs/msg/Imu")
    mcap = next((tmp_path / "b").glob("*.mcap"))
    assert bg.topic_info(mcap) == info  # bare file: the same summary


def test_metadata_that_disagrees_with_the_file_goes_through_rosbags(tmp_path):
    """A topic whose QoS in metadata.yaml differs from the mcap channel: the fast readers
    step aside and the result is rosbags' (which does not match that connection)."""
    write_all(tmp_path / "b", n=5)
    meta_path = tmp_path / "b" / "metadata.yaml"
    meta = yaml.safe_load(meta_path.read_text())
    tm = meta["rosbag2_bagfile_information"]["topics_with_message_count"][0]["topic_metadata"]
    tm["offered_qos_profiles"][0]["depth"] = 3
    meta_path.write_text(yaml.safe_dump(meta, sort_keys=False))
    with pytest.raises(mcap_index._FastPathUnavailable):
        mcap_index._open_fast(tmp_path / "b")
    ref = reference(tmp_path / "b")
    got = bg.read_bag(tmp_path / "b")
    assert {t: len(v) for t, v in got.items()} == {t: len(v) for t, v in ref.items()}
    info = bg.topic_info(tmp_path / "b")
    assert {t: s.count for t, s in info.items()} == {t: len(v) for t, v in ref.items()}


def test_damaged_files_read_as_rosbags_reads_them(tmp_path):
    """Flipped bytes anywhere in the file (records, chunk headers, indexes, summary): the
    fast readers either give rosbags' result or step aside, so read_bag returns what
    rosbags returns, or raises BagError where rosbags fails."""
    write_all(tmp_path / "good", n=12, chunk_bytes=4000)
    good = next((tmp_path / "good").glob("*.mcap")).read_bytes()
    rng = np.random.default_rng(17)
    for k, pos in enumerate(rng.integers(8, len(good) - 8, 40).tolist()):
        d = tmp_path / f"d{k}"
        d.mkdir()
        (d / "metadata.yaml").write_text((tmp_path / "good" / "metadata.yaml").read_text())
        raw = bytearray(good)
        raw[pos] ^= 0x5A
        (d / "good.mcap").write_bytes(bytes(raw))
        try:
            ref = reference(d)
        except Exception:  # noqa: BLE001 - rosbags cannot read it
            ref = None
        if ref is None:
            with pytest.raises(BagError):
                bg.read_bag(d)
            continue
        try:
            got = bg.read_bag(d)
        except BagError:
            # rosbags reads the records but one cannot be deserialised: the same failure
            with pytest.raises(Exception):
                for t, rows in ref.items():
                    pass
                raise RuntimeError
            continue
        assert set(got) == set(ref), pos
        for t in ref:
            assert len(got[t]) == len(ref[t]) and all(
                a0 == b0 and same(a1, b1) for (a0, a1), (b0, b1) in zip(got[t], ref[t])
            ), (pos, t)


# ------------------------------------------------------------------------- writing
def _rows(n, rng):
    out = []
    for i in range(n):
        ns, msgs = sample_msgs(i, rng)
        for k, msg in msgs.items():
            out.append(
                (
                    f"/lpv_sysid/{k}",
                    ns + (k == "imu"),
                    bytes(TS.serialize_cdr(msg, TOPICS[f"/lpv_sysid/{k}"])),
                )
            )
    return out


def test_write_many_writes_the_file_write_raw_writes(tmp_path):
    rows = _rows(60, np.random.default_rng(5))
    results = []
    for name, bulk in (("a", False), ("b", True)):
        (tmp_path / name).mkdir()
        tick = itertools.count(0.0, 0.011)
        with bg.BagWriter(
            tmp_path / name / "bag", chunk_bytes=5000, flush_messages=37, clock=lambda: next(tick)
        ) as w:
            for t, ty in TOPICS.items():
                w.add_topic(t, ty)
            if bulk:
                assert w.write_many(iter(rows)) == len(rows)
            else:
                for r in rows:
                    w.write_raw(*r)
            results.append((w.flushes, dict(w.durable_counts)))
    fa, fb = ((tmp_path / n / "bag" / "bag.mcap").read_bytes() for n in "ab")
    assert fa == fb
    assert (tmp_path / "a" / "bag" / "metadata.yaml").read_text() == (
        tmp_path / "b" / "bag" / "metadata.yaml"
    ).read_text()
    assert results[0] == results[1] and results[0][0] > 5


def test_write_many_checks_like_write_raw(tmp_path):
    with bg.BagWriter(tmp_path / "b", storage="sqlite3") as w:
        w.add_topic("/e", "sensor_msgs/msg/JointState")
        data = bytes(
            TS.serialize_cdr(m.excitation_msg(F, 1, np.ones(4)), "sensor_msgs/msg/JointState")
        )
        assert w.write_many([("/e", 1, data), ("/e", 2, data)]) == 2
    assert len(bg.read_bag(tmp_path / "b")["/e"]) == 2
    with bg.BagWriter(tmp_path / "c") as w:
        w.add_topic("/e", "sensor_msgs/msg/JointState")
        with pytest.raises(BagError, match="was not added"):
            w.write_many([("/x", 1, data)])
        with pytest.raises(BagError, match="outside"):
            w.write_many([("/e", -1, data)])
        w.write_many([("/e", 3, data)])
    assert [ns for ns, _ in bg.read_bag(tmp_path / "c")["/e"]] == [3]


def test_encode_block_is_serialize_cdr():
    rng = np.random.default_rng(9)
    n = 25
    stamps = rng.integers(0, 2**40, n)
    vel = rng.normal(size=(n, 4))
    vel[0, 1] = -0.0
    tmpl = m.rotor_speeds_msg(F, 0, np.zeros(4))
    block = bg.encode_block(
        "sensor_msgs/msg/JointState",
        tmpl,
        {
            "header.stamp.sec": stamps // 10**9,
            "header.stamp.nanosec": stamps % 10**9,
            "velocity": vel,
        },
    )
    for k in range(n):
        want = bytes(
            TS.serialize_cdr(
                m.rotor_speeds_msg(F, int(stamps[k]), vel[k]), "sensor_msgs/msg/JointState"
            )
        )
        assert block[k].tobytes() == want
    with pytest.raises(bg.LayoutError, match="outside uint32"):
        bg.encode_block(
            "sensor_msgs/msg/JointState", tmpl, {"header.stamp.nanosec": np.full(2, -1)}
        )
    with pytest.raises(bg.LayoutError, match="expected shape"):
        bg.encode_block("sensor_msgs/msg/JointState", tmpl, {"velocity": np.zeros((2, 3))})
    with pytest.raises(bg.LayoutError, match="no numeric field"):
        bg.encode_block("sensor_msgs/msg/JointState", tmpl, {"name": np.zeros(2)})
    assert bg.records_close("sensor_msgs/msg/JointState", block[1], block[1])
    assert not bg.records_close("sensor_msgs/msg/JointState", block[1], block[2])
