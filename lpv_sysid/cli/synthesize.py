"""`lpv-sysid synthesize`: robust LPV H-infinity state feedback (seed 0 Lemma 1) -> gains.yaml.

    lpv-sysid synthesize --models vertex_models.yaml --config config/synthesis.yaml \
        --out gains.yaml

Writes gains.yaml (ARCHITECTURE.md section 5) with the certificate entry and the sidecar
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
models file in its interval (synthesis/robust_lmi.py); ``certificate.certified_set`` states
exactly which plants (``kind``, the box in the sidecar) and which scheduling signals
(``scheduling.variation``: frozen | arbitrary | rate_bounded, ``covers_design_signal``) the bound
covers, and ``certificate.problem`` the sizes -- for a corner polytope also seed 0's Lemma 1 over
the same systems counted the package's way and the way CVX reports them (docs/certificate.md).
"""

from __future__ import annotations

import argparse
import logging
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Optional

import numpy as np

from lpv_sysid.errors import ConfigError, SolverError

COMMAND = "synthesize"
HELP = (
    "robust polytopic LPV H-infinity state feedback (seed 0 Lemma 1) -> gains.yaml + certificate"
)

log = logging.getLogger(__name__)

_TOP_KEYS = {"hinf", "weights", "velocity_states", "uncertainty", "verify", "feedforward"}


def feedforward_settings(cfg: dict, cfg_path: str) -> tuple[bool, dict, float]:
    """``feedforward``: true (default) | false | {enabled, cond_max, free_states,
    accelerated_states, held_states, kinematic_states, rate_states} -> (enabled, layout dict,
    cond_max)."""
    from lpv_sysid.synthesis.feedforward import COND_MAX_DEFAULT, FeedforwardLayout

    v = cfg.get("feedforward", True)
    if isinstance(v, bool):
        return v, FeedforwardLayout().to_dict(), COND_MAX_DEFAULT
    if not isinstance(v, dict):
        raise ConfigError(f"{cfg_path}: feedforward must be true, false or a mapping, got {v!r}")
    v = dict(v)
    enabled = v.pop("enabled", True)
    if not isinstance(enabled, bool):
        raise ConfigError(
            f"{cfg_path}: feedforward.enabled must be true or false, got {enabled!r}"
        )
    try:
        cond_max = float(v.pop("cond_max", COND_MAX_DEFAULT))
    except (TypeError, ValueError):
        raise ConfigError(f"{cfg_path}: feedforward.cond_max must be a number") from None
    return enabled, FeedforwardLayout.from_dict(v).to_dict(), cond_max


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


def load_config(path: str) -> dict:
    from lpv_sysid.io.yaml_file import read_yaml_mapping

    cfg = read_yaml_mapping(path)
    bad = set(cfg) - _TOP_KEYS
    if bad:
        raise ConfigError(f"{path}: unknown key(s) {sorted(bad)}; known: {sorted(_TOP_KEYS)}")
    for key in ("hinf", "weights", "uncertainty", "verify"):  # sections: mappings (or empty)
        if cfg.get(key) is not None and not isinstance(cfg[key], dict):
            raise ConfigError(f"{path}: {key}: expected a mapping, got {type(cfg[key]).__name__}")
    return cfg


