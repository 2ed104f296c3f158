"""`lpv-sysid preflight`: go/no-go check of a PX4 vehicle before an offboard experiment.

``lpv-sysid preflight --connect udpin:127.0.0.1:14540`` checks the link, autopilot and
firmware (AUTOPILOT_VERSION), mode and arming state, the offboard-loss parameters
(COM_OF_LOSS_T, COM_OBL_RC_ACT against the stick input, ...), the telemetry streams and
the rotor-speed source (ESC telemetry or the estimate from the motor outputs), prints a
table with the reasons and fixes and exits 0 (GO), 1 (NO-GO) or 2 (bad input).
``--config config/mavlink_bridge.yaml`` checks with the bridge's link streams and
``rotor_estimate`` settings (``--connect`` replaces its URL). Battery, GPS fix, EKF health
and the home position are always checked; ``--campaign config/campaign.yaml`` also checks
the battery and PX4's velocity and tilt limits against that campaign's plan (what
``lpv-sysid fly phase1`` checks before it flies).
"""

from __future__ import annotations

import argparse

from lpv_sysid.errors import ConfigError

COMMAND = "preflight"
HELP = "check link, firmware, modes and failsafe parameters of a PX4 vehicle; print go/no-go"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--connect",
        required=True,
        metavar="URL",
        help="udpin:H:P, udpout:H:P, tcp:H:P, serial device[:baud], or udp://:14540",
    )
    parser.add_argument(
        "--timeout", type=float, default=5.0, help="seconds to gather facts at most (default 5)"
    )
    parser.add_argument(
        "--grace",
        type=float,
        default=1.5,
        help="seconds to wait for streams that may be absent (ESC_STATUS, RC) after the "
        "stream requests (default 1.5)",
    )
    parser.add_argument(
        "--config",
        default=None,
        metavar="FILE",
        help="bridge config (config/mavlink_bridge.yaml): link streams and rotor_estimate",
    )
    parser.add_argument(
        "--campaign",
        default=None,
        metavar="FILE",
        help="campaign file (config/campaign.yaml): check battery and PX4's MPC_* limits "
        "against its plan",
    )
    parser.add_argument(
        "--endurance-min",
        type=float,
        default=15.0,
        metavar="MIN",
        help="hover endurance of one battery [min] (with --campaign; default 15)",
    )
    parser.add_argument(
        "--signing-key",
        default=None,
        metavar="FILE",
        help="MAVLink 2 signing secret (32 raw bytes or 64 hex chars)",
    )
    parser.add_argument(
        "--baud",
        type=int,
        default=None,
        help="serial baud rate (default: the config's, else 921600)",
    )


def run(args: argparse.Namespace) -> int:
    import dataclasses

    from lpv_sysid.mavlink.bridge import BridgeConfig
    from lpv_sysid.mavlink.link import LinkConfig, MavlinkLink
    from lpv_sysid.mavlink.preflight import format_table, run_checks, verdict
    from lpv_sysid.mavlink.telemetry import RotorEstimateConfig

    if not (args.timeout > 0 and args.timeout < 600):
        raise ConfigError("--timeout must be in (0, 600) s")
    if not (args.grace > 0 and args.grace < 600):
        raise ConfigError("--grace must be in (0, 600) s")
    if args.config:
        bridge = BridgeConfig.load(args.config)
        kw = {"url": args.connect, "baud": args.baud or bridge.link.baud}
        if args.signing_key:
            kw["signing_key_file"] = args.signing_key
        cfg, rotor = dataclasses.replace(bridge.link, **kw), bridge.rotor_estimate
    else:
        cfg = LinkConfig(
            url=args.connect, baud=args.baud or 921600, signing_key_file=args.signing_key
        )
        rotor = RotorEstimateConfig()
    cfg.validate()
    demands = needed = None
    if args.campaign:
        from lpv_sysid.flight.campaign import FlyConfig, plan_flight

        if not args.endurance_min > 0:
            raise ConfigError("--endurance-min must be > 0 minutes")
        plan = plan_flight(FlyConfig.load(args.campaign), args.connect)
        demands = plan.demands()
        needed = plan.budget(args.endurance_min * 60.0).battery_needed_pct
    link = MavlinkLink(cfg)
    link.open()
    try:
        checks = run_checks(
            link,
            timeout=args.timeout,
            grace=args.grace,
            rotor_estimate=rotor,
            demands=demands,
            battery_needed_pct=needed,
        )
    finally:
        link.close()
    print(format_table(checks))
    ok = verdict(checks)
    print(f"preflight {args.connect}: {'GO' if ok else 'NO-GO'}")
    return 0 if ok else 1
