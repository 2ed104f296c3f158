"""The offboard state machine tells the truth about mode changes and arming (issue 10,
finding 1 / build item 3): PX4 v1.16 answers DO_SET_MODE and arming twice (ACCEPTED from
its MAVLink receiver, then the commander's verdict), so only the final verdict plus a
HEARTBEAT showing exactly the requested state confirms a step; the hand-back walks a
fallback chain and keeps the neutral setpoint streaming until a mode is confirmed.

Pure machine, scripted clock: every ACK and HEARTBEAT below is what PX4 v1.16 SITL sends
in the situation named by the test."""

from __future__ import annotations

import pytest

from lpv_sysid.errors import ConfigError
from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.offboard import (
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_SET_MODE,
    OffboardConfig,
    OffboardMachine,
    SendCommand,
    SendSetpoint,
    State,
    StatusEvent,
)

ACC, TMP, DEN = px4.MAV_RESULT_ACCEPTED, px4.MAV_RESULT_TEMPORARILY_REJECTED, px4.MAV_RESULT_DENIED
DT = 0.01


def kinds(actions, cls):
    return [a for a in actions if isinstance(a, cls)]


def mode_cmd(mode: px4.Px4Mode, attempt: int = 1) -> SendCommand:
    return SendCommand(MAV_CMD_DO_SET_MODE, (1.0, float(mode.main), float(mode.sub)), attempt)


class Script:
    """Drives a machine on a scripted clock; commands arrive every step (fresh input)."""

    def __init__(self, cfg: OffboardConfig, neutral="zero") -> None:
        self.m = OffboardMachine(cfg, neutral)
        self.t = 0.0
        self.log: list = []

    def run(self, dt_total: float, cmd: bool = True) -> list:
        acts: list = []
        end = self.t + dt_total
        while self.t < end - 1e-9:
            self.t = round(self.t + DT, 9)
            if cmd:
                acts += self.m.on_command(self.t, "sp")
            acts += self.m.step(self.t)
        self.log += acts
        return acts

    def at(self, dt: float) -> float:
        """Advance the clock by dt without stepping (an event arrives at that time)."""
        self.t = round(self.t + dt, 9)
        return self.t

    def ack(self, dt: float, command: int, result: int) -> list:
        acts = self.m.on_ack(self.at(dt), command, result)
        self.log += acts
        return acts

    def hb(self, dt: float, mode: px4.Px4Mode, armed: bool) -> list:
        acts = self.m.on_heartbeat(self.at(dt), mode, armed)
        self.log += acts
        return acts

    def active(self, armed: bool = True) -> None:
        """Pre-stream, OFFBOARD (double ACK, HEARTBEAT), arming if configured -> ACTIVE."""
        self.m.on_heartbeat(self.t, px4.HOLD, False)
        self.log += self.m.start(self.t)
        self.run(1.3)
        assert self.m.state == State.SWITCHING
        self.ack(0.01, MAV_CMD_DO_SET_MODE, ACC)
        self.ack(0.03, MAV_CMD_DO_SET_MODE, ACC)
        self.hb(0.2, px4.OFFBOARD, False)
        self.run(0.05)
        if self.m.config.arm:
            assert self.m.state == State.ARMING
            self.ack(0.01, MAV_CMD_COMPONENT_ARM_DISARM, ACC)
            self.ack(0.03, MAV_CMD_COMPONENT_ARM_DISARM, ACC)
            self.hb(0.3, px4.OFFBOARD, armed)
            self.run(0.05)
        assert self.m.state == State.OFFBOARD_ACTIVE


