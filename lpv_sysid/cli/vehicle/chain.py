"""`lpv-sysid chain`: the whole two-phase job on a connected PX4 vehicle, end to end.

    lpv-sysid chain --connect udpin:127.0.0.1:14540 --out DIR [--set-param COM_OBL_RC_ACT=5]

The steps and what each writes: :mod:`lpv_sysid.flight.chain`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lpv_sysid.flight.chain import chain

COMMAND = "chain"
HELP = (
    "on a connected PX4: phase-1 campaign -> rate-plant identification -> signals -> synthesis + "
    "verification -> phase-2 flight under the LPV law -> report"
)


# ================================================================================== CLI
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--connect", required=True, metavar="URL", help="MAVLink URL of the PX4 vehicle"
    )
    parser.add_argument("--out", required=True, type=Path, help="output directory")
    parser.add_argument(
        "--campaign",
        default=None,
        help="phase-1 campaign config (default config/campaign_chain.yaml)",
    )
    parser.add_argument(
        "--set-param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="PARAM_SET before phase 1 (e.g. COM_OBL_RC_ACT=5 on a SITL without RC), held "
        "through phase 2 and set back when the chain ends",
    )
    parser.add_argument(
        "--kappa", type=float, default=1.0, help="phase-2 excitation multiplier (seed 0 Eq. 33)"
    )
    parser.add_argument(
        "--phase1",
        default=None,
        metavar="DIR",
        help="use the bags of an earlier phase-1 flight (its DIR/phase1) instead of flying "
        "phase 1; the vehicle must be armed and in the air (HOLD) for phase 2",
    )
    parser.add_argument(
        "--k-sigma",
        type=float,
        default=2.0,
        help="model intervals nominal +- k std of the identified entries (0: nominal only)",
    )


def run(args: argparse.Namespace) -> int:
    from lpv_sysid.cli.vehicle.fly import parse_params

    return chain(
        args.connect,
        args.out,
        params=parse_params(args.set_param),
        campaign_config=args.campaign,
        kappa=args.kappa,
        k_sigma=args.k_sigma,
        phase1_dir=args.phase1,
        echo=print,
    )
