"""Data-logger core: no loss at 1 kHz, splitting, metadata, write errors, SIGTERM close."""

import errno
import hashlib
import logging
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
import yaml
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from lpv_sysid.errors import BagError, ConfigError
from lpv_sysid.io.bag import BagWriter, read_bag
from lpv_sysid.io.recorder import Recorder, RecorderConfig

TS = get_typestore(Stores.ROS2_JAZZY)
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
T0 = 1_704_067_200 * 10**9
TOPICS = {
    "/lpv_sysid/state": "nav_msgs/msg/Odometry",
    "/lpv_sysid/actuator_command": "sensor_msgs/msg/JointState",
    "/lpv_sysid/imu": "sensor_msgs/msg/Imu",
}


def joint_state(stamp_ns, values, names=("ut", "ua", "ue", "ur")):
    T = TS.types
    sec, ns = divmod(stamp_ns, 10**9)
    hdr = T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=ns), frame_id=""
    )
    return T["sensor_msgs/msg/JointState"](
        header=hdr,
        name=list(names),
        position=np.asarray(values, float),
        velocity=np.zeros(0),
        effort=np.zeros(0),
    )


def cdr(msg):
    return bytes(TS.serialize_cdr(msg, msg.__msgtype__))


def count_messages(bagdir):
    with AnyReader([bagdir]) as reader:
        return [(c.topic, t) for c, t, _ in reader.messages()]


def full_disk_on(write_no):
    """A ``writer_factory`` whose bag writers fail the ``write_no``-th write (counted over all
    of them) with ENOSPC."""

    class FullDisk(BagWriter):
        writes = 0

        def write(self, topic, stamp_ns, msg):
            FullDisk.writes += 1
            if FullDisk.writes == write_no:
                raise OSError(errno.ENOSPC, "No space left on device")
            return super().write(topic, stamp_ns, msg)

    return lambda p, s: FullDisk(p, storage=s)


def test_1khz_for_60s_no_loss(tmp_path):
    """1 kHz aggregate (250 Hz state-like + 750 Hz others) for 60 s simulated: every one."""
    cfg = RecorderConfig(
        out_dir=str(tmp_path / "exp"),
        topics={"/a": "sensor_msgs/msg/JointState", "/b": "sensor_msgs/msg/JointState"},
        split_duration_s=20.0,
    )
    rec = Recorder(cfg)
    rec.start(T0)
    raw = cdr(joint_state(T0, [0.1, 0.2, 0.3, 0.4]))
    n = 60_000
    for k in range(n):
        stamp = T0 + k * 1_000_000
        # alternate raw CDR bytes (how the node records) and message objects
        if k % 4 == 0:
            rec.record("/a", stamp, joint_state(stamp, [k, 0, 0, 0]))
        else:
            rec.record("/b", stamp, raw)
    rec.stop(T0 + n * 1_000_000)
    meta = yaml.safe_load((tmp_path / "exp" / "experiment.yaml").read_text())
    assert meta["closed_cleanly"] is True and meta["error"] is None
    assert meta["status"] == "closed_cleanly"
    assert [b["path"] for b in meta["bags"]] == ["bag_0000", "bag_0001", "bag_0002"]
    assert [b["messages"] for b in meta["bags"]] == [20_000, 20_000, 20_000]
    got = []
    for b in meta["bags"]:
        got += count_messages(tmp_path / "exp" / b["path"])
    stamps = sorted(t for _, t in got)
    assert len(got) == n and stamps == [T0 + k * 1_000_000 for k in range(n)]
    assert meta["topics"]["/a"]["count"] == 15_000 and meta["topics"]["/b"]["count"] == 45_000
    assert meta["topics"]["/a"]["rate_hz"] == pytest.approx(250.0, rel=1e-3)
    assert meta["topics"]["/b"]["rate_hz"] == pytest.approx(750.0, rel=1e-3)
    # content survives: /a position[0] carries k
    a = read_bag(str(tmp_path / "exp" / "bag_0001"), topics=["/a"])["/a"]
    assert [int(m.position[0]) for _, m in a][:3] == [20_000, 20_004, 20_008]


def test_split_by_size_and_metadata_content(tmp_path):
    gains = tmp_path / "gains.yaml"
    gains.write_text("format: lpv_sysid/gains@1\n")
    conf = tmp_path / "logger.yaml"
    conf.write_text("data_logger:\n  ros__parameters: {}\n")
    msg_len = len(cdr(joint_state(T0, [1.0, 2.0, 3.0, 4.0])))
    cfg = RecorderConfig(
        out_dir=str(tmp_path / "exp"),
        topics={"/lpv_sysid/actuator_command": "sensor_msgs/msg/JointState"},
        split_size_bytes=10 * msg_len,
        config_files=(str(conf),),
        gains_file=str(gains),
        storage="sqlite3",
    )
    rec = Recorder(cfg)
    rec.start(T0)
    for k in range(25):
        rec.record(
            "/lpv_sysid/actuator_command",
            T0 + k * 10**7,
            joint_state(T0 + k * 10**7, [1.0, 2.0, 3.0, 4.0]),
        )
    rec.note_dropped("/lpv_sysid/actuator_command", 3)
    rec.stop()
    meta = yaml.safe_load((tmp_path / "exp" / "experiment.yaml").read_text())
    assert [b["messages"] for b in meta["bags"]] == [10, 10, 5]
    assert meta["gains"]["sha256"] == hashlib.sha256(gains.read_bytes()).hexdigest()
    # paths relative to the experiment directory; bytes = the bag's files on disk
    assert meta["config_files"]["../logger.yaml"] == conf.read_text()
    assert meta["gains"]["path"] == "../gains.yaml"
    for b in meta["bags"]:
        on_disk = sum(p.stat().st_size for p in (tmp_path / "exp" / b["path"]).iterdir())
        assert b["bytes"] == on_disk > 10 * msg_len * b["messages"] // 10
    assert meta["topics"]["/lpv_sysid/actuator_command"]["dropped"] == 3
    git = subprocess.run(["git", "-C", ROOT, "rev-parse", "HEAD"], capture_output=True, text=True)
    assert meta["git_revision"] == (git.stdout.strip() or None)
    for b in meta["bags"]:
        assert len(count_messages(tmp_path / "exp" / b["path"])) == b["messages"]