# ------------------------------------------------------------------- hand-back
def test_posctl_handback_without_rc_ends_in_confirmed_hold_never_done_posctl():
    """The exact PX4 v1.16 SITL sequence of issue 10 finding 1: POSCTL ACCEPTED, then
    TEMPORARILY_REJECTED; the offboard-loss failsafe would then show POSCTL in the
    HEARTBEAT. The machine tries HOLD next and reports DONE only with HOLD confirmed."""
    s = Script(OffboardConfig(arm=True, handback_chain=("POSCTL", "HOLD", "LAND")))
    s.active()
    acts = s.m.abort(s.t, "end of test")
    assert s.m.state == State.HANDBACK and kinds(acts, SendCommand) == [mode_cmd(px4.POSCTL)]
    s.ack(0.01, MAV_CMD_DO_SET_MODE, ACC)  # PX4 mavlink receiver
    s.run(0.02)
    assert s.m.state == State.HANDBACK  # not settled: the verdict may follow
    acts = s.ack(0.02, MAV_CMD_DO_SET_MODE, TMP)  # commander: no RC for Position mode
    assert kinds(acts, SendCommand) == [mode_cmd(px4.HOLD)]
    warn = kinds(acts, StatusEvent)[0]
    assert (
        warn.level == "warn"
        and "POSCTL (command 176) accepted, then rejected: TEMPORARILY_REJECTED" in warn.reason
    )
    # a failsafe HEARTBEAT showing POSCTL is no confirmation of anything
    s.hb(0.3, px4.POSCTL, True)
    s.run(0.5)
    assert s.m.state == State.HANDBACK and s.m.confirmed_mode is None
    s.ack(0.01, MAV_CMD_DO_SET_MODE, ACC)
    s.ack(0.03, MAV_CMD_DO_SET_MODE, ACC)
    s.hb(0.4, px4.HOLD, True)
    s.run(0.05)
    assert s.m.state == State.DONE and s.m.confirmed_mode == px4.HOLD
    assert s.m.reason.startswith("hand-back confirmed: vehicle in HOLD after POSCTL:")
    done = [e for e in kinds(s.log, StatusEvent) if e.state == "DONE" and e.previous == "HANDBACK"]
    assert len(done) == 1 and done[0].level == "info"
    assert not any(
        e.state == "DONE" and "vehicle in POSCTL" in e.reason for e in kinds(s.log, StatusEvent)
    )


def test_rejection_within_the_settle_time_beats_a_heartbeat_showing_the_mode():
    """HEARTBEAT with the requested mode between ACCEPTED and the commander's rejection
    (failsafe POSCTL) must not count: the ACK sequence has not settled."""
    s = Script(OffboardConfig(handback_chain=("POSCTL",)))
    s.active()
    s.m.abort(s.t, "abort")
    s.ack(0.01, MAV_CMD_DO_SET_MODE, ACC)
    s.hb(0.01, px4.POSCTL, False)
    s.run(0.05)
    assert s.m.state == State.HANDBACK
    s.ack(0.01, MAV_CMD_DO_SET_MODE, TMP)
    s.run(0.05)
    assert s.m.state == State.FAILED and s.m.confirmed_mode is None
    failed = kinds(s.log, StatusEvent)[-1]
    assert failed.level == "error" and failed.state == "FAILED"
    assert failed.reason.startswith(
        "hand-back NOT confirmed: POSCTL: POSCTL (command 176) accepted, then rejected"
    )
    assert "PX4 failsafe in charge" in failed.reason


def test_a_heartbeat_showing_another_mode_is_not_a_confirmation():
    """Old rule 'anything but OFFBOARD is success' is gone: HOLD was requested, PX4 shows
    LAND (its own failsafe): after mode_confirm_timeout the chain moves to LAND, which is
    then confirmed."""
    s = Script(OffboardConfig(handback_chain=("HOLD", "LAND"), mode_confirm_timeout=1.0))
    s.active()
    s.m.abort(s.t, "abort")
    t_acc = s.t + 0.01
    s.ack(0.01, MAV_CMD_DO_SET_MODE, ACC)
    s.ack(0.03, MAV_CMD_DO_SET_MODE, ACC)
    s.hb(0.2, px4.LAND, True)
    acts = s.run(1.0)
    assert s.m.state == State.HANDBACK and kinds(acts, SendCommand) == [mode_cmd(px4.LAND)]
    ev = [e for e in kinds(acts, StatusEvent) if "trying LAND" in e.reason]
    assert len(ev) == 1 and 1.0 < ev[0].t - t_acc <= 1.0 + DT + 1e-9
    assert (
        "HOLD (command 176) accepted but the HEARTBEAT did not show it within 1.0 s"
        in ev[0].reason
    )
    s.ack(0.01, MAV_CMD_DO_SET_MODE, ACC)
    s.ack(0.03, MAV_CMD_DO_SET_MODE, ACC)
    s.hb(0.5, px4.LAND, True)
    s.run(0.05)
    assert s.m.state == State.DONE and s.m.confirmed_mode == px4.LAND


