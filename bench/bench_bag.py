"""rosbag2 reading and writing (io/bag; issue 15 rows "bag read (typed topics)", "bag
write in bulk", and the bag side of "identify (9 bags)").

    .venv/bin/python -m bench.bench_bag

Bag: one phase-1 run as ``simulate phase1`` writes it (40 s, mcap, 44 040 messages;
typed topics = state, rotor_speeds, imu, velocity_reference, actuator_command).

* ``read_arrays`` (column-wise, the fixed-layout block decode) against the floor: the same
  records already in memory, joined per topic and decoded with one numpy structured view;
* ``read_bag`` (message objects, constructed from the decoded columns) against rosbags'
  AnyReader + ``deserialize_cdr`` per message (what read_bag did before);
* ``topic_info`` from the mcap summary and message indexes against the record walk;
* writing: ``BagWriter.write`` per message, ``write_many`` of finished records.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from bench.harness import Page, Row, interleaved, load_average, status

TYPED = ("state", "rotor_speeds", "imu", "velocity_reference", "actuator_command")


def main() -> None:
    from lpv_sysid.control.baseline import BaselineGains
    from lpv_sysid.io import bag as bg
    from lpv_sysid.io import messages
    from lpv_sysid.io.bag import collect, records
    from lpv_sysid.io.bag.cdr import layout
    from lpv_sysid.io.bag.mcap import index as mcap_index
    from lpv_sysid.models.quadrotor import Quadrotor
    from lpv_sysid.sim import phase1
    from lpv_sysid.sim.phase1 import bag as phase1_bag
    from lpv_sysid.sim.vehicle import SensorConfig

    load0 = load_average()
    page = Page("bag", "rosbag2 I/O (io/bag, issue 15)", ".venv/bin/python -m bench.bench_bag")
    cfg = replace(phase1.Phase1Config(), hover_validation=False)
    rec = phase1.run_phase1(Quadrotor(), BaselineGains(), SensorConfig(), cfg, [8])[0]
    root = Path(tempfile.mkdtemp(prefix="bench_bag_"))
    try:
        path = phase1.write_run_bag(rec, root / "run")
        topics = [f"/lpv_sysid/{t}" for t in TYPED]
        info = bg.topic_info(path)
        n_typed = sum(info[t].count for t in topics)
        n_all = sum(s.count for s in info.values())
        # floor: the records in memory, one join + one structured view per topic
        src = records._Source()
        mcap_index._read_fast(path, set(topics), src)
        per = {}
        for t, _ns, d in src.records:
            per.setdefault(t, []).append(bytes(d))
        ts = bg.jazzy_typestore()
        lays = {t: layout._LAYOUTS.for_record(ts, info[t].msgtype, v[0]) for t, v in per.items()}

        def floor():
            for t, v in per.items():
                lays[t].decode(np.frombuffer(b"".join(v), np.uint8).reshape(len(v), -1))

        def before():
            from rosbags.highlevel import AnyReader

            with AnyReader([path], default_typestore=ts) as r:
                conns = [c for c in r.connections if c.topic in topics]
                for c, _ns, data in r.messages(connections=conns):
                    ts.deserialize_cdr(data, c.msgtype)

        st = interleaved(
            {"arrays": lambda: bg.read_arrays(path, topics=topics), "floor": floor},
            number=1,
            repeat=9,
            clock=time.process_time,
        )
        rb = interleaved(
            {"read_bag": lambda: bg.read_bag(path, topics=topics)},
            number=1,
            repeat=5,
            clock=time.process_time,
        )["read_bag"]
        old = interleaved({"before": before}, number=1, repeat=2, clock=time.process_time)[
            "before"
        ]
        ti = interleaved(
            {
                "index": lambda: bg.topic_info(path),
                "walk": lambda: collect._collect(path, None, True),
            },
            number=1,
            repeat=5,
            clock=time.process_time,
        )
        # writing
        f = messages.MsgFactory.rosbags()
        items = phase1_bag._message_items(rec, f)[:6000]
        rows = [
            (f"/lpv_sysid/{n}", s, bytes(ts.serialize_cdr(m, messages.TYPES[n])))
            for s, n, m in items
        ]
        k = [0]

        def write_each():
            k[0] += 1
            with bg.BagWriter(root / f"w{k[0]}") as w:
                for n in phase1.BAG_TOPICS:
                    w.add_topic(f"/lpv_sysid/{n}", messages.TYPES[n])
                for s, n, m in items:
                    w.write(f"/lpv_sysid/{n}", s, m)

        def write_many():
            k[0] += 1
            with bg.BagWriter(root / f"w{k[0]}") as w:
                for n in phase1.BAG_TOPICS:
                    w.add_topic(f"/lpv_sysid/{n}", messages.TYPES[n])
                w.write_many(rows)

        wr = interleaved(
            {"write": write_each, "many": write_many}, number=1, repeat=3, clock=time.process_time
        )
    finally:
        shutil.rmtree(root, ignore_errors=True)
    rate = n_typed / st["arrays"].median
    frate = n_typed / st["floor"].median
    ratio = st["arrays"].median / st["floor"].median
    page.add(f"## Reading ({n_all} messages, {n_typed} on the typed topics; CPU time per read)")
    page.add()
    page.table(
        ["what", "median [p10-p90]", "msgs/s"],
        [
            [
                "`read_arrays(typed topics)` (mcap index gather + block decode)",
                st["arrays"].fmt(1e3, "ms"),
                f"{rate:,.0f}",
            ],
            [
                "floor: records in memory, `np.frombuffer` + one structured view per topic",
                st["floor"].fmt(1e3, "ms"),
                f"{frate:,.0f}",
            ],
            [
                "`read_bag(typed topics)` (message objects from the decoded columns)",
                rb.fmt(1e3, "ms"),
                f"{n_typed / rb.median:,.0f}",
            ],
            [
                "before: rosbags AnyReader + `deserialize_cdr` per message",
                old.fmt(1e3, "ms"),
                f"{n_typed / old.median:,.0f}",
            ],
            ["`topic_info` (summary + message indexes)", ti["index"].fmt(1e3, "ms"), ""],
            ["`topic_info` before (every record read to count)", ti["walk"].fmt(1e3, "ms"), ""],
        ],
    )
    n_w = len(rows)
    page.add(f"## Writing ({n_w} messages of the phase-1 mix, mcap; CPU time)")
    page.add()
    page.table(
        ["what", "median [p10-p90]", "msgs/s"],
        [
            [
                "`BagWriter.write` per message (rosbags CDR serialisation + store)",
                wr["write"].fmt(1, "s"),
                f"{n_w / wr['write'].median:,.0f}",
            ],
            [
                "`BagWriter.write_many` of finished records (what `write_run_bag` uses)",
                wr["many"].fmt(1, "s"),
                f"{n_w / wr['many'].median:,.0f}",
            ],
        ],
    )
    page.rows.append(
        Row(
            "bag read (typed topics)",
            "15",
            f"`read_arrays` {rate:,.0f} msgs/s; `read_bag` {n_typed / rb.median:,.0f} msgs/s "
            f"(before {n_typed / old.median:,.0f}); "
            f"`topic_info` {ti['index'].median * 1e3:.1f} ms "
            f"(before {ti['walk'].median * 1e3:.0f} ms)",
            f"numpy block decode {frate:,.0f} msgs/s",
            f"{ratio:.2f}x",
            ">= 500k msgs/s",
            status(rate >= 5e5),
            order=9,
        )
    )
    page.write(load0)


if __name__ == "__main__":
    main()
