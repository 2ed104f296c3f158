"""`lpv-sysid preflight`: go/no-go check of a PX4 vehicle before an offboard experiment.

``lpv-sysid preflight --connect udpin:127.0.0.1:14540`` checks the link, autopilot and
firmware (AUTOPILOT_VERSION), mode and arming state, the offboard-loss parameters
(COM_OF_LOSS_T, COM_OBL_RC_ACT, ...) and the telemetry streams, prints a table and exits
0 (GO), 1 (NO-GO) or 2 (bad input).
"""

from __future__ import annotations

import argparse

from lpv_sysid.errors import ConfigError

COMMAND = "preflight"
HELP = "check link, firmware, modes and failsafe parameters of a PX4 vehicle; print go/no-go"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--connect", required=True, metavar="URL",
                        help="udpin:H:P, udpout:H:P, tcp:H:P, serial device[:baud], or udp://:14540")
    parser.add_argument("--timeout", type=float, default=5.0, help="seconds to gather facts (default 5)")
    parser.add_argument("--signing-key", default=None, metavar="FILE",
                        help="MAVLink 2 signing secret (32 raw bytes or 64 hex chars)")
    parser.add_argument("--baud", type=int, default=921600, help="serial baud rate (default 921600)")


def run(args: argparse.Namespace) -> int:
    from lpv_sysid.mavlink.link import LinkConfig, MavlinkLink
    from lpv_sysid.mavlink.preflight import format_table, run_checks, verdict

    if not (args.timeout > 0 and args.timeout < 600):
        raise ConfigError("--timeout must be in (0, 600) s")
    cfg = LinkConfig(url=args.connect, baud=args.baud, signing_key_file=args.signing_key)
    cfg.validate()
    link = MavlinkLink(cfg)
    link.open()
    try:
        checks = run_checks(link, timeout=args.timeout)
    finally:
        link.close()
    print(format_table(checks))
    ok = verdict(checks)
    print(f"preflight {args.connect}: {'GO' if ok else 'NO-GO'}")
    return 0 if ok else 1