def test_neutral_setpoint_streams_during_handback_and_stops_when_confirmed():
    cfg = OffboardConfig(setpoint_rate_hz=20.0, input_timeout=0.2)
    s = Script(cfg)
    s.active()
    t_last_cmd = s.t
    acts = s.run(1.0, cmd=False)  # commands stop: stale input -> HANDBACK
    hb = [
        e for e in kinds(acts, StatusEvent) if e.state == "HANDBACK" and e.previous != "HANDBACK"
    ]
    assert (
        len(hb) == 1 and cfg.input_timeout < hb[0].t - t_last_cmd <= cfg.input_timeout + DT + 1e-9
    )
    after = acts[acts.index(hb[0]) :]
    sps = kinds(after, SendSetpoint)
    # 20 Hz neutral stream for the ~0.79 s of hand-back so far: PX4 never sees a gap
    assert all(a.setpoint == "zero" for a in sps) and 14 <= len(sps) <= 17
    s.ack(0.01, MAV_CMD_DO_SET_MODE, ACC)
    s.ack(0.03, MAV_CMD_DO_SET_MODE, ACC)
    s.hb(0.3, px4.HOLD, True)
    s.run(0.05, cmd=False)
    assert s.m.state == State.FAILED and s.m.confirmed_mode == px4.HOLD  # fault: stale input
    assert kinds(s.log, StatusEvent)[-1].level == "warn"
    assert kinds(s.run(1.0, cmd=False), SendSetpoint) == []  # confirmed: stream off
    # without a neutral setpoint (attitude_rate transport) nothing is streamed in HANDBACK
    s2 = Script(OffboardConfig(setpoint_rate_hz=20.0, input_timeout=0.5), neutral=None)
    s2.active()
    acts = s2.run(1.0, cmd=False)
    idx = acts.index(next(e for e in kinds(acts, StatusEvent) if e.state == "HANDBACK"))
    assert kinds(acts[idx:], SendSetpoint) == []


def test_nothing_confirmed_ends_failed_loudly_and_stops_the_stream():
    """No ACK at all (link gone): each chain mode is sent 1 + max_retries times, then FAILED."""
    cfg = OffboardConfig(handback_chain=("HOLD", "LAND"), ack_timeout=0.3, max_retries=2)
    s = Script(cfg)
    s.active()
    t0 = s.t
    s.m.abort(s.t, "operator abort")
    acts = s.run(3.0)
    cmds = kinds(acts, SendCommand)
    assert cmds == [
        mode_cmd(px4.HOLD, 2),
        mode_cmd(px4.HOLD, 3),
        mode_cmd(px4.LAND, 1),
        mode_cmd(px4.LAND, 2),
        mode_cmd(px4.LAND, 3),
    ]
    failed = [e for e in kinds(s.log, StatusEvent) if e.state == "FAILED"]
    assert len(failed) == 1 and failed[0].level == "error"
    assert failed[0].reason.startswith(
        "hand-back NOT confirmed: HOLD: no COMMAND_ACK for command 176"
    )
    assert "; LAND: no COMMAND_ACK" in failed[0].reason and failed[0].reason.endswith(
        "[operator abort]"
    )
    # 2 modes x 3 attempts x ack_timeout (each timeout seen at the next step)
    assert 1.8 < failed[0].t - t0 <= 1.8 + 6 * DT + 1e-9
    idx = s.log.index(failed[0])
    assert kinds(s.log[idx:], SendSetpoint) == []
    assert s.m.status(s.t)["confirmed_mode"] == "" and s.m.status(s.t)["state"] == "FAILED"


def test_lost_acks_are_confirmed_by_a_heartbeat_showing_the_change():
    s = Script(OffboardConfig())
    s.active()
    s.m.abort(s.t, "abort")
    s.hb(0.5, px4.HOLD, True)  # both ACKs lost, the mode changed
    s.run(0.05)
    assert s.m.state == State.DONE and s.m.confirmed_mode == px4.HOLD


