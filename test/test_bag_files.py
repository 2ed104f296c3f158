"""Hostile paths inside a bag (issue 14 B): a FIFO, a device or a symlink to one in place of
``metadata.yaml``, a storage file, a sqlite3 journal, the writer's lock file or the
``.tmp`` of an atomic write is refused with a BagError naming that file -- never opened,
so never a hang.

Every call runs in a daemon thread with a deadline (a regression would block in ``open``
of the FIFO); the FIFO is then opened for writing once, which releases such a blocked
reader, so the test fails instead of hanging.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

import numpy as np
import pytest

from lpv_sysid.errors import BagError
from lpv_sysid.io import bag as bg
from lpv_sysid.io import messages as m
from lpv_sysid.io.files import atomic_write_text

F = m.MsgFactory.rosbags()
T0 = 1_700_000_000_000_000_000
JS = "sensor_msgs/msg/JointState"
DEADLINE_S = 20.0


def write_bag(path: Path, storage: str = "mcap", n: int = 5) -> Path:
    with bg.BagWriter(path, storage) as w:
        w.add_topic("/e", JS)
        for k in range(n):
            w.write("/e", T0 + k * 1_000_000, m.excitation_msg(F, T0, np.full(4, float(k))))
    return path


def fifo_instead_of(path: Path) -> Path:
    path.unlink()
    os.mkfifo(path)
    return path


def bounded(fn, *fifos: Path):
    """``fn()`` in a daemon thread: its result, or the exception it raised; fails when it is
    still running after the deadline (and then unblocks it through the FIFOs)."""
    box: dict = {}

    def run():
        try:
            box["value"] = fn()
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            box["error"] = exc

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(DEADLINE_S)
    if t.is_alive():
        for f in fifos:  # a reader blocked in open() of a FIFO returns once a writer appears
            try:
                os.close(os.open(f, os.O_WRONLY | os.O_NONBLOCK))
            except OSError:
                pass
        t.join(DEADLINE_S)
        pytest.fail(f"{fn} still blocked after {DEADLINE_S} s (opened a FIFO?)")
    if "error" in box:
        return box["error"]
    return box["value"]


def refused(fn, bad: Path, *fifos: Path) -> BagError:
    got = bounded(fn, *(fifos or (bad,)))
    assert isinstance(got, BagError), got
    text = str(got)
    assert str(bad) in text, text
    return got


READERS = {
    "read_bag": lambda p: bg.read_bag(p),
    "read_arrays": lambda p: bg.read_arrays(p),
    "topic_info": lambda p: bg.topic_info(p),
    "repair_bag": lambda p: bg.repair_bag(p),
}


@pytest.mark.parametrize("reader", sorted(READERS))
def test_fifo_as_metadata_yaml_is_refused(tmp_path, reader):
    bag = write_bag(tmp_path / "b")
    meta = fifo_instead_of(bag / "metadata.yaml")
    exc = refused(lambda: READERS[reader](bag), meta)
    assert "FIFO" in str(exc)
    assert isinstance(exc, bg.UnsafeBagFile)


@pytest.mark.parametrize("reader", sorted(READERS))
@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_fifo_as_storage_file_is_refused(tmp_path, reader, storage):
    bag = write_bag(tmp_path / "b", storage)
    (f,) = [p for p in bag.iterdir() if p.suffix in (".mcap", ".db3")]
    fifo = fifo_instead_of(f)
    exc = refused(lambda: READERS[reader](bag), fifo)
    assert "FIFO" in str(exc)


@pytest.mark.parametrize("reader", ["read_bag", "read_arrays", "topic_info"])
def test_fifo_given_as_the_bag_file_is_refused(tmp_path, reader):
    fifo = tmp_path / "x.mcap"
    os.mkfifo(fifo)
    refused(lambda: READERS[reader](fifo), fifo)


def test_symlink_to_a_device_as_metadata_is_refused(tmp_path):
    bag = write_bag(tmp_path / "b")
    (bag / "metadata.yaml").unlink()
    (bag / "metadata.yaml").symlink_to("/dev/zero")
    exc = refused(lambda: bg.read_bag(bag), bag / "metadata.yaml")
    assert "character device" in str(exc)


def test_fifo_as_sqlite_journal_is_refused(tmp_path):
    bag = write_bag(tmp_path / "b", "sqlite3")
    (db,) = bag.glob("*.db3")
    journal = db.with_name(db.name + "-journal")
    os.mkfifo(journal)
    for fn in (lambda: bg.read_bag(bag), lambda: bg.repair_bag(bag)):
        refused(fn, journal)


def test_tolerant_read_leaves_the_fifo_out_and_reads_the_rest(tmp_path):
    """strict=False: a FIFO metadata.yaml is a problem, the healthy mcap is still read."""
    bag = write_bag(tmp_path / "b", n=7)
    meta = fifo_instead_of(bag / "metadata.yaml")
    got = bounded(lambda: bg.read_bag(bag, strict=False), meta)
    assert not isinstance(got, BaseException), got
    assert [int(msg.position[0]) for _, msg in got["/e"]] == list(range(7))
    assert any(str(meta) in p and "FIFO" in p for p in got.problems), got.problems
    arr = bounded(lambda: bg.read_arrays(bag, strict=False), meta)
    assert not isinstance(arr, BaseException), arr
    assert arr["/e"].fields["position"][:, 0].tolist() == [float(k) for k in range(7)]


def test_fifo_as_lock_file_does_not_block_repair(tmp_path):
    """writer_alive() used to open the lock file for reading: a FIFO there blocked it."""
    bag = write_bag(tmp_path / "b")
    lock = bag / bg.LOCK_FILE
    os.mkfifo(lock)
    assert bounded(lambda: bg.writer_alive(lock), lock) is True  # cannot be ours: no repair
    refused(lambda: bg.repair_bag(bag), lock)


def test_atomic_write_replaces_a_fifo_left_at_its_tmp_name(tmp_path):
    """atomic_write_text used to open path.tmp for writing: a FIFO there blocked it."""
    target = tmp_path / "metadata.yaml"
    tmp = tmp_path / "metadata.yaml.tmp"
    os.mkfifo(tmp)
    got = bounded(lambda: atomic_write_text(target, "a: 1\n"), tmp)
    assert got is None
    assert target.read_text() == "a: 1\n"
    assert not tmp.exists()


def test_atomic_write_does_not_follow_a_symlink_at_its_tmp_name(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("keep")
    (tmp_path / "out.yaml.tmp").symlink_to(victim)
    atomic_write_text(tmp_path / "out.yaml", "new\n")
    assert victim.read_text() == "keep"
    assert (tmp_path / "out.yaml").read_text() == "new\n"


def test_healthy_bag_reads_as_before(tmp_path):
    """The screening changes nothing for regular files (also behind a symlink)."""
    bag = write_bag(tmp_path / "b", n=4)
    real = tmp_path / "elsewhere.mcap"
    (f,) = bag.glob("*.mcap")
    f.rename(real)
    f.symlink_to(real)
    assert [int(x.position[0]) for _, x in bg.read_bag(bag)["/e"]] == [0, 1, 2, 3]
    assert bg.topic_info(bag)["/e"].count == 4


def test_fifo_as_recorder_lock_does_not_block_experiment_repair(tmp_path):
    from lpv_sysid.io.recorder import LOCK_FILE, Recorder, RecorderConfig, repair_experiment

    out = tmp_path / "exp"
    rec = Recorder(RecorderConfig(out_dir=str(out), topics={"/e": JS}))
    rec.start(T0)
    for k in range(3):
        rec.record("/e", T0 + k, m.excitation_msg(F, T0 + k, np.full(4, float(k))))
    rec.stop(T0 + 3)
    lock = out / LOCK_FILE
    os.mkfifo(lock)
    exc = refused(lambda: repair_experiment(out), lock)
    assert "FIFO" in str(exc)
