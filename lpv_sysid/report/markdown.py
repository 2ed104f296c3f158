"""Markdown report of a run directory (report.md + PNG figures next to it).

Sections follow the method of seed 0: phase-1 equilibria (Table 1), identification R^2
(Table 2), validation TIC/NRMSE (Table 3), signal design (Figs. 5-7), synthesis certificate
(Lemma 1), independent verification, phase-2 achieved gain vs gamma (Eq. 29), tracking
(Figs. 8-9) and regressor correlations (Fig. 10). A section is written only when its input
exists; otherwise the report says which file is missing.
"""

from __future__ import annotations

import logging
import shutil
from pathlib import Path
from typing import Any, Iterable, Optional, Sequence

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.report import plots
from lpv_sysid.report.data import (
    CANDIDATES,
    RunData,
    equilibrium_table,
    fit_table,
    load_run,
    trims_table,
    validation_table,
)
from lpv_sysid.report.regressors import AXES, REGRESSOR_NAMES, RegressorCorrelation

log = logging.getLogger(__name__)

SECTION_INPUTS = {
    "trims": "phase-1 model trims",
    "models": "identified vertex models (Tables 1, 2)",
    "validation": "independent validation (Table 3)",
    "signals_summary": "signal design summary",
    "signals": "signal time histories",
    "gains": "LPV gains + certificate",
    "verification": "independent verification",
    "phase2_summary": "phase-2 simulation",
}


def md_table(header: Sequence[str], rows: Iterable[Sequence[Any]], fmt: str = "{:.3g}") -> str:
    """GitHub-flavoured Markdown table; floats with ``fmt``, None as '-'."""

    def cell(v: Any) -> str:
        if v is None:
            return "-"
        if isinstance(v, (float, np.floating)):
            return "nan" if not np.isfinite(v) else fmt.format(float(v))
        if isinstance(v, (bool, np.bool_)):
            return "yes" if v else "NO"
        return str(v).replace("|", "\\|")

    lines = [
        "| " + " | ".join(str(h).replace("|", "\\|") for h in header) + " |",
        "|" + "|".join("---" for _ in header) + "|",
    ]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def _flatten(d: Any, prefix: str = "") -> list[tuple[str, Any]]:
    out: list[tuple[str, Any]] = []
    if isinstance(d, dict):
        for k, v in d.items():
            out += _flatten(v, f"{prefix}.{k}" if prefix else str(k))
    elif (
        isinstance(d, list) and d and all(isinstance(x, (int, float)) for x in d) and len(d) <= 16
    ):
        out.append((prefix, "[" + ", ".join(f"{x:g}" for x in d) + "]"))
    elif isinstance(d, list) and d and all(isinstance(x, dict) for x in d):
        for i, x in enumerate(d):
            out += _flatten(x, f"{prefix}[{i}]")
    elif isinstance(d, list) and len(d) > 16:
        out.append((prefix, f"<{len(d)} values>"))
    else:
        out.append((prefix, d))
    return out


def _kv_table(d: Any) -> str:
    return md_table(["key", "value"], _flatten(d), fmt="{:.6g}")


class _Report:
    def __init__(self, data: RunData, out_path: Path) -> None:
        self.data = data
        self.out = Path(out_path)
        self.fig_dir = self.out.parent
        self.lines: list[str] = []
        self.figures: list[Path] = []

    def h(self, level: int, text: str) -> None:
        self.lines += ["", "#" * level + " " + text, ""]

    def p(self, text: str) -> None:
        self.lines += [text, ""]

    def fig(self, path: Path, caption: str) -> None:
        self.figures.append(path)
        self.p(f"![{caption}]({path.name})\n\n*{caption}*")

    def missing(self, key: str) -> None:
        if key in self.data.problems:
            self.p(f"**Input unreadable:** {self.data.problems[key]}")
        else:
            self.p(
                f"**Input missing:** none of `{'`, `'.join(CANDIDATES[key])}` in the run directory."
            )

    def guard(self, label: str, fn) -> None:
        """Run one section; a malformed (but parseable) file ends that section only."""
        try:
            fn()
        except (ConfigError, KeyError, TypeError, ValueError, IndexError, OSError) as exc:
            log.warning("%s: %s", label, exc)
            self.p(f"**Could not build this section:** {exc}")

    def with_input(self, key: str, label: str, fn) -> bool:
        """``fn()`` under :meth:`guard` when input ``key`` was loaded, else the
        :meth:`missing` note; whether the input was there."""
        if getattr(self.data, key) is None:
            self.missing(key)
            return False
        self.guard(label, fn)
        return True


