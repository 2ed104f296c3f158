"""The struct-based MAVLink fast path of mavlink/link/connection.py against pymavlink itself: the
same message objects (every attribute), the same link statistics and codec counters, on round
trips of every fast message type and on corrupted, cut, concatenated and foreign packets."""

from __future__ import annotations

import os
import random

import numpy as np
import pytest

from lpv_sysid.mavlink import codec
from lpv_sysid.mavlink.link import FAST_MESSAGES, FastDecoder, LinkConfig, MavlinkLink, x25_crc

MOD = codec.dialect_module()


def packets(n: int, seed: int = 0, system: int = 1, component: int = 1) -> list[bytes]:
    """n MAVLink 2 packets of every FAST_MESSAGES type with random field values (zero
    fields make MAVLink 2 truncate the payload), plus a few other ids."""
    rng = np.random.default_rng(seed)
    tx = codec.make_codec(None, system, component)
    esc = codec.esc_status_class()

    def f(k=None, zero=False):
        v = rng.normal(size=k) * 10
        return (np.zeros(k) if k else 0.0) if zero else (v.tolist() if k else float(v))

    out = []
    for i in range(n):
        z = i % 4 == 0
        k = i % 11
        if k == 0:
            m = tx.heartbeat_encode(2, 12, 81, int(rng.integers(0, 2**31)), 4)
        elif k == 1:
            m = tx.attitude_encode(i, f(), f(), f(), f(), f(), f())
        elif k == 2:
            m = tx.attitude_quaternion_encode(i, f(), f(), f(), f(), f(), f(), f(), f(4, z))
        elif k == 3:
            m = tx.local_position_ned_encode(i, f(), f(), f(), f(), f(), f())
        elif k == 4:
            m = tx.highres_imu_encode(
                i * 1000, *[f() for _ in range(12)], 0x1FF if not z else 0, i % 3
            )
        elif k == 5:
            m = tx.odometry_encode(
                i * 1000,
                1,
                12,
                f(),
                f(),
                f(),
                f(4),
                f(),
                f(),
                f(),
                f(),
                f(),
                f(),
                f(21, z),
                f(21, z),
                i % 7,
                0,
                50,
            )
        elif k == 6:
            m = tx.servo_output_raw_encode(
                i,
                i % 2,
                *[int(x) for x in rng.integers(900, 2000, 8)],
                *([0] * 8 if z else [int(x) for x in rng.integers(0, 2000, 8)]),
            )
        elif k == 7:
            m = tx.actuator_output_status_encode(i * 1000, 8, f(32, z))
        elif k == 8:
            m = esc(
                i % 2 * 4, i * 1000, [int(x) for x in rng.integers(-9000, 9000, 4)], f(4), f(4, z)
            )
        elif k == 9:
            m = tx.sys_status_encode(
                1, 1, 1, 500, 12000, -1, 50, 0, 0, 0, 0, 0, 0
            )  # not a fast id
        else:
            m = tx.statustext_encode(4, b"hello %d" % i)  # char[] field
        out.append(m.pack(tx))
        tx.seq = (tx.seq + 1) % 256
    return out


def link(fast: bool = True) -> MavlinkLink:
    lk = MavlinkLink(LinkConfig(url="udpin:127.0.0.1:1"))
    lk.codec = codec.make_codec(None, 2, 1)
    if not fast:
        lk._no_fast = lk.codec  # pymavlink for everything
    return lk


def same_message(a, b) -> bool:
    if type(a) is not type(b) or list(a.__dict__) != list(b.__dict__):
        return False
    for k, v in a.__dict__.items():
        w = b.__dict__[k]
        if k == "_header":
            if (
                type(v) is not type(w)
                or v.__dict__ != w.__dict__
                or list(v.__dict__) != list(w.__dict__)
            ):
                return False
        elif type(v) is not type(w) or v != w:
            return False
    return True


def feed_all(lk: MavlinkLink, datagrams) -> list:
    out: list = []
    for i, d in enumerate(datagrams):
        lk.feed(d, 0.001 * i, out)
    return out


def assert_same_as_pymavlink(datagrams) -> MavlinkLink:
    fast, slow = link(True), link(False)
    a, b = feed_all(fast, datagrams), feed_all(slow, datagrams)
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert same_message(x, y), (x, y)
    assert fast.stats == slow.stats
    for attr in ("total_packets_received", "total_bytes_received", "total_receive_errors"):
        assert getattr(fast.codec, attr) == getattr(slow.codec, attr), attr
    assert fast._counts == slow._counts and fast._last_seq == slow._last_seq
    assert (fast.target_system, fast.last_heartbeat_t) == (
        slow.target_system,
        slow.last_heartbeat_t,
    )
    return fast


