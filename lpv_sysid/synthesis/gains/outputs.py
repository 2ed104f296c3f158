"""What a synthesis writes: gains.yaml with its certificate and the reference feedforward
terms, the sidecar ``<stem>.cert.npz`` (X, S, H, scaling, the certified systems, the element
box), and the lines that say what was solved."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from lpv_sysid.synthesis.gains.certificate import certificate_entry, lmi_form
from lpv_sysid.synthesis.gains.inputs import Inputs


@dataclass
class GainsWritten:
    """The files one synthesis wrote and what it solved (one line each)."""

    gains: Path
    sidecar: Path
    lines: list[str] = field(default_factory=list)


def feedforward_terms(inp: Inputs, lines: list[str]):
    """(F_ff, F_jerk, layout) from the nominal vertex models (synthesis/feedforward.py), or
    Nones when the feedforward is off (by config, or by default for a non-quadrotor layout;
    then a line in ``lines`` says so)."""
    enabled, layout, cond_max = inp.feedforward
    model = inp.model
    if enabled and not inp.cfg.feedforward.given:
        # default on, but only for models that have the layout's states (generic plants: off)
        names = set(model.state_names)
        if not all(set(layout[k]) <= names for k in layout):
            lines.append(
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


def write_gains(
    out: Path, models: str, inp: Inputs, res, seal_key: Optional[bytes] = None
) -> GainsWritten:
    """``out`` (gains.yaml with the certificate about the models file ``models``, sealed;
    ``seal_key``: with the operator's keyed seal too) and its sidecar ``<stem>.cert.npz``
    from the synthesis result ``res``."""
    from lpv_sysid.io.files import save_yaml
    from lpv_sysid.io.formats import box_arrays, gains_dict, save_certificate_npz

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    side = out.with_name(out.stem + ".cert.npz")
    extra = None
    if inp.method == "box":
        rob = res.info["robust"]
        extra = box_arrays(res.info["box"], rob["t"], lmi_form(inp), rob["rate"])
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
    cert = certificate_entry(inp, res, models, side, side_sha)
    opts = inp.opts
    gamma_file = (
        float(opts.gamma)
        if opts.effective_objective != "min_gamma"
        else float(max(res.gamma_certified, 1e-12))
    )
    lines: list[str] = []
    F_ff, F_jerk, ff_layout = feedforward_terms(inp, lines)
    gains = gains_dict(
        inp.raw,
        inp.model,
        res.K,
        inp.R,
        inp.Q,
        gamma_file,
        cert,
        F_ff,
        ff_layout,
        F_jerk,
        seal_key=seal_key,
    )
    save_yaml(gains, out)
    lines += result_lines(inp, res, cert, F_ff, F_jerk, ff_layout)
    return GainsWritten(out, side, lines)


def result_lines(inp: Inputs, res, cert: dict, F_ff, F_jerk, ff_layout) -> list[str]:
    """What was solved and certified, one line each."""
    out: list[str] = []
    opts, pr = inp.opts, cert["problem"]
    size = res.size
    out.append(
        f"LMI solved ({pr['method']}): {size.lmi_blocks} blocks (total dim {size.lmi_total_dim}, "
        f"{size.scalar_constraints} scalar constraints), {size.scalar_variables} scalar "
        f"variables; compile {res.compile_time:.2f} s, solve {res.solve_time:.2f} s, load + "
        f"synthesis wall {res.info['wall']:.2f} s ({res.solver}, {res.status}, objective "
        f"{opts.effective_objective})"
    )
    if "seed_lemma1" in pr:
        sp = pr["seed_lemma1"]
        label = (
            "not the problem solved (that is its restriction X_i^j = X_i above): "
            if not sp.get("solved", True)
            else ""
        )
        out.append(
            f"seed 0 Lemma 1 over these sum M_i = {sp['sum_M']} systems (N = {sp['N']}), "
            f"{label}"
            f"{sp['package']['scalar_variables']} scalar variables and "
            f"{sp['package']['cone_entries']} cone entries in {sp['psd_cones']} PSD cones "
            "(package, primal); as CVX reports it (dual): "
            f"{sp['as_cvx_reports']['variables']} variables with "
            f"{sp['as_cvx_reports']['constraints']} constraints"
        )
    if res.info.get("eq30"):
        e30 = res.info["eq30"]
        out.append(
            f"Eq. (30) re-checked with numpy at all {e30['systems']} systems (X_i^j = X_i): "
            f"gamma {e30['gamma']:.4g}, min margin {e30['margin']:.3g} ({e30['check_s']:.2f} s)"
        )
    cs = cert["certified_set"]
    covers = cs["scheduling"].get("covers_design_signal")
    out.append(
        f"certified set: {cs['kind']}; scheduling: {cs['scheduling']['variation']} v_d"
        + ("" if covers is None else f" (covers the designed v_d(t): {covers})")
    )
    solved_at = (
        f" (solved at {res.gamma_solver:.4g} = gamma x design_gamma_fraction)"
        if opts.design_gamma_fraction != 1 and opts.effective_objective != "min_gamma"
        else ""
    )
    out.append(
        f"gamma requested {opts.gamma:g}{solved_at}, certified (numpy re-evaluation) "
        f"{res.gamma_certified:.4g}, min margin {res.min_margin:.3g}"
    )
    ld = cert.get("loop_delay")
    if ld:
        out.append(
            f"loop delay: certified up to {ld['bound_s'] * 1e3:.2f} ms ({ld['source']}); "
            f"proven margins: ||u_e -> z|| < gamma up to {ld['performance_margin_s'] * 1e3:.2f} "
            f"ms, stable up to {ld['stability_margin_s'] * 1e3:.2f} ms (frozen systems)"
        )
    if F_ff is not None:
        jerk = (
            f", jerk term F_jerk ({F_jerk.shape[1]}x{F_jerk.shape[2]})"
            if F_jerk is not None
            else ""
        )
        out.append(
            f"reference feedforward F_ff ({F_ff.shape[1]}x{F_ff.shape[2]} per vertex, rows "
            f"{ff_layout['free_states']} + inputs) from the nominal vertex models{jerk}"
        )
    return out
