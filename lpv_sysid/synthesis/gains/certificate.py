"""The ``certificate`` entry of gains.yaml written by `lpv-sysid synthesize`.

What was solved (the LMI, its form and solver, the problem sizes -- for a corner polytope also
seed 0's Lemma 1 over the same systems counted the package's way and the way CVX reports them),
how well (gamma requested / solved / certified, margin), over exactly which plants and
scheduling signals (``certified_set``, ``input_structure``) and the sidecar (docs/certificate.md).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import numpy as np

from lpv_sysid.synthesis.gains.inputs import Inputs


def _structure_entry(model) -> dict:
    """certificate.input_structure: which Eq. (23) structure Lemma 1 was solved for."""
    st = dict(model.input_structure)
    if model.box is not None:
        st["covers"] = "scheduling box interior (element box, B hull common to all vertices)"
    elif model.common_input is not None:
        st["B_hull"] = [
            {"row": e.row, "col": e.col, "lower": e.lower, "upper": e.upper, "nominal": e.nominal}
            for e in model.common_input.elements
        ]
        st["covers"] = "scheduling box interior (Lemma 1, common B)"
    else:
        st["covers"] = "scheduling vertices (per-vertex B: interior only spot-checked)"
    return st


#: certified_set.scheduling.variation per hinf.lyapunov
VARIATION = {"vertex": "frozen", "common": "arbitrary", "rate": "rate_bounded"}


LMI_TEXT = {
    "corners": "seed 0 Lemma 1, Eq. (30) at every Eq. (23) system (Rotondo et al. Thm. 2)",
    "box": (
        "robust LMI over the element box: structured norm-bounded perturbation of the box centre, "
        "S-procedure with diagonal multipliers (Petersen 1987; Khargonekar, Petersen & Zhou 1990; "
        "Boyd et "
        "al. 1994 Sec. 5.1, 6.3.2), synthesis/robust/synthesize.py"
    ),
}


def _motor_summary(box, state_names, input_names) -> str:
    if tuple(state_names[8:12]) != ("dt", "da", "de", "dr") or tuple(input_names) != (
        "ut",
        "ua",
        "ue",
        "ur",
    ):
        return "not a quadrotor layout"
    labs = set()
    for i in range(box.N):
        r, c, _ = box.arrays(i)
        for k, (a, b) in enumerate(zip(r, c)):
            if 8 <= a < 12 and (b == a or b == box.n + a - 8):
                labs.add(box.labels[i][k] if box.labels and k < len(box.labels[i]) else "")
    if not labs:
        return (
            "not uncertain (the models file lists no motor element and uncertainty.motor_std is "
            "unset)"
        )
    if any(lb.startswith("motor constant") for lb in labs):
        return (
            "uncertain, intervals from uncertainty.motor_std of the synthesis config (nominal "
            "+/- k std)"
        )
    return (
        "uncertain, intervals of the models file (a_Omega, b_Omega identified per vertex; each "
        "motor row "
        "entry its own element)"
    )


def certified_set_entry(model, res, opts, design: Optional[dict]) -> dict:
    """certificate.certified_set: exactly which plants and which scheduling signals the bound
    covers."""
    lyap = opts.lyapunov
    method = res.info.get("method", "corners")
    var = VARIATION[lyap]
    sched: dict[str, Any] = {
        "variation": var,
        "lyapunov": {
            "vertex": "X_i per scheduling vertex (frozen v_d)"
            if method == "box"
            else "X_i^j per vertex and system (frozen v_d)",
            "common": "one X for all v_d and all plants in the set",
            "rate": "X(v_d) = sum_i alpha_i X_i, rate-bounded",
        }[lyap],
    }
    design_rate = None if design is None else [float(x) for x in design["reference_rate"]]
    if design_rate is not None:
        sched["design_reference_rate"] = design_rate
    if var == "arbitrary":
        sched["covers_design_signal"] = True
        sched["note"] = (
            "V = x^T X^-1 x decreases along every trajectory of the set: the u_e -> z bound of "
            "the deviation dynamics holds for any scheduling signal v_d(t) in the box; the "
            "reference-driven terms (d/dt x0(v_d), feedforward and x0/u0 interpolation errors) "
            "are not in it: references are bounded by certificate.design (rate, acceleration), "
            "refused before flight beyond it"
        )
    elif var == "rate_bounded":
        rate = [float(x) for x in opts.rate_bound]
        sched["rate_bound"] = rate
        sched["rate_source"] = (
            "certificate.design.reference_rate"
            if res.info.get("rate_from_design")
            else "hinf.rate_bound of the synthesis config"
        )
        sched["covers_design_signal"] = (
            None
            if design_rate is None
            else bool(all(d <= r * (1 + 1e-9) for d, r in zip(design_rate, rate)))
        )
    else:
        sched["covers_design_signal"] = False
        sched["note"] = (
            "frozen v_d only (seed 0 Lemma 1 with vertex-dependent X): the bound holds for every "
            "constant v_d in the box, not for the time-varying phase-2 reference"
        )
    entry: dict = {"scheduling": sched, "lmi": LMI_TEXT[method]}
    rate_txt = {
        "arbitrary": "any scheduling signal v_d(t) in the scheduling box (u_e -> z only; "
        "references within certificate.design's rate and acceleration bounds)",
        "frozen": "every constant (frozen) v_d in the scheduling box",
        "rate_bounded": (
            f"v_d(t) in the scheduling box with |dv_d,k/dt| <= {sched.get('rate_bound')} m/s^2"
        ),
    }[var]
    if model.box is not None:
        box = model.box
        n = box.n
        n_a = [int(np.sum(box.arrays(i)[1] < n)) for i in range(box.N)]
        n_b = [int(np.sum(box.arrays(i)[1] >= n)) for i in range(box.N)]
        counts: dict = {}
        for labs in box.labels:
            for lb in labs:
                counts[lb] = counts.get(lb, 0) + 1
        entry.update(
            {
                "kind": "full_identified_box",
                "statement": (
                    "||z||_2 <= gamma ||u_e||_2 from rest for u_c = K(v_d) dx (Eq. 31) on every "
                    "plant "
                    "[A, B] = [sum_i alpha_i(v_d) A_i(theta_i), B]: "
                    + rate_txt
                    + "; at every vertex i "
                    "every A element listed in the models file in its interval (independently per "
                    "vertex "
                    "and element), B anywhere in the common hull below; the elements and "
                    "intervals are "
                    "in the sidecar (box_rows, box_cols, box_half about box_Ac, box_Bc)"
                ),
                "elements": {
                    "per_vertex": box.p,
                    "A_per_vertex": n_a,
                    "B_hull": n_b[0] if n_b else 0,
                    "interval_sources": counts,
                    "rule": "stored [lower, upper] where lower < upper; nominal +/- k std where a "
                    "file "
                    "stores lower = upper with std > 0 (format @1); motor rows from "
                    "uncertainty.motor_std where the file has none",
                },
                "motor_constants": _motor_summary(box, model.state_names, model.input_names),
                "B_hull": [
                    {
                        "row": int(r),
                        "col": int(c - n),
                        "lower": float(box.B_centre[r, c - n] - h),
                        "upper": float(box.B_centre[r, c - n] + h),
                    }
                    for r, c, h in zip(*box.arrays(0))
                    if c >= n
                ],
                "runtime_systems": (
                    f"{len(model.systems[0])} per vertex from the box (centre, nominal, seeded "
                    "corners)"
                ),
            }
        )
        cov = dict(box.coverage or {})
        infl = cov.pop("box_inflation", None)
        interp = cov.pop("interpolation", None)
        entry["interpolation"] = interp or {
            "statement": "no interpolation error added (the models file has no "
            "meta.interpolation): between the vertices only seed 0's Assumption 2 (multilinear "
            "interpolation is the plant) covers the plant"
        }
        if interp:
            entry["statement"] += (
                "; every half-width also carries the interpolation error measured between the "
                "vertices (certified_set.interpolation: on a grid, not proven between its "
                "points)"
            )
        entry["robustness"] = {
            "box_inflation": infl,
            "statement": (
                f"the proof holds for the box with every half-width x {1 + infl:g} (the "
                "sidecar's box is the inflated one): the stated margin, not the solver's eps"
                if infl
                else "no stated margin: the proof holds for the box itself (margin = eps)"
            ),
        }
        if infl:
            entry["statement"] += (
                f"; proven with every half-width inflated by {100 * infl:g} % "
                "(certified_set.robustness)"
            )
        if cov.get("probability") is not None:
            jc = cov
            entry["joint_coverage"] = jc
            entry["statement"] += (
                f"; the intervals are simultaneous: they hold all {jc['elements']} identified "
                f"elements at once with probability >= {jc['probability']:g} "
                "(certified_set.joint_coverage), not each element marginally"
            )
        else:
            entry["joint_coverage"] = {
                "probability": None,
                "statement": "marginal intervals as stored (uncertainty.joint_probability: "
                "null): no joint probability is claimed",
            }
    else:
        Ms = [len(lst) for lst in model.systems]
        entry.update(
            {
                "kind": "reduced_polytope",
                "statement": (
                    "||z||_2 <= gamma ||u_e||_2 from rest for u_c = K(v_d) dx on every plant in "
                    "the convex "
                    "hull of the Eq. (23) systems of each vertex (sidecar A_sys, B_sys; "
                    f"sum M_i = {sum(Ms)}), interpolated over "
                    + rate_txt
                    + ". NOT the full identified "
                    "box: the reduction keeps a few corner parameters and holds the other "
                    "elements at "
                    "their nominal values (uncertainty.set: full_box certifies every element)"
                ),
                "systems_per_vertex": Ms,
            }
        )
        if model.common_input is None:
            entry["statement"] += (
                "; per-vertex B: the vertices are certified, the interior only spot-checked"
            )
    return entry


def problem_entry(model, res, opts) -> dict:
    """certificate.problem: the sizes of what was solved and, for a corner polytope, of seed 0's
    Lemma 1 over the same systems counted the package's way and the way CVX reports them."""
    from lpv_sysid.synthesis.hinf import seed_problem_size

    out = dict(res.size.as_dict())
    if res.info.get("size"):
        out.update({k: v for k, v in res.info["size"].items() if k not in out})
    out["method"] = res.info.get("method", "corners")
    # the counts above (and ``solved``) are those of the problem the solver was given
    out["solved"] = {
        "scalar_variables": int(res.size.scalar_variables),
        "lmi_blocks": int(res.size.lmi_blocks),
        "scalar_constraints": int(res.size.scalar_constraints),
        "what": (
            "one robust Eq. (30) block per scheduling vertex over the box of its corner "
            "systems (X_i^j = X_i tied per vertex), then Eq. (30) re-evaluated with numpy at "
            "every corner system"
            if out["method"] == "box"
            else "seed 0 Lemma 1 as posed (Eq. 30 at every system, X_i^j free)"
        ),
    }
    if model.box is None:
        n, m = model.n_x, model.n_u
        ne = res.info.get("n_e", m)
        nz = res.info.get("n_z", 3)
        tied = out["method"] == "box"
        sp = seed_problem_size([len(lst) for lst in model.systems], n, m, ne, nz, tied=tied)
        sp["solved"] = not tied
        sp["relation"] = (
            "NOT the problem solved: the solve is its restriction X_i^j = X_i (a feasible point "
            "of the restriction is one of seed 0 Lemma 1 over the same systems; the converse "
            "does not hold); method: corners solves it as posed"
            if tied
            else "the problem solved (seed 0 Lemma 1 as posed)"
        )
        out["seed_lemma1"] = sp
    return out


