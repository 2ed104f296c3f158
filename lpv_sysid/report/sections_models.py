"""What a reviewer of an unstable vehicle asks first about the identified models (issue 23
item 3), from ``vertex_models.yaml`` alone:

- open-loop poles per vertex: the eigenvalues of the nominal ``A`` (seed 0 Eq. 20), the
  largest real part and the time to double ``ln 2 / max Re(lambda)`` of the divergent mode
  (amplitude ``exp(Re(lambda) t)``: it doubles in that time), or "stable";
- the loop margins of the LPV controller (``gains.yaml``, ``du = K dx``, Eq. 31) on each
  vertex model, with python-control: loop at a time (the loop broken at one virtual input,
  the others closed: ``L_i = -K_i (sI - A - B_o K_o)^-1 B_i``), classical gain/phase
  margins and the balanced disk margin, and the disk margin of all four loops at once
  (``L = -K (sI - A)^-1 B``, unstructured: ``1 / max sigma(0.5 (S - T))``, a lower bound;
  0 when the closed loop ``A + B K`` is unstable);
- the identified parameters with their confidence intervals (Eq. 22: lower, upper =
  nominal -/+ k std) and significance (``|t| = |nominal| / std``; ``*``: the interval
  excludes zero), one row per element, one column per vertex.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from lpv_sysid.report.document import Report, md_table

LN2 = math.log(2.0)


def _names(models: dict, key: str) -> list[str]:
    return [str(c.get("name", i)) for i, c in enumerate(models.get(key) or [])]


def _vertex_label(v: dict) -> str:
    return "[" + " ".join(f"{float(c):+g}" for c in v.get("scheduling", [])) + "]"


def pole_rows(models: dict | None) -> list[list[Any]]:
    """Per vertex: its scheduling point, the unstable poles, max Re (1/s), time to double (s)."""
    if not isinstance(models, dict):
        return []
    rows = []
    for v in models.get("vertices") or []:
        try:
            A = np.asarray(v["A"], dtype=float)
            lam = np.linalg.eigvals(A)
        except (KeyError, TypeError, ValueError, np.linalg.LinAlgError):
            continue
        re = float(np.max(lam.real))
        unstable = sorted((x for x in lam if x.real > 1e-9), key=lambda x: -x.real)
        text = ", ".join(
            f"{x.real:+.3g}" + (f"{x.imag:+.3g}j" if abs(x.imag) > 1e-9 else "")
            for x in unstable
            if x.imag >= -1e-9
        )
        rows.append(
            [
                _vertex_label(v),
                text or "none",
                re,
                LN2 / re if re > 1e-9 else "stable",
            ]
        )
    return rows


def element_name(e: dict, states: Sequence[str], inputs: Sequence[str]) -> str:
    m, i, j = e.get("matrix"), int(e.get("row", 0)), int(e.get("col", 0))
    cols = states if m == "A" else inputs
    row = states[i] if i < len(states) else str(i)
    col = cols[j] if j < len(cols) else str(j)
    return f"{m}[{row}, {col}]"


def parameter_rows(models: dict | None) -> tuple[list[str], list[list[str]]]:
    """(header, rows) of the identified elements: ``nominal [lower, upper] |t|``, ``*`` when
    the interval excludes zero; elements with std 0 (known, not identified) left out."""
    if not isinstance(models, dict):
        return [], []
    states, inputs = _names(models, "states"), _names(models, "inputs")
    vertices = [v for v in models.get("vertices") or [] if isinstance(v, dict)]
    table: dict[str, list[str]] = {}
    for k, v in enumerate(vertices):
        for e in v.get("uncertain") or []:
            try:
                nom, std = float(e["nominal"]), float(e["std"])
                lo, hi = float(e["lower"]), float(e["upper"])
            except (KeyError, TypeError, ValueError):
                continue
            if std <= 0.0:
                continue
            name = element_name(e, states, inputs)
            t = abs(nom) / std
            sig = "*" if lo > 0.0 or hi < 0.0 else ""
            cell = f"{nom:+.3g} [{lo:+.3g}, {hi:+.3g}] {t:.1f}{sig}"
            table.setdefault(name, [""] * len(vertices))[k] = cell
    header = ["element"] + [_vertex_label(v) for v in vertices]
    return header, [[n, *cells] for n, cells in table.items()]


#: frequency grid of the disk margins [rad/s]
OMEGA = np.logspace(-2, 3, 1500)


def loop_margins(A, B, K, omega=OMEGA) -> dict:
    """Per input channel ``(gm_db, pm_deg, disk_margin, disk_gm_db, disk_pm_deg)`` of the loop
    broken there (others closed) and the MIMO balanced disk margin (module docstring)."""
    import control

    A, B, K = (np.asarray(m, dtype=float) for m in (A, B, K))
    n, m = B.shape
    rows = []
    for i in range(m):
        o = [j for j in range(m) if j != i]
        Ao = A + B[:, o] @ K[o, :]
        L = control.ss(Ao, B[:, [i]], -K[[i], :], np.zeros((1, 1)))
        gm, pm, *_ = control.stability_margins(L)
        dm, dgm, dpm = control.disk_margins(L, omega)
        rows.append(
            (
                20 * math.log10(gm) if np.isfinite(gm) and gm > 0 else float("inf"),
                float(pm),
                float(dm),
                float(dgm),
                float(dpm),
            )
        )
    # all loops at once: the unstructured balanced disk margin 1 / max_w sigma_max(0.5 (S - T))
    # (a lower bound of the structured one, which needs slycot's mu)
    peak = 0.0
    eye = np.eye(m)
    for w in omega:
        Lw = -K @ np.linalg.solve(1j * w * np.eye(n) - A, B)
        M = 0.5 * (eye - Lw) @ np.linalg.inv(eye + Lw)
        peak = max(peak, float(np.linalg.svd(M, compute_uv=False)[0]))
    stable = bool(np.max(np.linalg.eigvals(A + B @ K).real) < 0.0)
    return {
        "channels": rows,
        "mimo_disk_margin": (1.0 / peak if peak > 0 else float("inf")) if stable else 0.0,
        "closed_loop_stable": stable,
    }


def margin_rows(models: dict | None, gains: dict | None) -> list[list]:
    """One row per vertex and channel of :func:`loop_margins` (vertices matched by their
    scheduling point)."""
    if not isinstance(models, dict) or not isinstance(gains, dict):
        return []
    inputs = _names(models, "inputs")
    by_point = {
        tuple(np.round(np.asarray(v["scheduling"], float), 9)): v
        for v in models.get("vertices") or []
    }
    rows = []
    for g in gains.get("vertices") or []:
        key = tuple(np.round(np.asarray(g["scheduling"], float), 9))
        v = by_point.get(key)
        if v is None:
            continue
        res = loop_margins(v["A"], v["B"], g["K"])
        for i, ch in enumerate(res["channels"]):
            rows.append(
                [
                    _vertex_label(g) if i == 0 else "",
                    inputs[i] if i < len(inputs) else str(i),
                    *ch,
                    res["mimo_disk_margin"] if i == 0 else "",
                ]
            )
    return rows


def stability_section(r: Report) -> None:
    """Open-loop poles / time to double and the parameter table (module docstring)."""
    d = r.data
    r.h(2, "Identified models: open-loop stability and parameters")

    def body() -> None:
        rows = pole_rows(d.models)
        if rows:
            worst = min((x[3] for x in rows if not isinstance(x[3], str)), default=None)
            r.p(
                "Open-loop poles of each vertex's nominal A (seed 0 Eq. 20): the unstable ones "
                "(upper half plane), the largest real part and the time to double "
                "ln 2 / max Re(lambda) of the fastest divergent mode"
                + (f"; shortest: **{worst:.2f} s**." if worst is not None else ".")
            )
            r.p(
                md_table(
                    ["vertex", "unstable poles [1/s]", "max Re [1/s]", "time to double [s]"],
                    rows,
                    fmt="{:.3g}",
                )
            )
        header, prows = parameter_rows(d.models)
        if prows:
            r.p(
                "Identified parameters per vertex: nominal [lower, upper] (the Eq. 22 interval, "
                "nominal -/+ k std) and |t| = |nominal| / std; * = the interval excludes zero "
                "(significant)."
            )
            r.p(md_table(header, prows))

        oe = ((d.models or {}).get("meta") or {}).get("validation", {}).get("output_error")
        if isinstance(oe, dict) and isinstance(oe.get("nrmse"), dict):
            order = ("u", "v", "w", "p", "q", "r")
            axes = [a for a in order if a in oe["nrmse"]]
            axes += [a for a in oe["nrmse"] if a not in order]
            r.p(
                "Output-error (free-run) validation on the validation maneuver: the LPV model "
                "driven by the measured inputs alone, restarted from the measured state every "
                f"{float(oe.get('horizon_s', 0)):.2f} s (ident/vertex/pipeline.free_run)."
            )
            r.p(
                md_table(
                    ["metric", *axes],
                    [[m.upper(), *[oe.get(m, {}).get(a) for a in axes]] for m in ("tic", "nrmse")],
                    fmt="{:.3f}",
                )
            )

    r.with_input("models", "open-loop poles", body)
    if d.models is not None and d.gains is not None:

        def margins() -> None:
            try:
                rows = margin_rows(d.models, d.gains)
            except ImportError:
                r.p("Loop margins need python-control (requirements.txt pins it).")
                return
            if not rows:
                return
            r.p(
                "Loop margins of the LPV controller (gains.yaml, du = K dx, Eq. 31) on each "
                "vertex model, python-control: loop at a time at each virtual input (the "
                "others closed): gain margin [dB] (a negative value: the loop tolerates a gain "
                "reduction down to that, as an unstable plant needs), phase margin [deg], "
                "balanced disk margin alpha with its gain [dB] and phase [deg] margins; last "
                "column: the disk margin of all four loops at once (unstructured, a lower "
                "bound; 0: the closed loop A + B K is unstable)."
            )
            r.p(
                md_table(
                    [
                        "vertex",
                        "loop",
                        "GM [dB]",
                        "PM [deg]",
                        "disk alpha",
                        "disk GM [dB]",
                        "disk PM [deg]",
                        "MIMO disk alpha",
                    ],
                    rows,
                    fmt="{:.3g}",
                )
            )

        r.guard("loop margins", margins)


#: where ``lpv-sysid identify-nonlinear --out`` is looked for in a run directory
NONLINEAR_CANDIDATES = ("nonlinear_model.yaml", "phase2/nonlinear_model.yaml")


def nonlinear_rows(doc: dict) -> list[list]:
    """Per lumped parameter of seed 0 Eq. (6): regression estimate, std, |t|, and the
    output-error refinement (estimate, std) when present."""
    K, std = doc.get("K") or {}, doc.get("std") or {}
    ref = doc.get("refined") or {}
    rk, rs = ref.get("K") or {}, ref.get("std") or {}
    rows = []
    for name, v in K.items():
        sd = std.get(name)
        t = None
        if isinstance(sd, (int, float)) and sd > 0 and np.isfinite(sd):
            t = abs(float(v)) / float(sd)
        rows.append([name, float(v), sd, t, rk.get(name), rs.get(name)])
    return rows


def nonlinear_section(r: Report) -> None:
    """The nonlinear identification (``identify-nonlinear``) when its file is in the run
    directory; nothing otherwise."""
    from lpv_sysid.io.files import read_yaml

    path = next(
        (r.data.run_dir / c for c in NONLINEAR_CANDIDATES if (r.data.run_dir / c).is_file()), None
    )
    if path is None:
        return
    r.h(2, "Nonlinear identification (seed 0 Eq. 6)")

    def body() -> None:
        doc = read_yaml(path)
        if not isinstance(doc, dict) or not isinstance(doc.get("K"), dict):
            r.p(f"`{path.name}` has no `K` mapping.")
            return
        r.p(
            f"Lumped parameters of Eq. (6) from `{path.relative_to(r.data.run_dir)}` "
            "(`lpv-sysid identify-nonlinear`): least-squares estimate, standard error, |t| = "
            "|estimate| / std (significant above ~2), and the short-segment output-error "
            "refinement (seed 2 Sec. 4) when it was run."
        )
        r.p(
            md_table(
                ["K", "estimate", "std", "|t|", "refined", "refined std"],
                nonlinear_rows(doc),
                fmt="{:.4g}",
            )
        )

    r.guard("nonlinear identification", body)
