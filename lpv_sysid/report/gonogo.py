"""The go/no-go summary that opens the report: certificate, verification, margins, provenance.

Pure functions of the loaded :class:`~lpv_sysid.report.data.RunData` and the recomputed
:class:`~lpv_sysid.report.margins.RunMargins` (no plotting, no Markdown). Each row has a verdict:

- ``GO`` / ``NO-GO``: a condition for flying the gains (the overall verdict is GO only when no
  row is NO-GO);
- ``WATCH``: inside the limit that stops the run but a margin a reviewer should see (the body
  velocity left the certified scheduling box, but not by the supervisor's margin);
- ``INFO``: provenance (what was SIMULATED, what was FLOWN) and items that do not apply.

Rules: no ``verification.yaml`` = "not verified" (NO-GO; the report never re-runs the verifier),
as is one that records a failed check or whose ``gains.sha256`` / ``models.sha256`` is not the
SHA-256 of the run's ``gains.yaml`` / ``vertex_models.yaml`` (it verified other bytes).
Provenance: a phase-1 directory with the flight recorder's ``experiment.yaml`` or the campaign's
``campaign_summary.yaml`` (``lpv-sysid fly phase1``) was FLOWN on a PX4 over MAVLink; one without
them was written by ``lpv-sysid simulate phase1`` (SIMULATED); ``phase2/summary.yaml``
(:mod:`lpv_sysid.sim.phase2`) holds SIMULATED runs only, ``phase2/phase2_summary.yaml``
(``lpv-sysid fly phase2``) a flown one, labelled by its recorder's ``experiment.yaml``
(``vehicle.kind``: SIMULATED -- the package's own PX4 stand-in --, SITL, HITL, SIH or FLOWN;
FLOWN when a recording does not say).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from lpv_sysid.report.data import RunData
from lpv_sysid.report.margins import RunMargins

GO, NO_GO, WATCH, INFO = "GO", "NO-GO", "WATCH", "INFO"
SIMULATED, FLOWN = "SIMULATED", "FLOWN"
#: labels of a recording's vehicle (``experiment.yaml``: ``vehicle.kind`` of ``fly``,
#: ``provenance.vehicle_kind`` of ``import``): PX4 SITL, PX4 hardware-in-the-loop, PX4's
#: simulation in hardware, the package's own simulated PX4 (SIMULATED), a vehicle (FLOWN)
SITL, HITL, SIH = "SITL", "HITL", "SIH"
DATA_LABELS = (SIMULATED, SITL, HITL, SIH, FLOWN)
#: simulated in some way: a go/no-go on these alone is not one for a vehicle
SIMULATED_LABELS = (SIMULATED, SITL, HITL, SIH)


@dataclass(frozen=True)
class Row:
    item: str
    value: str
    limit: str
    verdict: str
    note: str = ""


@dataclass(frozen=True)
class DataSource:
    dataset: str
    label: str  # SIMULATED | FLOWN | "not in the run directory"
    evidence: str


def _g(x: Any, fmt: str = "{:.4g}") -> str:
    if x is None:
        return "-"
    try:
        v = float(x)
    except (TypeError, ValueError):
        return str(x)
    return "nan" if not math.isfinite(v) else fmt.format(v)


def vehicle_label(experiment: Any) -> tuple[str, str]:
    """(label, how it was told) of a flight recorder's ``experiment.yaml``: the vehicle kind
    ``fly`` (``vehicle.kind``) or ``import`` (``provenance.vehicle_kind``) recorded; FLOWN
    for a recording that does not say (older ``fly`` runs: a PX4 SITL and a vehicle were not
    told apart then)."""
    e = experiment if isinstance(experiment, dict) else {}
    veh = e.get("vehicle")
    veh = veh if isinstance(veh, dict) else {}
    imp = e.get("provenance")
    imp = imp if isinstance(imp, dict) else {}
    kind = veh.get("kind") or imp.get("vehicle_kind")
    site = veh.get("site") or imp.get("site")
    where = ""
    if isinstance(site, dict) and isinstance(site.get("latitude_deg"), (int, float)):
        alt = site.get("altitude_amsl_m")
        where = (
            f", site {site['latitude_deg']:.6f} deg N {site.get('longitude_deg', 0.0):.6f} deg E"
            + (f" {alt:.1f} m AMSL" if isinstance(alt, (int, float)) else "")
        )
    if kind in DATA_LABELS:
        src = "imported " + str((imp.get("source") or {}).get("kind", "log")) if imp else "PX4"
        return str(kind), f"{src}, vehicle kind {kind} from its records{where}"
    return FLOWN, "PX4 over MAVLink, vehicle kind not recorded"


def phase2_experiment(d: RunData) -> Optional[dict]:
    """The ``experiment.yaml`` of the flown phase 2: ``phase2/experiment.yaml``, or the run
    directory's own when it is a ``fly phase2`` directory (``phase2_summary.yaml`` next to it)."""
    if isinstance(d.flight_phase2_experiment, dict):
        return d.flight_phase2_experiment
    f, e = d.found.get("flight_phase2"), d.found.get("experiment")
    if f is not None and e is not None and f.parent == e.parent and d.campaign is None:
        return d.experiment if isinstance(d.experiment, dict) else None
    return None