def lmi_form(inp: Inputs) -> int:
    """certificate.lmi_form: 0 corners, 1/2/3 element box with common / vertex / rate X."""
    return 0 if inp.method != "box" else {"common": 1, "vertex": 2, "rate": 3}[inp.opts.lyapunov]


def _lmi_text(inp: Inputs, form: int) -> str:
    if form == 0:
        text = "seed 0 Lemma 1" + (
            " (common B: scheduling box interior covered)"
            if inp.model.common_input is not None
            else " (per-vertex B: vertices certified)"
        )
    else:
        kind = {
            1: "direct form, common X",
            2: "Eq. (30) form, X_i per vertex",
            3: "Eq. (30) form, rate-bounded X(v_d)",
        }[form]
        text = f"element-box robust LMI ({kind})"
    return text + (" + seed 2 Eq. (125) region (common H)" if inp.opts.region else "")


def loop_delay_entry(inp: Inputs, res) -> dict:
    """certificate.loop_delay: the constant loop delay the proof covers (synthesis/delay.py).

    ``loop_delay.bound_s`` of the synthesis config (the measured state -> command -> actuator
    latency plus margin) must be within the proven performance margin (SolverError otherwise);
    without it the bound is the proven margin itself (rounded down to 0.1 ms)."""
    from lpv_sysid.errors import SolverError
    from lpv_sysid.parallel.pool import one_blas_thread
    from lpv_sysid.synthesis import delay as dl

    want = inp.cfg.loop_delay.bound_s
    systems, K, gamma = inp.model.systems, np.asarray(res.K), float(inp.opts.gamma)
    with one_blas_thread():  # small dense problems (pipeline.synthesize: why)
        stab = dl.stability_margin(systems, K)
        perf = dl.performance_margin(systems, K, inp.R, inp.C, gamma)
    if want is not None and want > perf:
        raise SolverError(
            f"loop_delay.bound_s {want:g} s is not certified: the frozen loops keep "
            f"||u_e -> z|| <= gamma {gamma:g} only up to {perf * 1e3:.2f} ms of constant loop "
            f"delay (stable up to {stab * 1e3:.2f} ms); lower the delay (loop rate, "
            "transport) or synthesize for less bandwidth"
        )
    bound = float(want) if want is not None else float(np.floor(perf * 1e4) / 1e4)
    n_sys = sum(len(lst) for lst in systems)
    return {
        "bound_s": bound,
        "source": "loop_delay.bound_s of the synthesis config"
        if want is not None
        else "the proven performance margin (no loop_delay.bound_s configured)",
        "stability_margin_s": float(stab),
        "performance_margin_s": float(perf),
        "gamma": gamma,
        "proof": "D-scaled small gain (synthesis/delay.py): u_c = K x(t - tau), every constant "
        f"tau <= bound_s keeps ||u_e -> z||_inf < gamma on the {n_sys} frozen systems the "
        "sidecar stores (per vertex centre, nominal, seeded box corners); frozen v_d, not "
        "the common-X proof over the whole box; re-checked by lpv-sysid verify",
        "configured_delay": "input_latency_s + 1 / state_rate_hz + 1 / rate_hz of the "
        "controller settings; refused at start-up when above bound_s",
    }


