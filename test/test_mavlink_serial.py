"""The MAVLink link layer over a serial line: a pseudo-terminal pair (os.openpty), the link
on the slave side through pymavlink's ``mavserial`` (pyserial), a PX4-like peer on the
master side writing HEARTBEAT and telemetry with pymavlink. No hardware; every wait is
bounded (select with a timeout, a fixed number of tries)."""

from __future__ import annotations

import math
import os
import select
import tty

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

pytest.importorskip("serial")  # pyserial (ROS: python3-serial)

from lpv_sysid.mavlink import (
    codec,
    px4,  # noqa: E402
)
from lpv_sysid.mavlink.link import DEFAULT_STREAMS, LinkConfig, MavlinkLink  # noqa: E402
from lpv_sysid.mavlink.telemetry import (  # noqa: E402
    ImuSample,
    RotorSample,
    StateSample,
    TelemetryDecoder,
)

MOD = codec.dialect_module()
MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_PX4 = 2, 12


class Peer:
    """PX4 end of the line: system 1, component 1 (autopilot), MAVLink 2 on the pty master."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.written = 0
        self.tx = codec.make_codec(self, 1, 1)
        self.rx = codec.make_codec(None, 255, 0)
        self.received: list = []

    def write(self, data: bytes) -> None:  # pymavlink's "file": codec.send() lands here
        os.write(self.fd, bytes(data))
        self.written += len(data)

    def heartbeat(self) -> None:
        self.tx.send(
            self.tx.heartbeat_encode(
                MAV_TYPE_QUADROTOR,
                MAV_AUTOPILOT_PX4,
                px4.base_mode_flags(px4.POSCTL, False),
                px4.POSCTL.custom_mode,
                3,
            )
        )

    def read(self, until, tries: int = 50) -> list:
        """Parse what the link wrote until ``until(received)`` or ``tries`` x 0.1 s."""
        for _ in range(tries):
            if until(self.received):
                break
            if select.select([self.fd], [], [], 0.1)[0]:
                self.received += self.rx.parse_buffer(os.read(self.fd, 4096)) or []
        return self.received


def drain(link: MavlinkLink, peer: Peer, now: float, tries: int = 50) -> list:
    """Poll the link until it has read every byte the peer wrote (bounded)."""
    out: list = []
    for _ in range(tries):
        if link.stats.rx_bytes >= peer.written:
            break
        link.wait_readable(0.1)
        out += link.poll(now)
    return out


@pytest.fixture
def pty_pair():
    master, slave = os.openpty()
    tty.setraw(slave)  # pyserial also sets raw mode when it opens the device
    yield master, os.ttyname(slave)
    for fd in (master, slave):
        try:
            os.close(fd)
        except OSError:
            pass


def test_serial_link_over_pty_decodes_telemetry_survives_garbage_and_answers(pty_pair):
    master, path = pty_pair
    link = MavlinkLink(
        LinkConfig(url=f"serial://{path}:921600", heartbeat_period=0.1, link_timeout=0.5)
    )
    link.open(0.0)
    assert type(link.conn).__name__ == "mavserial"  # the pyserial path, not a socket
    peer = Peer(master)
    dec = TelemetryDecoder()
    rng = np.random.default_rng(5)
    samples, msgs, sent = [], [], 0
    last = None
    for k in range(25):  # 0.5 s of simulated time at 50 Hz
        t = 0.02 * k
        if k % 5 == 0:
            peer.heartbeat()
            sent += 1
        rot = Rotation.from_euler("ZYX", rng.uniform([-3, -0.5, -0.5], [3, 0.5, 0.5]))
        x, y, z, w = rot.as_quat()
        v_ned = rng.normal(0.0, 2.0, 3)
        acc, gyr = rng.normal(0.0, 3.0, 3), rng.normal(0.0, 0.5, 3)
        rpm = [int(r) for r in rng.integers(3000, 9000, 4)]
        ms, us = 1000 + 20 * k, (1000 + 20 * k) * 1000
        peer.tx.send(peer.tx.attitude_quaternion_encode(ms, w, x, y, z, 0.1, -0.2, 0.3, [0.0] * 4))
        peer.tx.send(peer.tx.local_position_ned_encode(ms, 1.0, 2.0, -3.0, *v_ned))
        peer.tx.send(
            peer.tx.highres_imu_encode(
                us, *acc, *gyr, 0.2, 0.0, 0.4, 1013.0, 0.0, 3.0, 25.0, 0x1FF, 0
            )
        )
        peer.tx.send(codec.esc_status_class()(0, us, rpm, [16.0] * 4, [1.0] * 4))
        sent += 4
        if k == 10:  # line noise without MAVLink magic bytes, then a cut-off packet's head
            noise = bytes(
                b for b in rng.integers(0, 256, 64, dtype=np.uint8) if b not in (0xFD, 0xFE)
            )
            peer.write(noise)
        if k == 15:
            buf = peer.tx.heartbeat_encode(2, 12, 0, 0, 3).pack(peer.tx)
            peer.write(buf[:7])  # header only: swallows what follows
        got = drain(link, peer, t)
        link.step(t)
        msgs += got
        for m in got:
            samples += dec.on_message(m, t)
        if k == 24:
            last = (rot, v_ned, acc, gyr, rpm)
    st = link.stats
    assert st.rx_bytes == peer.written
    assert st.bad_prefix >= 1 and st.bad_data >= 2  # the noise and the broken packet
    # every packet except those the truncated head swallowed (at most the next step's 4 + HB)
    assert sent - 5 <= st.rx_messages <= sent and len(msgs) == st.rx_messages
    assert link.link_up(0.48) and link.target_system == 1 and link.target_component == 1
    # the last step decoded exactly (float32 on the wire) against scipy
    rot, v_ned, acc, gyr, rpm = last
    s = [x for x in samples if isinstance(x, StateSample)][-1]
    np.testing.assert_allclose(s.v_body, rot.inv().apply(np.float32(v_ned)), atol=1e-5)
    np.testing.assert_allclose(s.euler[::-1], rot.as_euler("ZYX"), atol=1e-5)
    imu = [x for x in samples if isinstance(x, ImuSample)][-1]
    np.testing.assert_array_equal(imu.accel_frd, np.float32(acc))
    np.testing.assert_array_equal(imu.gyro_frd, np.float32(gyr))
    rot_s = [x for x in samples if isinstance(x, RotorSample)][-1]
    np.testing.assert_allclose(rot_s.omega, np.array(rpm) * 2 * math.pi / 60, rtol=1e-12)
    # what the link wrote back on the line: our HEARTBEAT and SET_MESSAGE_INTERVAL per stream
    want = {
        int(getattr(MOD, f"MAVLINK_MSG_ID_{n}", codec.MAVLINK_MSG_ID_ESC_STATUS)): r
        for n, r in DEFAULT_STREAMS
    }

    def complete(rx):
        return sum(m.get_type() == "COMMAND_LONG" for m in rx) >= len(want)

    rx = peer.read(complete)
    hb = [m for m in rx if m.get_type() == "HEARTBEAT"]
    assert hb and all(
        (m.get_srcSystem(), m.get_srcComponent(), m.type, m.autopilot) == (1, 191, 18, 8)
        for m in hb
    )
    cmds = [m for m in rx if m.get_type() == "COMMAND_LONG"]
    assert all(m.command == 511 and (m.target_system, m.target_component) == (1, 1) for m in cmds)
    assert {int(m.param1): m.param2 for m in cmds} == {
        mid: round(1e6 / r) for mid, r in want.items()
    }
    link.close()


def test_serial_link_loss_reopens_device_and_reports_dead_peer(pty_pair):
    master, path = pty_pair
    link = MavlinkLink(LinkConfig(url=f"{path}:57600", link_timeout=0.3, reconnect_period=0.5))
    link.open(0.0)
    peer = Peer(master)
    peer.heartbeat()
    drain(link, peer, 0.1)
    link.step(0.1)
    assert [e.kind for e in link.events()] == ["link_up"]
    # the autopilot goes quiet: link lost, then the device is reopened (serial reconnect)
    link.step(0.5)
    link.step(0.7)
    kinds = [e.kind for e in link.events()]
    assert kinds == ["link_lost", "reconnect"] and link.stats.reconnects == 1 and link.is_open
    peer.heartbeat()  # it talks again on the reopened port
    drain(link, peer, 0.8)
    link.step(0.8)
    assert link.link_up(0.8) and [e.kind for e in link.events()] == ["link_up"]
    # the other end hangs up (USB cable pulled): the read fails, the link closes, no raise
    os.close(master)
    for _ in range(20):
        link.wait_readable(0.05)
        link.poll(0.9)
        if not link.is_open:
            break
    ev = link.events()
    assert not link.is_open and ev and ev[0].kind == "io_error" and link.stats.io_errors == 1
    link.step(2.0)  # the pty is gone: the reopen attempt is reported, not raised
    ev = link.events()
    assert [e.kind for e in ev] == ["link_lost", "io_error"] and path in ev[1].detail
    assert not link.is_open and link.stats.reconnects == 1
    link.close()