# --------------------------------------------------------------- into OFFBOARD
def test_offboard_switch_accepted_then_rejected_is_retried_then_fails():
    s = Script(OffboardConfig(max_retries=1))
    s.m.on_heartbeat(0.0, px4.HOLD, False)
    s.m.start(0.0)
    s.run(1.3)
    assert s.m.state == State.SWITCHING
    s.ack(0.01, MAV_CMD_DO_SET_MODE, ACC)
    acts = s.ack(0.03, MAV_CMD_DO_SET_MODE, TMP)  # e.g. stream not seen by the commander
    assert kinds(acts, SendCommand) == [mode_cmd(px4.OFFBOARD, 2)]
    s.ack(0.01, MAV_CMD_DO_SET_MODE, ACC)
    s.ack(0.03, MAV_CMD_DO_SET_MODE, TMP)
    assert s.m.state == State.FAILED and s.m.reason.startswith(
        "switch to OFFBOARD failed: OFFBOARD"
    )
    assert "accepted, then rejected: TEMPORARILY_REJECTED" in s.m.reason
    assert kinds(s.run(0.5), SendSetpoint) == []


def test_stale_offboard_after_auto_disarm_is_no_confirmation():
    """PX4 keeps reporting OFFBOARD after an auto-disarm. A HEARTBEAT that showed OFFBOARD
    before the switch proves nothing: without a final ACCEPTED the switch is not confirmed;
    when it fails the machine hands back (clearing the stale OFFBOARD)."""
    cfg = OffboardConfig(ack_timeout=0.3, max_retries=1)
    s = Script(cfg)
    s.m.on_heartbeat(0.0, px4.OFFBOARD, False)  # leftover of an auto-disarm
    s.m.start(0.0)
    s.run(1.3)
    assert s.m.state == State.SWITCHING
    s.hb(0.1, px4.OFFBOARD, False)  # no ACK arrives
    s.run(0.7)
    assert (
        s.m.state == State.HANDBACK and "switch to OFFBOARD failed: no COMMAND_ACK" in s.m.reason
    )
    # same start, but PX4 answers: ACCEPTED, ACCEPTED -> confirmed
    s2 = Script(cfg)
    s2.m.on_heartbeat(0.0, px4.OFFBOARD, False)
    s2.m.start(0.0)
    s2.run(1.3)
    s2.hb(0.1, px4.OFFBOARD, False)
    s2.run(0.3)
    assert s2.m.state == State.SWITCHING
    s2.ack(0.01, MAV_CMD_DO_SET_MODE, ACC)
    s2.ack(0.03, MAV_CMD_DO_SET_MODE, ACC)
    s2.run(0.25)
    assert s2.m.state == State.OFFBOARD_ACTIVE


# ---------------------------------------------------------------------- arming
@pytest.mark.parametrize("verdict", [DEN, TMP])
def test_arm_accepted_then_rejected_fails_and_hands_back(verdict):
    s = Script(OffboardConfig(arm=True, max_retries=0))
    s.m.on_heartbeat(0.0, px4.HOLD, False)
    s.m.start(0.0)
    s.run(1.3)
    s.ack(0.01, MAV_CMD_DO_SET_MODE, ACC)
    s.ack(0.03, MAV_CMD_DO_SET_MODE, ACC)
    s.hb(0.2, px4.OFFBOARD, False)
    s.run(0.05)
    assert s.m.state == State.ARMING
    s.ack(0.01, MAV_CMD_COMPONENT_ARM_DISARM, ACC)
    s.hb(0.01, px4.OFFBOARD, True)  # even a HEARTBEAT armed in between
    acts = s.ack(0.02, MAV_CMD_COMPONENT_ARM_DISARM, verdict)
    assert s.m.state == State.HANDBACK
    assert s.m.reason == (
        f"ARMING failed: arm (command 400) accepted, then rejected: {px4.result_name(verdict)}"
    )
    assert kinds(acts, SendCommand) == [mode_cmd(px4.HOLD)]
    assert not any(e.state == "OFFBOARD_ACTIVE" for e in kinds(s.log, StatusEvent))


