"""`lpv-sysid sim-vehicle`: a simulated PX4-like quadrotor speaking MAVLink 2 on UDP.

``lpv-sysid sim-vehicle --udp 127.0.0.1:14540`` sends like PX4 SITL to the offboard
port 14540 (connect the bridge with ``udpin:127.0.0.1:14540`` or MAVSDK with
``udpin://127.0.0.1:14540``). Its socket is bound to the local interface that routes to
that destination (loopback by default), never to all interfaces; ``--bind HOST[:PORT]``
chooses another. ``--config config/sim_vehicle_px4.yaml`` loads every option of
:class:`lpv_sysid.sim.px4_vehicle.vehicle.SimVehicleConfig` (flags given on the command line
win). It runs in real time until ``--duration`` elapses or Ctrl-C, then prints the
mode/arming history it went through. The vehicle's errors name the configuration field
(``bind``); this command appends the flag that sets it (``[--bind]``, :data:`FLAG_OF_FIELD`).
"""

from __future__ import annotations

import argparse
import logging
import re
from typing import Iterable

from lpv_sysid.errors import ConfigError, LpvSysidError

COMMAND = "sim-vehicle"
HELP = "run a simulated PX4-like quadrotor speaking MAVLink 2 (UDP) for bridge/MAVSDK tests"

log = logging.getLogger(__name__)

#: SimVehicleConfig fields that a command-line flag sets (the vehicle's errors name the field)
FLAG_OF_FIELD = {
    "url": "--udp/--connect",
    "bind": "--bind",
    "initial_mode": "--mode",
    "system_id": "--system-id",
    "physics_hz": "--physics-hz",
    "signing_key_file": "--signing-key",
    "allow_unsigned": "--allow-unsigned",
    "rc_present": "--rc",
    "esc_telemetry": "--no-esc-telemetry",
    "actuator_output_scale": "--actuator-output-scale",
    "sensor_noise": "--noise",
}


def with_flag(message: str, fields: Iterable[str] = tuple(FLAG_OF_FIELD)) -> str:
    """``message`` with the flag of the first of ``fields`` (SimVehicleConfig field names) it
    names appended: ``"... in the bind field (HOST[:PORT])"`` -> ``"... [--bind]"``."""
    for name in fields:
        if re.search(rf"(?<![\w.]){re.escape(name)}(?!\w)", message, re.IGNORECASE):
            return f"{message} [{FLAG_OF_FIELD[name]}]"
    return message


def add_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_mutually_exclusive_group()
    g.add_argument(
        "--udp",
        metavar="HOST:PORT",
        default=None,
        help="send to HOST:PORT like PX4 SITL (default 127.0.0.1:14540)",
    )
    g.add_argument(
        "--connect",
        metavar="URL",
        default=None,
        help="any link URL instead (udpin:H:P, udpout:H:P, tcpin:H:P, serial device)",
    )
    parser.add_argument(
        "--config",
        metavar="FILE",
        default=None,
        help="YAML with SimVehicleConfig keys (e.g. config/sim_vehicle_px4.yaml)",
    )
    parser.add_argument(
        "--bind",
        metavar="HOST[:PORT]",
        default=None,
        help="local address of the UDP socket (default: the interface that routes to "
        "the destination, 127.0.0.1 for a loopback destination)",
    )
    parser.add_argument(
        "--duration",
        type=float,
        default=None,
        help="stop after this many simulated seconds (default: run until Ctrl-C)",
    )
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override a PX4 parameter, e.g. COM_OBL_RC_ACT=5 (repeatable)",
    )
    parser.add_argument("--mode", default=None, help="initial PX4 mode name (default HOLD)")
    parser.add_argument(
        "--system-id", type=int, default=None, help="MAVLink system id (default 1)"
    )
    parser.add_argument(
        "--physics-hz", type=float, default=None, help="physics/controller rate (default 250)"
    )
    parser.add_argument(
        "--signing-key",
        default=None,
        metavar="FILE",
        help="MAVLink 2 signing secret (32 raw bytes or 64 hex chars): unsigned "
        "messages are then ignored",
    )
    parser.add_argument(
        "--allow-unsigned",
        action="store_true",
        default=None,
        help="with --signing-key: still accept unsigned messages",
    )
    parser.add_argument(
        "--rc",
        action="store_true",
        default=None,
        help="an RC transmitter is present (sticks centred); default: no RC, as SITL",
    )
    parser.add_argument(
        "--no-esc-telemetry",
        action="store_true",
        default=None,
        help="no ESC_STATUS (like SIH or PWM ESCs); motor outputs only",
    )
    parser.add_argument(
        "--actuator-output-scale",
        choices=("pwm", "normalized"),
        default=None,
        help="ACTUATOR_OUTPUT_STATUS values (default pwm)",
    )
    parser.add_argument(
        "--noise", action="store_true", default=None, help="add sensor noise to the telemetry"
    )
    parser.add_argument(
        "--speed",
        type=float,
        default=1.0,
        help="simulated seconds per wall-clock second (default 1 = real time)",
    )