def weights_from_config(
    cfg: dict, n_u: int, summary_path: str | None, cfg_path: str
) -> tuple[np.ndarray, np.ndarray, str]:
    """(R, Q, source) from a signals summary (R, Q entries) or from Eqs. (27)-(28)."""
    from lpv_sysid.io.yaml_file import read_yaml_mapping
    from lpv_sysid.synthesis.hinf_lmi import excitation_R, output_Q

    w = dict(cfg.get("weights") or {})
    summary_path = summary_path or w.get("summary")
    if summary_path:
        p = Path(summary_path)
        if not p.is_absolute() and not p.exists():
            p = Path(cfg_path).parent / p
        s = read_yaml_mapping(p, f"signals summary {p}")
        if "R" not in s or "Q" not in s:
            raise ConfigError(
                f"{p}: signals summary has no 'R'/'Q' (write it with weights in the signals "
                "config)"
            )
        R = np.array(s["R"], dtype=float)
        Q = np.array(s["Q"], dtype=float)
        if R.shape[0] != n_u or Q.ndim != 2 or Q.shape[0] != Q.shape[1]:
            raise ConfigError(f"{p}: R {R.shape} / Q {Q.shape} do not fit {n_u} inputs")
        return R, Q, str(p)
    bad = set(w) - {"T", "input_magnitudes", "output_magnitudes", "summary"}
    if bad:
        raise ConfigError(f"{cfg_path}: weights: unknown key(s) {sorted(bad)}")
    try:
        T = float(w["T"])
        R = excitation_R(w["input_magnitudes"], T)
        Q = output_Q(w["output_magnitudes"], T)
    except KeyError as exc:
        raise ConfigError(f"{cfg_path}: weights.{exc.args[0]} missing") from None
    if R.shape[0] != n_u:
        raise ConfigError(
            f"{cfg_path}: weights.input_magnitudes has {R.shape[0]} entries, the model {n_u} "
            "inputs"
        )
    return R, Q, "Eqs. (27)-(28)"


def design_from_summary(source: str) -> Optional[dict]:
    """``certificate.design`` (lpv_sysid.signals.excitation.design_envelope) when the weights came
    from a phase-2 signals summary (``source`` is its path), else None."""
    from lpv_sysid.signals.excitation import design_envelope
    from lpv_sysid.io.yaml_file import read_yaml_mapping

    if source.startswith("Eqs."):
        return None
    try:
        return design_envelope(
            read_yaml_mapping(source, f"signals summary {source}"),
            source=f"signals summary {Path(source).name}",
        )
    except ConfigError as exc:
        print(f"note: {exc}")
        return None


def velocity_index(cfg: dict, state_names: tuple) -> tuple[int, ...]:
    names = cfg.get("velocity_states", ["u", "v", "w"])
    try:
        return tuple(state_names.index(n) for n in names)
    except ValueError:
        raise ConfigError(
            f"velocity_states {names} not all among the model states {list(state_names)}"
        ) from None


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
        "al. 1994 Sec. 5.1, 6.3.2), synthesis/robust_lmi.py"
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
            "V = x^T X^-1 x decreases along every trajectory of the set: any v_d(t) in the box"
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
        "arbitrary": "v_d(t) in the scheduling box, varying arbitrarily fast",
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
    from lpv_sysid.synthesis.hinf_lmi import seed_problem_size

    out = dict(res.size.as_dict())
    if res.info.get("size"):
        out.update({k: v for k, v in res.info["size"].items() if k not in out})
    out["method"] = res.info.get("method", "corners")
    if model.box is None:
        n, m = model.n_x, model.n_u
        ne = res.info.get("n_e", m)
        nz = res.info.get("n_z", 3)
        out["seed_lemma1"] = seed_problem_size(
            [len(lst) for lst in model.systems], n, m, ne, nz, tied=out["method"] == "box"
        )
    return out


@dataclass
class Inputs:
    """What one synthesis run works on (:func:`load_inputs`)."""

    cfg: dict
    opts: Any  # synthesis.hinf_lmi.HinfOptions
    uncertainty: dict
    feedforward: tuple[bool, dict, float]
    model: Any  # models.lpv.PolytopicModel
    raw: dict
    R: np.ndarray
    Q: np.ndarray
    weights_source: str
    vidx: tuple[int, ...]
    C: np.ndarray
    design: Optional[dict]
    rate_from_design: bool
    method: str
    t0: float


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


