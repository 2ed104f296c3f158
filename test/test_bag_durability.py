"""Data durability (issue 12 items 8, 9): a killed or starved recording stays readable by
standard tools (rosbags' AnyReader), experiment.yaml never claims more than is on disk.

Real ``kill -9`` of a child recording at 1 kHz through Recorder with each storage, a real
full disk (a small tmpfs; skipped without the right to mount one) and an injected ENOSPC,
mcap files cut at every kind of offset against rosbags' own reading of the intact file,
the sqlite3 hot journal, the bounded flush interval on a simulated clock, and the
``lpv-sysid bag repair`` CLI.
"""

import errno
import os
import signal
import struct
import subprocess
import sys
import textwrap
import time
import zlib
from pathlib import Path

import numpy as np
import pytest
import yaml
from rosbags.highlevel import AnyReader
from rosbags.rosbag2.storage_mcap import McapReader

from lpv_sysid.cli.main import main
from lpv_sysid.errors import BagError
from lpv_sysid.io import bag as bg
from lpv_sysid.io import messages as m
from lpv_sysid.io.recorder import LOCK_FILE, Recorder, RecorderConfig, repair_experiment

F = m.MsgFactory.rosbags()
TS = bg.jazzy_typestore()
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
T0 = 1_700_000_000_000_000_000
JS = "sensor_msgs/msg/JointState"


def joint(k: int, ns: int | None = None):
    ns = T0 + k * 1_000_000 if ns is None else ns
    return m.excitation_msg(F, ns, np.full(4, float(k)))


def readable(bagdir) -> list[int]:
    """The k (position[0]) of every message rosbags' AnyReader delivers, in bag order."""
    out = []
    with AnyReader([Path(bagdir)], default_typestore=TS) as reader:
        for c, _, raw in reader.messages():
            out.append(int(reader.deserialize(raw, c.msgtype).position[0]))
    return out


def meta_of(out):
    return yaml.safe_load((Path(out) / "experiment.yaml").read_text())


def leftovers(root) -> list[str]:
    """Temporary, lock, journal or empty files left anywhere below ``root``."""
    bad = []
    for dirpath, _, names in os.walk(root):
        for n in names:
            p = Path(dirpath) / n
            if (
                n.endswith(".tmp")
                or n.endswith("-journal")
                or n in (bg.LOCK_FILE, LOCK_FILE)
                or p.stat().st_size == 0
            ):
                bad.append(str(p.relative_to(root)))
    return bad


# --------------------------------------------------------------------- kill -9 at 1 kHz
CHILD = textwrap.dedent("""
    import sys, time
    import numpy as np
    sys.path.insert(0, {root!r})
    from lpv_sysid.io import messages as m
    from lpv_sysid.io.recorder import Recorder, RecorderConfig
    F = m.MsgFactory.rosbags()
    rec = Recorder(RecorderConfig(out_dir={out!r}, storage={storage!r},
                                  topics={{"/a": "sensor_msgs/msg/JointState"}}))
    rec.start({t0})
    side = open({side!r}, "w", buffering=1)
    k, t_next = 0, time.monotonic()
    while True:
        ns = {t0} + k * 1_000_000
        rec.record("/a", ns, m.excitation_msg(F, ns, np.full(4, float(k))))
        side.write(f"{{k}} {{time.monotonic()!r}}\\n")     # passed to record() and returned
        k += 1
        t_next += 0.001                                   # 1 kHz
        time.sleep(max(0.0, t_next - time.monotonic()))
""")