def test_temporarily_rejected_arm_is_retried():
    s = Script(OffboardConfig(arm=True, max_retries=2))
    s.m.on_heartbeat(0.0, px4.HOLD, False)
    s.m.start(0.0)
    s.run(1.3)
    s.ack(0.01, MAV_CMD_DO_SET_MODE, ACC)
    s.ack(0.03, MAV_CMD_DO_SET_MODE, ACC)
    s.hb(0.2, px4.OFFBOARD, False)
    s.run(0.05)
    s.ack(0.01, MAV_CMD_COMPONENT_ARM_DISARM, ACC)
    acts = s.ack(0.03, MAV_CMD_COMPONENT_ARM_DISARM, TMP)
    assert kinds(acts, SendCommand) == [SendCommand(MAV_CMD_COMPONENT_ARM_DISARM, (1.0, 0.0), 2)]
    s.ack(0.01, MAV_CMD_COMPONENT_ARM_DISARM, ACC)
    s.ack(0.03, MAV_CMD_COMPONENT_ARM_DISARM, ACC)
    s.hb(0.3, px4.OFFBOARD, True)
    s.run(0.05)
    assert s.m.state == State.OFFBOARD_ACTIVE


def test_disarm_during_offboard_hands_back():
    s = Script(OffboardConfig(arm=True))
    s.active()
    acts = s.hb(0.1, px4.OFFBOARD, False)  # auto-disarm: mode still OFFBOARD
    assert s.m.state == State.HANDBACK and "vehicle disarmed during OFFBOARD" in s.m.reason
    assert kinds(acts, SendCommand) == [mode_cmd(px4.HOLD)]


# ---------------------------------------------------------------------- finish
def test_finish_lands_and_reports_the_disarm():
    s = Script(OffboardConfig(arm=True))
    s.active()
    acts = s.m.finish(s.t, "LAND")
    assert s.m.state == State.HANDBACK and kinds(acts, SendCommand) == [mode_cmd(px4.LAND)]
    s.ack(0.01, MAV_CMD_DO_SET_MODE, ACC)
    s.ack(0.03, MAV_CMD_DO_SET_MODE, ACC)
    s.hb(0.5, px4.LAND, True)
    s.run(0.05)
    assert s.m.state == State.DONE and s.m.confirmed_mode == px4.LAND
    assert s.m.reason == "hand-back confirmed: vehicle in LAND: finish requested: LAND"
    assert s.m.status(s.t)["disarmed"] == "False"
    s.hb(5.0, px4.LAND, True)
    assert s.m.status(s.t)["disarmed"] == "False"
    acts = s.hb(1.0, px4.LAND, False)  # landed, PX4 auto-disarms
    ev = kinds(acts, StatusEvent)
    assert len(ev) == 1 and ev[0].reason == "vehicle disarmed in LAND (landed or auto-disarm)"
    assert s.m.status(s.t)["disarmed"] == "True" and s.m.state == State.DONE
    assert kinds(s.hb(1.0, px4.LAND, False), StatusEvent) == []  # reported once


