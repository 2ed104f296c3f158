"""Absurd finite commands abort; they are not clipped (issue 25 item 4).

Within ``command_abort_factor`` (10) times a transport's range a command is the law's
saturation and is clipped (PX4 gets full thrust / full rate); beyond it the command is
absurd (a broken law, a corrupt gains file, a hostile publisher): SafetyError in the
transport, which the bridge turns into an abort (hand-back) with an error event. The
ranges are the transports' own: thrust [0, 1] (attitude_rate) or thrust_max (rate_setpoint),
``max_rate`` for the body rates; moments become rate increments tau / K_p (seed 0 Eq. 7
inverted, see AttitudeRateTransport).
"""

from __future__ import annotations

import numpy as np
import pytest

from lpv_sysid.control.envelope import EnvelopeConfig
from lpv_sysid.errors import ConfigError, SafetyError
from lpv_sysid.mavlink import codec as mavcodec
from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.bridge import (
    ActuatorSetpoint,
    AttitudeRateTransport,
    BridgeConfig,
    BridgeCore,
    RateSetpointTransport,
    TransportContext,
)
from lpv_sysid.mavlink.link import LinkConfig, free_udp_port
from lpv_sysid.mavlink.offboard import MAV_CMD_DO_SET_MODE, State, StatusEvent

CODEC = mavcodec.make_codec(None, 1, 191)
CTX = TransportContext(0, 1, 1, omega=np.zeros(3))
ARM = 0.225  # config/quadrotor.yaml arm length [m]; s = ARM sqrt(2)/2


def _encode(tr, u):
    (m,) = tr.encode(CODEC, ActuatorSetpoint(tuple(float(x) for x in u)), CTX)
    return m


def test_attitude_rate_transport_clips_saturation_but_aborts_on_absurd_values():
    tr = AttitudeRateTransport(ARM, rate_p=(0.15, 0.15, 0.2), max_rate=4.0)
    m = _encode(tr, [3.0, 0.0, 0.0, 0.0])  # 3 x full thrust: saturation, clipped
    assert m.thrust == pytest.approx(1.0)
    s = ARM * np.sqrt(2) / 2
    # a roll moment giving 8 rad/s of increment (2 x max_rate): clipped to 4 rad/s
    m = _encode(tr, [0.5, 8.0 * 0.15 * 4 * s, 0.0, 0.0])
    assert m.body_roll_rate == pytest.approx(4.0)
    with pytest.raises(SafetyError, match="thrust command 1e\\+39 is absurd"):
        _encode(tr, [1e39, 0.0, 0.0, 0.0])
    with pytest.raises(SafetyError, match="roll moment"):
        _encode(tr, [0.5, 1e30, 0.0, 0.0])
    with pytest.raises(SafetyError, match="yaw moment"):
        _encode(tr, [0.5, 0.0, 0.0, -1e6])
    # the bound is 10 x the range: 41 rad/s of increment is absurd, 39 is saturation
    with pytest.raises(SafetyError, match="pitch moment"):
        _encode(tr, [0.5, 0.0, 41.0 * 0.15 * 4 * s, 0.0])
    assert _encode(tr, [0.5, 0.0, 39.0 * 0.15 * 4 * s, 0.0]).body_pitch_rate == pytest.approx(4.0)


def test_rate_setpoint_transport_aborts_on_absurd_values():
    tr = RateSetpointTransport(max_rate=2.0)
    assert _encode(tr, [2.0, 5.0, 0.0, 0.0]).body_roll_rate == pytest.approx(2.0)
    for u, what in (([1e39, 0, 0, 0], "thrust"), ([0.5, 0, -1e30, 0], "q_sp")):
        with pytest.raises(SafetyError, match=what):
            _encode(tr, u)
    with pytest.raises(ConfigError, match="command_abort_factor"):
        RateSetpointTransport(absurd_factor=1e9)
    with pytest.raises(ConfigError, match="command_abort_factor"):
        BridgeConfig.from_dict({"command_abort_factor": 0.5})


def test_bridge_aborts_on_an_absurd_command_while_offboard():
    cfg = BridgeConfig(
        command="attitude_rate",
        link=LinkConfig(url=f"udpin:127.0.0.1:{free_udp_port()}"),
        envelope=EnvelopeConfig(enabled=False),
    )
    core = BridgeCore(cfg)
    core.transport = RateSetpointTransport()  # the phase-2 rate-plant path, as flight/phase2
    core.open(0.0)
    try:
        core.start(0.0)
        t = 0.0
        while core.state == State.PRESTREAM and t < 3.0:
            t += 0.02
            assert core.on_actuator_command(t, [0.5, 0.0, 0.0, 0.0])
            core.poll(t)
        assert core.state == State.SWITCHING
        core.machine.on_ack(t, MAV_CMD_DO_SET_MODE, 0)
        core.machine.on_heartbeat(t + 0.01, px4.OFFBOARD, False)
        for k in range(20):
            core.on_actuator_command(t + 0.02 * k, [0.5, 0.0, 0.0, 0.0])
            core.poll(t + 0.02 * k)
        assert core.state == State.OFFBOARD_ACTIVE
        sent = core.link.stats.tx_messages
        t += 0.5
        core.on_actuator_command(t, [1e39, 0.0, 0.0, 0.0])
        events = core.poll(t).events
        assert core.state == State.HANDBACK
        errs = [e for e in events if isinstance(e, StatusEvent) and e.level == "error"]
        assert any("absurd" in e.reason for e in errs)
        # nothing but the hand-back's DO_SET_MODE (and possibly our HEARTBEAT) went out
        assert core.link.stats.tx_messages - sent <= 2
    finally:
        core.close()