def record_and_kill(tmp_path, storage, seconds=3.0):
    """A child records at 1 kHz through Recorder; SIGKILL after ``seconds`` of recording.
    Returns (experiment dir, [(k, monotonic time) written], monotonic time of the kill)."""
    out, side = tmp_path / "exp", tmp_path / "written.txt"
    code = CHILD.format(root=ROOT, out=str(out), storage=storage, side=str(side), t0=T0)
    proc = subprocess.Popen([sys.executable, "-c", code])
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if side.exists() and side.stat().st_size > 0:
                first = float(side.read_text().split("\n", 1)[0].split()[1])
                if time.monotonic() - first >= seconds:
                    break
            time.sleep(0.05)
        assert proc.poll() is None, "recording child ended by itself"
        t_kill = time.monotonic()
        proc.send_signal(signal.SIGKILL)
        assert proc.wait(timeout=30) == -signal.SIGKILL
    finally:
        if proc.poll() is None:
            proc.kill()
    written = []
    for line in side.read_text().splitlines():
        parts = line.split()
        if len(parts) == 2:  # the last line may be cut by the kill
            written.append((int(parts[0]), float(parts[1])))
    return out, written, t_kill


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_kill9_at_1khz_readable_by_anyreader_after_repair(tmp_path, storage, capsys):
    out, written, t_kill = record_and_kill(tmp_path, storage)
    old = [k for k, t in written if t <= t_kill - 1.0]  # written > 1 s before the kill
    assert len(old) > 1000 and len(written) > 2000
    bag = out / "bag_0000"
    # what the kill left: no metadata.yaml (AnyReader refuses), experiment.yaml "recording"
    # with counts that are committed, hence never more than what the repair finds
    assert not (bag / "metadata.yaml").exists()
    with pytest.raises(Exception, match="metadata"):
        readable(bag)
    before = meta_of(out)
    assert before["status"] == "recording" and before["closed_cleanly"] is False

    assert main(["bag", "repair", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "bag_0000: " + storage in printed and "status recording -> incomplete" in printed

    got = readable(bag)
    # a gap-free prefix; the kill may fall between record() returning and the side line
    assert got == list(range(len(got))) and len(got) <= len(written) + 1
    kept_old = set(got) & set(old)
    assert len(kept_old) >= 0.99 * len(old), (len(kept_old), len(old))
    assert before["topics"]["/a"]["count"] <= len(got)
    meta = meta_of(out)
    assert meta["status"] == "incomplete" and meta["closed_cleanly"] is False
    assert "interrupted" in meta["error"]
    assert meta["topics"]["/a"]["count"] == meta["bags"][0]["messages"] == len(got)
    assert meta["bags"][0]["start_ns"] == T0 + got[0] * 1_000_000
    assert meta["repaired"]["status_before"] == "recording"
    assert leftovers(out) == []
    # a second repair has nothing to do
    rep = repair_experiment(out)
    assert not rep.changed and rep.messages == len(got)


def test_logger_restart_on_killed_recording_repairs_it(tmp_path):
    out, written, _ = record_and_kill(tmp_path, "mcap", seconds=1.5)
    cfg = RecorderConfig(out_dir=str(out), topics={"/a": JS})
    with pytest.raises(
        BagError,
        match=r"not empty: it held an interrupted recording, now "
        r"repaired \(experiment.yaml: status recording -> incomplete; \d+ "
        r"message\(s\) readable in 1 bag\(s\)\); choose a new out_dir",
    ):
        Recorder(cfg).start(T0)
    got = readable(out / "bag_0000")
    assert 0 < len(got) <= len(written) + 1
    assert meta_of(out)["topics"]["/a"]["count"] == len(got)
    with pytest.raises(BagError, match=r"exists and is not empty$"):  # now intact: no repair
        Recorder(cfg).start(T0)


# ------------------------------------------------------------------------- disk full
@pytest.fixture
def small_disk(tmp_path):
    """A 4 MiB tmpfs (skipped when this process may not mount one)."""
    disk = tmp_path / "disk"
    disk.mkdir()
    res = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(disk)],
        capture_output=True,
        text=True,
    )
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({(res.stderr or res.stdout).strip()})")
    try:
        yield disk
    finally:
        subprocess.run(["umount", "-l", str(disk)], capture_output=True)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_disk_full_bag_opens_and_metadata_claims_no_more(small_disk, storage):
    out = small_disk / "exp"
    rec = Recorder(RecorderConfig(out_dir=str(out), storage=storage, topics={"/a": JS}))
    rec.start(T0)
    accepted = 0
    with pytest.raises(BagError) as err:
        for k in range(10**6):
            rec.record("/a", T0 + k * 1_000_000, bytes(TS.serialize_cdr(joint(k), JS)))
            accepted += 1
    assert accepted > 5000
    assert "No space left on device" in str(err.value) or "disk is full" in str(err.value)
    rec.stop()
    got = readable(out / "bag_0000")  # opens with AnyReader, strict
    # everything record() accepted is readable (the reserve made room for the pending
    # chunk / rows, the index and metadata.yaml); the failing message may be there too
    assert got[:accepted] == list(range(accepted)) and len(got) <= accepted + 1
    meta = meta_of(out)
    assert meta["status"] == "incomplete" and meta["closed_cleanly"] is False
    assert "No space left" in meta["error"] or "disk is full" in meta["error"]
    assert meta["topics"]["/a"]["count"] == meta["bags"][0]["messages"] == len(got)
    assert leftovers(out) == []
    assert bg.repair_bag(out / "bag_0000").action == "none"