def test_finish_after_a_hold_handback_and_retarget_during_handback():
    s = Script(OffboardConfig())
    s.active()
    s.m.abort(s.t, "vertex done")
    s.ack(0.01, MAV_CMD_DO_SET_MODE, ACC)
    acts = s.m.finish(s.at(0.05), "LAND")  # re-target while HOLD is pending
    assert kinds(acts, SendCommand) == [mode_cmd(px4.LAND)]
    assert kinds(s.ack(0.01, MAV_CMD_DO_SET_MODE, ACC), SendCommand) == []  # counted for LAND now
    assert s.m.status(s.t)["handback_target"] == "LAND" and "ACCEPTED@" in s.m.status(s.t)["acks"]
    s.hb(0.4, px4.LAND, True)
    s.run(0.05)
    assert s.m.state == State.DONE and s.m.confirmed_mode == px4.LAND
    # from DONE in HOLD: a later finish(LAND) requests LAND with the same rules
    s2 = Script(OffboardConfig())
    s2.active()
    s2.m.abort(s2.t, "end")
    s2.hb(0.5, px4.HOLD, True)
    s2.run(0.05)
    assert s2.m.state == State.DONE and s2.m.confirmed_mode == px4.HOLD
    acts = s2.m.finish(s2.t, px4.LAND)
    assert s2.m.state == State.HANDBACK and kinds(acts, SendCommand) == [mode_cmd(px4.LAND)]
    s2.ack(0.01, MAV_CMD_DO_SET_MODE, DEN)  # LAND refused: fall back along the chain
    assert kinds(s2.log, SendCommand)[-1] == mode_cmd(px4.HOLD)
    s2.ack(0.01, MAV_CMD_DO_SET_MODE, ACC)
    s2.run(0.25)
    assert s2.m.state == State.HANDBACK  # a HEARTBEAT after the command is needed
    s2.hb(0.5, px4.HOLD, True)
    assert (
        s2.m.state == State.DONE and s2.m.confirmed_mode == px4.HOLD
    )  # HOLD shown before: ACK needed
    with pytest.raises(ConfigError, match="ACRO"):
        s2.m.finish(s2.t, "ACRO")


# ---------------------------------------------------------------------- config
def test_handback_chain_config():
    assert OffboardConfig().chain == (px4.HOLD, px4.LAND)
    assert OffboardConfig.from_dict({"handback_chain": ["posctl", "HOLD"]}).chain == (
        px4.POSCTL,
        px4.HOLD,
    )
    # the bridge node's single-mode parameter: tried first, then the rest of the chain
    assert OffboardConfig(handback_mode="POSCTL").chain == (px4.POSCTL, px4.HOLD, px4.LAND)
    assert OffboardConfig(handback_mode="LAND").chain == (px4.LAND, px4.HOLD)
    for bad, match in (
        ({"handback_chain": []}, "handback_chain"),
        ({"handback_chain": "HOLD"}, "handback_chain"),
        ({"handback_chain": ["HOLD", "OFFBOARD"]}, "OFFBOARD"),
        ({"handback_chain": ["HOLD", "hold"]}, "duplicate names"),
        ({"ack_settle_s": 2.0}, "ack_settle_s"),
        ({"ack_settle_s": -0.1}, "ack_settle_s"),
        ({"handback_mode": "ACRO"}, "handback_mode"),
    ):
        with pytest.raises(ConfigError, match=match):
            OffboardConfig.from_dict(bad)