def _inputs_section(r: _Report) -> None:
    d = r.data
    r.h(2, "Inputs")
    rows = []
    for key, label in SECTION_INPUTS.items():
        if key in d.problems:
            rows.append([label, "UNREADABLE", d.problems[key]])
        elif key in d.derived:
            rows.append([label, "derived", d.derived[key]])
        elif key in d.found:
            rows.append([label, "found", f"`{d.found[key].relative_to(d.run_dir)}`"])
        else:
            rows.append(
                [label, "missing", "looked for " + ", ".join(f"`{c}`" for c in CANDIDATES[key])]
            )
    for name in ("eq33", "nonlinear"):
        key = f"phase2_{name}"
        if key in d.found:
            rows.append(
                [
                    f"phase-2 {name} time histories",
                    "found",
                    f"`{d.found[key].relative_to(d.run_dir)}`",
                ]
            )
        elif key in d.problems:
            rows.append([f"phase-2 {name} time histories", "UNREADABLE", d.problems[key]])
    r.p(md_table(["input", "status", "file"], rows))
    absent = [
        SECTION_INPUTS[k]
        for k in SECTION_INPUTS
        if (k not in d.found and k not in d.derived) or k in d.problems
    ]
    if absent:
        r.p("Missing or unreadable inputs: " + "; ".join(absent) + ".")
    else:
        r.p("All inputs present.")


def _phase1_section(r: _Report) -> None:
    d = r.data
    r.h(2, "Phase 1: vertex equilibria (seed 0 Table 1)")

    def table1() -> None:
        header, rows = equilibrium_table(d.models)
        r.p(
            "Equilibria `x0` of the identified vertex models (from flight data in the seed; "
            "here from the phase-1 runs)."
        )
        r.p(md_table(header, rows, fmt="{:.2f}"))

    r.with_input("models", "Table 1", table1)
    if d.trims is not None:

        def trims() -> None:
            header, rows = trims_table(d.trims)
            r.p(
                "Phase-1 runs (`trims.yaml`): achieved equilibrium (mean over the trim segment, as "
                "seed 0 Table 1), the model trim, and the seed's Table 1 row where the vertex matches."
            )
            r.p(md_table(header, rows, fmt="{:.2f}"))

        r.guard("trims", trims)
    elif "trims" in d.problems:
        r.missing("trims")


def uncertainty_rows(models: dict | None) -> list[list]:
    """Per vertex: identified elements, dof, std widening, how the motor constants entered and
    the identified derivative at the flown trim mean (``vertex_models.yaml`` ``meta``, @2)."""
    if not isinstance(models, dict) or not isinstance(models.get("vertices"), list):
        return []
    meta = models.get("meta") or {}
    std = meta.get("std") or {}
    motor = meta.get("motor") or []
    flown = (meta.get("operating_point") or {}).get("xdot_flown") or []
    rows = []
    for i, v in enumerate(models["vertices"]):
        if not isinstance(v, dict):
            continue
        vtx = "[" + " ".join(f"{float(c):+g}" for c in v.get("scheduling", [])) + "]"
        dof = (std.get("dof") or [None] * (i + 1))[i] if i < len(std.get("dof") or []) else None
        tf = (
            (std.get("t_factor") or [None] * (i + 1))[i]
            if i < len(std.get("t_factor") or [])
            else None
        )
        m = motor[i].get("mode") if i < len(motor) and isinstance(motor[i], dict) else "known"
        xd = flown[i] if i < len(flown) and flown[i] is not None else None
        rows.append(
            [
                vtx,
                len(v.get("uncertain") or []),
                dof,
                tf,
                m,
                None if xd is None else ", ".join(f"{float(a):+.3f}" for a in xd[2:5]),
            ]
        )
    return rows


