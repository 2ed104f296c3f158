"""Options of the MAVLink link (:class:`LinkConfig`, ``config/mavlink_bridge.yaml`` section
``link``), the MAVLink ids the link uses and the signing-key file it reads."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from lpv_sysid.configuration import fields as cf
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


_HZ = cf.FieldSpec(cf.NUMBER, "Hz, 0 = off", lo=0.0, hi=1000.0, unit=" Hz")
_ID = {"hi": 255}  # MAVLink system and component ids are uint8


@dataclass(frozen=True)
class LinkConfig:
    """Link parameters (``config/mavlink_bridge.yaml`` section ``link``), checked by
    :meth:`validate` (also for a config built in code: :class:`MavlinkLink` calls it)."""

    url: str = cf.text(
        "udpin:127.0.0.1:14540",
        "pymavlink connection string (udpin:H:P, udpout:H:P, tcp:H:P, serial device)",
    )
    baud: int = cf.count(921600, "serial baud rate (serial URLs only)", lo=1)
    source_system: int = cf.count(1, "our MAVLink system id", lo=1, **_ID)
    source_component: int = cf.count(191, "our component id (MAV_COMP_ID_ONBOARD_COMPUTER)", **_ID)
    target_system: int = cf.count(
        0,
        "autopilot system id; 0: the first autopilot HEARTBEAT while it is the only one (a "
        "second autopilot system id makes the link refuse both: set the id explicitly)",
        **_ID,
    )
    target_component: int = cf.count(
        1,
        "autopilot component id (MAV_COMP_ID_AUTOPILOT1); the only component whose HEARTBEAT, "
        "COMMAND_ACK, HOME_POSITION and telemetry count",
        **_ID,
    )
    dialect: str = cf.text(codec.DEFAULT_DIALECT, "MAVLink dialect (PX4: development)")
    heartbeat_period: float = cf.number(
        1.0,
        "our HEARTBEAT period [s]; 0.05 .. 5 s: faster floods the link, slower than 5 s and "
        "PX4 (and a GCS) may declare the companion lost",
        lo=0.05,
        hi=5.0,
        unit=" s",
    )
    link_timeout: float = cf.number(
        1.5,
        "no autopilot HEARTBEAT (1 Hz) for this long -> link lost [s]; 0.1 .. 10 s: longer "
        "hides a lost link past PX4's own datalink-loss time (COM_DL_LOSS_T, 10 s)",
        lo=0.1,
        hi=10.0,
        unit=" s",
    )
    reconnect_period: float = cf.number(
        2.0,
        "reopen period of a lost serial/TCP link [s]; 0.1 .. 60 s (shorter spins on a "
        "missing device)",
        lo=0.1,
        hi=60.0,
        unit=" s",
    )
    stream_request_period: float = cf.number(
        1.0,
        "SET_MESSAGE_INTERVAL retry period for missing streams [s]; 0.1 .. 60 s",
        lo=0.1,
        hi=60.0,
        unit=" s",
    )
    streams: tuple[tuple[str, float], ...] = cf.table(
        DEFAULT_STREAMS,
        "requested telemetry rates, MESSAGE_NAME: Hz in [0, 1000] (0: off)",
        item=_HZ,
        pairs=True,
    )
    signing_key_file: str | None = cf.text(
        None,
        "MAVLink 2 signing key file (32 raw bytes or 64 hex chars); null or empty: unsigned",
        nonempty=False,
        optional=True,
    )
    signing_link_id: int = cf.count(0, "MAVLink 2 signing link id (uint8)", hi=255)
    allow_unsigned: bool = cf.flag(False, "with a signing key: still accept unsigned messages")
    mav_type: int = cf.count(
        MAV_TYPE_ONBOARD_CONTROLLER, "MAV_TYPE of our HEARTBEAT (uint8)", hi=255
    )

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "link") -> "LinkConfig":
        cfg = cls(**cf.parse_fields(cls, d, where))
        cfg.validate(where)
        return cfg

    def validate(self, where: str = "link") -> None:
        """The declared fields, then the URL and the stream names against the dialect."""
        cf.check_fields(self, where)
        cf.under(cf.join(where, "url"), parse_url, self.url)
        mod = cf.under(cf.join(where, "dialect"), codec.dialect_module, self.dialect)
        for name, _ in self.streams:
            if name != "ESC_STATUS" and not hasattr(mod, f"MAVLINK_MSG_ID_{name}"):
                raise cf.error(
                    where, f"streams.{name}", f"unknown MAVLink message (dialect {self.dialect})"
                )


def load_signing_key(path: str) -> bytes:
    """Read a MAVLink 2 signing secret: 32 raw bytes, or 64 hexadecimal characters."""
    from lpv_sysid.io.files import read_key

    return read_key(path, "signing key file")