# --------------------------------------------------------------- real PX4 SITL
def test_real_px4_posctl_handback_without_rc_ends_in_confirmed_hold():
    """Against PX4 v1.16 SIH (skipped without PX4_SITL_DIR): take off in OFFBOARD, hand
    back with POSCTL first. PX4 answers POSCTL ACCEPTED, then TEMPORARILY_REJECTED; the
    bridge must end DONE in a HOLD confirmed by the HEARTBEAT, never DONE POSCTL, and the
    vehicle must not have entered its offboard-loss failsafe (altitude kept)."""
    import time

    from px4_sitl import Px4Sitl, find_px4

    from lpv_sysid.mavlink.bridge import BridgeConfig, BridgeCore
    from lpv_sysid.mavlink.link import LinkConfig

    d, why = find_px4()
    if d is None:
        pytest.skip(why)
    with Px4Sitl(d, instance=6) as sitl:  # instance 6: hand-back test
        core = BridgeCore(
            BridgeConfig(
                link=LinkConfig(url=sitl.url),
                offboard=OffboardConfig(arm=True, handback_chain=("POSCTL", "HOLD", "LAND")),
            )
        )
        acks: list = []
        events: list = []
        orig = core._on_message

        def spy(msg, now, out):
            if msg.get_type() == "COMMAND_ACK" and msg.command == MAV_CMD_DO_SET_MODE:
                acks.append((now, msg.result))
            orig(msg, now, out)

        core._on_message = spy
        core.open(time.monotonic())
        z: list = []

        def run(seconds, ref=None, until=None):
            end = time.monotonic() + seconds
            next_ref = 0.0
            while time.monotonic() < end:
                now = time.monotonic()
                if ref is not None and now >= next_ref:
                    next_ref = now + 0.02
                    core.on_velocity_reference(now, ref, 0.0)
                out = core.poll(now)
                events.extend(out.events)
                z.extend(s.pos_ned[2] for s in out.samples if hasattr(s, "pos_ned"))
                if until is not None and until():
                    return
                time.sleep(0.004)

        try:
            run(2.0, (0.0, 0.0, 0.0))
            events.extend(core.start(time.monotonic()))
            run(20.0, (0.0, 0.0, 0.0), until=lambda: core.state == State.OFFBOARD_ACTIVE)
            assert core.state == State.OFFBOARD_ACTIVE, [e.reason for e in events]
            # climb until 3.5 m (bounded): PX4's take-off ramp and a loaded machine make a
            # fixed climb time unreliable
            run(20.0, (0.0, 0.0, -1.5), until=lambda: bool(z) and z[-1] < -3.5)
            run(2.0, (0.0, 0.0, 0.0))
            z_abort = z[-1]
            assert z_abort < -3.0
            n_acks = len(acks)
            events.extend(core.abort(time.monotonic(), "end of test"))
            run(10.0, until=lambda: core.state in (State.DONE, State.FAILED))
            final = [
                e
                for e in events
                if isinstance(e, StatusEvent)
                and e.previous == "HANDBACK"
                and e.state in ("DONE", "FAILED")
            ]
            assert len(final) == 1 and final[0].state == "DONE", final
            assert core.machine.confirmed_mode == px4.HOLD and "after POSCTL" in final[0].reason
            assert [r for _, r in acks[n_acks : n_acks + 2]] == [ACC, TMP]  # PX4's two answers
            run(2.0)
            assert abs(z[-1] - z_abort) < 1.0 and core.machine.vehicle_mode == px4.HOLD
        finally:
            core.close()


def test_vehicle_back_in_offboard_after_done_is_reported_each_time():
    """Issue 25 item 8: after a confirmed hand-back (DONE) nothing streams; a HEARTBEAT
    showing OFFBOARD again is an error-level StatusEvent, every time it happens."""
    s = Script(OffboardConfig(arm=True))
    s.active()
    s.m.abort(s.t, "operator")
    s.ack(0.01, MAV_CMD_DO_SET_MODE, ACC)
    s.hb(0.3, px4.HOLD, True)
    s.run(0.05)
    assert s.m.state == State.DONE and s.m.confirmed_mode == px4.HOLD
    assert kinds(s.hb(1.0, px4.HOLD, True), StatusEvent) == []
    ev = kinds(s.hb(1.0, px4.OFFBOARD, True), StatusEvent)
    assert len(ev) == 1 and ev[0].level == "error" and ev[0].state == "DONE"
    assert ev[0].reason.startswith("vehicle back in OFFBOARD after the run ended (DONE")
    assert s.m.status(s.t)["reverted_to_offboard"] == "1"
    assert kinds(s.hb(1.0, px4.OFFBOARD, True), StatusEvent) == []  # same episode: once
    assert kinds(s.hb(1.0, px4.POSCTL, True), StatusEvent) == []
    ev = kinds(s.hb(1.0, px4.OFFBOARD, True), StatusEvent)  # a second episode
    assert len(ev) == 1 and s.m.status(s.t)["reverted_to_offboard"] == "2"
    assert s.m.state == State.DONE and kinds(s.run(0.5), SendSetpoint) == []


def test_unconfirmed_handback_still_in_offboard_is_not_a_revert():
    """FAILED with the vehicle never out of OFFBOARD is FAILED's own error, not a revert."""
    s = Script(OffboardConfig(arm=True, handback_chain=("HOLD",)))
    s.active()
    s.m.abort(s.t, "operator")
    for _ in range(8):
        s.ack(0.01, MAV_CMD_DO_SET_MODE, 4)  # FAILED
        if s.m.state == State.FAILED:
            break
    assert s.m.state == State.FAILED
    events = kinds(s.hb(1.0, px4.OFFBOARD, True), StatusEvent)
    assert all("back in OFFBOARD" not in e.reason for e in events)
    assert s.m.status(s.t)["reverted_to_offboard"] == "0"