def _ident_section(r: _Report) -> None:
    d = r.data
    r.h(2, "Identification: equation-error R^2 (seed 0 Table 2)")

    def table2() -> None:
        header, rows, percent = fit_table(d.models, "r2")
        if not rows:
            r.p("`vertex_models.yaml` has no `fit.r2` entries.")
            return
        r.p(f"Coefficient of determination per state-equation axis{' [%]' if percent else ''}.")
        r.p(md_table(header, rows, fmt="{:.1f}" if percent else "{:.3f}"))
        box = uncertainty_rows(d.models)
        if box:
            meta = d.models.get("meta") or {}
            r.p(
                f"Identified uncertainty box (Eq. 22, `{d.models.get('format', '?')}`): every identified "
                f"element with lower/upper = nominal -/+ k std, k = {meta.get('k_sigma', '?')}; std = "
                f"{(meta.get('std') or {}).get('method', 'per-row')} standard error widened to the Student-t "
                "quantile of the same coverage; the operating point x0 is the identified model's equilibrium "
                "at the flown velocity (the flown trim mean is not one: its derivative below)."
            )
            r.p(
                md_table(
                    [
                        "vertex",
                        "elements",
                        "dof",
                        "std widening",
                        "a_Omega, b_Omega",
                        "|d/dt| at the flown mean (u, v, w)",
                    ],
                    box,
                    fmt="{:.3g}",
                )
            )

    r.with_input("models", "Table 2", table2)

    r.h(2, "Validation: TIC and NRMSE (seed 0 Table 3, Eqs. 24-25)")

    def table3() -> None:
        header, rows = validation_table(d.validation)
        if "validation" in d.derived:
            r.p(
                f"Independent validation maneuver `{d.validation.get('maneuver', '?')}` "
                f"({d.derived['validation']}):"
            )
        r.p(md_table(header, rows, fmt="{:.3f}"))
        for name in ("identification.png", "vertex_models_validation.png"):  # identify --plot
            fig4 = d.run_dir / name
            if fig4.is_file():
                dst = r.fig_dir / "validation.png"
                shutil.copyfile(fig4, dst)
                r.fig(
                    dst,
                    "Independent validation time histories, model vs flight-data state "
                    f"derivatives (Fig. 4; from `{name}`)",
                )
                break

    if not r.with_input("validation", "Table 3", table3):
        if d.models is not None:
            r.p("`vertex_models.yaml` carries no `meta.validation` either.")

            def fit_metrics() -> None:
                for metric in ("tic", "nrmse"):
                    header, rows, _ = fit_table(d.models, metric)
                    if rows:
                        r.p(
                            f"{metric.upper()} on the identification data per vertex (from `vertex_models.yaml`):"
                        )
                        r.p(md_table(header, rows, fmt="{:.3f}"))

            r.guard("fit metrics", fit_metrics)


def _get(d: dict, *keys: str) -> Any:
    for k in keys:
        if k in d:
            return d[k]
    return None


