"""rosbag2 recordings (mcap by default, sqlite3 optional) through rosbags 0.11.9.

This package is the only owner of the bag format: writing, reading, salvaging and
repairing. One module per job:

=========================  ===============================================================
module                     job
=========================  ===============================================================
:mod:`.writer`             :class:`BagWriter`: topics, messages, bulk writes, flushes
:mod:`.writer_recovery`    what a writer saves after a write error (disk full)
:mod:`.durability`         the writer's lock and disk reserve, :func:`writer_alive`
:mod:`.typestore`          the Jazzy typestore, QoS profiles, stored definitions
:mod:`.cdr.layout`         the CDR block codec (:class:`CdrLayout`, :func:`encode_block`)
:mod:`.records`            what the readers return (:class:`TopicStats`, ...)
:mod:`.reader`             :func:`read_bag` (message objects), :func:`topic_info`
:mod:`.arrays`             :func:`read_arrays` (numpy columns)
:mod:`.cdr.builder`        message objects from decoded columns
:mod:`.collect`            raw records of any bag (index, rosbags, salvage)
:mod:`.mcap.index`         a healthy mcap bag through its summary and message indexes
:mod:`.mcap.records`       MCAP record primitives
:mod:`.mcap.walk`          the record walk (salvage parser) of an unfinished mcap file
:mod:`.mcap.repair`        in-place repair of an mcap file
:mod:`.sqlite`             damaged sqlite3 files: salvage, roll-back, repair
:mod:`.metadata`           ``metadata.yaml``: read, screened, compared, written after a repair
:mod:`.repair`             :func:`repair_bag` (``lpv-sysid bag repair DIR``)
:mod:`.bagfiles`           the files of a bag and how they are opened (no FIFO, no device)
=========================  ===============================================================

Writing: ``with BagWriter(path) as bag: bag.add_topic(...); bag.write(...)``; messages are
CDR-serialised with the ROS 2 Jazzy typestore, each topic registered with its message
definition, RIHS01 type hash and offered QoS, so ``ros2 bag info`` / ``ros2 bag play``
accept the result. A killed writer loses at most ``flush_interval_s`` of data and a full
disk still leaves a readable bag (:mod:`.writer`).

Reading: :func:`read_bag` returns ``{topic: [(stamp_ns, msg), ...]}``, :func:`read_arrays`
the same records column-wise (``{topic: TopicArrays}``: one numpy array per numeric field,
e.g. ``fields["pose.pose.position.x"]``), :func:`topic_info` counts and time spans, all in
bag-timestamp order. The fast paths (index reader, block codec) give values identical to
rosbags' (checked in test_bag_codec.py); whatever they do not recognise goes through
``AnyReader``. ``strict=False`` recovers what a damaged bag still holds. Every file of a
bag is screened before it is opened: a FIFO or device in place of ``metadata.yaml`` or a
storage file is a :class:`BagError` naming it, never a hang (:mod:`.bagfiles`).

Repair: :func:`repair_bag` makes a killed or starved recording readable by standard tools
(:mod:`.repair`); nothing that was complete on disk is dropped: the complete records of an
mcap chunk the cut went through are re-chunked. mcap chunks are written with their CRC
(:func:`~lpv_sysid.io.bag.mcap.write_chunk_crcs`), which every reader checks.
"""

from __future__ import annotations

from lpv_sysid.io.bag.arrays import read_arrays
from lpv_sysid.io.bag.bagfiles import UnsafeBagFile
from lpv_sysid.io.bag.cdr import CdrLayout, LayoutError, encode_block, records_close
from lpv_sysid.io.bag.durability import (
    LOCK_FILE,
    RESERVE_BYTES,
    DiskReserve,
    now_iso,
    writer_alive,
)
from lpv_sysid.io.bag.mcap import MCAP_MAGIC
from lpv_sysid.io.bag.reader import read_bag, topic_info
from lpv_sysid.io.bag.records import merge_topic_stats
from lpv_sysid.io.bag.repair import RepairReport, repair_bag
from lpv_sysid.io.bag.typestore import jazzy_typestore
from lpv_sysid.io.bag.writer import FLUSH_INTERVAL_S, FLUSH_MESSAGES, STORAGES, BagWriter

__all__ = [
    "BagWriter",
    "CdrLayout",
    "DiskReserve",
    "FLUSH_INTERVAL_S",
    "FLUSH_MESSAGES",
    "LOCK_FILE",
    "LayoutError",
    "MCAP_MAGIC",
    "RESERVE_BYTES",
    "RepairReport",
    "STORAGES",
    "UnsafeBagFile",
    "encode_block",
    "jazzy_typestore",
    "merge_topic_stats",
    "now_iso",
    "read_arrays",
    "read_bag",
    "records_close",
    "repair_bag",
    "topic_info",
    "writer_alive",
]