def test_x25_crc_is_pymavlinks():
    rng = random.Random(3)
    for n in range(0, 300, 7):
        data = bytes(rng.randrange(256) for _ in range(n))
        extra = rng.randrange(256)
        assert x25_crc(data) == MOD.x25crc(bytearray(data)).crc
        assert x25_crc(data, extra) == MOD.x25crc(bytearray(data + bytes([extra]))).crc


def test_every_fast_type_round_trips_exactly():
    pk = packets(330)
    lk = assert_same_as_pymavlink(pk)
    assert lk._fast is not None
    names = {
        MOD.mavlink_map[i].msgname if i in MOD.mavlink_map else "ESC_STATUS"
        for i in lk._fast.specs
    }
    assert names == set(FAST_MESSAGES)
    # several packets per datagram, and a datagram with foreign ids in the middle
    assert_same_as_pymavlink([b"".join(pk[i : i + 7]) for i in range(0, len(pk), 7)])
    # a second source system: its own sequence tracking
    mixed = [p for pair in zip(packets(60, 1, 1, 1), packets(60, 2, 7, 3)) for p in pair]
    lk = assert_same_as_pymavlink(mixed)
    assert set(lk._last_seq) == {(1, 1), (7, 3)}


def test_corrupted_packets_are_pymavlinks_business():
    rng = random.Random(9)
    good = packets(400, seed=4)
    bad = []
    for i, p in enumerate(good):
        b = bytearray(p)
        kind = i % 8
        if kind == 0:  # bit flip anywhere (CRC, header, length, payload)
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
        elif kind == 1:  # cut
            b = b[: rng.randrange(1, len(b))]
        elif kind == 2:  # junk before
            b = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 9))) + b
        elif kind == 3:  # two packets, the first damaged
            c = bytearray(good[(i + 1) % len(good)])
            c[-1] ^= 0xFF
            b = bytes(c) + b
        elif kind == 4:  # signed flag set (no signature block)
            b[2] |= 0x01
        elif kind == 5:  # MAVLink 1 marker
            b[0] = 0xFE
        bad.append(bytes(b))
    lk = assert_same_as_pymavlink(bad)
    st = lk.stats
    assert st.bad_crc > 0 and st.bad_prefix > 0 and st.truncated > 0
    # a stream transport (TCP, serial): packets split across reads
    stream = b"".join(bad)
    chunks = [stream[i : i + 53] for i in range(0, len(stream), 53)]
    fast, slow = link(True), link(False)
    fast._device = slow._device = "tcp:127.0.0.1:1"
    a, b = feed_all(fast, chunks), feed_all(slow, chunks)
    assert len(a) == len(b) and all(same_message(x, y) for x, y in zip(a, b))
    assert fast.stats == slow.stats


def test_no_fast_path_with_signing_or_callbacks():
    lk = link(True)
    codec.setup_signing(lk.codec, os.urandom(32), allow_unsigned=True)
    assert lk._fast_decoder() is None
    lk2 = link(True)
    lk2.codec.set_callback(lambda m: None)
    assert lk2._fast_decoder() is None
    lk3 = link(True)
    assert isinstance(lk3._fast_decoder(), FastDecoder)


def test_decoder_stops_at_the_first_packet_it_does_not_handle():
    pk = packets(22, seed=2)
    fd = FastDecoder(codec.make_codec(None, 2, 1), MOD)
    data = b"".join(pk[:9]) + pk[9] + b"".join(pk[11:15])  # pk[9] is SYS_STATUS
    out, counts, seqs = [], {}, {}
    pos, got, lost, beats = fd.decode(data, out, counts, seqs)
    assert pos == sum(len(p) for p in pk[:9]) and got == 9 and lost == 0 and len(beats) == 1
    broken = bytearray(pk[2])
    broken[-2] ^= 0x01
    assert fd.decode(bytes(broken), [], {}, {})[0] == 0


@pytest.mark.parametrize("name", ["ATTITUDE_QUATERNION", "HIGHRES_IMU", "ESC_STATUS"])
def test_messages_are_usable_like_pymavlinks(name):
    pk = [p for p in packets(120, seed=5)]
    fast = feed_all(link(True), pk)
    slow = feed_all(link(False), pk)
    for a, b in zip(fast, slow):
        if a.get_type() == name:
            assert a.to_dict() == b.to_dict()
            assert a.get_msgbuf() == b.get_msgbuf() and a.get_crc() == b.get_crc()
            assert (a.get_srcSystem(), a.get_seq()) == (b.get_srcSystem(), b.get_seq())