def load_inputs(args: argparse.Namespace) -> Inputs:
    """Config, options (with the command-line overrides), models, weights and design envelope."""
    from lpv_sysid.synthesis.uncertainty_set import load_models, uncertainty_settings
    from lpv_sysid.synthesis.hinf_lmi import HinfOptions, performance_matrix, resolve_method

    cfg = load_config(args.config)
    opts = HinfOptions.from_dict(cfg.get("hinf"))
    if args.gamma is not None:
        opts = replace(opts, gamma=float(args.gamma))
    if args.solver is not None:
        opts = HinfOptions.from_dict(
            {**{k: getattr(opts, k) for k in opts.__dataclass_fields__}, "solver": args.solver}
        )
    unc_cfg = uncertainty_settings(cfg.get("uncertainty"))
    ff = feedforward_settings(cfg, args.config)
    t0 = time.perf_counter()
    model, raw = load_models(args.models, unc_cfg)
    R, Q, source = weights_from_config(cfg, model.n_u, args.summary, args.config)
    vidx = velocity_index(cfg, model.state_names)
    C = performance_matrix(Q, model.n_x, vidx)
    print(
        f"models: {args.models} ({model.n_vertices} vertices, {model.n_x} states, "
        f"{model.n_u} inputs); R, Q from {source}"
    )
    if model.ts is not None:
        raise ConfigError(
            f"{args.models}: Lemma 1 is a continuous-time result; the models are discrete "
            f"(Ts={model.ts})"
        )
    design = design_from_summary(source)
    rate_from_design = False
    if opts.lyapunov == "rate" and opts.rate_bound == "design":
        if design is None:
            raise ConfigError(
                "hinf.rate_bound: design needs the phase-2 signals summary (--summary) for the "
                "design envelope's reference_rate"
            )
        opts = replace(opts, rate_bound=[float(x) for x in design["reference_rate"]])
        rate_from_design = True
    method = resolve_method(model, opts)
    return Inputs(
        cfg=cfg,
        opts=opts,
        uncertainty=unc_cfg,
        feedforward=ff,
        model=model,
        raw=raw,
        R=R,
        Q=Q,
        weights_source=source,
        vidx=vidx,
        C=C,
        design=design,
        rate_from_design=rate_from_design,
        method=method,
        t0=t0,
    )


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
    from lpv_sysid.synthesis.hinf_lmi import synthesize_hinf

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


def _lmi_form(inp: Inputs) -> int:
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


def certificate_entry(inp: Inputs, res, models_path: str, side: Path, side_sha: str) -> dict:
    """gains.yaml ``certificate``: what was solved, how well, over which set, and the sidecar."""
    from lpv_sysid.io.file_hash import sha256_file

    opts, model = inp.opts, inp.model
    form = _lmi_form(inp)
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


def feedforward_terms(inp: Inputs):
    """(F_ff, F_jerk, layout) from the nominal vertex models (synthesis/feedforward.py), or
    Nones when the feedforward is off (by config, or by default for a non-quadrotor layout)."""
    enabled, layout, cond_max = inp.feedforward
    model = inp.model
    if enabled and "feedforward" not in inp.cfg:
        # default on, but only for models that have the layout's states (generic plants: off)
        names = set(model.state_names)
        if not all(set(layout[k]) <= names for k in layout):
            print(
                f"feedforward: off (default layout {layout['free_states']} not among the model "
                "states)"
            )
            enabled = False
    if not enabled:
        return None, None, None
    from lpv_sysid.synthesis.feedforward import FeedforwardLayout, vertex_feedforward

    F_ff, F_jerk = vertex_feedforward(
        model.A, model.B, model.state_names, FeedforwardLayout.from_dict(layout), cond_max
    )
    return F_ff, F_jerk, layout


