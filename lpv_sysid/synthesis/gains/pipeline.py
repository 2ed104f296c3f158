"""One synthesis, start to end: what is about to be solved, the solve, the independent
verification of what was written (``lpv-sysid synthesize``, ``lpv-sysid chain``).

    inp = load_inputs("vertex_models.yaml", "config/synthesis.yaml", summary=".../summary.yaml")
    res = synthesize(inp)
    written = write_gains(Path("gains.yaml"), "vertex_models.yaml", inp, res)
    report = verify_written(written.gains, "vertex_models.yaml", inp)
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from lpv_sysid.errors import SolverError
from lpv_sysid.synthesis.gains.certificate import VARIATION
from lpv_sysid.synthesis.gains.inputs import Inputs

log = logging.getLogger(__name__)


def describe_problem(inp: Inputs) -> list[str]:
    """Which certified set and input structure is about to be solved, one line each."""
    model, opts = inp.model, inp.opts
    st = model.input_structure
    Ms = st["M"]
    if model.box is not None:
        box = model.box
        per = box.p[0] if len(set(box.p)) == 1 else box.p
        return [
            f"certified set: the full identified box (uncertainty.set: full_box), {per} "
            "elements per vertex as a structured perturbation (B hull common to all vertices); "
            f"Lyapunov matrix: {opts.lyapunov} ({VARIATION[opts.lyapunov]} v_d)"
        ]
    if model.common_input is not None:
        els = ", ".join(
            f"B[{e.row},{e.col}] in [{e.lower:.6g}, {e.upper:.6g}]"
            for e in model.common_input.elements
        )
        covers = (
            "Lemma 1 covers the whole box"
            if _all_corners(inp)
            else "Lemma 1 covers the scheduling box interior for these reduced corner systems "
            "only (a reduced polytope, NOT the whole identified box: the influence reduction "
            "holds the other elements at their nominal values)"
        )
        return [
            "input matrix common to all vertices (uncertainty.common_b): hull "
            f"{els or '(B identical)'}; M_i = M_A x M_B = {st['M_A']} x {st['M_B']} = {Ms} "
            f"(sum {sum(Ms)}, {st['B_method']} corners); {covers}"
        ]
    lines = [
        f"uncertainty vertices per scheduling vertex M_i = {Ms} (per-vertex B, "
        "uncertainty.common_b: false)"
    ]
    bs = {tuple(np.round(np.array([b for _, b in lst]), 12).ravel()) for lst in model.systems}
    if len(bs) > 1:
        lines.append(
            "note: B differs between scheduling vertices; Lemma 1 certifies the vertices, "
            "the interior (B(v_d) S(v_d) is bilinear) is only checked by the verifier's "
            "random interior points"
        )
    return lines


def _all_corners(inp: Inputs) -> bool:
    """True when the corner polytope is the whole identified box: the B hull taken with all its
    corners and every vertex's free A elements all varied (M_A,i = 2^(free A elements))."""
    st = inp.model.input_structure
    if st.get("B_method") != "box":
        return False
    free_a = [
        sum(
            1
            for e in v.get("uncertain") or []
            if e.get("matrix") == "A" and float(e["upper"]) > float(e["lower"])
        )
        for v in inp.raw.get("vertices", [])
    ]
    M_A = st.get("M_A")
    M_A = list(M_A) if isinstance(M_A, (list, tuple)) else [M_A] * len(free_a)
    return len(M_A) == len(free_a) and all(int(m) == 2**f for m, f in zip(M_A, free_a))


def synthesize(inp: Inputs):
    """Lemma 1 (or the element-box LMI) on the loaded inputs: the HinfResult, its info
    completed; SolverError with the structural hint on failure (ConfigError names the
    configuration field)."""
    from lpv_sysid.parallel.pool import one_blas_thread
    from lpv_sysid.synthesis.hinf import synthesize_hinf

    model = inp.model
    try:
        # one BLAS thread: the LMI is a few hundred variables, and OpenBLAS' second thread
        # spins for its share of the work; with the host's cores busy (load 14 on 2 cores)
        # the same CLARABEL solve took 69 s instead of 6.4 s (1.7 s CPU either way)
        with one_blas_thread():
            res = synthesize_hinf(model, inp.R, inp.C, inp.opts)
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


def verify_written(gains: Path, models: str, inp: Inputs):
    """The independent verification (:func:`lpv_sysid.synthesis.verify.verify_files`) of the
    written ``gains`` with the synthesis config's ``verify`` settings: the VerifyReport (not
    passed: the gains must not be flown)."""
    from lpv_sysid.synthesis.verify import verify_files

    log.info("independent verification of %s", gains)
    return verify_files(
        gains,
        models,
        n_random=inp.cfg.verify.n_random,
        seed=inp.cfg.verify.seed,
        velocity_index=inp.vidx,
    )
