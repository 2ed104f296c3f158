"""MAVLink evidence only from the autopilot component (issue 25 item 3).

Mode/arming (HEARTBEAT), COMMAND_ACK and HOME_POSITION decide hand-back confirmations and the
envelope's floor, ceiling and geofence: only the target autopilot component
(MAV_COMP_ID_AUTOPILOT1 = 1 of the target system) is evidence. Another component of the
vehicle's system id (compid 2, e.g. a spoofer or a companion claiming to be an autopilot) is
not; ``target_system: 0`` does not pick one of several autopilots. Messages are encoded by
pymavlink codecs with the given (sysid, compid) and sent over UDP on 127.0.0.1 to a real
:class:`BridgeCore` (bounded polls).
"""

from __future__ import annotations

import socket
import time

from lpv_sysid.mavlink import codec, px4
from lpv_sysid.mavlink.bridge import BridgeConfig, BridgeCore
from lpv_sysid.mavlink.link import LinkConfig, free_udp_port

_TX: dict[tuple[int, int], object] = {}


def _bytes(name: str, *args, sysid: int = 1, compid: int = 1) -> bytes:
    c = _TX.setdefault((sysid, compid), codec.make_codec(None, sysid, compid))
    return getattr(c, f"{name}_encode")(*args).pack(c)


def _heartbeat(mode: px4.Px4Mode, armed: bool, sysid: int = 1, compid: int = 1) -> bytes:
    # MAV_TYPE_QUADROTOR (2), MAV_AUTOPILOT_PX4 (12), MAV_STATE_ACTIVE (4)
    flags = px4.base_mode_flags(mode, armed)
    return _bytes("heartbeat", 2, 12, flags, mode.custom_mode, 4, sysid=sysid, compid=compid)


def _home(x: float, y: float, z: float, sysid: int = 1, compid: int = 1) -> bytes:
    return _bytes(
        "home_position", 0, 0, 0, x, y, z, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0,
        sysid=sysid, compid=compid,
    )  # fmt: skip


def _ack(command: int, result: int, sysid: int = 1, compid: int = 1) -> bytes:
    return _bytes("command_ack", command, result, sysid=sysid, compid=compid)


class _Stand:
    """A BridgeCore on a free udpin port and a peer socket sending to it."""

    def __init__(self, target_system: int = 0) -> None:
        port = free_udp_port()
        link = LinkConfig(url=f"udpin:127.0.0.1:{port}", target_system=target_system)
        self.core = BridgeCore(BridgeConfig(link=link))
        self.core.open(0.0)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.addr = ("127.0.0.1", port)
        self.events: list = []

    def send(self, data: bytes, now: float) -> None:
        """Send one datagram and poll until the link has received it (bounded)."""
        before = self.core.link.stats.rx_datagrams
        self.sock.sendto(data, self.addr)
        for _ in range(2000):
            self.events += self.core.poll(now).events
            if self.core.link.stats.rx_datagrams > before:
                return
            time.sleep(0.001)
        raise AssertionError("datagram not received")

    def close(self) -> None:
        self.sock.close()
        self.core.close()


def test_heartbeat_of_another_component_is_no_mode_evidence():
    s = _Stand()
    try:
        s.send(_heartbeat(px4.OFFBOARD, True), 0.1)
        m = s.core.machine
        assert s.core.link.target_system == 1 and s.core.link.target_component == 1
        assert (m.vehicle_mode, m.armed) == (px4.OFFBOARD, True)
        # a spoofed HOLD, disarmed HEARTBEAT from component 2 of the vehicle's system id
        s.send(_heartbeat(px4.HOLD, False, compid=2), 0.2)
        assert (m.vehicle_mode, m.armed) == (px4.OFFBOARD, True)
        assert m._t_hb == 0.1  # the spoofed beat is not the newest evidence either
        # the autopilot's own HOLD is
        s.send(_heartbeat(px4.HOLD, False), 0.3)
        assert (m.vehicle_mode, m.armed, m._t_hb) == (px4.HOLD, False, 0.3)
    finally:
        s.close()


def test_home_position_and_ack_only_from_the_autopilot_component():
    s = _Stand()
    acks: list[tuple[int, int]] = []
    try:
        s.send(_heartbeat(px4.HOLD, False), 0.1)
        real_on_ack = s.core.machine.on_ack

        def on_ack(now, command, result):
            acks.append((command, result))
            return real_on_ack(now, command, result)

        s.core.machine.on_ack = on_ack  # type: ignore[method-assign]
        s.send(_home(200.0, 0.0, -200.0, compid=2), 0.2)  # spoofed 200 m away, 200 m up
        assert s.core.envelope.home_position is None
        s.send(_ack(176, 0, compid=2), 0.25)
        assert acks == []
        s.send(_home(1.0, 2.0, -0.5), 0.3)
        assert list(s.core.envelope.home_position) == [1.0, 2.0, -0.5]
        s.send(_ack(176, 0), 0.35)
        assert acks == [(176, 0)]
        # a foreign system's HOME_POSITION is no evidence either
        s.send(_home(-300.0, 0.0, 0.0, sysid=42), 0.4)
        assert list(s.core.envelope.home_position) == [1.0, 2.0, -0.5]
    finally:
        s.close()


def test_target_system_0_refuses_when_two_autopilots_are_heard():
    s = _Stand(target_system=0)
    try:
        s.send(_heartbeat(px4.HOLD, False, sysid=42), 0.1)  # a foreign autopilot first
        assert s.core.link.link_up(0.1)
        s.send(_heartbeat(px4.HOLD, False, sysid=1), 0.2)
        assert s.core.link.ambiguous_target and not s.core.link.link_up(0.2)
        kinds = [getattr(e, "kind", None) for e in s.events]
        assert "ambiguous_target" in kinds
        assert s.core.telemetry.target is None or not s.core.link.link_up(0.3)
        # stays refused: more beats of either change nothing
        s.send(_heartbeat(px4.OFFBOARD, True, sysid=42), 0.3)
        assert not s.core.link.link_up(0.3)
        assert not s.core.link.from_autopilot(s.core.link.last_heartbeat)
    finally:
        s.close()


def test_explicit_target_system_ignores_a_foreign_autopilot():
    s = _Stand(target_system=1)
    try:
        s.send(_heartbeat(px4.OFFBOARD, True, sysid=42), 0.1)
        assert not s.core.link.link_up(0.1)
        assert s.core.machine.vehicle_mode != px4.OFFBOARD
        s.send(_heartbeat(px4.HOLD, False, sysid=1), 0.2)
        assert s.core.link.link_up(0.2) and s.core.machine.vehicle_mode == px4.HOLD
        s.send(_heartbeat(px4.OFFBOARD, True, sysid=1, compid=2), 0.3)
        assert s.core.machine.vehicle_mode == px4.HOLD
    finally:
        s.close()


def test_preflight_says_no_go_for_an_ambiguous_target():
    from lpv_sysid.mavlink.preflight import NOGO, judge

    s = _Stand(target_system=0)
    try:
        s.send(_heartbeat(px4.HOLD, False, sysid=42), 0.1)
        s.send(_heartbeat(px4.HOLD, False, sysid=1), 0.2)
        (check,) = judge(s.core.link.last_heartbeat, None, {}, set(), link=s.core.link)
        assert check.verdict == NOGO and "systems [1, 42]" in check.value
    finally:
        s.close()
