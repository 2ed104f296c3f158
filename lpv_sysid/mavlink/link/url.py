"""MAVLink connection URLs: the accepted forms (pymavlink ``mavutil`` device strings and the
MAVSDK-style URLs) translated into ``(device, baud)``, and the warning for a URL that listens
on every network interface."""

from __future__ import annotations

import logging

from lpv_sysid.errors import ConfigError

log = logging.getLogger(__name__)


def parse_url(url: str, baud: int = 921600) -> tuple[str, int]:
    """Translate a connection URL into ``(mavutil device string, baud)``.

    Accepted: ``udpin:H:P``, ``udpout:H:P``, ``udp:H:P`` (= udpin), ``tcp:H:P``,
    ``tcpin:H:P``, a serial device path (``/dev/ttyACM0`` or ``/dev/ttyACM0:57600``) and
    the MAVSDK forms ``udp://[H]:P``, ``udpin://[H]:P``, ``udpout://H:P``, ``tcp://H:P``,
    ``serial:///dev/ttyX[:baud]``.
    """
    if not isinstance(url, str) or not url.strip():
        raise ConfigError("connection URL is empty")
    u = url.strip()
    if "://" in u:
        scheme, rest = u.split("://", 1)
        scheme = scheme.lower()
        if scheme == "serial":
            dev, _, b = rest.partition(":")
            return dev, _baud(b, baud, url)
        host, sep, port = rest.rpartition(":")
        if not sep:
            raise ConfigError(f"connection URL {url!r} has no port")
        _port(port, url)
        if scheme in ("udp", "udpin"):
            return f"udpin:{host or '0.0.0.0'}:{port}", baud
        if scheme == "udpout":
            return f"udpout:{host or '127.0.0.1'}:{port}", baud
        if scheme in ("tcp", "tcpout"):
            return f"tcp:{host or '127.0.0.1'}:{port}", baud
        if scheme == "tcpin":
            return f"tcpin:{host or '0.0.0.0'}:{port}", baud
        raise ConfigError(f"connection URL {url!r}: unsupported scheme {scheme!r}")
    for prefix in ("udpin:", "udpout:", "udp:", "tcp:", "tcpin:"):
        if u.startswith(prefix):
            parts = u[len(prefix) :].split(":")
            if len(parts) != 2 or not parts[0]:
                raise ConfigError(f"connection URL {url!r}: expected {prefix}HOST:PORT")
            _port(parts[1], url)
            if prefix == "udp:":
                return "udpin:" + u[len(prefix) :], baud
            return u, baud
    if u.startswith("/dev/") or u.upper().startswith("COM"):
        dev, _, b = u.partition(":") if u.startswith("/dev/") else (u, "", "")
        return dev, _baud(b, baud, url)
    raise ConfigError(
        f"connection URL {url!r} not understood (udpin:H:P, udpout:H:P, tcp:H:P, /dev/ttyX, udp://:P)"
    )


#: bind addresses that listen on every network interface
ALL_INTERFACES = ("0.0.0.0", "::", "", "*")


def warn_if_all_interfaces(what: str, host: str) -> bool:
    """Log (and return True) when ``host`` binds all interfaces: anyone on any network the
    machine is on can then send commands, parameters and setpoints to the port."""
    if host.strip("[]") not in ALL_INTERFACES:
        return False
    log.warning(
        "%s listens on ALL network interfaces (%s): any host that can reach this port can "
        "send it commands, PARAM_SETs and setpoints. Bind to 127.0.0.1 or one interface "
        "address (e.g. udpin:127.0.0.1:14540) and use MAVLink signing on shared networks",
        what,
        host or "no host given",
    )
    return True


def _port(p: str, url: str) -> int:
    try:
        v = int(p)
    except ValueError:
        raise ConfigError(f"connection URL {url!r}: port {p!r} is not an integer") from None
    if not 0 < v < 65536:
        raise ConfigError(f"connection URL {url!r}: port {v} out of range")
    return v


def _baud(b: str, default: int, url: str) -> int:
    if not b:
        return default
    try:
        v = int(b)
    except ValueError:
        raise ConfigError(f"connection URL {url!r}: baud {b!r} is not an integer") from None
    if v <= 0:
        raise ConfigError(f"connection URL {url!r}: baud must be positive")
    return v
