"""`lpv-sysid sim-vehicle`: a simulated PX4-like quadrotor speaking MAVLink 2 on UDP.

``lpv-sysid sim-vehicle --udp 127.0.0.1:14540`` sends like PX4 SITL to the offboard
port 14540 (connect the bridge with ``udpin:127.0.0.1:14540`` or MAVSDK with
``udpin://0.0.0.0:14540``). It runs in real time until ``--duration`` elapses or Ctrl-C,
then prints the mode/arming history it went through.
"""

from __future__ import annotations

import argparse
import logging

from lpv_sysid.errors import ConfigError

COMMAND = "sim-vehicle"
HELP = "run a simulated PX4-like quadrotor speaking MAVLink 2 (UDP) for bridge/MAVSDK tests"

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_mutually_exclusive_group()
    g.add_argument("--udp", metavar="HOST:PORT", default=None,
                   help="send to HOST:PORT like PX4 SITL (default 127.0.0.1:14540)")
    g.add_argument("--connect", metavar="URL", default=None,
                   help="any link URL instead (udpin:H:P, udpout:H:P, tcpin:H:P, serial device)")
    parser.add_argument("--duration", type=float, default=None,
                        help="stop after this many simulated seconds (default: run until Ctrl-C)")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                        help="override a PX4 parameter, e.g. COM_OBL_RC_ACT=5 (repeatable)")
    parser.add_argument("--mode", default="HOLD", help="initial PX4 mode name (default HOLD)")
    parser.add_argument("--system-id", type=int, default=1, help="MAVLink system id (default 1)")
    parser.add_argument("--physics-hz", type=float, default=250.0, help="physics/controller rate")
    parser.add_argument("--signing-key", default=None, metavar="FILE",
                        help="MAVLink 2 signing secret (32 raw bytes or 64 hex chars)")
    parser.add_argument("--noise", action="store_true", help="add sensor noise to the telemetry")
    parser.add_argument("--speed", type=float, default=1.0,
                        help="simulated seconds per wall-clock second (default 1 = real time)")


def _params(items: list[str]) -> dict[str, float]:
    out: dict[str, float] = {}
    for it in items:
        name, sep, value = it.partition("=")
        if not sep or not name:
            raise ConfigError(f"--param {it!r}: expected NAME=VALUE")
        try:
            out[name.strip().upper()] = float(value)
        except ValueError:
            raise ConfigError(f"--param {it!r}: value is not a number") from None
    return out


def run(args: argparse.Namespace) -> int:
    from lpv_sysid.mavlink.sim_vehicle import SimVehicle, SimVehicleConfig

    if args.connect:
        url = args.connect
    else:
        hostport = args.udp or "127.0.0.1:14540"
        if hostport.count(":") != 1:
            raise ConfigError(f"--udp {hostport!r}: expected HOST:PORT")
        url = f"udpout:{hostport}"
    if args.duration is not None and not args.duration > 0:
        raise ConfigError("--duration must be positive")
    if not (args.speed > 0 and args.speed <= 100):
        raise ConfigError("--speed must be in (0, 100]")
    if not 1 <= args.system_id <= 255:
        raise ConfigError("--system-id must be 1..255")
    cfg = SimVehicleConfig(url=url, system_id=args.system_id, physics_hz=args.physics_hz,
                           params=_params(args.param), initial_mode=args.mode,
                           signing_key_file=args.signing_key, sensor_noise=args.noise)
    veh = SimVehicle(cfg)
    veh.open()
    print(f"sim-vehicle: PX4-like quadrotor (system {cfg.system_id}, autopilot PX4 v1.16 emulation) "
          f"on {url}; mode {veh.mode.name}; "
          + ", ".join(f"{k}={veh.param(k):g}" for k in ("COM_OF_LOSS_T", "COM_OBL_RC_ACT", "COM_DISARM_PRFLT")),
          flush=True)
    try:
        veh.run_realtime(args.duration, speed=args.speed)
    except KeyboardInterrupt:
        pass
    finally:
        veh.close()
    print(f"sim-vehicle: stopped after {veh.t:.1f} s; received {veh.setpoints_received} setpoints; "
          f"final mode {veh.mode.name}, {'armed' if veh.armed else 'disarmed'}, "
          f"position NED {[round(float(v), 2) for v in veh.x[0:3]]}")
    for t, mode, reason in veh.mode_log:
        print(f"  t={t:7.2f} s  {mode:<10} {reason}")
    print(f"  link: {veh.link.stats.as_dict()}")
    return 0