def _signals_section(r: _Report) -> None:
    d = r.data
    r.h(2, "Signal design (seed 0 Sec. V, Figs. 5-7)")
    if d.signals_summary is None and d.signals is None:
        r.missing("signals_summary")
        return
    s = d.signals_summary or {}
    names = _get(s, "names", "channels")
    channels = s.get("channels") if isinstance(s.get("channels"), list) else []
    if isinstance(names, list) and names and isinstance(names[0], dict):
        names = [str(c.get("name")) for c in names]

    def summary() -> None:
        rpf = _get(s, "rpf", "RPF", "relative_peak_factor")
        if rpf is None and channels and all(isinstance(c, dict) for c in channels):
            keys = [
                k
                for k in (
                    "group",
                    "frequency_range_hz",
                    "n_harmonics",
                    "rpf",
                    "peak",
                    "rms",
                    "leakage_fraction",
                )
                if any(k in c for c in channels)
            ]
            r.p("Channels (`signals/summary.yaml`):")
            r.p(
                md_table(
                    ["channel"] + keys,
                    [[c.get("name")] + [_short(c.get(k)) for k in keys] for c in channels],
                    fmt="{:.4g}",
                )
            )
        if isinstance(rpf, dict):
            r.p("Relative peak factor per channel:")
            r.p(
                md_table(["channel", "RPF"], [[k, float(v)] for k, v in rpf.items()], fmt="{:.3f}")
            )
        elif isinstance(rpf, list) and names and len(rpf) == len(names):
            r.p("Relative peak factor per channel:")
            r.p(
                md_table(
                    ["channel", "RPF"], [[n, float(v)] for n, v in zip(names, rpf)], fmt="{:.3f}"
                )
            )
        corr = _get(s, "correlation", "corr", "correlation_matrix")
        if isinstance(corr, dict):
            names_c = corr.get("names", names)
            corr = corr.get("matrix", corr.get("values"))
        else:
            names_c = names
        if isinstance(corr, list) and corr:
            C = np.asarray(corr, dtype=float)
            labels = (
                list(names_c)
                if names_c and len(names_c) == C.shape[0]
                else [str(i) for i in range(C.shape[0])]
            )
            off = np.abs(C - np.diag(np.diag(C)))
            r.p(
                f"Largest |correlation| between distinct channels: **{off.max():.4f}** "
                "(seed 0 Fig. 7 reports at most 0.075)."
            )
            r.p(
                md_table(
                    [""] + labels,
                    [[labels[i]] + [float(x) for x in C[i]] for i in range(C.shape[0])],
                    fmt="{:+.4f}",
                )
            )
            r.fig(
                plots.plot_correlation_matrix(
                    labels, C, r.fig_dir / "signal_correlation.png", "signal correlation"
                ),
                "Signal channel correlation (Fig. 7)",
            )
        scalars = {k: v for k, v in s.items() if isinstance(v, (int, float, str))}
        if scalars:
            r.p(_kv_table(scalars))

    r.with_input("signals_summary", "signals summary", summary)

    if d.signals is not None:

        def sig_plot() -> None:
            t = np.asarray(d.signals["t"], dtype=float)
            u = np.asarray(d.signals["u"], dtype=float)
            nm = [str(x) for x in d.signals.get("names", np.arange(u.shape[1]))]
            r.p(
                f"`signals.npz`: {u.shape[1]} channels ({', '.join(nm)}), {t.size} samples, "
                f"T = {t[-1] - t[0]:.2f} s, dt = {np.median(np.diff(t)):.4g} s."
            )
            r.fig(
                plots.plot_signals(t, u, nm, r.fig_dir / "signals.png", "normalised channels"),
                "Reference and excitation signals normalised to unit amplitude (Fig. 5)",
            )

        r.guard("signals plot", sig_plot)


def _synthesis_section(r: _Report) -> None:
    d = r.data
    r.h(2, "Robust LPV synthesis (seed 0 Lemma 1, Eqs. 27-31)")

    def body() -> None:
        g = d.gains
        vertices = g.get("vertices") or []
        rows = [["gamma (design)", g.get("gamma")], ["vertices", len(vertices)]]
        sched = g.get("scheduling")
        if isinstance(sched, dict):
            rows.append(["box min", sched.get("min")])
            rows.append(["box max", sched.get("max")])
        for key in ("R", "Q"):
            M = g.get(key)
            if isinstance(M, list):
                rows.append([f"diag({key})", [float(M[i][i]) for i in range(len(M))]])
        if vertices and isinstance(vertices[0], dict) and "K" in vertices[0]:
            norms = [float(np.linalg.norm(np.asarray(v["K"], dtype=float), 2)) for v in vertices]
            rows.append(["max ||K_i||_2", max(norms)])
        r.p(md_table(["quantity", "value"], [[k, _short(v)] for k, v in rows], fmt="{:.6g}"))
        cert = g.get("certificate")
        if isinstance(cert, dict):
            r.p("Certificate:")
            r.p(_kv_table(cert))
        else:
            r.p("**gains.yaml carries no certificate.**")

    r.with_input("gains", "synthesis", body)


def _failing_and_worst(checks: list[dict]) -> list[dict]:
    """Failing rows, then per check kind the passing row with the largest value."""
    out = [c for c in checks if c.get("ok") is False]
    for kind in dict.fromkeys(c.get("check") for c in checks):
        rows = [c for c in checks if c.get("check") == kind and c.get("ok") is not False]
        if rows:
            out.append(max(rows, key=lambda c: float(c.get("value") or 0.0)))
    return out


def _short(v: Any) -> Any:
    if isinstance(v, list):
        return (
            "["
            + ", ".join(f"{float(x):g}" if isinstance(x, (int, float)) else str(x) for x in v)
            + "]"
        )
    return v


