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

The steps of :func:`run` live in :mod:`lpv_sysid.synthesis.gains.inputs` (config, options, models,
weights), :mod:`lpv_sysid.synthesis.gains.certificate` (the certificate entry) and
:mod:`lpv_sysid.synthesis.gains.outputs` (gains.yaml, sidecar, printed result); their names are
re-exported here.
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

import numpy as np

from lpv_sysid.errors import ConfigError, SolverError
from lpv_sysid.synthesis.gains import VARIATION, Inputs, load_inputs, write_outputs

COMMAND = "synthesize"
HELP = (
    "robust polytopic LPV H-infinity state feedback (seed 0 Lemma 1) -> gains.yaml + certificate"
)

log = logging.getLogger(__name__)


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


def run(args: argparse.Namespace) -> int:
    """``lpv-sysid synthesize``: load, synthesise, write gains.yaml + sidecar, verify."""
    inp = load_inputs(args)
    describe_problem(args.models, inp)
    res = synthesize(inp, args)
    out, side = write_outputs(args, inp, res)
    print(f"wrote {out}")
    print(f"wrote {side}")
    if args.no_verify:
        return 0
    return verify(out, args.models, inp)


def describe_problem(models_path: str, inp: Inputs) -> None:
    """Print which certified set and input structure is about to be solved."""
    model, opts = inp.model, inp.opts
    st = model.input_structure
    Ms = st["M"]
    if model.box is not None:
        box = model.box
        per = box.p[0] if len(set(box.p)) == 1 else box.p
        print(
            f"certified set: the full identified box (uncertainty.set: full_box), {per} "
            "elements per vertex as a structured perturbation (B hull common to all vertices); "
            f"Lyapunov matrix: {opts.lyapunov} ({VARIATION[opts.lyapunov]} v_d)"
        )
    elif model.common_input is not None:
        els = ", ".join(
            f"B[{e.row},{e.col}] in [{e.lower:.6g}, {e.upper:.6g}]"
            for e in model.common_input.elements
        )
        print(
            "input matrix common to all vertices (uncertainty.common_b): hull "
            f"{els or '(B identical)'}; M_i = M_A x M_B = {st['M_A']} x {st['M_B']} = {Ms} "
            f"(sum {sum(Ms)}, {st['B_method']} corners); Lemma 1 covers the whole box"
        )
    else:
        print(
            f"uncertainty vertices per scheduling vertex M_i = {Ms} (per-vertex B, "
            "uncertainty.common_b: false)"
        )
        bs = {tuple(np.round(np.array([b for _, b in lst]), 12).ravel()) for lst in model.systems}
        if len(bs) > 1:
            print(
                "note: B differs between scheduling vertices; Lemma 1 certifies the vertices, "
                "the interior (B(v_d) S(v_d) is bilinear) is only checked by the verifier's "
                "random interior points"
            )


#: command-line flags that set a configuration field (named in core errors by the field)
FLAG_OF_FIELD = {
    "hinf.gamma": "--gamma",
    "hinf.solver": "--solver",
    "weights.summary": "--summary",
}


def with_flag(message: str) -> str:
    """A core's error message with the command-line flag of the field it names appended."""
    for name, flag in FLAG_OF_FIELD.items():
        if message.startswith(name) or f"({name})" in message:
            return f"{message} [{flag}]"
    return message


def synthesize(inp: Inputs, args: argparse.Namespace):
    """Lemma 1 (or the element-box LMI) on the loaded inputs: the HinfResult, its info
    completed; SolverError with the structural hint on failure."""
    from lpv_sysid.synthesis.hinf import synthesize_hinf

    model = inp.model
    try:
        res = synthesize_hinf(model, inp.R, inp.C, inp.opts)
    except ConfigError as exc:
        raise ConfigError(with_flag(str(exc))) from None
    except SolverError as exc:
        hint = ""
        if model.common_input is not None and model.common_input.elements:
            hint = (
                " | the input matrix is the hull over all vertices (uncertainty.common_b: true); "
                "if B(v_d) varies strongly across the box, narrow the box; common_b: false "
                "certifies the vertices only"
            )
        raise SolverError(str(exc).replace("\n", " | ") + hint) from None
    res.info["rate_from_design"] = inp.rate_from_design
    res.info["n_e"], res.info["n_z"] = inp.R.shape[1], inp.C.shape[0]
    res.info["wall"] = time.perf_counter() - inp.t0
    return res


def verify(out: Path, models_path: str, inp: Inputs) -> int:
    """The independent verification (synthesis/verify/checker.py) of what was written: 0 passed, 1
    failed (the gains must not be flown)."""
    from lpv_sysid.synthesis.verify import verify_files

    vcfg = inp.cfg.get("verify") or {}
    log.info("independent verification of %s", out)
    t1 = time.perf_counter()
    rep = verify_files(
        out,
        models_path,
        n_random=int(vcfg.get("n_random", 20)),
        seed=int(vcfg.get("seed", 0)),
        velocity_index=inp.vidx,
    )
    print(rep.table())
    print(f"verification took {time.perf_counter() - t1:.2f} s")
    if not rep.passed:
        print(
            "independent verification FAILED (see table); the gains file was written but must "
            "not be flown"
        )
        return 1
    return 0
