"""`lpv-sysid synthesize`: robust LPV H-infinity state feedback (seed 0 Lemma 1) -> gains.yaml.

    lpv-sysid synthesize --models vertex_models.yaml --config config/synthesis.yaml \
        --out gains.yaml

Writes gains.yaml (format: lpv_sysid.io.formats) with the certificate entry and the sidecar
``<out stem>.cert.npz`` (X, S, H, scaling) referenced by name and sha256; then runs the
independent verification (``lpv-sysid verify``) on what it wrote unless ``--no-verify``.
The certificate also records ``gains_sha256`` (the hash of the certified law), the sidecar
holds the certified systems (A_ij, B_ij), and with a phase-2 signals summary (``--summary``)
``design`` (the signal envelope the gains are designed for): the flight runtime
(lpv_controller_node) refuses gains without all three.

With ``uncertainty.common_b: true`` (config/synthesis.yaml) the input matrix of the Eq. (23)
polytope is the interval hull over all vertices, common to every vertex (lpv_sysid.models.lpv),
so Lemma 1 covers the interior of the scheduling box; ``certificate.input_structure`` records
which structure was solved (B common | per_vertex, M_A, M_B, the B hull) and the verifier
rebuilds and checks exactly that structure. Prints the sizes M_i = M_A x M_B and the wall time.

With ``uncertainty.set: full_box`` (the shipped config) the certified set is every element of the
models file in its interval (synthesis/robust/synthesize.py); ``certificate.certified_set`` states
exactly which plants (``kind``, the box in the sidecar) and which scheduling signals
(``scheduling.variation``: frozen | arbitrary | rate_bounded, ``covers_design_signal``) the bound
covers, and ``certificate.problem`` the sizes -- for a corner polytope also seed 0's Lemma 1 over
the same systems counted the package's way and the way CVX reports them (docs/certificate.md).

With ``--loop-delay S`` (the configured loop delay of the controller that will fly the gains,
e.g. 0.06 for config/lpv_controller_px4.yaml) the synthesis is repeated with a smaller pole
region until ``certificate.loop_delay.bound_s`` >= S (:mod:`lpv_sysid.synthesis.gains.loop_cover`,
the chain's step 4 too); the configuration used is written next to the gains
(``<out stem>.synthesis.yaml``); exit 1 when no region covers S.

The steps are :mod:`lpv_sysid.synthesis.gains` (inputs, solve, certificate, files,
verification); this command maps their errors to its flags and prints what they did.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

from lpv_sysid.errors import ConfigError
from lpv_sysid.io.formats import load_seal_key
from lpv_sysid.synthesis.gains import (
    cover_loop,
    describe_problem,
    load_inputs,
    synthesize,
    verify_written,
    write_gains,
)

COMMAND = "synthesize"
HELP = (
    "robust polytopic LPV H-infinity state feedback (seed 0 Lemma 1) -> gains.yaml + certificate"
)

#: command-line flags that set a configuration field (named in core errors by the field)
FLAG_OF_FIELD = {
    "hinf.gamma": "--gamma",
    "hinf.solver": "--solver",
    "weights.summary": "--summary",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--models", required=True, help="vertex_models.yaml (identify)")
    parser.add_argument("--config", required=True, help="config/synthesis.yaml")
    parser.add_argument(
        "--out", required=True, help="gains.yaml to write (sidecar <stem>.cert.npz next to it)"
    )
    parser.add_argument(
        "--summary", default=None, help="signals summary.yaml with R and Q (overrides weights)"
    )
    parser.add_argument("--gamma", type=float, default=None, help="override hinf.gamma")
    parser.add_argument(
        "--solver", default=None, help="override hinf.solver (CLARABEL, SCS, MOSEK)"
    )
    parser.add_argument(
        "--no-verify", action="store_true", help="skip the independent verification"
    )
    parser.add_argument(
        "--loop-delay",
        type=float,
        default=None,
        metavar="S",
        help="configured loop delay [s] of the controller that flies the gains: synthesize "
        "again with a smaller pole region until the certificate's delay bound covers it",
    )
    parser.add_argument(
        "--key",
        default=None,
        metavar="FILE",
        help="operator seal key (32 raw bytes or 64 hex characters, like a MAVLink signing "
        "key): the gains file also gets seal.hmac_sha256, which only a key holder can write "
        "(docs/certificate.md, 'Seal')",
    )


def with_flag(message: str) -> str:
    """A core's error message with the command-line flag of the field it names appended."""
    for name, flag in FLAG_OF_FIELD.items():
        if message.startswith(name) or f"({name})" in message:
            return f"{message} [{flag}]"
    return message


def run(args: argparse.Namespace) -> int:
    """``lpv-sysid synthesize``: load, synthesise, write gains.yaml + sidecar, verify; with
    ``--loop-delay`` until the certificate covers that loop."""
    if args.loop_delay is None:
        return _once(args, args.config)
    if not (math.isfinite(args.loop_delay) and 0.0 < args.loop_delay < 1.0):
        raise ConfigError(f"--loop-delay must be in (0, 1) s, got {args.loop_delay!r}")
    if args.no_verify:
        raise ConfigError("--loop-delay needs the verification (drop --no-verify)")
    out = Path(args.out)

    def attempt(cfg: Path) -> tuple[bool, Path]:
        return _once(args, str(cfg)) == 0, out

    used = out.with_name(out.stem + ".synthesis.yaml")
    ok, tried = cover_loop(args.config, used, args.loop_delay, attempt, print)
    print(f"wrote {used} (the configuration of the gains written)")
    if ok and tried[-1].get("loop_delay_bound_s", 0.0) >= args.loop_delay:
        return 0
    print(
        f"no pole region tried certifies the {args.loop_delay * 1e3:.1f} ms loop: the "
        "controller refuses these gains at start; lower the loop delay (loop rate, transport)"
    )
    return 1


def _once(args: argparse.Namespace, config: str) -> int:
    """One synthesis with ``config``, written and (unless ``--no-verify``) verified."""
    try:
        inp = load_inputs(args.models, config, args.summary, args.gamma, args.solver)
        for line in inp.notes + describe_problem(inp):
            print(line)
        res = synthesize(inp)
    except ConfigError as exc:
        raise ConfigError(with_flag(str(exc))) from None
    key = load_seal_key(args.key) if args.key else None
    written = write_gains(Path(args.out), args.models, inp, res, seal_key=key)
    for line in written.lines:
        print(line)
    print(f"wrote {written.gains}")
    print(f"wrote {written.sidecar}")
    if args.no_verify:
        return 0
    t1 = time.perf_counter()
    rep = verify_written(written.gains, args.models, inp)
    print(rep.table())
    print(f"verification took {time.perf_counter() - t1:.2f} s")
    if not rep.passed:
        print(
            "independent verification FAILED (see table); the gains file was written but must "
            "not be flown"
        )
        return 1
    return 0
