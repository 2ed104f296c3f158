"""Options of the MAVLink link (:class:`LinkConfig`, ``config/mavlink_bridge.yaml`` section
``link``), the MAVLink ids the link uses and the signing-key file it reads."""

from __future__ import annotations

import binascii
from dataclasses import dataclass
from typing import Any, Mapping

from lpv_sysid.configuration.fields import check_config_keys
from lpv_sysid.errors import ConfigError
from lpv_sysid.mavlink import codec
from lpv_sysid.mavlink.link.url import parse_url

# MAVLink ids used below (common.xml); kept numeric so that no dialect global is needed.
MSG_HEARTBEAT = 0
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_TYPE_GCS = 6
MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_AUTOPILOT_INVALID = 8
MAV_AUTOPILOT_PX4 = 12
MAV_STATE_ACTIVE = 4

#: default telemetry streams [Hz] (message name -> rate); ids resolved from the dialect.
DEFAULT_STREAMS: tuple[tuple[str, float], ...] = (
    ("LOCAL_POSITION_NED", 50.0),
    ("ATTITUDE_QUATERNION", 100.0),
    ("HIGHRES_IMU", 100.0),
    ("ESC_STATUS", 50.0),
)


@dataclass(frozen=True)
class LinkConfig:
    """Link parameters (``config/mavlink_bridge.yaml`` section ``link``)."""

    url: str = "udpin:127.0.0.1:14540"
    baud: int = 921600
    source_system: int = 1
    source_component: int = 191  # MAV_COMP_ID_ONBOARD_COMPUTER
    target_system: int = 0  # 0: learn from the first autopilot HEARTBEAT
    target_component: int = 1  # MAV_COMP_ID_AUTOPILOT1
    dialect: str = codec.DEFAULT_DIALECT
    heartbeat_period: float = 1.0
    link_timeout: float = 1.5
    reconnect_period: float = 2.0
    stream_request_period: float = 1.0
    streams: tuple[tuple[str, float], ...] = DEFAULT_STREAMS
    signing_key_file: str | None = None
    signing_link_id: int = 0
    allow_unsigned: bool = False
    mav_type: int = MAV_TYPE_ONBOARD_CONTROLLER

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "LinkConfig":
        check_config_keys(d, cls.__dataclass_fields__, "link")
        kw = dict(d)
        if "streams" in kw:
            s = kw["streams"]
            if not isinstance(s, Mapping):
                raise ConfigError("link.streams must be a mapping MESSAGE_NAME: rate_hz")
            kw["streams"] = tuple(
                (str(k), _positive(f"link.streams.{k}", v, allow_zero=True)) for k, v in s.items()
            )
        cfg = cls(**kw)
        cfg.validate()
        return cfg

    def validate(self) -> None:
        if not isinstance(self.url, str) or not self.url:
            raise ConfigError("link.url must be a non-empty string")
        parse_url(self.url)
        for name in ("source_system", "target_system", "source_component", "target_component"):
            v = getattr(self, name)
            if not isinstance(v, int) or not 0 <= v <= 255:
                raise ConfigError(f"link.{name} must be an integer 0..255, got {v!r}")
        if self.source_system == 0:
            raise ConfigError("link.source_system must be 1..255")
        for name in (
            "heartbeat_period",
            "link_timeout",
            "reconnect_period",
            "stream_request_period",
        ):
            _positive(f"link.{name}", getattr(self, name))
        mod = codec.dialect_module(self.dialect)
        for name, rate in self.streams:
            if name != "ESC_STATUS" and not hasattr(mod, f"MAVLINK_MSG_ID_{name}"):
                raise ConfigError(f"link.streams: unknown MAVLink message {name!r}")
            _positive(f"link.streams.{name}", rate, allow_zero=True)


def _positive(name: str, v: Any, allow_zero: bool = False) -> float:
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise ConfigError(f"{name} must be a number, got {v!r}") from None
    if f != f or f in (float("inf"), float("-inf")) or f < 0 or (f == 0 and not allow_zero):
        raise ConfigError(
            f"{name} must be a finite {'non-negative' if allow_zero else 'positive'} number, got "
            f"{v!r}"
        )
    return f


def load_signing_key(path: str) -> bytes:
    """Read a MAVLink 2 signing secret: 32 raw bytes, or 64 hexadecimal characters."""
    from lpv_sysid.errors import FileReadError
    from lpv_sysid.io.files import read_bytes

    try:  # regular files only (a FIFO would block the reader), at most 4 KiB
        raw = read_bytes(path, f"signing key file {path!r}", max_bytes=4096)
    except FileReadError as exc:
        raise ConfigError(f"signing key file {path!r} cannot be read: {exc.reason}") from None
    if len(raw) == 32:
        return raw
    text = raw.strip()
    if len(text) == 64:
        try:
            return binascii.unhexlify(text)
        except (binascii.Error, ValueError):
            raise ConfigError(
                f"signing key file {path!r}: 64 characters but not hexadecimal"
            ) from None
    raise ConfigError(
        f"signing key file {path!r}: expected 32 raw bytes or 64 hex characters, "
        f"got {len(raw)} bytes"
    )
