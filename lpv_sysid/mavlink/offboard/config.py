"""``offboard`` section of ``config/mavlink_bridge.yaml``: the settings of the PX4
offboard state machine (:mod:`lpv_sysid.mavlink.offboard`) and their PX4 limits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

from lpv_sysid.configuration.fields import check_config_keys
from lpv_sysid.errors import ConfigError
from lpv_sysid.mavlink import px4


@dataclass(frozen=True)
class OffboardConfig:
    """``config/mavlink_bridge.yaml`` section ``offboard``.

    ``handback_chain``: PX4 modes tried in turn on hand-back (names of
    :data:`lpv_sysid.mavlink.px4.HANDBACK_MODES`). ``handback_mode`` (optional, the
    single-mode key of earlier releases and of the bridge node's parameters): tried first,
    then the other modes of ``handback_chain``.
    """

    setpoint_rate_hz: float = 20.0
    prestream_time: float = 1.2
    arm: bool = False
    handback_chain: tuple[str, ...] = ("HOLD", "LAND")
    handback_mode: str | None = None
    input_timeout: float = 0.5  # no ROS command for longer -> hand back
    ack_timeout: float = 0.5  # per attempt, for the first COMMAND_ACK
    ack_settle_s: float = 0.2  # quiet time after the last ACK before a step counts
    max_retries: int = 3
    mode_confirm_timeout: float = 2.0  # HEARTBEAT must show the mode/arming after ACCEPTED
    send_on_command: bool = True  # forward a new command at once (latency)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "OffboardConfig":
        check_config_keys(d, cls.__dataclass_fields__, "offboard")
        kw = dict(d)
        chain = kw.get("handback_chain")
        if chain is not None:
            if isinstance(chain, (str, bytes)) or not isinstance(chain, Sequence):
                raise ConfigError(
                    f"offboard.handback_chain must be a list of PX4 mode names, got {chain!r}"
                )
            kw["handback_chain"] = tuple(chain)
        cfg = cls(**kw)
        cfg.validate()
        return cfg

    def validate(self) -> None:
        def num(name: str, lo: float, hi: float = math.inf) -> None:
            v = getattr(self, name)
            if (
                isinstance(v, bool)
                or not isinstance(v, (int, float))
                or not (lo <= v <= hi)
                or v != v
            ):
                raise ConfigError(f"offboard.{name} must be a number in [{lo}, {hi}], got {v!r}")

        num("setpoint_rate_hz", 2.0001, 1000.0)  # PX4 needs > 2 Hz
        num("prestream_time", 1.0001, 60.0)  # PX4 needs > 1 s
        num("input_timeout", 0.01, 60.0)
        num("ack_timeout", 0.01, 60.0)
        num("ack_settle_s", 0.0, 10.0)
        num("mode_confirm_timeout", 0.01, 60.0)
        if self.ack_settle_s >= self.mode_confirm_timeout:
            raise ConfigError(
                f"offboard.ack_settle_s ({self.ack_settle_s}) must be below "
                f"offboard.mode_confirm_timeout ({self.mode_confirm_timeout})"
            )
        if (
            not isinstance(self.max_retries, int)
            or isinstance(self.max_retries, bool)
            or not 0 <= self.max_retries <= 100
        ):
            raise ConfigError(
                f"offboard.max_retries must be an integer 0..100, got {self.max_retries!r}"
            )
        if not isinstance(self.arm, bool) or not isinstance(self.send_on_command, bool):
            raise ConfigError("offboard.arm and offboard.send_on_command must be booleans")
        chain = self.handback_chain
        if isinstance(chain, (str, bytes)) or not isinstance(chain, Sequence) or not chain:
            raise ConfigError(
                f"offboard.handback_chain must be a non-empty list of mode names, got {chain!r}"
            )
        for name in chain:
            if not isinstance(name, str) or name.upper() not in px4.HANDBACK_MODES:
                raise ConfigError(
                    f"offboard.handback_chain: {name!r} is not a hand-back mode; use "
                    f"{sorted(px4.HANDBACK_MODES)}"
                )
        if len({n.upper() for n in chain}) != len(chain):
            raise ConfigError(f"offboard.handback_chain lists a mode twice: {list(chain)}")
        if self.handback_mode is not None and (
            not isinstance(self.handback_mode, str)
            or self.handback_mode.upper() not in px4.HANDBACK_MODES
        ):
            raise ConfigError(
                f"offboard.handback_mode must be one of {sorted(px4.HANDBACK_MODES)}, "
                f"got {self.handback_mode!r}"
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
