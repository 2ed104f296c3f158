"""``DIR/report.md`` of the PX4 chain (:mod:`lpv_sysid.flight.chain`): the design, the steps,
the identification, the rate-loop inversion measurement, the certificate and what the vehicle
did in phase 2."""

from __future__ import annotations

from pathlib import Path
from typing import Optional


def format_identification(rep: dict) -> str:
    lines = ["  row   R^2     notes"]
    for row, d in rep["rows"].items():
        extra = ""
        if "delay_s" in d:
            extra = (
                f"bandwidth {d['bandwidth_rad_s']:.2f} rad/s, best delay {d['delay_s']:.2f} s, "
                "free-fit DC gain "
                f"{d['unconstrained']['dc_gain']}"
            )
        lines.append(f"  {row:<5} {d['r2']:.3f}   {extra}")
    p = rep["params"]
    lines.append("  pooled: " + ", ".join(f"{k} {p[k]:.3g}" for k in ("X_u", "Y_v", "Z_w", "Z_T")))
    if rep.get("vertices"):
        names = ("X_u", "Y_v", "Z_w", "Z_T", "L_p", "M_q", "N_r")
        lines.append(
            "  per vertex (estimate +- std; seed 0 Tables 1-2):\n"
            f"  {'#':>2} {'vertex [m/s]':<18} {'source':<7} " + " ".join(f"{n:>16}" for n in names)
        )
        for v in rep["vertices"]:
            q, sd = v["params"], v["params"]["std"]
            vtx = "[" + " ".join(f"{c:+.3g}" for c in v["vertex"]) + "]"
            lines.append(
                f"  {v['index']:>2} {vtx:<18} {v['source']:<7} "
                + " ".join(f"{f'{q[n]:.3g}+-{sd.get(n, 0.0):.2g}':>16}" for n in names)
                + (f"  ({v['reason']})" if v["reason"] else "")
            )
        sch = rep.get("scheduling") or {}
        diffs = [
            f"{n} {sch[n]['max_difference_sigmas']:g}"
            for n in names
            if "max_difference_sigmas" in sch.get(n, {})
        ]
        if diffs:
            lines.append(
                "  largest difference between two vertices in combined std (> 3: depends on "
                "the vertex): " + ", ".join(diffs)
            )
    return "\n".join(lines)


