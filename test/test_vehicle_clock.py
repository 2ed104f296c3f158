"""Samples carry their sample time on the receiver's clock (issue 27 item 3's root cause):
a link poll that runs late reads a backlog of states at once; stamped with the poll's
clock they shared one stamp and looked fresh (real Jazzy: runs of 10+ states with one
stamp, up to 250 ms late). Oracle: the messages' own PX4 times and the receipt times the
test chooses (exact binary fractions, so equalities are exact)."""

from __future__ import annotations

import math

from lpv_sysid.mavlink.telemetry import TelemetryDecoder, VehicleClock
from lpv_sysid.mavlink.telemetry.clock import CATCH_UP, LIVE_RISE, MAX_AGE_S

from test_telemetry_hygiene import BOOT, att_q, lpos


def test_lower_envelope_rise_reset_and_other_time_base():
    c = VehicleClock()
    assert c.local(5.0, 7.0) == 7.0  # no estimate yet: the receipt time
    c.observe(100.0625, 5.0)  # 62.5 ms late
    c.observe(100.0390625, 5.03125)  # 7.8 ms late: the envelope
    assert c.offset == 100.0390625 - 5.03125
    assert c.local(5.0, 100.125) == 5.0 + c.offset  # sample time, not receipt
    assert c.local(5.5, 100.125) == 100.125  # never after its receipt
    # later, all messages 0.5 s late for 10 s of vehicle time: rises at LIVE_RISE only
    off0 = c.offset
    c.observe(100.0390625 + 10.0 + 0.5, 15.03125)
    assert math.isclose(c.offset, off0 + LIVE_RISE * 10.0)
    # a reboot (vehicle time 10 s back or more): starts again
    c.observe(200.0, 1.0)
    assert c.offset == 199.0
    # a time far before the receipt is on another base (a wrapped counter): the receipt
    assert c.local(0.5, 199.5 + MAX_AGE_S + 0.25) == 199.5 + MAX_AGE_S + 0.25
    assert c.local(1.0 + MAX_AGE_S / 2, 200.0 + MAX_AGE_S) == 199.0 + 1.0 + MAX_AGE_S / 2
    for bad in (math.nan, math.inf, -1.0, 0.0):
        c.observe(300.0, bad)
        assert c.offset == 199.0
        assert c.local(bad, 301.0) == 301.0


def test_a_backlog_read_in_one_poll_keeps_each_states_time():
    dec = TelemetryDecoder()
    # 4 ms states delivered on time: the offset is learnt (receipt = PX4 time - BOOT)
    t = 0.0
    for k in range(50):
        t = k / 256
        for m in (att_q(t), lpos(t)):
            dec.on_message(m, t)
    # a 10-state backlog (40 ms of states) read by one late poll at t_poll
    t_poll = t + 11 / 256
    stamps = []
    for k in range(1, 11):
        tk = t + k / 256
        for m in (att_q(tk), lpos(tk)):
            for s in dec.on_message(m, t_poll):
                stamps.append((s.t, s.t_vehicle))
    assert len(stamps) >= 10
    for st, tv in stamps:
        # its own time on the receiver's clock, within the ms rounding of two messages
        assert abs(st - (tv - BOOT)) <= 2e-3
        assert st < t_poll
    # one stamp per PX4 time (the two messages of a time give one state each)
    assert len({st for st, _ in stamps}) == len({tv for _, tv in stamps}) == 10
    oldest = t_poll - stamps[0][0]
    assert oldest >= 9 / 256  # its real age, not 0


def test_a_lower_envelope_never_sends_a_streams_stamps_back():
    """Phase 2 under real Jazzy on PX4 SITL (load 10) aborted on two states stamped 76 us
    backwards: a less-delayed message lowered the envelope by more than the samples'
    spacing. Per stream the offset follows the envelope down at CATCH_UP only; other streams
    and a stream-less call see the new estimate (oracle: exact binary fractions)."""
    c = VehicleClock()
    c.observe(100.0625, 5.0)  # 62.5 ms late: offset 95.0625
    s1 = c.local(5.0, 100.0625, "state")
    assert s1 == 100.0625
    c.observe(100.078125, 5.0625)  # 15.6 ms after: the envelope drops to 95.015625
    assert c.offset == 100.078125 - 5.0625
    # the next state (vehicle time 1/128 s after s1's) would map before s1: its offset falls
    # by CATCH_UP x 1/128 s only, so it comes half the spacing after s1
    assert 5.0078125 + c.offset < s1
    s2 = c.local(5.0078125, 100.078125, "state")
    assert s2 == s1 + (1 - CATCH_UP) / 128 > s1
    assert c.local(5.0078125, 100.078125) == 5.0078125 + c.offset  # no stream: as mapped
    assert c.local(5.0078125, 100.078125, "imu") == 5.0078125 + c.offset  # its own stream
    # once the stream's offset has reached the envelope, stamps follow it again
    assert c.local(5.1, 100.25, "state") == 5.1 + c.offset > s1
