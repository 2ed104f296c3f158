"""``offboard`` section of ``config/mavlink_bridge.yaml``: the settings of the PX4
offboard state machine (:mod:`lpv_sysid.mavlink.offboard`) and their PX4 limits.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from lpv_sysid.configuration import fields as cf
from lpv_sysid.mavlink import px4

#: PX4 modes a hand-back may request (names compared in upper case, kept as written)
_MODES: dict[str, Any] = {"choices": tuple(px4.HANDBACK_MODES), "fold_case": True}


@dataclass(frozen=True)
class OffboardConfig:
    """``config/mavlink_bridge.yaml`` section ``offboard``, checked by :meth:`validate` (also
    for a config built in code: the offboard machine calls it).

    ``handback_chain``: PX4 modes tried in turn on hand-back (names of
    :data:`lpv_sysid.mavlink.px4.HANDBACK_MODES`). ``handback_mode`` (optional, the
    single-mode key of earlier releases and of the bridge node's parameters): tried first,
    then the other modes of ``handback_chain``. The timeouts bound the hand-back: each mode
    takes at most ``(max_retries + 1) ack_timeout + mode_confirm_timeout``.
    """

    setpoint_rate_hz: float = cf.number(
        20.0,
        "setpoint stream rate [Hz]; PX4 needs > 2 Hz (COM_OF_LOSS_T), at most 1000 Hz",
        lo=2.0,
        lo_open=True,
        hi=1000.0,
        unit=" Hz",
    )
    prestream_time: float = cf.number(
        1.2,
        "setpoints streamed before OFFBOARD is requested [s]; PX4 needs > 1 s, at most 60 s",
        lo=1.0,
        lo_open=True,
        hi=60.0,
        unit=" s",
    )
    arm: bool = cf.flag(False, "arm via MAV_CMD_COMPONENT_ARM_DISARM on start")
    handback_chain: tuple[str, ...] = cf.texts(
        ("HOLD", "LAND"),
        "PX4 modes tried in turn on hand-back until the HEARTBEAT confirms one",
        unique=True,
        **_MODES,
    )
    handback_mode: str | None = cf.choice(
        None,
        doc="tried before the chain (single-mode key of earlier releases)",
        optional=True,
        **_MODES,
    )
    input_timeout: float = cf.number(
        0.5,
        "no ROS command for this long -> hand back [s]; 0.01 .. 2 s: the last command is "
        "streamed meanwhile, so this is how long the vehicle flies on after its commander "
        "died (PX4's own offboard-loss time COM_OF_LOSS_T is 1 s)",
        lo=0.01,
        hi=2.0,
        unit=" s",
    )
    ack_timeout: float = cf.number(
        0.5,
        "per attempt, for the first COMMAND_ACK [s]; 0.01 .. 5 s (PX4 answers within "
        "~50 ms; longer only delays the hand-back)",
        lo=0.01,
        hi=5.0,
        unit=" s",
    )
    ack_settle_s: float = cf.number(
        0.2,
        "quiet time after the last ACK before a step counts [s]; 0 .. 1 s (PX4's verdict "
        "follows its first ACCEPTED within 0-15 ms on v1.16 SIH, ~50 ms seen)",
        lo=0.0,
        hi=1.0,
        unit=" s",
    )
    max_retries: int = cf.count(
        3, "command retries per step; at most 10 (each costs ack_timeout of hand-back)", hi=10
    )
    mode_confirm_timeout: float = cf.number(
        2.0,
        "after ACCEPTED, for the HEARTBEAT (1 Hz) to show the mode/arming [s]; 0.01 .. 10 s",
        lo=0.01,
        hi=10.0,
        unit=" s",
    )
    send_on_command: bool = cf.flag(True, "forward a new command at once (latency)")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "offboard") -> "OffboardConfig":
        cfg = cls(**cf.parse_fields(cls, d, where))
        cfg.validate(where)
        return cfg

    def validate(self, where: str = "offboard") -> None:
        """The declared fields, then: the settle time fits in the confirmation time."""
        cf.check_fields(self, where)
        if self.ack_settle_s >= self.mode_confirm_timeout:
            raise cf.error(
                where,
                "ack_settle_s",
                f"{self.ack_settle_s} s must be below mode_confirm_timeout "
                f"({self.mode_confirm_timeout} s)",
            )

    @property
    def chain(self) -> tuple[px4.Px4Mode, ...]:
        """The hand-back modes in the order they are tried."""
        modes = [px4.HANDBACK_MODES[n.upper()] for n in self.handback_chain]
        if self.handback_mode is not None:
            first = px4.HANDBACK_MODES[self.handback_mode.upper()]
            modes = [first] + [m for m in modes if m != first]
        return tuple(modes)

    @property
    def handback(self) -> px4.Px4Mode:
        """The first hand-back choice."""
        return self.chain[0]
