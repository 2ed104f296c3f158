"""What a flight learns about its vehicle from the MAVLink stream, for ``experiment.yaml``
(:class:`VehicleRecord`): firmware (AUTOPILOT_VERSION), the PX4 parameter snapshot
(PARAM_VALUE, e.g. after a PARAM_REQUEST_LIST), battery at start and end (SYS_STATUS,
BATTERY_STATUS), the site (HOME_POSITION: WGS-84 latitude/longitude, altitude AMSL, the
local NED home), PX4's boot time on the recording clock, and what kind of vehicle it is.

Boot time. Every message with ``time_boot_ms`` was sent after PX4's clock read that value,
so ``receive_time - time_boot_ms`` over-estimates PX4's boot time (on the receiver's clock)
by the message's latency; the minimum over all messages is the estimate, within the
smallest latency + 1 ms (the ms truncation). With it, a ULog (microseconds since boot) and
the bags (receiver clock) line up: ``bag_stamp_ns = ulog_timestamp_us * 1000 +
boot_ns``. SYSTEM_TIME's ``time_unix_usec - time_boot_ms`` (PX4's own wall clock of its
boot, from GPS or the host in SITL) is recorded next to it.

Vehicle kind (:func:`vehicle_kind`, first match): ``SIMULATED`` -- the package's own
simulated PX4 (``sim/px4_vehicle``: AUTOPILOT_VERSION ``flight_custom_version`` =
:data:`SIM_MARKER`); ``HITL`` -- ``SYS_HITL`` 1 or the HEARTBEAT's HIL flag; ``SIH`` --
``SYS_HITL`` 2 (simulation in hardware); ``SITL`` -- PX4 built for the host (parameters
of its simulation modules, ``SIM_*`` / ``SIH_*`` with ``SYS_HITL`` 0, which a flight
controller's build does not have);
else ``FLOWN``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.telemetry.clock import VehicleClock

#: AUTOPILOT_VERSION.flight_custom_version of the package's simulated PX4 vehicle
SIM_MARKER = b"lpvsim\0\0"
MAV_MODE_FLAG_HIL_ENABLED = 32
VEHICLE_KINDS = ("SIMULATED", "HITL", "SIH", "SITL", "FLOWN")
_MISSING = object()


def vehicle_kind(params: dict, hil_flag: bool, custom_version: bytes | None) -> str:
    """The kind of vehicle (module docstring)."""
    if custom_version is not None and bytes(custom_version)[:8] == SIM_MARKER:
        return "SIMULATED"
    hitl = int(params.get("SYS_HITL", 0) or 0)
    if hitl == 1 or (hil_flag and hitl != 2):
        return "HITL"
    if hitl == 2:
        return "SIH"
    if any(k.startswith(("SIM_", "SIH_")) for k in params):
        return "SITL"
    return "FLOWN"


@dataclass
class VehicleRecord:
    """Absorbs the target's messages (:meth:`absorb`) and summarises them
    (:meth:`summary`)."""

    version: dict | None = None
    custom_version: bytes | None = None
    params: dict = field(default_factory=dict)
    hil_flag: bool = False
    boot_ns: int | None = None  # PX4 boot on the receive clock (ns), minimum estimate
    boot_samples: int = 0
    system_time: dict | None = None
    battery_first: dict | None = None
    battery_last: dict | None = None
    site: dict | None = None  # first HOME_POSITION with a global position
    site_last: dict | None = None

    #: per second of PX4 time: (min receive - time_boot, time_boot) (ns), for the clock fit
    windows: dict = field(default_factory=dict)
    #: live lower envelope of receive - time_boot (the decoder's own estimator, clock.py)
    live: VehicleClock = field(default_factory=VehicleClock)
    #: counts the material changes (firmware, a parameter's value, the HIL flag, the site,
    #: the first battery reading, SYSTEM_TIME, the first boot estimate): a publisher of the
    #: record sends it again when this moved, not at telemetry rate (the clock knots and the
    #: last battery reading change every second)
    revision: int = 0
    #: why ``px4_clock`` is empty when no message carries PX4's boot time (e.g. through
    #: MAVROS), written into it by :meth:`summary`
    clock_note: str | None = None

    def absorb(self, m: Any, receive_ns: int) -> None:
        """One MAVLink message of the target received at ``receive_ns`` (recording clock)."""
        mt = m.get_type()
        tb = getattr(m, "time_boot_ms", None)
        if isinstance(tb, int) and tb > 0:
            self.observe_boot(receive_ns, tb * 1_000_000)
        if mt == "HEARTBEAT":
            self.observe_base_mode(int(m.base_mode))
        elif mt == "AUTOPILOT_VERSION":
            self.set_firmware(
                int(m.flight_sw_version),
                bytes(m.flight_custom_version),
                int(m.board_version),
                int(m.vendor_id),
                int(m.product_id),
                int(m.uid),
            )
        elif mt == "PARAM_VALUE":
            name = px4.param_id_str(m.param_id)
            self.set_param(name, px4.param_from_wire(m.param_value, m.param_type))
        elif mt == "SYSTEM_TIME":
            if int(m.time_unix_usec) > 0:
                self.revision += self.system_time is None
                self.system_time = {
                    "time_unix_usec": int(m.time_unix_usec),
                    "time_boot_ms": int(m.time_boot_ms),
                    "boot_epoch_ns": int(m.time_unix_usec) * 1000
                    - int(m.time_boot_ms) * 1_000_000,
                }
        elif mt == "HOME_POSITION":
            self._home(m, receive_ns)
        elif mt == "SYS_STATUS":
            v = int(m.voltage_battery)
            if v not in (0, 65535):
                self.battery_reading(receive_ns, v * 1e-3, int(m.battery_remaining))
        elif mt == "BATTERY_STATUS":
            cells = [c for c in m.voltages if c not in (0, 65535)]
            if cells:
                self.battery_reading(receive_ns, sum(cells) * 1e-3, int(m.battery_remaining))

    # -- the facts, whatever carried them (MAVLink above; MAVROS: flight/bridge/runtime.py) --
    def observe_boot(self, receive_ns: int, time_boot_ns: int) -> None:
        """PX4's clock read ``time_boot_ns`` (since boot) before the message left; it was
        received at ``receive_ns`` (recording clock): one sample of the boot estimate."""
        est = int(receive_ns) - int(time_boot_ns)
        if self.boot_ns is None:
            self.revision += 1
        self.boot_ns = est if self.boot_ns is None else min(self.boot_ns, est)
        self.boot_samples += 1
        self.live.observe(int(receive_ns) * 1e-9, int(time_boot_ns) * 1e-9)
        w = int(time_boot_ns) // 1_000_000_000
        old = self.windows.get(w)
        if old is None or est < old[0]:
            self.windows[w] = (est, int(time_boot_ns))

    def observe_base_mode(self, base_mode: int) -> None:
        """A HEARTBEAT's ``base_mode``: its HIL flag latches."""
        if int(base_mode) & MAV_MODE_FLAG_HIL_ENABLED and not self.hil_flag:
            self.hil_flag = True
            self.revision += 1

    def set_firmware(
        self, sw_version: int, custom: bytes, board: int, vendor: int, product: int, uid: int
    ) -> None:
        """AUTOPILOT_VERSION's fields (``flight_sw_version``, ``flight_custom_version``, ...)."""
        major, minor, patch, kind = px4.decode_flight_sw_version(int(sw_version))
        self.custom_version = bytes(custom)
        old = self.version
        self.version = {
            "flight_sw_version": f"v{major}.{minor}.{patch}"
            + ("" if kind == 255 else f" (type {kind})"),
            "flight_custom_version": bytes(custom).hex(),
            "board_version": int(board),
            "vendor_id": int(vendor),
            "product_id": int(product),
            "uid": int(uid),
        }
        self.revision += self.version != old

    def set_param(self, name: str, value: float | int) -> None:
        """One PX4 parameter's value (a change counts as a new revision)."""
        if self.params.get(name, _MISSING) != value:
            self.params[name] = value
            self.revision += 1

    def _home(self, m: Any, receive_ns: int) -> None:
        """HOME_POSITION (latitude/longitude degE7, altitude mm AMSL, x y z local NED m); a
        home without a global position (MAVROS' local home, latitude 0 and longitude 0)
        gives no site."""
        lat, lon, alt = (getattr(m, k, None) for k in ("latitude", "longitude", "altitude"))
        if not isinstance(lat, int) or not isinstance(lon, int) or (lat == 0 and lon == 0):
            return
        self.set_site(
            "HOME_POSITION",
            lat * 1e-7,
            lon * 1e-7,
            None if not isinstance(alt, int) else alt * 1e-3,
            [float(getattr(m, k, 0.0)) for k in "xyz"],
            receive_ns,
        )

    def set_site(
        self,
        source: str,
        latitude_deg: float,
        longitude_deg: float,
        altitude_amsl_m: float | None,
        local_ned_m,
        receive_ns: int,
        **extra: Any,
    ) -> None:
        """The autopilot's home: WGS-84 latitude/longitude [deg], altitude AMSL [m] (None:
        unknown), the local NED home [m]; ``extra``: what the source adds (e.g. MAVROS'
        ellipsoid height). A latitude and longitude both 0 is no global home: ignored."""
        if latitude_deg == 0.0 and longitude_deg == 0.0:
            return
        h = {
            "source": source,
            "latitude_deg": float(latitude_deg),
            "longitude_deg": float(longitude_deg),
            "altitude_amsl_m": None if altitude_amsl_m is None else float(altitude_amsl_m),
            "local_ned_m": [round(float(x), 3) for x in local_ned_m],
            "stamp_ns": int(receive_ns),
            **extra,
        }
        if self.site is None:
            self.site = h
        keys = ("latitude_deg", "longitude_deg", "altitude_amsl_m", "local_ned_m")
        if self.site_last is None or any(self.site_last[k] != h[k] for k in keys):
            self.revision += 1
        self.site_last = h

    def battery_reading(self, ns: int, volts: float, remaining: int) -> None:
        """A battery reading at ``ns``: voltage [V], remaining [%] (negative: unknown)."""
        b = {
            "stamp_ns": int(ns),
            "voltage_v": round(volts, 3),
            "remaining_pct": None if remaining < 0 else remaining,
        }
        if self.battery_first is None:
            self.battery_first = b
            self.revision += 1
        self.battery_last = b

    def clock_fit(self) -> tuple[int, float] | None:
        """``(boot_ns, rate)``: the bag time of PX4's boot and the bag nanoseconds per PX4
        nanosecond, a straight line through the per-second minima of receive - time_boot
        (a PX4 SITL in lock-step runs slower than the wall clock under load: the offset
        drifts, a single minimum is then off by the drift over the flight); None with fewer
        than 3 seconds of data (then ``boot_ns``, rate 1)."""
        if len(self.windows) < 3:
            return None
        items = sorted(self.windows.values(), key=lambda p: p[1])
        tb = np.array([p[1] for p in items], dtype=float)
        off = np.array([p[0] for p in items], dtype=float)
        # offset(tb) = off[0] + c0 + c1 (tb - tb[0]) (seconds in the fit, ns outside)
        c1, c0 = np.polyfit((tb - tb[0]) * 1e-9, (off - off[0]) * 1e-9, 1)
        boot = off[0] + c0 * 1e9 - c1 * tb[0]
        return int(round(boot)), float(1.0 + c1)

    def bag_ns_of(self, t_vehicle: float) -> int | None:
        """The bag-clock time (ns) of PX4 time ``t_vehicle`` (s since boot) by the live
        estimate (:class:`~lpv_sysid.mavlink.telemetry.clock.VehicleClock`: the lower
        envelope of receive - time_boot, rising at most ``LIVE_RISE``); None before the
        first message or for a time that is not one."""
        offset = self.live.offset
        if offset is None or not (t_vehicle > 0.0 and np.isfinite(t_vehicle)):
            return None
        return int(round((float(t_vehicle) + offset) * 1e9))

    def clock_knots(self) -> list[list]:
        """``[[time_boot_s, offset_ns], ...]``: per second of PX4 time the smallest
        receive - time_boot (at the PX4 time it was seen), in time order. A lock-step SITL's
        clock rate changes with the load, so a line (:meth:`clock_fit`) is not enough;
        between knots the offset is interpolated."""
        items = sorted(self.windows.values(), key=lambda p: p[1])
        return [[round(tb * 1e-9, 6), int(off)] for off, tb in items]

    def site_summary(self) -> dict | None:
        """The ``site`` of ``experiment.yaml``: the first home position the autopilot sent
        and, when it moved (a home reset), the last one; None without a global home."""
        if self.site is None:
            return None
        out = dict(self.site)
        last = self.site_last
        if last is not None and last is not self.site:
            keys = ("latitude_deg", "longitude_deg", "altitude_amsl_m", "local_ned_m")
            if any(last[k] != self.site[k] for k in keys):
                out["last"] = {k: last[k] for k in (*keys, "stamp_ns")}
        return out

    @property
    def kind(self) -> str:
        return vehicle_kind(self.params, self.hil_flag, self.custom_version)

    def summary(self) -> dict:
        """The ``vehicle`` entry of ``experiment.yaml``."""
        p = self.params
        fit = self.clock_fit()
        return {
            "kind": self.kind,
            "firmware": self.version,
            "airframe": {
                "SYS_AUTOSTART": p.get("SYS_AUTOSTART"),
                "MAV_TYPE": p.get("MAV_TYPE"),
                "CA_AIRFRAME": p.get("CA_AIRFRAME"),
            },
            "hil_flag": self.hil_flag,
            "battery": {"start": self.battery_first, "end": self.battery_last},
            "site": self.site_summary(),
            "px4_clock": {
                "boot_ns": self.boot_ns if fit is None else fit[0],
                "rate": 1.0 if fit is None else fit[1],
                "boot_ns_min": self.boot_ns,
                "knots": self.clock_knots(),
                "boot_samples": self.boot_samples,
                "meaning": "bag_stamp_ns = PX4 time since boot [ns] (ULog timestamp us * 1000) "
                "+ offset, offset interpolated in knots [PX4 time s, offset ns] (the per-second "
                "minima of receive time - time_boot_ms, late by the smallest latency); "
                "boot_ns + rate * PX4 time: the line through them; boot_ns_min: the overall "
                "minimum",
                "system_time": self.system_time,
                **({"note": self.clock_note} if self.clock_note and not self.boot_samples else {}),
            },
            "px4_parameters": dict(sorted(p.items())),
        }