def _full_box_paragraph(r: _Report, fb: dict) -> None:
    """The empirical full-identified-box Monte Carlo (synthesis.verify item 5): not certified."""
    r.h(3, "Full identified uncertainty box (empirical Monte Carlo, not certified)")
    try:
        worst, gamma, frac = float(fb["worst_norm"]), float(fb["gamma"]), float(fb["fraction_ok"])
        r.p(
            f"Every identified element drawn independently from its full interval (k = {float(fb['k_sigma']):g} "
            f"std, {fb.get('k_sigma_source', '')}; {fb.get('intervals_stored', '?')} stored / "
            f"{fb.get('intervals_k_std', '?')} nominal +/- k std intervals), {fb['samples']} frozen samples "
            f"(scheduling corners, random interior points and first-order worst corners; seed {fb.get('seed', '?')}): worst closed-loop H-inf norm u_e -> z **{worst:.4g}** vs "
            f"gamma {gamma:g} at v_d {_short(fb.get('worst_v_d', []))} ({fb.get('worst_where', '')}); "
            f"{100 * frac:.1f} % of samples stable with norm <= gamma; all stable: "
            f"{'yes' if fb.get('all_stable') else 'NO'}; max spectral abscissa {float(fb['max_abscissa']):.4g}. "
            + (
                "All samples within the bound."
                if fb.get("passed")
                else "**WARNING:** samples outside the bound -- the certificate covers the reduced polytope only."
            )
        )
    except (KeyError, TypeError, ValueError):
        r.p(_kv_table(fb))


def _verification_section(r: _Report) -> None:
    d = r.data
    r.h(2, "Independent verification")

    def body() -> None:
        v = d.verification
        if isinstance(v, dict):
            ok = _get(v, "passed", "ok", "pass")
            checks = _get(v, "checks", "results")
            if ok is not None:
                n_fail = (
                    sum(
                        1
                        for c in checks
                        if isinstance(c, dict) and c.get("ok") is False and not c.get("advisory")
                    )
                    if isinstance(checks, list)
                    else None
                )
                n_warn = (
                    sum(
                        1
                        for c in checks
                        if isinstance(c, dict) and c.get("ok") is False and c.get("advisory")
                    )
                    if isinstance(checks, list)
                    else 0
                )
                r.p(
                    f"Overall: **{'PASSED' if ok else 'FAILED'}**"
                    + (
                        f" ({len(checks)} checks, {n_fail} failed"
                        + (f", {n_warn} advisory warnings" if n_warn else "")
                        + ")"
                        if n_fail is not None
                        else ""
                    )
                )
            if v.get("source"):
                r.p(f"Source: {v['source']}.")
            elif "verification" in d.derived:
                r.p(f"Source: {d.derived['verification']}.")
            if isinstance(checks, list) and checks and all(isinstance(c, dict) for c in checks):
                keys: list[str] = []
                for c in checks:
                    keys += [k for k in c if k not in keys]
                canon = ("check", "where", "value", "limit", "ok", "note")
                keys = [k for k in canon if k in keys] + [k for k in keys if k not in canon]
                shown = checks
                if len(checks) > 20 and "check" in keys:
                    shown = _failing_and_worst(checks)
                    r.p("Failing checks, then the worst passing row of each check:")
                r.p(
                    md_table(keys, [[_short(c.get(k)) for k in keys] for c in shown], fmt="{:.4g}")
                )
                rest = {
                    k: x
                    for k, x in v.items()
                    if k not in ("checks", "results", "source", "passed", "full_box")
                }
                if rest:
                    r.p(_kv_table(rest))
            else:
                r.p(_kv_table(v))
            if isinstance(v.get("full_box"), dict):
                _full_box_paragraph(r, v["full_box"])
        elif isinstance(v, list):
            r.p(_kv_table({"checks": v}))
        else:
            raise ConfigError(f"{d.found['verification']}: expected a mapping or a list")

    r.with_input("verification", "verification", body)


RUN_LABELS = (
    ("eq33", "LPV closed loop, Eq. (33)"),
    ("linear_ff", "LPV model + feedforward, no x0'"),
    ("nonlinear", "nonlinear quadrotor"),
)