def write_report(out: Path, summary: dict, p2: Optional[dict], rep: dict) -> None:
    """``out/report.md`` from the chain summary, the phase-2 summary and the
    identification report."""
    from lpv_sysid.io.files import read_yaml

    L = [
        "# PX4 chain report",
        "",
        "Design (plant) of every flight: phase 1 = PX4's own velocity/attitude/rate cascade "
        "(velocity "
        "setpoints); phase 2 = **rate plant** (PX4 rate loop inside the LPV model; inputs thrust "
        "+ body-rate "
        "setpoints sent as SET_ATTITUDE_TARGET; lpv_sysid/models/rate_plant.py).",
        "",
        f"Vehicle: `{summary.get('connect')}`. Result: **{summary.get('result')}**.",
        "",
        "## Steps",
        "",
        "| step | start [s] | end [s] | outcome |",
        "|---|---|---|---|",
    ]
    for s in summary["steps"]:
        outcome = (
            s.get("reason")
            or s.get("result")
            or ("status %s" % s.get("status") if "status" in s else "")
        )
        L.append(f"| {s['step']} | {s.get('t_start_s')} | {s.get('t_end_s', '-')} | {outcome} |")
    L += [
        "",
        "## Identification (per-vertex equation error)",
        "",
        "```",
        format_identification(rep),
        "```",
    ]
    inv = summary.get("inversion_error")
    if inv:
        L += [
            "",
            f"## Why the rate plant (measured on this flight's phase-1 run `{inv.get('run')}`)",
            "",
            "Torque error of the rate-loop inversion omega_sp = omega + tau/K_p, K_p (omega(t-d) "
            "- omega(t)) rms "
            "(PX4 normalised torque), against the seed's design virtual torques "
            f"{', '.join(f'{x:.3g}' for x in inv['design_torque'])} (roll, pitch, yaw):",
            "",
            "| telemetry age d [s] | roll | pitch | yaw | ratio to design (roll, pitch, yaw) |",
            "|---|---|---|---|---|",
        ]
        for r in inv["by_delay"]:
            e, q = r["torque_error_rms"], r["ratio_to_design_torque"]
            L.append(
                f"| {r['delay_s']:.2f} | {e[0]:.3g} | {e[1]:.3g} | {e[2]:.3g} | "
                f"{q[0]:.1f}, {q[1]:.1f}, {q[2]:.1f} |"
            )
    gains = out / "gains.yaml"
    if gains.exists():
        g = read_yaml(gains)
        cert = g.get("certificate", {})
        L += [
            "",
            "## Certificate",
            "",
            f"gamma (file) {g.get('gamma'):.4g}, certified {cert.get('gamma_achieved')}, "
            f"solver {cert.get('solver')}, {cert.get('lmi')}",
        ]
    if p2:
        L += [
            "",
            "## Phase 2 (what the vehicle did)",
            "",
            f"ok: {p2.get('ok')}; {p2.get('reason')}",
        ]
        hb = p2.get("handback") or {}
        L.append(f"hand-back: {hb.get('state')} {hb.get('mode')} ({hb.get('reason')})")
        if "tracking_rms" in p2:
            tr, ref = p2["tracking_rms"], p2["reference_rms"]
            L += [
                "",
                "| axis | tracking RMS [m/s] | max [m/s] | reference RMS [m/s] |",
                "|---|---|---|---|",
            ]
            for a in "uvw":
                L.append(f"| {a} | {tr[a]:.3f} | {p2['tracking_max'][a]:.3f} | {ref[a]:.3f} |")
            gi = p2["gain_u_e_to_z"]
            L += [
                "",
                f"u_e -> z (seed 0 Eqs. 26-29; {gi.get('method')}): energy ratio "
                f"{gi.get('energy_ratio', float('nan')):.4g}, FIR peak gain "
                f"{gi.get('fir_peak_gain', float('nan')):.4g}, "
                f"fit R^2 {gi.get('fit_r2', float('nan')):.3f} vs gamma {gi['gamma']:.4g} -> "
                f"{'within' if gi['within_gamma'] else 'NOT within'} gamma. Raw ||z||/||u_e|| "
                "mixed with tracking "
                f"error (for reference only): {p2['raw_ratio_mixed_with_tracking']:.4g}.",
                f"Commands clipped by the transport: {p2['commands_clipped']} of "
                f"{p2['commands']}; control rate "
                f"{p2['control_rate_hz']:.1f} Hz; signal flown {p2['flown_signal_s']:.1f} s.",
            ]
        mc = p2.get("model_check_r2")
        if mc:
            L += [
                "",
                "Identified rate plant (phase-1 data) against the phase-2 flight (rate setpoints "
                "from the "
                "law), R^2 of x' per row: " + ", ".join(f"{k} {v}" for k, v in mc.items()),
            ]
        for key, what in (
            ("model_check_output_error", "first-order rate plant"),
            ("model_check_lag_output_error", "with motor lag + delay"),
        ):
            oe = p2.get(key)
            if oe and "error" not in oe:
                L += [
                    "",
                    f"Output error on the phase-2 flight ({what}; rows simulated from the "
                    f"recorded setpoints, restarted every {oe.get('window_s')} s), R^2 per row: "
                    + ", ".join(
                        f"{k} {v}" for k, v in oe.items() if k not in ("window_s", "samples")
                    ),
                ]
    full = _full_report(out)
    if full is not None:
        L += [
            "",
            f"The run report of this directory (go/no-go first, data source of every figure, "
            f"phase-1 time histories, poles and time to double, margins): `{full}`.",
        ]
    (out / "report.md").write_text("\n".join(L) + "\n")


def _full_report(out: Path) -> Optional[Path]:
    """``out/report/report.md`` (:func:`lpv_sysid.report.write_report`, the report every run
    kind gets) next to the chain's own summary; None (logged) when it cannot be written."""
    import logging

    from lpv_sysid.errors import LpvSysidError
    from lpv_sysid.report import write_report as run_report

    try:
        return run_report(out).relative_to(out)
    except (LpvSysidError, OSError, ValueError) as exc:
        logging.getLogger(__name__).warning("run report of %s not written: %s", out, exc)
        return None