def provenance(d: RunData) -> list[DataSource]:
    """Where each data set came from (module docstring)."""
    out = []
    rel = lambda key: f"`{d.found[key].relative_to(d.run_dir)}`"  # noqa: E731
    exp2 = phase2_experiment(d)
    if exp2 is not None and exp2 is d.experiment:
        p1 = DataSource("phase-1 flights", "not in the run directory", "-")
    elif d.experiment is not None or d.campaign is not None:
        url = (d.campaign or {}).get("connect") or "URL not recorded"
        files = ", ".join(rel(k) for k in ("experiment", "campaign") if k in d.found)
        label, how = vehicle_label(d.experiment)
        p1 = DataSource("phase-1 flights", label, f"{how} ({url}); {files}")
    elif (d.run_dir / "phase1").is_dir() or d.trims is not None:
        p1 = DataSource(
            "phase-1 flights",
            SIMULATED,
            "`lpv-sysid simulate phase1` (the package's quadrotor model): no flight recorder "
            "metadata (`phase1/experiment.yaml`)",
        )
    else:
        p1 = DataSource("phase-1 flights", "not in the run directory", "-")
    out.append(p1)
    bl = d.broken_loop
    if isinstance(bl, dict):
        out.append(
            DataSource(
                "broken-loop run",
                p1.label,
                "the same vehicle after phase 1: multisine on thrust + body-rate setpoints, "
                f"stabilised ({bl.get('reason') or 'no result recorded'}); {rel('broken_loop')}",
            )
        )
    if d.models is not None:
        what = "the phase-1 runs above"
        if isinstance(bl, dict):
            what += (
                " (design model); with the broken-loop run, the prediction model (lag "
                "dynamics, output error)"
            )
        out.append(DataSource("identification data", p1.label, what))
    if d.flight_phase2 is not None:
        label2, how2 = vehicle_label(exp2)
        out.append(
            DataSource(
                "phase-2 flight",
                label2,
                f"{how2}; {rel('flight_phase2')} (`lpv-sysid fly phase2`)",
            )
        )
    s = d.phase2_summary
    if isinstance(s, dict):
        where = rel("phase2_summary")
        for name, what in (
            ("eq33", "LPV closed loop of Eq. (33) (identified model)"),
            ("linear_ff", "LPV model with the feedforward law"),
            ("nonlinear", "nonlinear quadrotor model, noisy sensors"),
        ):
            e = s.get(name)
            if isinstance(e, dict) and not e.get("skipped"):
                out.append(
                    DataSource(f"phase-2 {name}", SIMULATED, f"{what}; {where} (sim.phase2)")
                )
    return out


def _certificate_row(d: RunData) -> Row:
    g = d.gains or {}
    cert = g.get("certificate")
    if not isinstance(cert, dict):
        why = d.problems.get(
            "gains", "gains.yaml missing" if d.gains is None else "no certificate"
        )
        return Row("certificate", "none", "-", NO_GO, why)
    gamma, ga, mm = g.get("gamma"), cert.get("gamma_achieved"), cert.get("min_margin")
    kind = (cert.get("certified_set") or {}).get("kind", "not stated")
    var = ((cert.get("certified_set") or {}).get("scheduling") or {}).get("variation", "?")
    nums = [x for x in (ga, gamma, mm) if isinstance(x, (int, float)) and math.isfinite(x)]
    ok = len(nums) == 3 and nums[0] <= nums[1] and nums[2] > 0
    return Row(
        "certificate (gains.yaml)",
        f"gamma_achieved {_g(ga)}, min margin {_g(mm)}",
        f"gamma {_g(gamma)}, margin > 0",
        GO if ok else NO_GO,
        f"{kind}, {var} v_d",
    )