def gain_row(label: str, e: dict, gamma) -> list:
    """One row of the phase-2 gains table from a run's summary entry (``phase2_summary@2``;
    an ``@1`` entry has only the mixed ratio ``gain``, shown as the total, the gain unknown)."""
    d = e.get("decomposition") or {}
    g = e.get("excitation_gain")
    within = None if g is None or gamma is None else bool(float(g) <= float(gamma))
    total = e.get("total_ratio", e.get("gain"))
    track = (d.get("tracking") or d.get("tracking_and_excitation") or {}).get("ratio")
    note = e.get("safety_event") or ("completed" if e.get("completed", True) else "stopped")
    how = str(
        d.get("method", "not separated (older summary: the ratio mixes tracking and offset)")
    )
    return [
        label,
        g,
        within,
        how.split(" (")[0],
        (d.get("offset") or {}).get("ratio"),
        track,
        total,
        note,
    ]


def _phase2_section(r: _Report) -> None:
    d = r.data
    r.h(2, "Phase 2: LPV-controlled excitation (seed 0 Sec. VII)")
    s = d.phase2_summary

    def gains_table() -> None:
        gamma = s.get("gamma")
        rows = []
        for name, label in RUN_LABELS:
            e = s.get(name)
            if not isinstance(e, dict):
                continue
            if e.get("skipped"):
                rows.append(
                    [label, None, None, "", None, None, None, "skipped: " + str(e["skipped"])]
                )
                continue
            rows.append(gain_row(label, e, gamma))
        r.p(
            f"Excitation multiplier kappa = {s.get('kappa')}, design gamma = {gamma}: the bound of Lemma 1 "
            "on ||z_e||_2 / ||kappa u_e||_2, the gain from the excitation to the performance output (Eq. 29)."
        )
        r.p(
            md_table(
                [
                    "simulation",
                    "u_e -> z gain",
                    "<= gamma",
                    "separated by",
                    "equilibrium offset",
                    "tracking",
                    "total ||z||/||kappa u_e||",
                    "run",
                ],
                rows,
                fmt="{:.4g}",
            )
        )
        r.p(
            "z = Q^-1 (v - v_d) (Eq. 18) holds three parts, reported apart (each as its L2 norm over "
            "||kappa u_e||_2; the norms overlap and do not add): the response to the excitation u_e, the "
            "only part gamma bounds; the equilibrium offset Q^-1 (v0(v_d) - v_d), because the vertex "
            "equilibria fly a velocity other than the commanded one (seed 0 Table 1); and the lag in "
            "following v_d (none in Eq. 33, where x0' of Eq. 34 carries the equilibrium along; present "
            "with the feedforward law instead of x0' and on the vehicle, which must accelerate). The "
            "excitation part comes from superposition, exact for the linear model (Eq. 33: its unexcited "
            "run stays at x0(v_d); the feedforward run: the same run with -u_e), on the nonlinear flight "
            "from two more flights with the same sensor noise (--superposition) or otherwise from a FIR "
            "regression of z on u_e above the reference band; the offset part is exact."
        )
        details = []
        for name in ("eq33", "linear_ff", "nonlinear"):
            e = s.get(name)
            if isinstance(e, dict) and not e.get("skipped"):
                for k, v in e.items():
                    if k not in (
                        "gain",
                        "z_norm",
                        "ue_norm",
                        "within_gamma",
                        "completed",
                        "safety_event",
                        "excitation_gain",
                        "total_ratio",
                        "decomposition",
                    ):
                        details.append(
                            [
                                f"{name}.{k}",
                                _short(v)
                                if not isinstance(v, dict)
                                else ", ".join(f"{a}: {b}" for a, b in v.items()),
                            ]
                        )
        if details:
            r.p(md_table(["run detail", "value"], details, fmt="{:.4g}"))
        events = s.get("safety_events") or []
        if events:
            r.p("**Safety events:** " + "; ".join(str(e) for e in events))

    r.with_input("phase2_summary", "phase-2 gains", gains_table)

    for name, label in (
        ("eq33", "LPV closed loop Eq. (33)"),
        ("nonlinear", "nonlinear quadrotor"),
    ):
        ser = d.phase2_series.get(name)
        if ser is None:
            continue

        def tracking(ser=ser, name=name, label=label) -> None:
            t = np.asarray(ser["t"], dtype=float)
            vd = np.asarray(ser["v_d"], dtype=float)
            v = np.asarray(ser["v"], dtype=float)
            err = v - vd
            rms = np.sqrt(np.mean(err**2, axis=0))
            r.p(
                f"{label}: {t.size} samples over {t[-1] - t[0]:.2f} s; RMS tracking error "
                f"u/v/w = {rms[0]:.3f} / {rms[1]:.3f} / {rms[2]:.3f} m/s, max |v - v_d| = "
                f"{np.max(np.abs(err)):.3f} m/s."
            )
            r.fig(
                plots.plot_tracking(t, vd, v, r.fig_dir / f"tracking_{name}.png", label),
                f"Body velocity and reference, {label} (Fig. 8)",
            )
            r.fig(
                plots.plot_perturbation(t, err, r.fig_dir / f"perturbation_{name}.png", label),
                f"Body velocity perturbation, {label} (Fig. 9)",
            )

        r.guard(f"phase-2 {name} plots", tracking)

    if s is not None and isinstance(s.get("regressor_correlation"), dict):

        def fig10() -> None:
            rc = s["regressor_correlation"]
            corrs = regressor_correlations_from_summary(rc)
            r.h(3, "Regressor correlation (seed 0 Eq. 6, Fig. 10)")
            src = {"eq33": "Eq. (33) LPV closed-loop", "nonlinear": "nonlinear quadrotor"}.get(
                rc.get("source"), str(rc.get("source", "phase-2"))
            )
            partial = "" if rc.get("complete_run", True) else " (run stopped early: partial data)"
            r.p(
                f"Computed from the {src} simulation data{partial}, {rc.get('n_samples', '?')} samples. "
                "Largest |correlation| between distinct regressors of each axis:"
            )
            r.p(
                md_table(
                    ["axis", "regressors", "max |corr|", "pair"],
                    [[c.axis, len(c.names), c.max_offdiag(), _worst_pair(c)] for c in corrs],
                    fmt="{:.3f}",
                )
            )
            r.fig(
                plots.plot_regressor_correlations(
                    corrs, r.fig_dir / "regressor_correlation.png", "Eq. (6) regressor correlation"
                ),
                "Regressor correlation coefficients per axis (Fig. 10)",
            )

        r.guard("Fig. 10", fig10)