def certificate_entry(inp: Inputs, res, models_path: str, side: Path, side_sha: str) -> dict:
    """gains.yaml ``certificate``: what was solved, how well, over which set, and the sidecar."""
    from lpv_sysid.io.files import sha256_file

    opts, model = inp.opts, inp.model
    form = lmi_form(inp)
    cert: dict[str, Any] = {
        "lmi": _lmi_text(inp, form),
        "lmi_form": form,
        "solver": res.solver,
        "status": res.status,
        "objective": opts.effective_objective,
        "gamma_requested": float(opts.gamma),
        "gamma_solved": float(res.gamma_solver),
        "gamma_achieved": float(res.gamma_certified),
        "min_margin": float(res.min_margin),
        "eps": float(opts.eps),
        "models_sha256": sha256_file(models_path),
        "uncertainty": inp.uncertainty,
        "uncertainty_vertices": model.input_structure["M"],
        "input_structure": _structure_entry(model),
        "certified_set": certified_set_entry(model, res, opts, inp.design),
        "velocity_states": [model.state_names[k] for k in inp.vidx],
        "problem": problem_entry(model, res, opts),
        "compile_time_s": round(res.compile_time, 3),
        "solve_time_s": round(res.solve_time, 3),
        "synthesis_wall_s": round(res.info["wall"], 3),
        "sidecar": {"file": side.name, "sha256": side_sha},
    }
    if res.info.get("eq30"):
        e30 = res.info["eq30"]
        cert["eq30_check"] = {
            "systems": e30["systems"],
            "gamma": float(e30["gamma"]),
            "margin": float(e30["margin"]),
            "note": "seed 0 Eq. (30) re-evaluated with numpy at every Eq. (23) system with "
            "X_i^j = X_i, S_i, H of the element-box solve",
        }
    cert["loop_delay"] = loop_delay_entry(inp, res)
    if opts.region is not None:
        cert["region"] = opts.region.to_dict()
    if inp.design is not None:
        cert["design"] = inp.design
    else:
        print(
            "note: no phase-2 signals summary (--summary): the certificate has no design "
            "envelope, so lpv_controller_node will refuse these gains (it bounds v_d and u_e "
            "by that envelope)"
        )
    return cert