def write_outputs(args: argparse.Namespace, inp: Inputs, res) -> tuple[Path, Path]:
    """gains.yaml (with the certificate) and its sidecar ``<stem>.cert.npz``; prints the
    result. Returns both paths."""
    from lpv_sysid.io.formats import box_arrays, gains_dict, save_certificate_npz
    from lpv_sysid.io.yaml_file import save_yaml

    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    side = out.with_name(out.stem + ".cert.npz")
    extra = None
    if inp.method == "box":
        rob = res.info["robust"]
        extra = box_arrays(res.info["box"], rob["t"], _lmi_form(inp), rob["rate"])
        if rob["W"] is not None:
            extra["W"] = np.array(rob["W"])
    side_sha = save_certificate_npz(
        side,
        res.X,
        res.S,
        res.H,
        res.scaling.t,
        res.scaling.s_u,
        inp.R,
        inp.C,
        systems=inp.model.systems,
        extra=extra,
    )
    cert = certificate_entry(inp, res, args.models, side, side_sha)
    opts = inp.opts
    gamma_file = (
        float(opts.gamma)
        if opts.effective_objective != "min_gamma"
        else float(max(res.gamma_certified, 1e-12))
    )
    F_ff, F_jerk, ff_layout = feedforward_terms(inp)
    gains = gains_dict(
        inp.raw, inp.model, res.K, inp.R, inp.Q, gamma_file, cert, F_ff, ff_layout, F_jerk
    )
    save_yaml(gains, out)
    print_result(inp, res, cert, F_ff, F_jerk, ff_layout)
    return out, side


def print_result(inp: Inputs, res, cert: dict, F_ff, F_jerk, ff_layout) -> None:
    opts, pr = inp.opts, cert["problem"]
    size = res.size
    print(
        f"LMI ({pr['method']}): {size.lmi_blocks} blocks (total dim {size.lmi_total_dim}, "
        f"{size.scalar_constraints} scalar constraints), {size.scalar_variables} scalar "
        f"variables; compile {res.compile_time:.2f} s, solve {res.solve_time:.2f} s, load + "
        f"synthesis wall {res.info['wall']:.2f} s ({res.solver}, {res.status}, objective "
        f"{opts.effective_objective})"
    )
    if "seed_lemma1" in pr:
        sp = pr["seed_lemma1"]
        print(
            f"seed 0 Lemma 1 over these sum M_i = {sp['sum_M']} systems (N = {sp['N']}): "
            f"{sp['package']['scalar_variables']} scalar variables and "
            f"{sp['package']['cone_entries']} cone entries in {sp['psd_cones']} PSD cones "
            "(package, primal); as CVX reports it (dual): "
            f"{sp['as_cvx_reports']['variables']} variables with "
            f"{sp['as_cvx_reports']['constraints']} constraints"
        )
    if res.info.get("eq30"):
        e30 = res.info["eq30"]
        print(
            f"Eq. (30) re-checked with numpy at all {e30['systems']} systems (X_i^j = X_i): "
            f"gamma {e30['gamma']:.4g}, min margin {e30['margin']:.3g} ({e30['check_s']:.2f} s)"
        )
    cs = cert["certified_set"]
    covers = cs["scheduling"].get("covers_design_signal")
    print(
        f"certified set: {cs['kind']}; scheduling: {cs['scheduling']['variation']} v_d"
        + ("" if covers is None else f" (covers the designed v_d(t): {covers})")
    )
    solved_at = (
        f" (solved at {res.gamma_solver:.4g} = gamma x design_gamma_fraction)"
        if opts.design_gamma_fraction != 1 and opts.effective_objective != "min_gamma"
        else ""
    )
    print(
        f"gamma requested {opts.gamma:g}{solved_at}, certified (numpy re-evaluation) "
        f"{res.gamma_certified:.4g}, min margin {res.min_margin:.3g}"
    )
    if F_ff is not None:
        jerk = (
            f", jerk term F_jerk ({F_jerk.shape[1]}x{F_jerk.shape[2]})"
            if F_jerk is not None
            else ""
        )
        print(
            f"reference feedforward F_ff ({F_ff.shape[1]}x{F_ff.shape[2]} per vertex, rows "
            f"{ff_layout['free_states']} + inputs) from the nominal vertex models{jerk}"
        )


def verify(out: Path, models_path: str, inp: Inputs) -> int:
    """The independent verification (synthesis/verify.py) of what was written: 0 passed, 1
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