class _FullBio:
    """File wrapper whose writes fail with ENOSPC (the recovery reopens the file)."""

    def __init__(self, bio):
        self.bio = bio

    def write(self, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    def __getattr__(self, name):
        return getattr(self.bio, name)


def sim_writer(clock):
    """BagWriter factory on a simulated clock (interval just under 0.5 s: 500 steps of
    1 ms are unambiguously due, 499 are not)."""
    return lambda p, s: bg.BagWriter(p, s, clock=lambda: clock[0], flush_interval_s=0.4995)


def test_injected_enospc_mcap_recorder_keeps_every_accepted_message(tmp_path):
    clock = [0.0]
    rec = Recorder(
        RecorderConfig(out_dir=str(tmp_path / "exp"), topics={"/a": JS}),
        writer_factory=sim_writer(clock),
    )
    rec.start(T0)
    for k in range(1700):  # 1 kHz: flushes after k = 500, 1001, 1502 (oldest + 0.5 s)
        clock[0] = k * 1e-3
        rec.record("/a", T0 + k * 1_000_000, joint(k))
    assert meta_of(tmp_path / "exp")["topics"]["/a"]["count"] == 1503
    storage = rec._writer._writer.storage
    storage.bio = _FullBio(storage.bio)  # the disk is full from now on
    accepted = 1700
    with pytest.raises(
        BagError,
        match=r"ENOSPC.*closed; all 2004 message\(s\) written are "
        r"readable.*bag_0000 closed with 2004 message\(s\) readable",
    ):
        for k in range(1700, 2300):  # the next flush (k = 2003) fails
            clock[0] = k * 1e-3
            rec.record("/a", T0 + k * 1_000_000, joint(k))
            accepted += 1
    assert accepted == 2003
    rec.stop()
    # the failing message had reached the pending chunk: it is saved with the others
    assert readable(tmp_path / "exp" / "bag_0000") == list(range(2004))
    meta = meta_of(tmp_path / "exp")
    assert (meta["status"], meta["topics"]["/a"]["count"]) == ("incomplete", 2004)
    assert "No space left on device" in meta["error"]
    assert leftovers(tmp_path / "exp") == []


# ------------------------------------------------------- truthful at every moment
@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_experiment_yaml_counts_committed_data_at_every_moment(tmp_path, storage):
    """Simulated clock, 1 kHz: the metadata is rewritten at every flush (every 0.5 s of
    clock or 1000 messages) with the committed count, so at any moment it claims no more
    than is on disk and at most 0.5 s of data is not yet in it."""
    clock = [0.0]
    out = tmp_path / "exp"
    rec = Recorder(
        RecorderConfig(out_dir=str(out), storage=storage, topics={"/a": JS}),
        writer_factory=sim_writer(clock),
    )
    rec.start(T0)
    seen = []
    for k in range(1600):
        clock[0] = k * 1e-3
        rec.record("/a", T0 + k * 1_000_000, joint(k))
        meta = meta_of(out)
        n = meta["topics"]["/a"]["count"]
        assert meta["status"] == "recording"
        assert n == rec._writer.durable_counts["/a"] <= k + 1
        assert k + 1 - n <= 500  # <= flush_interval_s of data at risk
        if not seen or seen[-1] != n:
            seen.append(n)
        assert not list(out.glob("*.tmp"))
    assert seen == [0, 501, 1002, 1503]  # each time the oldest pending message is 0.5 s old
    # the stream stops: a timer's flush_if_due commits the rest 0.5 s after the oldest
    clock[0] = 1.503 + 0.49
    assert rec.flush_if_due() is False and meta_of(out)["topics"]["/a"]["count"] == 1503
    clock[0] = 1.503 + 0.5
    assert rec.flush_if_due() is True
    assert meta_of(out)["topics"]["/a"]["count"] == 1600
    rec.stop()
    assert meta_of(out)["status"] == "closed_cleanly" and len(readable(out / "bag_0000")) == 1600


def test_count_based_flush_bounds_a_burst(tmp_path):
    b = bg.BagWriter(tmp_path / "b", flush_messages=300, clock=lambda: 0.0).open()
    b.add_topic("/e", JS)
    for k in range(1000):
        b.write("/e", T0 + k, joint(k))
    assert (b.flushes, b.durable_counts["/e"], b.pending_messages) == (3, 900, 100)
    b.close()


def test_bad_durability_options(tmp_path):
    with pytest.raises(BagError, match="flush_interval_s must be a finite number > 0"):
        bg.BagWriter(tmp_path / "b", flush_interval_s=float("nan"))
    with pytest.raises(BagError, match="flush_messages must be an integer >= 1"):
        bg.BagWriter(tmp_path / "b", flush_messages=0)
    from lpv_sysid.errors import ConfigError

    # the declared (0, 1] s: the data a killed recorder may lose
    with pytest.raises(ConfigError, match=r"^recorder\.flush_interval_s: 5 s exceeds the limit"):
        RecorderConfig(out_dir="x", topics={"/a": JS}, flush_interval_s=5.0)
    with pytest.raises(ConfigError, match=r"^recorder\.fsync: expected true or false"):
        RecorderConfig.from_dict({"out_dir": "x", "topics": {"/a": JS}, "fsync": "yes"})


# ---------------------------------------------------------------- mcap repair, cut anywhere
def _chunked_bag(path, n=300, **kw):
    with bg.BagWriter(path, chunk_bytes=2500, **kw) as b:
        b.add_topic("/e", JS)
        b.add_topic("/o", "nav_msgs/msg/Odometry", qos={"reliability": "best_effort", "depth": 5})
        for k in range(n):
            b.write("/e", T0 + k * 1_000_000, joint(k))


def _message_ends(intact: bytes, chunk_start: int) -> list[int]:
    """File offsets where the Message records of the (uncompressed) chunk at
    ``chunk_start`` end, read from the bytes by the MCAP spec (Chunk: start, end, size u64,
    crc u32, compression string, records length u64, records; a record: opcode u8, length
    u64, body; Message opcode 0x05)."""
    p = chunk_start + 9 + 28
    (clen,) = struct.unpack_from("<I", intact, p)
    assert clen == 0  # uncompressed (rosbags' default)
    p += 4 + clen
    (rlen,) = struct.unpack_from("<Q", intact, p)
    p += 8
    end, out = p + rlen, []
    while p < end:
        op, n = intact[p], struct.unpack_from("<Q", intact, p + 1)[0]
        p += 9 + n
        if op == 0x05:
            out.append(p)
    return out


def test_mcap_cut_anywhere_keeps_every_complete_record(tmp_path):
    """Oracle: rosbags' McapReader on the intact file (its chunk index) and the record
    boundaries of the MCAP spec. A cut at offset c must give back exactly the messages
    whose Message record lies entirely before c -- those of the chunks that end at or before
    c (a chunk whose message index was cut off gets a new one) and the complete records of
    the chunk the cut goes through (issue 25 item 9: they used to be dropped) -- all of
    them once the data section is complete."""
    src = tmp_path / "src"
    _chunked_bag(src)
    f = src / "src.mcap"
    intact = f.read_bytes()
    reader = McapReader(f)
    reader.open()
    chunks = [(c.chunk_start_offset, c.chunk_start_offset + c.chunk_length) for c in reader.chunks]
    data_end = reader.data_end
    reader.close()
    ends = [e for start, _ in chunks for e in _message_ends(intact, start)]
    assert len(chunks) > 10 and len(ends) == 300
    cuts = sorted(
        {0, 5, 8, 20, 40, len(intact) - 1, len(intact) - 30, data_end, data_end + 5}
        | {e + d for _, e in chunks[:4] for d in (-1, 0, 1, 9, 40)}
        | {e for _, e in chunks}
        | {ends[k] + d for k in (0, 1, 7, 13, 150) for d in (-1, 0, 1)}
    )
    for c in cuts:
        d = tmp_path / f"cut{c}"
        d.mkdir()
        (d / "src.mcap").write_bytes(intact[:c])
        rep = bg.repair_bag(d)
        want = sum(1 for e in ends if e <= c) if c < data_end else 300
        got = readable(d)
        assert got == list(range(want)), c
        assert rep.messages == want and rep.action in ("storage", "metadata")
        assert bg.repair_bag(d).action == "none"  # idempotent


def test_repair_of_one_big_chunk_cut_in_half_keeps_its_complete_messages(tmp_path):
    """The audit's case: a 1 MB chunk cut at 50 % shrank to 174 bytes (2,771 intact
    messages gone, exit 0). Now every message whose record is whole stays, and the
    re-chunked records carry their CRC."""
    src = tmp_path / "big"
    with bg.BagWriter(src, flush_interval_s=1e3, flush_messages=10**9) as b:
        b.add_topic("/e", JS)
        for k in range(4000):
            b.write("/e", T0 + k * 1_000_000, joint(k))
    f = src / "big.mcap"
    intact = f.read_bytes()
    reader = McapReader(f)
    reader.open()
    (chunk,) = reader.chunks
    reader.close()
    ends = _message_ends(intact, chunk.chunk_start_offset)
    c = len(intact) // 2
    f.write_bytes(intact[:c])
    rep = bg.repair_bag(src)
    want = sum(1 for e in ends if e <= c)
    assert want > 1500 and rep.messages == want
    assert readable(src) == list(range(want))
    rb = McapReader(f)
    rb.open()
    (new,) = rb.chunks
    rb.close()
    data = f.read_bytes()
    t0, t1, usize, crc = struct.unpack_from("<QQQI", data, new.chunk_start_offset + 9)
    records = data[new.chunk_start_offset + 9 + 28 + 4 + 8 :][:usize]
    assert crc == zlib.crc32(records) != 0


def test_chunks_carry_crcs_and_a_flipped_byte_is_caught_on_read(tmp_path):
    """Chunks used to be written with CRC 0 ("none"): a flipped byte inside one was read
    silently by identify and replay. Oracle: zlib.crc32 of each chunk's records; rosbags'
    own reader then refuses the flipped file too."""
    src = tmp_path / "src"
    _chunked_bag(src)
    f = src / "src.mcap"
    data = f.read_bytes()
    reader = McapReader(f)
    reader.open()
    starts = [c.chunk_start_offset for c in reader.chunks]
    reader.close()
    for s0 in starts:
        _t0, _t1, usize, crc = struct.unpack_from("<QQQI", data, s0 + 9)
        records = data[s0 + 9 + 28 + 4 + 8 :][:usize]
        assert crc == zlib.crc32(records) and crc != 0
    s0 = starts[3]
    flipped = bytearray(data)
    flipped[s0 + 9 + 28 + 4 + 8 + 200] ^= 0x10
    f.write_bytes(bytes(flipped))
    with pytest.raises(BagError, match="[Cc]hecksum"):
        bg.read_bag(src)
    with pytest.raises(Exception, match="[Cc]hecksum"):
        readable(src)


def test_repaired_metadata_equals_what_rosbags_writes(tmp_path):
    """QoS profiles, type hashes and counts regenerated from the file match rosbags' own
    metadata.yaml of the same bag closed cleanly."""
    src = tmp_path / "src"
    _chunked_bag(src, n=120)
    want = yaml.safe_load((src / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    reader = McapReader(src / "src.mcap")
    reader.open()
    data_end = reader.data_end
    reader.close()
    raw = (src / "src.mcap").read_bytes()
    d = tmp_path / "d"
    d.mkdir()
    (d / "d.mcap").write_bytes(raw[:data_end])  # killed just before the summary
    assert bg.repair_bag(d).action == "storage"
    got = yaml.safe_load((d / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    for key in (
        "version",
        "storage_identifier",
        "message_count",
        "topics_with_message_count",
        "starting_time",
        "duration",
    ):
        assert got[key] == want[key], key
    assert readable(d) == list(range(120))


def test_out_of_order_stamps_survive_repair(tmp_path):
    stamps = [30, 10, 20, 10, 50, 40] * 50
    b = bg.BagWriter(tmp_path / "b", chunk_bytes=1500).open()
    b.add_topic("/e", JS)
    for k, s in enumerate(stamps):
        b.write("/e", T0 + s, joint(k, T0 + s))
    b.flush()
    b._writer.storage.bio.close()  # the process dies here
    b._reserve._fh.close()
    bg.repair_bag(tmp_path / "b")
    with AnyReader([tmp_path / "b"]) as reader:
        got = [t for _, t, _ in reader.messages()]
    assert got == sorted(T0 + s for s in stamps)


def test_dry_run_changes_nothing_and_live_writer_is_refused(tmp_path):
    b = bg.BagWriter(tmp_path / "b").open()
    b.add_topic("/e", JS)
    for k in range(50):
        b.write("/e", T0 + k, joint(k))
    b.flush()
    with pytest.raises(BagError, match=r"being written by a running process"):
        bg.repair_bag(tmp_path / "b")
    assert main(["bag", "repair", str(tmp_path / "b")]) == 2
    b._writer.storage.bio.close()  # dies
    b._reserve._fh.close()
    before = {p.name: p.read_bytes() for p in (tmp_path / "b").iterdir()}
    rep = bg.repair_bag(tmp_path / "b", dry_run=True)
    assert (rep.action, rep.messages, rep.dry_run) == ("storage", 50, True)
    assert {p.name: p.read_bytes() for p in (tmp_path / "b").iterdir()} == before
    assert main(["bag", "repair", "--dry-run", str(tmp_path / "b")]) == 0
    assert {p.name: p.read_bytes() for p in (tmp_path / "b").iterdir()} == before
    assert main(["bag", "repair", str(tmp_path / "b")]) == 0
    assert readable(tmp_path / "b") == list(range(50))


def test_repair_refuses_what_is_not_a_bag(tmp_path, capsys):
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "x.mcap").write_bytes(b"garbage!" * 100)
    with pytest.raises(BagError, match="not an mcap file .bad magic.; not repaired"):
        bg.repair_bag(tmp_path / "x")
    (tmp_path / "y").mkdir()
    assert main(["bag", "repair", str(tmp_path / "y")]) == 2
    assert "no .mcap or .db3 storage file" in capsys.readouterr().err


def test_repair_of_a_file_killed_before_its_header(tmp_path):
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "b.mcap").write_bytes(bg.MCAP_MAGIC[:5])
    rep = bg.repair_bag(tmp_path / "b")
    assert rep.messages == 0 and readable(tmp_path / "b") == []


# ----------------------------------------------------------------- sqlite3 hot journal
SPILL_CHILD = textwrap.dedent("""
    import sys
    import numpy as np
    sys.path.insert(0, {root!r})
    from lpv_sysid.io import bag as bg
    from lpv_sysid.io import messages as m
    F = m.MsgFactory.rosbags()
    b = bg.BagWriter({path!r}, storage="sqlite3", flush_messages=10**9, flush_interval_s=1e9)
    b.open()
    b.add_topic("/e", "sensor_msgs/msg/JointState")
    for k in range(200):
        b.write("/e", k, m.excitation_msg(F, k, np.full(4, float(k))))
    b.flush()
    for k in range(200, 3200):       # 30 MB in one open transaction: SQLite spills pages
        b.write_raw("/e", k, bytes(10000))
    print("ready", flush=True)
    sys.stdin.read()
""")


def test_sqlite_kill_inside_a_spilled_transaction_reads_only_committed_rows(tmp_path):
    path = tmp_path / "b"
    proc = subprocess.Popen(
        [sys.executable, "-c", SPILL_CHILD.format(root=ROOT, path=str(path))],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout.readline().strip() == "ready"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    journal = path / "b.db3-journal"
    assert journal.exists() and journal.stat().st_size > 0
    salvage = bg.read_bag(path, strict=False)  # rolls back in a copy: committed rows only
    assert len(salvage["/e"]) == 200
    assert any("hot journal" in p for p in salvage.problems)
    assert journal.exists()  # reading changed nothing
    rep = bg.repair_bag(path)
    assert rep.action == "storage" and rep.messages == 200
    assert "uncommitted transaction rolled back" in rep.summary()
    assert not journal.exists()
    assert readable(path) == list(range(200))


def _die(rec):
    """What kill -9 leaves of an in-process Recorder: files and locks dropped, nothing closed."""
    rec._writer._writer.storage.bio.close()
    rec._writer._reserve._fh.close()
    rec._lock._fh.close()


def test_cli_repairs_nested_experiments(tmp_path, capsys):
    """``lpv-sysid fly`` records DIR (runs) and DIR/flight (whole flight): both repaired."""
    clock = [0.0]
    outer = Recorder(
        RecorderConfig(out_dir=str(tmp_path / "x"), topics={"/a": JS}),
        writer_factory=sim_writer(clock),
    )
    outer.start(T0)
    inner = Recorder(
        RecorderConfig(out_dir=str(tmp_path / "x" / "flight"), topics={"/a": JS}),
        writer_factory=sim_writer(clock),
    )
    inner.start(T0)
    for k in range(1200):
        clock[0] = k * 1e-3
        outer.record("/a", T0 + k * 1_000_000, joint(k))
        inner.record("/a", T0 + k * 1_000_000, joint(k))
    _die(outer)
    _die(inner)
    assert main(["bag", "repair", str(tmp_path / "x")]) == 0
    printed = capsys.readouterr().out
    assert printed.count("status recording -> incomplete; 1002 message(s) readable") == 2
    for d in (tmp_path / "x", tmp_path / "x" / "flight"):
        assert readable(d / "bag_0000") == list(range(1002))
        assert meta_of(d)["topics"]["/a"]["count"] == 1002