def _params(items: list[str]) -> dict[str, float]:
    out: dict[str, float] = {}
    for it in items:
        name, sep, value = it.partition("=")
        if not sep or not name:
            raise ConfigError(f"--param {it!r}: expected NAME=VALUE")
        try:
            v = float(value)
        except ValueError:
            raise ConfigError(f"--param {it!r}: value is not a number") from None
        out[name.strip().upper()] = int(v) if v.is_integer() else v
    return out


def build_config(args: argparse.Namespace):
    """The SimVehicleConfig of the command line (``--config`` file, then the flags)."""
    from lpv_sysid.sim.px4_vehicle import SimVehicleConfig

    base = SimVehicleConfig.load(args.config) if args.config else SimVehicleConfig()
    kw: dict = {}
    if args.connect:
        kw["url"] = args.connect
    elif args.udp or not args.config:
        hostport = args.udp or "127.0.0.1:14540"
        if hostport.count(":") != 1:
            raise ConfigError(f"--udp {hostport!r}: expected HOST:PORT")
        kw["url"] = f"udpout:{hostport}"
    flags = {
        "bind": args.bind,
        "initial_mode": args.mode,
        "system_id": args.system_id,
        "physics_hz": args.physics_hz,
        "signing_key_file": args.signing_key,
        "allow_unsigned": args.allow_unsigned,
        "rc_present": args.rc,
        "esc_telemetry": False if args.no_esc_telemetry else None,
        "actuator_output_scale": args.actuator_output_scale,
        "sensor_noise": args.noise,
    }
    kw.update({k: v for k, v in flags.items() if v is not None})
    if args.param:
        kw["params"] = {**dict(base.params), **_params(args.param)}
    if kw.get("system_id") is not None and not 1 <= kw["system_id"] <= 255:
        raise ConfigError("--system-id must be 1..255")
    d = {k: getattr(base, k) for k in base.__dataclass_fields__}
    d.update(kw)
    try:
        return SimVehicleConfig.from_dict(d, "")  # errors name the bare field (with_flag)
    except ConfigError as exc:  # name the flag only for a value that came from one
        raise ConfigError(with_flag(str(exc), [k for k in FLAG_OF_FIELD if k in kw])) from None


def run(args: argparse.Namespace) -> int:
    from lpv_sysid.sim.px4_vehicle import SimVehicle

    if args.duration is not None and not args.duration > 0:
        raise ConfigError("--duration must be positive")
    if not (args.speed > 0 and args.speed <= 100):
        raise ConfigError("--speed must be in (0, 100]")
    cfg = build_config(args)
    veh = SimVehicle(cfg)
    try:
        veh.open()
    except LpvSysidError as exc:  # e.g. no route to the destination: choose the bind address
        raise type(exc)(with_flag(str(exc), ["bind"])) from None
    local = f"{veh.local_address[0]}:{veh.local_address[1]}" if veh.local_address else "n/a"
    print(
        f"sim-vehicle: PX4-like quadrotor (system {cfg.system_id}, autopilot PX4 v1.16 emulation) "
        f"on {cfg.url} (local socket {local}); mode {veh.mode.name}; "
        f"RC {'present' if cfg.rc_present else 'absent'}; ESC telemetry "
        f"{'on' if cfg.esc_telemetry else 'off'}; signing "
        f"{'on' if cfg.signing_key_file else 'off'}; "
        + ", ".join(
            f"{k}={veh.param(k):g}"
            for k in ("COM_OF_LOSS_T", "COM_OBL_RC_ACT", "COM_DISARM_PRFLT", "COM_RC_IN_MODE")
        ),
        flush=True,
    )
    try:
        veh.run_realtime(args.duration, speed=args.speed)
    except KeyboardInterrupt:
        pass
    finally:
        veh.close()
    print(
        f"sim-vehicle: stopped after {veh.t:.1f} s; received {veh.setpoints_received} setpoints; "
        f"final mode {veh.mode.name}, {'armed' if veh.armed else 'disarmed'}, "
        f"position NED {[round(float(v), 2) for v in veh.x[0:3]]}"
    )
    for t, mode, reason in veh.mode_log:
        print(f"  t={t:7.2f} s  {mode:<10} {reason}")
    for t, err in veh.param_rejections:
        print(f"  t={t:7.2f} s  PARAM_SET refused: {err}")
    print(f"  link: {veh.link.stats.as_dict()}")
    return 0