def test_write_error_keeps_bag_readable(tmp_path):
    """Disk full on the 8th write: clear error, the 7 written messages stay readable."""
    cfg = RecorderConfig(
        out_dir=str(tmp_path / "exp"), topics={"/a": "sensor_msgs/msg/JointState"}
    )
    rec = Recorder(cfg, writer_factory=full_disk_on(8))
    rec.start(T0)
    with pytest.raises(BagError, match="No space left on device.*bag_0000 closed with 7"):
        for k in range(20):
            rec.record("/a", T0 + k, joint_state(T0 + k, [0.0] * 4))
    assert len(count_messages(tmp_path / "exp" / "bag_0000")) == 7
    meta = yaml.safe_load((tmp_path / "exp" / "experiment.yaml").read_text())
    assert meta["closed_cleanly"] is False and "No space left" in meta["error"]
    assert meta["status"] == "incomplete"
    assert meta["topics"]["/a"]["count"] == meta["bags"][0]["messages"] == 7
    with pytest.raises(BagError, match="not recording"):
        rec.record("/a", T0 + 100, joint_state(T0, [0.0] * 4))


def test_unwritable_metadata_after_write_error_is_logged(tmp_path, caplog):
    """A write error (disk full) when experiment.yaml cannot be written either, the reserve
    already given back: the recorder still raises the BagError naming the write error and
    logs the metadata failure (it raised UnboundLocalError: the handler named an unbound
    exception)."""
    out = tmp_path / "exp"
    cfg = RecorderConfig(out_dir=str(out), topics={"/a": "sensor_msgs/msg/JointState"})
    rec = Recorder(cfg, writer_factory=full_disk_on(3))
    rec.start(T0)
    meta = out / "experiment.yaml"
    meta.unlink()
    meta.mkdir()  # a non-empty directory: every rename onto it fails, also for root
    (meta / "keep").write_text("")
    with caplog.at_level(logging.ERROR), pytest.raises(BagError, match="No space left on device"):
        for k in range(20):
            rec.record("/a", T0 + k, joint_state(T0 + k, [0.0] * 4))
    rec.stop(T0 + 100)  # the lock is gone as well: logged again, never raised
    failed = [r.getMessage() for r in caplog.records if r.getMessage().startswith("cannot write")]
    assert len(failed) >= 2 and all(str(meta) in m for m in failed)
    assert len(count_messages(out / "bag_0000")) == 2


def test_bad_inputs(tmp_path):
    with pytest.raises(ConfigError, match="topic 'state'"):
        RecorderConfig(out_dir=str(tmp_path), topics={"state": "nav_msgs/msg/Odometry"})
    with pytest.raises(ConfigError, match="bogus"):
        RecorderConfig.from_dict({"out_dir": "x", "topics": {"/a": "a/msg/B"}, "bogus": 1})
    rec = Recorder(
        RecorderConfig(out_dir=str(tmp_path / "e"), topics={"/a": "std_msgs/msg/Empty"})
    )
    rec.start(T0)
    with pytest.raises(BagError, match="'/other' is not configured"):
        rec.record("/other", T0, b"")
    rec.stop()
    with pytest.raises(BagError, match="not empty"):
        Recorder(
            RecorderConfig(out_dir=str(tmp_path / "e"), topics={"/a": "std_msgs/msg/Empty"})
        ).start(T0)


CHILD = textwrap.dedent("""
    import sys, time
    import numpy as np
    sys.path.insert(0, {root!r})
    from rosbags.typesys import Stores, get_typestore
    from lpv_sysid.io.recorder import Recorder, RecorderConfig
    from lpv_sysid.io.recorder.signals import stop_on_signals
    TS = get_typestore(Stores.ROS2_JAZZY)
    T = TS.types
    rec = Recorder(RecorderConfig(out_dir={out!r}, topics={{"/a": "sensor_msgs/msg/JointState"}}))
    rec.start(0)
    k = 0
    with stop_on_signals(rec):
        while True:
            k += 1
            stamp = T["builtin_interfaces/msg/Time"](sec=k, nanosec=0)
            hdr = T["std_msgs/msg/Header"](stamp=stamp, frame_id="")
            rec.record("/a", k * 10**9, T["sensor_msgs/msg/JointState"](header=hdr, name=["x"],
                       position=np.array([float(k)]), velocity=np.zeros(0), effort=np.zeros(0)))
            if k == 50:
                print("ready", flush=True)
            time.sleep(0.0005)
""")


def test_sigterm_leaves_readable_bag(tmp_path):
    out = str(tmp_path / "exp")
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD.format(root=ROOT, out=out)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout.readline().strip() == "ready"
        time.sleep(0.05)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 128 + signal.SIGTERM
    finally:
        if proc.poll() is None:
            proc.kill()
    meta = yaml.safe_load(open(os.path.join(out, "experiment.yaml")))
    assert meta["closed_cleanly"] is True
    msgs = count_messages(tmp_path / "exp" / "bag_0000")
    assert len(msgs) == meta["topics"]["/a"]["count"] >= 50
    assert [t for _, t in msgs] == [k * 10**9 for k in range(1, len(msgs) + 1)]