def _delay_row(d: RunData) -> Row:
    """certificate.loop_delay (issue 20 item 7): the constant loop delay the proof covers and
    the proven margins; NO-GO when the certificate states none (no delay is covered)."""
    cert = (d.gains or {}).get("certificate")
    ld = cert.get("loop_delay") if isinstance(cert, dict) else None
    if not isinstance(ld, dict) or not isinstance(ld.get("bound_s"), (int, float)):
        return Row(
            "loop delay (certificate)",
            "not stated",
            "certificate.loop_delay.bound_s",
            NO_GO,
            "the proof covers no loop delay: synthesize again",
        )

    def ms(x) -> str:
        return f"{1e3 * x:.2f} ms" if isinstance(x, (int, float)) else "?"

    value = (
        f"bound {ms(ld['bound_s'])}; margins: gamma kept up to "
        f"{ms(ld.get('performance_margin_s'))}, stable up to {ms(ld.get('stability_margin_s'))}"
    )
    # the configured loop, when verify checked one (``verify --loop-delay``; the chain passes
    # the phase-2 controller's): above the bound the controller refuses to start -> NO-GO
    configured = [
        c for c in (d.verification.checks if d.verification else ()) if c["check"] == "loop config"
    ]
    if configured:
        c = configured[0]
        return Row(
            "loop delay (certificate)",
            f"configured loop {ms(c['value'])}; {value}",
            "configured loop delay <= bound",
            GO if c["ok"] else NO_GO,
            str(ld.get("source", ""))
            if c["ok"]
            else "the configured loop is slower than the proof covers: the controller refuses "
            "these gains at start-up (raise the loop rates, lower the latency, or synthesize "
            "for the delay)",
        )
    return Row(
        "loop delay (certificate)",
        value,
        "controller loop delay <= bound (refused at start-up otherwise)",
        GO,
        f"{ld.get('source', '')}; no configured loop checked (verify --loop-delay)",
    )


def _sha(path: Optional[Path]) -> Optional[str]:
    from lpv_sysid.errors import ConfigError
    from lpv_sysid.io.files import sha256_file

    if path is None:
        return None
    try:
        return sha256_file(path)
    except ConfigError:
        return None


def verification_rows(d: RunData) -> list[Row]:
    """``verify`` result and whether it checked this run's gains and models (module docstring)."""
    v = d.verification
    if v is None:
        why = d.problems.get("verification")
        return [
            Row(
                "independent verification",
                "unreadable" if why else "not verified",
                "verification.yaml, passed",
                NO_GO,
                why or "no verification.yaml: run `lpv-sysid verify --gains ... --models ...`",
            )
        ]
    n = v.numbers
    rows = [
        Row(
            "independent verification",
            f"{'passed' if v.passed and not v.failed else 'FAILED'}: {len(v.checks)} checks, "
            f"{len(v.failed)} failed, {len(v.warnings)} warnings",
            "0 failed",
            GO if v.passed and not v.failed else NO_GO,
            "; ".join(f"{c['check']} {c['where']}" for c in v.failed[:3]) or v.tool_version,
        ),
        Row(
            "verified H-inf / LMI",
            f"worst frozen H-inf {_g(n.get('worst_hinf'))}, LMI gamma {_g(n.get('lmi_gamma'))}, "
            f"LMI margin {_g(n.get('lmi_margin'))}, max Re(eig) {_g(n.get('max_real_eig'))}",
            f"gamma {_g(n.get('gamma'))}",
            INFO,
            "from verification.yaml numbers",
        ),
    ]
    for key, label in (("gains", "gains.yaml"), ("models", "vertex_models.yaml")):
        rec = v.gains_sha256 if key == "gains" else v.models_sha256
        have = _sha(d.found.get(key))
        same = have is not None and have == rec
        rows.append(
            Row(
                f"verified {label} = this run's",
                f"sha256 {rec[:12]}..." if same else f"recorded {rec[:12]}...",
                f"sha256 of {label}" + ("" if have is None else f" {have[:12]}..."),
                GO if same else NO_GO,
                "" if same else f"verification.yaml checked other bytes than {label}",
            )
        )
    return rows


