"""Report sections on the design inputs and outputs: phase-1 equilibria, identification,
validation, signal design, synthesis certificate and the independent verification."""

from __future__ import annotations

import logging
import shutil
from typing import Any

import numpy as np

from lpv_sysid.report import plots
from lpv_sysid.report.data import (
    RunData,
    equilibrium_table,
    fit_table,
    trims_table,
    validation_table,
)
from lpv_sysid.report.document import Report, get_first, kv_table, md_table, short
from lpv_sysid.report.gonogo import provenance

log = logging.getLogger(__name__)


def phase1_label(d: RunData) -> str:
    """SIMULATED / FLOWN of the phase-1 data (:func:`lpv_sysid.report.gonogo.provenance`)."""
    return provenance(d)[0].label


def _phase1_section(r: Report) -> None:
    d = r.data
    r.h(2, "Phase 1: vertex equilibria (seed 0 Table 1)")

    def table1() -> None:
        header, rows = equilibrium_table(d.models or {})
        r.p(
            "Equilibria `x0` of the identified vertex models (from flight data in the seed; "
            f"here from the {phase1_label(d)} phase-1 runs)."
        )
        r.p(md_table(header, rows, fmt="{:.2f}"))

    r.with_input("models", "Table 1", table1)
    if d.trims is not None:

        def trims() -> None:
            header, rows = trims_table(d.trims)
            r.p(
                "Phase-1 runs (`trims.yaml`): achieved equilibrium (mean over the trim segment, "
                "as seed 0 Table 1), the model trim, and the seed's Table 1 row where the vertex "
                "matches."
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


def _ident_section(r: Report) -> None:
    d = r.data
    r.h(2, "Identification: equation-error R^2 (seed 0 Table 2)")

    def table2() -> None:
        header, rows, percent = fit_table(d.models or {}, "r2")
        if not rows:
            r.p("`vertex_models.yaml` has no `fit.r2` entries.")
            return
        r.p(f"Coefficient of determination per state-equation axis{' [%]' if percent else ''}.")
        r.p(md_table(header, rows, fmt="{:.1f}" if percent else "{:.3f}"))
        box = uncertainty_rows(d.models)
        if box:
            meta = (d.models or {}).get("meta") or {}
            method = (meta.get("std") or {}).get("method", "per-row")
            fmt = (d.models or {}).get("format", "?")
            r.p(
                f"Identified uncertainty box (Eq. 22, `{fmt}`): every "
                "identified element with lower/upper = nominal -/+ k std, k = "
                f"{meta.get('k_sigma', '?')}; std = {method} standard error widened to the "
                "Student-t quantile of the same coverage; the operating point x0 is the "
                "identified "
                "model's equilibrium at the flown velocity (the flown trim mean is not one: its "
                "derivative below)."
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
        header, rows = validation_table(d.validation or {})
        if "validation" in d.derived:
            r.p(
                f"Independent validation maneuver `{(d.validation or {}).get('maneuver', '?')}` "
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
                    "Independent validation time histories, model vs measured state derivatives "
                    f"of the {phase1_label(d)} validation run (Fig. 4; from `{name}`)",
                )
                break

    if not r.with_input("validation", "Table 3", table3):
        if d.models is not None:
            r.p("`vertex_models.yaml` carries no `meta.validation` either.")

            def fit_metrics() -> None:
                for metric in ("tic", "nrmse"):
                    header, rows, _ = fit_table(d.models or {}, metric)
                    if rows:
                        r.p(
                            f"{metric.upper()} on the identification data per vertex "
                            "(from `vertex_models.yaml`):"
                        )
                        r.p(md_table(header, rows, fmt="{:.3f}"))

            r.guard("fit metrics", fit_metrics)


def _signals_section(r: Report) -> None:
    d = r.data
    r.h(2, "Signal design (seed 0 Sec. V, Figs. 5-7)")
    if d.signals_summary is None and d.signals is None:
        r.missing("signals_summary")
        return
    s = d.signals_summary or {}
    names = get_first(s, "names", "channels")
    channels = s.get("channels") if isinstance(s.get("channels"), list) else []
    if isinstance(names, list) and names and isinstance(names[0], dict):
        names = [str(c.get("name")) for c in names]

    def summary() -> None:
        rpf = get_first(s, "rpf", "RPF", "relative_peak_factor")
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
                    [[c.get("name")] + [short(c.get(k)) for k in keys] for c in channels],
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
        corr = get_first(s, "correlation", "corr", "correlation_matrix")
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
            r.p(kv_table(scalars))

    r.with_input("signals_summary", "signals summary", summary)

    if d.signals is not None:
        r.guard("signal spectra", lambda: _spectra(r, channels or [], s.get("f0_hz")))


def _spectra(r: Report, channels: list, f0: Any) -> None:
    """Amplitude spectra of the designed multisines (replaces the time-history plot: seven
    channels of 5000 samples each are a solid band at report size)."""
    sig = r.data.signals or {}
    t = np.asarray(sig["t"], dtype=float)
    u = np.asarray(sig["u"], dtype=float)
    nm = [str(x) for x in sig.get("names", np.arange(u.shape[1]))]
    by_name = {c.get("name"): c for c in channels if isinstance(c, dict)}
    harm = [by_name.get(n, {}).get("harmonics") for n in nm]
    T = float(t[-1] - t[0] + np.median(np.diff(t)))
    f0 = float(f0) if f0 else 1.0 / T
    r.p(
        f"`signals.npz`: {u.shape[1]} channels ({', '.join(nm)}), {t.size} samples, "
        f"T = {T:.2f} s, dt = {np.median(np.diff(t)):.4g} s, base frequency f0 = {f0:.4g} Hz."
    )
    r.fig(
        plots.plot_spectra(t, u, nm, harm, f0, r.fig_dir / "spectra.png", "multisine spectra"),
        "Amplitude spectra of the reference and excitation multisines over one period; dots: "
        "each channel's excited harmonics k f0 (signals/summary.yaml, or read from the "
        "spectrum where a panel's title says so), grey: all other bins "
        "(seed 0 Sec. V, Fig. 6)",
    )


def _synthesis_section(r: Report) -> None:
    d = r.data
    r.h(2, "Robust LPV synthesis (seed 0 Lemma 1, Eqs. 27-31)")

    def body() -> None:
        g = d.gains or {}
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
        r.p(md_table(["quantity", "value"], [[k, short(v)] for k, v in rows], fmt="{:.6g}"))
        cert = g.get("certificate")
        if isinstance(cert, dict):
            r.p("Certificate:")
            r.p(kv_table(cert))
        else:
            r.p("**gains.yaml carries no certificate.**")

    r.with_input("gains", "synthesis", body)


def _full_box_paragraph(r: Report, fb: dict, claimed: bool) -> None:
    """The full-identified-box Monte Carlo (synthesis.full_box_montecarlo): evidence, not proof;
    for a full-box certificate a cross-check of its claim, for a reduced-polytope one advisory."""
    r.h(3, "Full identified uncertainty box (empirical Monte Carlo)")
    try:
        worst, gamma, frac = float(fb["worst_norm"]), float(fb["gamma"]), float(fb["fraction_ok"])
        if fb.get("passed"):
            verdict = "All samples within the bound."
        elif claimed:
            verdict = (
                "**FAILED:** samples outside the bound -- the certificate claims this box, so "
                "the claim is contradicted."
            )
        else:
            verdict = (
                "**WARNING:** samples outside the bound -- this certificate covers the reduced "
                "polytope (`certified_set.kind: reduced_polytope`), not this box."
            )
        r.p(
            "Every identified element drawn independently from its full interval (k = "
            f"{float(fb['k_sigma']):g} std, {fb.get('k_sigma_source', '')}; "
            f"{fb.get('intervals_stored', '?')} stored / {fb.get('intervals_k_std', '?')} "
            f"nominal +/- k std intervals), {fb['samples']} frozen samples (scheduling corners, "
            "random interior points and first-order worst corners; seed "
            f"{fb.get('seed', '?')}): worst closed-loop H-inf norm u_e -> z **{worst:.4g}** vs "
            f"gamma {gamma:g} at v_d {short(fb.get('worst_v_d', []))} "
            f"({fb.get('worst_where', '')}); {100 * frac:.1f} % of samples stable with norm <= "
            f"gamma; all stable: {'yes' if fb.get('all_stable') else 'NO'}; max spectral "
            f"abscissa {float(fb['max_abscissa']):.4g}. "
            + ("A cross-check of the certified set. " if claimed else "")
            + verdict
        )
    except (KeyError, TypeError, ValueError):
        r.p(kv_table(fb))


def _verification_section(r: Report) -> None:
    d = r.data
    r.h(2, "Independent verification (`verification.yaml`)")

    def body() -> None:
        v = d.verification
        assert v is not None  # with_input
        r.p(
            f"Overall: **{'PASSED' if v.passed else 'FAILED'}** ({len(v.checks)} checks, "
            f"{len(v.failed)} failed"
            + (f", {len(v.warnings)} advisory warnings" if v.warnings else "")
            + f"); {v.tool_version}, {v.created}; gains `{v.gains_file}` (sha256 "
            f"{v.gains_sha256[:16]}...), models `{v.models_file}`."
        )
        r.p(
            md_table(
                ["number", "value"],
                [[k, val] for k, val in v.numbers.items()],
                fmt="{:.6g}",
            )
        )
        r.p("Per check (worst row of each kind):")
        keys = ["check", "rows", "failed", "warnings", "worst_value", "limit", "where", "result"]
        r.p(md_table(keys, [[c[k] for k in keys] for c in v.per_check()], fmt="{:.4g}"))
        bad = v.failed + v.warnings
        if bad:
            r.p("Failing rows:")
            cols = ["check", "where", "value", "limit", "ok", "note"]
            r.p(md_table(cols, [[c.get(k) for k in cols] for c in bad[:40]], fmt="{:.4g}"))
        if v.full_box is not None:
            cs = ((d.gains or {}).get("certificate") or {}).get("certified_set") or {}
            _full_box_paragraph(r, v.full_box, cs.get("kind") == "full_identified_box")

    r.with_input("verification", "verification", body)
