"""Report sections on what was flown (or simulated): the go/no-go summary with the safety
margins and the provenance of the data, the phase-2 gains and tracking (seed 0 Sec. VII,
Figs. 8-9) and the regressor correlation (Eq. 6, Fig. 10)."""

from __future__ import annotations

import logging
from typing import Any, Optional

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.ident.nonlinear import AXES, REGRESSOR_NAMES, RegressorCorrelation
from lpv_sysid.report import plots
from lpv_sysid.report.data import RunData
from lpv_sysid.report.document import Report, md_table, short
from lpv_sysid.report.gonogo import (
    DATA_LABELS,
    SIMULATED,
    SIMULATED_LABELS,
    go_no_go,
    provenance,
)
from lpv_sysid.report.margins import RunMargins, limits_from_summary, run_margins

log = logging.getLogger(__name__)


RUN_LABELS = (
    ("eq33", "LPV closed loop, Eq. (33)"),
    ("linear_ff", "LPV model + feedforward, no x0'"),
    ("nonlinear", "nonlinear quadrotor"),
)


def gain_row(label: str, e: dict, gamma: Any) -> list:
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


def _phase2_section(r: Report) -> None:
    d = r.data
    r.h(2, "Phase 2: LPV-controlled excitation (seed 0 Sec. VII)")
    s = d.phase2_summary

    def gains_table() -> None:
        s = d.phase2_summary or {}
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
            f"Excitation multiplier kappa = {s.get('kappa')}, design gamma = {gamma}: the bound "
            "of Lemma 1 on ||z_e||_2 / ||kappa u_e||_2, the gain from the excitation to the "
            "performance output (Eq. 29). All runs below are SIMULATED (sim.phase2)."
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
            "z = Q^-1 (v - v_d) (Eq. 18) holds three parts, reported apart (each as its L2 norm "
            "over ||kappa u_e||_2; the norms overlap and do not add): the response to the "
            "excitation u_e, the only part gamma bounds; the equilibrium offset Q^-1 (v0(v_d) - "
            "v_d), because the vertex equilibria fly a velocity other than the commanded one "
            "(seed 0 Table 1); and the lag in following v_d (none in Eq. 33, where x0' of Eq. 34 "
            "carries the equilibrium along; present with the feedforward law instead of x0' and "
            "on the vehicle, which must accelerate). The excitation part comes from "
            "superposition, exact for the linear model (Eq. 33: its unexcited run stays at "
            "x0(v_d); the feedforward run: the same run with -u_e), on the simulated nonlinear "
            "run from two more runs with the same sensor noise (--superposition) or otherwise "
            "from a FIR regression of z on u_e above the reference band; the offset part is exact."
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
                                short(v)
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
            sched = (d.gains or {}).get("scheduling") or (d.models or {}).get("scheduling")
            box = (
                (sched["min"], sched["max"])
                if isinstance(sched, dict) and "min" in sched and "max" in sched
                else None
            )
            title = f"[{SIMULATED}] {label}"
            r.fig(
                plots.plot_tracking(t, vd, v, r.fig_dir / f"tracking_{name}.png", title, box),
                f"[{SIMULATED}] Body velocity and reference with the scheduling box, {label} "
                "(Fig. 8)",
            )
            r.fig(
                plots.plot_perturbation(t, err, r.fig_dir / f"perturbation_{name}.png", title),
                f"[{SIMULATED}] Body velocity perturbation, {label} (Fig. 9)",
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
                f"Computed from the {src} simulation data{partial}, "
                f"{rc.get('n_samples', '?')} samples. Largest |correlation| between distinct "
                "regressors of each axis:"
            )
            r.p(
                md_table(
                    ["axis", "regressors", "max |corr|", "pair"],
                    [[c.axis, len(c.names), c.max_offdiag(), _worst_pair(c)] for c in corrs],
                    fmt="{:.3f}",
                )
            )
            pairs = collinear_pairs(corrs)
            if pairs:
                r.p(
                    f"**Near-collinear regressors (|r| >= {plots.COLLINEAR:g}):** the data cannot "
                    "separate the parameters of these pairs (seed 0 Sec. VII); their estimates "
                    "trade off against each other."
                )
                r.p(md_table(["axis", "regressor", "regressor", "r"], pairs, fmt="{:+.3f}"))
            else:
                r.p(f"No regressor pair reaches |r| >= {plots.COLLINEAR:g}.")
            r.fig(
                plots.plot_regressor_correlations(
                    corrs, r.fig_dir / "regressor_correlation.png", "Eq. (6) regressor correlation"
                ),
                "Signed regressor correlation coefficients per axis (Fig. 10), colour scale "
                f"-1..1; outlined: |r| >= {plots.COLLINEAR:g}",
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


def collinear_pairs(
    corrs: list[RegressorCorrelation], at: float = plots.COLLINEAR
) -> list[list[Any]]:
    """[axis, regressor, regressor, r] of every distinct pair with |r| >= ``at``, largest first."""
    out = []
    for c in corrs:
        n = len(c.names)
        for i in range(n):
            for j in range(i + 1, n):
                r = float(c.corr[i, j])
                if np.isfinite(r) and abs(r) >= at:
                    out.append([c.axis, c.names[i], c.names[j], r])
    return sorted(out, key=lambda row: -abs(row[3]))


def phase2_margins(d: RunData) -> Optional[RunMargins]:
    """Margins of the run that stands for the flight: the nonlinear one (the vehicle model),
    else the Eq. (33) run; None without a summary or time histories."""
    s = d.phase2_summary
    if not isinstance(s, dict):
        return None
    for name in ("nonlinear", "eq33"):
        arrays = d.phase2_series.get(name)
        if arrays is not None:
            window = (s.get(name) or {}).get("monitor_window_s")
            lim = limits_from_summary(s)
            return run_margins(name, arrays, lim, None if window is None else float(window))
    return None


def go_no_go_section(r: Report) -> Optional[RunMargins]:
    """The go/no-go table, the provenance of every data set and the margin plot; returns the
    margins used (None when there are no phase-2 time histories)."""
    d = r.data
    m: Optional[RunMargins] = None
    try:
        m = phase2_margins(d)
    except (ConfigError, KeyError, TypeError, ValueError, IndexError) as exc:
        log.warning("margins: %s", exc)
        r.p(f"**Safety margins could not be computed:** {exc}")
    rows, overall = go_no_go(d, m)
    src = provenance(d)
    labelled = [x for x in src if x.label in DATA_LABELS]
    all_sim = bool(labelled) and all(x.label in SIMULATED_LABELS for x in labelled)
    kinds = "/".join(dict.fromkeys(x.label for x in labelled))
    r.h(2, f"Go / no-go: **{overall}**" + (f" (on {kinds} data only)" if all_sim else ""))
    r.p(
        md_table(
            ["item", "value", "limit", "verdict", "note"],
            [[x.item, x.value, x.limit, x.verdict, x.note] for x in rows],
        )
    )
    r.p(
        "Data sources: "
        + (f"**{kinds}** data only -- nothing here was flown." if all_sim else "see the table.")
    )
    r.p(
        md_table(
            ["data set", "source", "evidence"], [[x.dataset, x.label, x.evidence] for x in src]
        )
    )
    if m is not None:
        L = m.limits
        limits = "; ".join(f"{k}: {v}" for k, v in L.source.items() if "default" in v)
        r.fig(
            plots.plot_margins(m, r.fig_dir / f"margins_{m.run}.png", f"safety margins, {m.run}"),
            f"Safety margins over the {m.run} run (SIMULATED): tilt, ESC headroom, distance to "
            "the scheduling-box edge and the bound-monitor ratio, each with its limit",
        )
        if limits:
            r.p(f"Limits not recorded by the run, taken from the code's defaults: {limits}.")
    return m


def flown_phase2_section(r: Report) -> None:
    """The flown phase 2 (``fly phase2`` / ``chain``: ``phase2_summary.yaml`` +
    ``phase2_log.npz``): outcome, aborts, hand-back, tracking and the u_e -> z gain against
    gamma, and the time histories with the scheduling box, the limits and the abort, every
    title labelled with the vehicle kind its recorder recorded."""
    d = r.data
    s = d.flight_phase2
    if not isinstance(s, dict):
        return
    from lpv_sysid.report.gonogo import phase2_experiment, vehicle_label

    label, how = vehicle_label(phase2_experiment(d))
    r.h(2, f"Phase 2: flown under the LPV law ({label})")

    def summary() -> None:
        hb = s.get("handback") or {}
        gi = s.get("gain_u_e_to_z") or {}
        lat = s.get("latency_state_to_setpoint_ms") or {}
        rows = [
            ["data", f"{label}: {how}"],
            ["outcome", ("complete" if s.get("ok") else "ABORTED") + f": {s.get('reason')}"],
            ["hand-back", f"{hb.get('state')} to {hb.get('mode')} ({hb.get('reason')})"],
            ["controller abort", (s.get("controller") or {}).get("abort") or "none"],
            [
                "signal / kappa / gamma",
                f"{s.get('signal_duration_s')} s / {s.get('kappa')} / {s.get('gamma')}",
            ],
            ["u_e -> z gain", f"{gi.get('gain', gi.get('ratio'))} ({gi.get('method', '-')})"],
            ["loop latency p50 / p99 [ms]", f"{lat.get('p50')} / {lat.get('p99')}"],
        ]
        for key, what in (("tracking_rms", "tracking RMS"), ("tracking_max", "tracking max")):
            v = s.get(key)
            if isinstance(v, dict):
                rows.append(
                    [
                        f"{what} u/v/w [m/s]",
                        " / ".join(f"{float(v[a]):.3f}" for a in "uvw" if a in v),
                    ]
                )
        r.p(md_table(["item", "value"], rows, fmt="{:.4g}"))

    r.guard("flown phase-2 summary", summary)
    log_ = d.flight_phase2_log
    if log_ is None:
        r.p(
            "**No time histories:** `phase2_log.npz` not found next to the phase-2 summary "
            "(written by `lpv-sysid fly phase2`)."
        )
        return

    def histories() -> None:
        t_abs = np.asarray(log_["t"], dtype=float)
        if t_abs.size < 2:
            raise ValueError("phase2_log.npz: fewer than 2 samples")
        t = t_abs - t_abs[0]
        x = np.asarray(log_["x"], dtype=float)
        v, vd = x[:, 2:5], np.asarray(log_["v_d"], dtype=float)
        u, sent = np.asarray(log_["u"], dtype=float), np.asarray(log_["sent"], dtype=float)
        lim = s.get("limits") or {}
        box = (lim["box_min"], lim["box_max"]) if "box_min" in lim else None
        if box is None:
            sched = (d.gains or {}).get("scheduling")
            if isinstance(sched, dict) and "min" in sched:
                box = (sched["min"], sched["max"])
        ins = None
        if "thrust" in lim and "max_rate_rad_s" in lim:
            mr = float(lim["max_rate_rad_s"])
            ins = [tuple(lim["thrust"])] + [(-mr, mr)] * 3
        tsig = np.asarray(log_["tsig"], dtype=float)
        on = np.nonzero(tsig >= 0)[0]
        signal = (float(t[on[0]]), float(t[on[-1]])) if on.size else None
        abort = None if s.get("ok") else (float(t[-1]), str(s.get("reason")))
        err = np.abs(v - vd)
        out_box = (
            None
            if box is None
            else float(np.max(np.maximum(np.asarray(box[0]) - v, v - np.asarray(box[1]))))
        )
        r.p(
            f"{t.size} commands over {t[-1]:.2f} s; max |v - v_d| {err.max():.3f} m/s"
            + (
                f" (limit {float(lim['max_tracking_error_m_s']):g} m/s)"
                if "max_tracking_error_m_s" in lim
                else ""
            )
            + (
                ""
                if out_box is None
                else f"; largest excursion beyond the scheduling box {max(out_box, 0.0):.3f} m/s"
            )
            + ("; " + ("ABORTED at the red line" if abort else "signal complete") + ".")
        )
        title = f"[{label}] phase-2 flight: body velocity, reference, box, limits"
        r.fig(
            plots.plot_flown_phase2(
                t,
                v,
                vd,
                u,
                sent,
                r.fig_dir / "phase2_flight.png",
                title,
                box,
                lim.get("max_tracking_error_m_s"),
                ins,
                lim.get("input_names") or ("thrust", "p_sp", "q_sp", "r_sp"),
                signal,
                abort,
            ),
            f"[{label}] Flown phase 2: u, v, w against v_d with the scheduling box (dotted), "
            "the tracking limit that hands back (grey band), the signal window (green), "
            "the inputs computed and sent with their limits (red dotted)"
            + (" and the abort (red line)" if abort else ""),
        )

    r.guard("flown phase-2 time histories", histories)