def regressor_correlations_from_summary(rc: dict) -> list[RegressorCorrelation]:
    """Summary block {axes: {X: {names, corr}, ...}} -> RegressorCorrelation list."""
    axes = rc.get("axes")
    if not isinstance(axes, dict):
        raise ConfigError("phase2/summary.yaml: regressor_correlation.axes must be a mapping")
    out = []
    for a in AXES:
        if a not in axes:
            continue
        names = tuple(axes[a].get("names") or REGRESSOR_NAMES[a])
        C = np.array([[np.nan if x is None else float(x) for x in row] for row in axes[a]["corr"]])
        if C.shape != (len(names), len(names)):
            raise ConfigError(
                f"phase2/summary.yaml: regressor_correlation.axes.{a}.corr has shape {C.shape}"
            )
        out.append(RegressorCorrelation(a, names, C))
    return out


def _worst_pair(c: RegressorCorrelation) -> str:
    A = np.abs(c.corr.copy())
    np.fill_diagonal(A, np.nan)
    if not np.any(np.isfinite(A)):
        return "-"
    i, j = np.unravel_index(np.nanargmax(A), A.shape)
    return f"{c.names[i]} / {c.names[j]}"


def write_report(
    run_dir: str | Path, out_path: Optional[str | Path] = None, verify: bool = True
) -> Path:
    """Write ``report.md`` (default ``RUN/report/report.md``) and its PNG figures; return its path.

    ``verify``: without a ``verification.yaml``, re-run the independent verifier on
    ``gains.yaml`` + ``vertex_models.yaml`` (about a second)."""
    data = load_run(run_dir, verify=verify)
    out = Path(out_path) if out_path is not None else data.run_dir / "report" / "report.md"
    if out.suffix.lower() != ".md":
        raise ConfigError(f"--out: {out} must end in .md")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"--out: cannot create {out.parent} ({exc.strerror})") from None
    r = _Report(data, out)
    r.lines = [
        "# lpv_sysid run report",
        "",
        f"Run directory: `{data.run_dir}`. Method: Hopwood & Woolsey, robust LPV control for "
        "safe and effective unstable-aircraft system identification (seed 0).",
    ]
    _inputs_section(r)
    _phase1_section(r)
    _ident_section(r)
    _signals_section(r)
    _synthesis_section(r)
    _verification_section(r)
    _phase2_section(r)
    text = "\n".join(r.lines).rstrip() + "\n"
    try:
        out.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"--out: cannot write {out} ({exc.strerror})") from None
    return out
