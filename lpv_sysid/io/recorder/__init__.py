"""Data-logger core: records topics to numbered rosbag2 directories with experiment metadata.

Layout of an experiment directory ``out``::

    out/experiment.yaml        metadata (config files, gains sha256, git revision, times,
                               per-topic counts / rates / drops, bags, clean close, error)
    out/bag_0000/              rosbag2 (mcap by default) written by io/bag.BagWriter
    out/bag_0001/              next split (size or duration limit reached)

Messages arrive as rosbags message objects or as serialized CDR bytes (the node shell
subscribes with ``raw=True``; bytes go to the bag untouched, as ``ros2 bag record`` does).
Durability. The bags are flushed at a bounded interval (``flush_interval_s`` <= 1 s,
``flush_messages``: :class:`~lpv_sysid.io.bag.BagWriter`), so a ``kill -9`` loses at most
that much. ``experiment.yaml`` is written atomically (temporary file + rename, no ``.tmp``
left behind) at start, at every flush, at every split and at stop, and is truthful at
every moment: ``status`` is ``recording`` / ``incomplete`` (ended by an error, or found
interrupted) / ``closed_cleanly``, and every count in it is what is on disk (committed),
never more. While recording, ``out/.lpv_sysid_recording`` is locked (``flock``; the lock
dies with the process) and holds a disk reserve for the metadata on a full disk. A write
error (disk full, ...) closes the current bag so what was written stays readable, is
recorded in the metadata (``status: incomplete``, ``error``) and raised as
:class:`~lpv_sysid.errors.BagError`. A recording whose process was killed is made
readable by :func:`repair_experiment` (``lpv-sysid bag repair OUT``), which also runs when
a recorder is started on that directory again.

Parts: :mod:`~lpv_sysid.io.recorder.config` (what to record),
:mod:`~lpv_sysid.io.recorder.metadata` (the counts and ``experiment.yaml``),
:mod:`~lpv_sysid.io.recorder.signals` (SIGINT/SIGTERM); this module is the recording lifecycle
(:class:`Recorder`).
"""

from __future__ import annotations

from lpv_sysid.io.recorder.config import RecorderConfig
from lpv_sysid.io.recorder.experiment import LOCK_FILE, METADATA_FILE, repair_experiment
from lpv_sysid.io.recorder.recorder import Recorder

__all__ = [
    "LOCK_FILE",
    "METADATA_FILE",
    "Recorder",
    "RecorderConfig",
    "repair_experiment",
]