def margin_rows(m: Optional[RunMargins]) -> list[Row]:
    """Tilt, ESC headroom, box distance and bound-monitor ratio extremes of one run."""
    if m is None:
        return [Row("safety margins", "no phase-2 time histories", "-", INFO)]
    L, ex = m.limits, m.extremes()
    tilt, t_tilt = ex["tilt_deg"]
    esc, t_esc = ex["esc_headroom"]
    box, t_box = ex["box_distance"]
    mon, t_mon = ex["monitor_ratio"]
    lim = L.monitor_limit
    rows = [
        Row(
            f"max tilt ({m.run})",
            f"{tilt:.1f} deg at t = {t_tilt:.1f} s",
            f"{L.max_tilt_deg:g} deg",
            GO if tilt < L.max_tilt_deg else NO_GO,
        ),
        Row(
            f"min ESC headroom ({m.run})",
            f"{100 * esc:.1f} % at t = {t_esc:.1f} s",
            "> 0 % (0 = saturated)",
            GO if esc > 0 else NO_GO,
        ),
    ]
    verdict = GO if box >= 0 else (WATCH if box > -L.box_margin else NO_GO)
    rows.append(
        Row(
            f"min distance to box edge ({m.run})",
            f"{box:+.2f} m/s at t = {t_box:.1f} s",
            f">= 0 m/s (supervisor stops at -{L.box_margin:g})",
            verdict,
            "" if box >= 0 else "the body velocity left the certified scheduling box",
        )
    )
    rows.append(
        Row(
            f"max bound-monitor ratio ({m.run})",
            "not judged" if math.isnan(mon) else f"{mon:.3f} at t = {t_mon:.1f} s",
            "-" if lim is None else f"gamma x margin = {lim:.3g}",
            INFO if lim is None or math.isnan(mon) else (GO if mon <= lim else NO_GO),
            "running ||z||/||u_e|| (contains the tracking part)",
        )
    )
    return rows


def events_rows(d: RunData) -> list[Row]:
    """Number of safety aborts and whether the hand-back to the autopilot was confirmed."""
    aborts: list[str] = []
    s = d.phase2_summary
    if isinstance(s, dict):
        aborts += [str(e) for e in s.get("safety_events") or []]
    f = d.flight_phase2
    if isinstance(f, dict) and f.get("ok") is False:
        aborts.append(f"flown phase 2: {f.get('reason')}")
    rows = [
        Row(
            "safety aborts",
            str(len(aborts)),
            "0",
            GO if not aborts else NO_GO,
            "; ".join(aborts[:3]),
        )
    ]
    hb = []
    if isinstance(f, dict):
        st = (f.get("handback") or {}).get("state")
        hb.append(("phase 2", st == "DONE", f"state {st}"))
    c = d.campaign
    if isinstance(c, dict):
        conf = (c.get("handback") or {}).get("confirmed")
        hb.append(("phase 1", conf is not None, f"confirmed at {conf}"))
    bl = d.broken_loop
    if isinstance(bl, dict):
        st = (bl.get("handback") or {}).get("state")
        hb.append(("broken-loop run", st == "DONE", f"state {st}"))
    if not hb:
        rows.append(Row("hand-back confirmed", "n/a", "-", INFO, "simulated: no autopilot"))
    for phase, ok, what in hb:
        rows.append(Row(f"hand-back confirmed ({phase})", what, "confirmed", GO if ok else NO_GO))
    return rows


def go_no_go(d: RunData, margins: Optional[RunMargins]) -> tuple[list[Row], str]:
    """All rows and the overall verdict (NO-GO when any row is)."""
    rows = (
        [_certificate_row(d), _delay_row(d)]
        + verification_rows(d)
        + margin_rows(margins)
        + events_rows(d)
    )
    overall = NO_GO if any(r.verdict == NO_GO for r in rows) else GO
    return rows, overall
