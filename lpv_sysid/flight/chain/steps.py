"""The whole two-phase job on a connected PX4 vehicle, end to end (`lpv-sysid chain`).

    lpv-sysid chain --connect udpin:127.0.0.1:14540 --out DIR [--set-param COM_OBL_RC_ACT=5]

The design is the **rate plant** (lpv_sysid/models/rate_plant.py): PX4 >= 1.14 accepts over
MAVLink only thrust + body-rate setpoints (SET_ATTITUDE_TARGET), so the plant that is
identified, certified and flown has PX4's rate loop inside, with inputs
(thrust, p_sp, q_sp, r_sp) exactly as sent (docs/px4_chain.md). Steps, each leaving its
artefacts in ``DIR``:

1. ``DIR/phase1``: the phase-1 campaign (``lpv-sysid fly phase1`` core, config
   ``config/campaign_chain.yaml``: box +-1.5/+-1.5/+-0.5 m/s, vertices 1 and 8 + hover, 17 s
   excitation, finish HOLD) with PX4's ATTITUDE_TARGET recorded on ``rate_setpoint``;
2. ``DIR/vertex_models.yaml``: pooled equation-error identification of the rate plant
   (lpv_sysid/ident/rate_plant.py) and its vertex models over the box;
3. ``DIR/signals``: phase-2 reference + excitation (config/signals_chain_phase2.yaml);
4. ``DIR/gains.yaml``: seed 0 Lemma 1 synthesis + independent verification
   (config/synthesis_chain.yaml: feasibility at gamma = 1 with a pole region that bounds the
   gains); the file's first line names the design (``# design: rate_plant ...``), as do
   ``DIR/chain_summary.yaml``, ``phase2_summary.yaml`` and the report. When phase 1 did not
   complete, models and gains are still written but phase 2 is not flown;
5. ``DIR/phase2``: the phase-2 flight under the LPV law
   (:func:`lpv_sysid.flight.phase2.sequence.fly_phase2`): the vehicle, still in the air in HOLD
   after phase 1, is taken into OFFBOARD with the law's rate setpoints (RateSetpointTransport on
   BridgeCore's ``attitude_rate`` command, envelope enforced by the bridge), the signal is flown
   with raised-cosine fades, then LAND;
6. ``DIR/report.md``: measured u_e -> z gain against gamma (seed 0 Eqs. 26-29, by regression
   on the excitation, :func:`lpv_sysid.flight.phase2.analysis.excitation_gain`), tracking RMS per
   axis, the design, what the vehicle did.

``lpv-sysid fly phase2 --connect URL --gains G --models M --signals S --out DIR`` flies step 5
alone (vehicle in the air, armed); ``lpv-sysid chain ... --phase1 OLD/phase1`` reruns steps 2-6
on the bags of an earlier phase-1 flight (the vehicle still in HOLD). The simulated ``lpv-sysid
demo`` / ``make demo`` is unchanged.

This module runs the steps (:func:`chain`); phase 1 is :mod:`lpv_sysid.flight.campaign`, the
flight of step 5 :mod:`lpv_sysid.flight.phase2`, the report :mod:`lpv_sysid.flight.chain.report`.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from lpv_sysid.configuration.defaults import config_file
from lpv_sysid.errors import LpvSysidError
from lpv_sysid.flight.chain.report import format_identification, write_report
from lpv_sysid.flight.phase2 import (
    Phase2Options,
    controller_loop_delay_s,
    fly_phase2,
    inversion_error,
    save_summary,
)
from lpv_sysid.synthesis.verify import verify_and_record

log = logging.getLogger(__name__)
EXIT_FAILED = 1


def chain(
    url: str,
    out_dir: str | Path,
    params: Mapping[str, float] | None = None,
    campaign_config: str | Path | None = None,
    kappa: float = 1.0,
    k_sigma: float = 2.0,
    echo: Callable[[str], None] = log.info,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    link_factory: Callable[[], Any] | None = None,
    phase2: Phase2Options | None = None,
    preflight: bool = True,
    phase1_dir: str | Path | None = None,
) -> int:
    """The six steps of the module docstring; returns the exit status. ``phase1_dir``: use the
    bags of an earlier phase-1 flight (``--phase1``, e.g. after a chain stopped at a later
    step with the vehicle still in HOLD) instead of flying phase 1.

    ``params`` (``--set-param``) hold for the whole job: set before phase 1 (or, with
    ``phase1_dir``, before anything else flies), kept through the broken-loop run and phase 2,
    and set back to their old values when the chain ends, whatever the reason, each
    confirmed by PARAM_VALUE (``chain_summary.yaml``: ``params_set``, ``params_restored``).
    A vehicle whose parameters changed between the phases would fly phase 2 as another
    airframe than the one identified (PX4 SIH: ``SIH_*``), or with another failsafe."""
    from lpv_sysid.control.law import check_kappa
    from lpv_sysid.flight.campaign import FlyConfig
    from lpv_sysid.flight.campaign.sequence import restore_params, vehicle_link

    kappa = check_kappa(kappa)  # before waiting for a vehicle (nan used to wait first)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summary: dict = {"design": "rate_plant", "connect": url, "steps": []}
    cfg = FlyConfig.load(campaign_config or config_file("campaign_chain.yaml"))
    changed: list[dict] = []
    try:
        return _steps(
            url,
            out,
            summary,
            cfg,
            dict(params or {}),
            changed,
            kappa,
            k_sigma,
            echo,
            clock,
            sleep,
            link_factory,
            phase2,
            preflight,
            phase1_dir,
        )
    finally:
        if changed:
            try:
                with vehicle_link(
                    cfg, url, clock, sleep, link_factory() if link_factory else None
                ) as link:
                    summary["params_restored"] = restore_params(link, changed, clock, sleep, echo)
            except LpvSysidError as exc:
                summary["params_restored"] = [
                    {"name": d["name"], "value": d["old"], "restored": False} for d in changed
                ]
                echo(
                    f"PARAMETERS NOT restored ({exc}): set back by hand "
                    + ", ".join(f"{d['name']}={d['old']}" for d in changed)
                )
            save_summary(out / "chain_summary.yaml", summary)


def _steps(
    url: str,
    out: Path,
    summary: dict,
    cfg,
    params: dict,
    changed: list,
    kappa: float,
    k_sigma: float,
    echo: Callable[[str], None],
    clock: Callable[[], float],
    sleep: Callable[[float], None],
    link_factory: Callable[[], Any] | None,
    phase2: Phase2Options | None,
    preflight: bool,
    phase1_dir: str | Path | None,
) -> int:
    """:func:`chain`'s steps; parameter changes confirmed on the vehicle go into ``changed``
    (restored by :func:`chain`)."""
    from lpv_sysid.flight.campaign import fly
    from lpv_sysid.flight.campaign.sequence import apply_params, vehicle_link
    from lpv_sysid.ident import rate_plant as rid
    from lpv_sysid.ident import rate_plant_dynamics as lag

    summary["params_set"] = changed
    t_all = clock()

    def step(title):
        echo(f"\n=== {title}")
        summary["steps"].append({"step": title, "t_start_s": round(clock() - t_all, 1)})

    def done(**kw):
        summary["steps"][-1].update({"t_end_s": round(clock() - t_all, 1), **kw})
        save_summary(out / "chain_summary.yaml", summary)

    if phase1_dir is not None:
        step(f"phase-1 bags of an earlier flight ({phase1_dir})")
        if params:  # phase 2 flies with them, as after a phase 1 of this chain
            with vehicle_link(
                cfg, url, clock, sleep, link_factory() if link_factory else None
            ) as lk:
                apply_params(lk, params, clock, sleep, echo, changed)
        p1 = Path(phase1_dir)
        from lpv_sysid.io.files import read_yaml_mapping

        cs = (
            read_yaml_mapping(p1 / "campaign_summary.yaml", finite=False)
            if (p1 / "campaign_summary.yaml").exists()
            else {}
        )
        ok1 = bool(cs.get("ok"))
        res = type(
            "Phase1",
            (),
            {
                "status": 0 if ok1 else EXIT_FAILED,
                "phase": cs.get("result", "unknown"),
                "reason": cs.get("reason") or "",
                "summary": cs,
            },
        )()
        bags = [p1 / b for b in (cs.get("bags") or {}).values()]
    else:
        step("phase-1 campaign on the vehicle (PX4 cascade, ATTITUDE_TARGET recorded)")
        res = fly(
            cfg,
            url,
            out / "phase1",
            params=params,
            keep_params=changed,  # held through phase 2, restored by chain()
            clock=clock,
            sleep=sleep,
            echo=echo,
            record_rate_setpoints=True,
            preflight=preflight,
            link=link_factory() if link_factory else None,
        )
        bags = [out / "phase1" / b for b in (res.summary.get("bags") or {}).values()]
    done(status=res.status, result=res.phase, reason=res.reason, bags=[str(b) for b in bags])
    bl_run = None
    if cfg.broken_loop is not None and phase1_dir is None and not res.status:
        from lpv_sysid.flight.campaign.broken_loop import fly_broken_loop

        step("broken-loop run (multisine on PX4's thrust + body-rate setpoints, stabilised)")
        try:
            bl = fly_broken_loop(
                out / "broken_loop",
                cfg.bridge_config,
                url,
                cfg.broken_loop,
                clock=clock,
                sleep=sleep,
                echo=echo,
                link=link_factory() if link_factory else None,
            )
        except LpvSysidError as exc:
            bl = {"ok": False, "reason": str(exc)}
        done(ok=bl.get("ok"), reason=bl.get("reason"), handback=bl.get("handback"))
        summary["broken_loop"] = {
            k: bl.get(k) for k in ("ok", "reason", "hover_thrust", "commands", "handback")
        }
        bag_bl = out / "broken_loop" / str(bl.get("bag") or "bag_0000")
        if bag_bl.exists():
            try:
                bl_run = rid.read_run(bag_bl)
            except LpvSysidError as exc:
                echo(f"  broken-loop bag unusable: {exc}")
        if not (bl.get("handback") or {}).get("state") == "DONE":
            res.status = EXIT_FAILED  # control not confirmed back with PX4: no phase 2
            res.reason = f"broken-loop run: {bl.get('reason')}"
    usable, rep, params_rp = [], None, None
    for b in bags:
        try:
            usable.append(rid.read_run(b))
        except LpvSysidError as exc:
            echo(f"  skipped {b.name}: {exc}")
    if not usable:
        summary["result"] = f"stopped: no usable phase-1 bag ({res.reason})"
        save_summary(out / "chain_summary.yaml", summary)
        echo(summary["result"])
        return EXIT_FAILED
    if res.status:
        echo(
            f"  phase 1 ended early ({res.reason}); identifying from the {len(usable)} usable "
            "run(s), "
            "phase 2 will not be flown"
        )
    step("rate-plant identification (per-vertex equation error)")
    c = cfg.campaign
    params_rp, rep = identify_rate_runs(
        usable, c.box_min, c.box_max, k_sigma, out / "vertex_models.yaml", echo
    )
    done(
        result=f"{len(usable)} run(s), {rep['samples']} samples",
        rows=rep["rows"],
        runs=rep["runs"],
        k_sigma=k_sigma,
    )
    # the measurement behind the choice of plant: the inversion's torque error on these flights
    last = usable[-1]
    t_raw, om_raw = _raw_rates(next(b for b in bags if b.name == last.name))
    inv = inversion_error(t_raw, om_raw)  # unfiltered telemetry rates (noise included)
    inv["run"] = last.name
    summary["inversion_error"] = inv
    r20 = [r for r in inv["by_delay"] if abs(r["delay_s"] - 0.02) < 1e-9]
    if r20:
        echo(
            "  rate-loop inversion (AttitudeRateTransport) on this flight: torque error at 20 ms "
            "telemetry age "
            + ", ".join(
                f"{a} {e:.3g} ({q:.1f} x design)"
                for a, e, q in zip(
                    "pqr", r20[0]["torque_error_rms"], r20[0]["ratio_to_design_torque"]
                )
            )
        )
    step("phase-2 signals")
    signals_dir = design_signals(config_file("signals_chain_phase2.yaml"), out / "signals", echo)
    done(status=0)
    step("Lemma 1 synthesis + independent verification (rate plant)")
    loop_s = controller_loop_delay_s(out / "gains.yaml")
    ok, attempts = synthesize_for_loop(
        out / "vertex_models.yaml",
        config_file("synthesis_chain.yaml"),
        signals_dir / "summary.yaml",
        out,
        loop_s,
        echo,
    )
    done(status=0 if ok else EXIT_FAILED, loop_delay_s=loop_s, attempts=attempts)
    if not ok:
        summary["result"] = "stopped: the synthesis did not pass its independent verification"
        save_summary(out / "chain_summary.yaml", summary)
        write_report(out, summary, None, rep)
        return EXIT_FAILED
    _mark_design(out / "gains.yaml")
    # with the loop phase 2 will fly: verification.yaml (and the report's go/no-go) show
    # whether the certificate's delay bound covers it, as the controller checks at start
    verify_and_record(out / "gains.yaml", out / "vertex_models.yaml", loop_delay_s=loop_s)
    if res.status:
        # models and gains from the usable runs are written; flying phase 2 after a phase-1 fault
        # (stall, envelope, failsafe) would start from a state nobody checked
        summary["result"] = f"stopped before phase 2: phase 1 did not complete ({res.reason})"
        save_summary(out / "chain_summary.yaml", summary)
        write_report(out, summary, None, rep)
        echo(summary["result"])
        return EXIT_FAILED
    step("phase-2 flight under the LPV law (rate plant)")
    opts = phase2 or Phase2Options(kappa=kappa)
    try:
        p2 = fly_phase2(
            out / "gains.yaml",
            out / "signals",
            out / "phase2",
            url=url,
            models=out / "vertex_models.yaml",
            opts=opts,
            clock=clock,
            sleep=sleep,
            echo=echo,
            link=link_factory() if link_factory else None,
        )
    except LpvSysidError as exc:
        p2 = {"ok": False, "reason": str(exc)}
    done(ok=p2.get("ok"), reason=p2.get("reason"))
    # the identified rate plant against the phase-2 flight (rate setpoints from the law, not PX4)
    # state at the telemetry rate + PX4's echo of the commands (rate_setpoint)
    bag2 = out / "phase2" / str(p2.get("bag") or "bag_0000")
    if bag2.exists():
        try:
            run2 = rid.read_run(bag2)
            p2["model_check_r2"] = rid.validate(params_rp, run2)
            echo(
                "  identified rate plant vs the phase-2 flight, R^2 per row: "
                + ", ".join(f"{k} {v}" for k, v in p2["model_check_r2"].items())
            )
            p2["model_check_output_error"] = rid.output_error(params_rp, run2)
            oe = p2["model_check_output_error"]
            echo(
                f"  output error (rows simulated from the recorded setpoints, restarted every "
                f"{oe['window_s']:g} s), R^2 per row: "
                + ", ".join(f"{k} {oe[k]}" for k in ("u", "v", "w", "p", "q", "r"))
            )
        except LpvSysidError as exc:
            p2["model_check_r2"] = {"error": str(exc)}
        else:
            # lag dynamics (motor lag + delay, surge/sway drag and offsets:
            # ident/rate_plant_dynamics.py) by output error, scored on the same flight and
            # windows. From the phase-1 runs pooled with the broken-loop run when flown: the
            # broken-loop run excites the rate and thrust setpoints independently of the state
            # (heave thrust and drag separable), the vertex runs give the speeds that show the
            # drag; the broken-loop run alone left drag unidentified (PX4 SIH, 2026-12-03:
            # X_u -0.06 against SIH's -0.46, surge output error -1.06 on phase 2; pooled 0.98)
            try:
                lag_runs = [*usable, bl_run] if bl_run is not None else usable
                lagp = lag.identify(lag_runs, start=params_rp)
                p2["lag_identified_from"] = (
                    "phase1+broken_loop" if bl_run is not None else "phase1"
                )
                loe = lag.output_error(lagp, run2, window_s=oe["window_s"])
            except (LpvSysidError, ValueError, np.linalg.LinAlgError) as exc:
                p2["model_check_lag_output_error"] = {"error": str(exc)}
            else:
                p2["lag_dynamics"] = lagp.as_dict()
                p2["model_check_lag_output_error"] = loe
                echo(
                    "  with motor lag + delay (output error, same windows), R^2 per row: "
                    + ", ".join(f"{k} {loe[k]}" for k in ("u", "v", "w", "p", "q", "r"))
                )
    summary["phase2"] = {
        k: v
        for k, v in p2.items()
        if k
        in (
            "ok",
            "reason",
            "tracking_rms",
            "gain_u_e_to_z",
            "handback",
            "model_check_r2",
            "model_check_output_error",
            "model_check_lag_output_error",
            "lag_dynamics",
            "lag_identified_from",
            "latency_state_to_setpoint_ms",
        )
    }
    summary["result"] = "complete" if p2.get("ok") else f"phase 2: {p2.get('reason')}"
    summary["wall_s"] = round(clock() - t_all, 1)
    save_summary(out / "chain_summary.yaml", summary)
    write_report(out, summary, p2, rep)
    echo(f"\nchain {summary['result']} in {summary['wall_s']:.0f} s; report: {out / 'report.md'}")
    return 0 if p2.get("ok") else EXIT_FAILED


def campaign_bags(bags_dir: str | Path) -> list[Path]:
    """The run bags of a phase-1 campaign directory: those its ``campaign_summary.yaml`` lists
    (``lpv-sysid fly phase1``), else every ``bag_*`` rosbag2 directory in it (a data logger's
    experiment directory under ``ros2 launch``), else ``bags_dir`` itself when it is one bag.
    The whole-flight log (``flight/``) is not a run."""
    from lpv_sysid.errors import BagError
    from lpv_sysid.io.files import read_yaml_mapping

    d = Path(bags_dir)
    if (d / "campaign_summary.yaml").is_file():
        listed = read_yaml_mapping(d / "campaign_summary.yaml", finite=False).get("bags") or {}
        return [d / str(b) for b in listed.values()]
    if (d / "metadata.yaml").is_file():
        return [d]
    found = sorted(p for p in d.glob("bag_*") if (p / "metadata.yaml").is_file())
    if not found:
        raise BagError(f"{d}: no campaign_summary.yaml, no bag_* rosbag2 directories")
    return found


def identify_rate_runs(
    runs: list,
    box_min,
    box_max,
    k_sigma: float,
    out: Path,
    echo: Callable[[str], None],
) -> tuple[Any, dict]:
    """Step 2 of the chain, also ``lpv-sysid identify --plant px4-rate``: per-vertex
    equation-error identification of the rate plant (:func:`lpv_sysid.ident.rate_plant.
    identify_vertices`: each corner its own fit from the runs flown there, the pooled fit of
    all runs where a corner lacks data, said in the output) from ``runs`` (``read_run`` of
    each bag), its vertex models over the box ``box_min``..``box_max`` with intervals of
    ``k_sigma`` standard deviations written to ``out``; returns (pooled params, report)."""
    from lpv_sysid.ident import rate_plant as rid
    from lpv_sysid.io.files import save_yaml

    fits, params, rep = rid.identify_vertices(runs, box_min, box_max)
    save_yaml(rid.models_document([f.params for f in fits], box_min, box_max, k_sigma, rep), out)
    echo(format_identification(rep))
    echo(f"wrote {out}")
    return params, rep


def _raw_rates(bag: Path) -> tuple[np.ndarray, np.ndarray]:
    """(t, omega (N, 3)) of a bag's ``state`` topic as recorded (no filtering)."""
    from lpv_sysid.io import bag as iobag
    from lpv_sysid.io import messages as ros_messages

    topic = [t for t in iobag.topic_info(str(bag)) if t.endswith("/state")][0]
    st = [
        ros_messages.state_from_odometry(m)
        for _, m in iobag.read_bag(str(bag), topics=[topic])[topic]
    ]
    return np.array([x.t for x in st]), np.array([x.omega for x in st])


def _mark_design(gains: Path) -> None:
    """Name the plant in gains.yaml itself: a leading comment (the gains format has no free
    metadata key and the certified law hash covers only the law; the input names thrust,
    p_sp, q_sp, r_sp say the same to a program)."""
    from lpv_sysid.models import rate_plant as rp

    text = gains.read_text()
    if not text.startswith("# design: "):
        gains.write_text(
            f"# design: {rp.DESIGN} -- {rp.DESIGN_TEXT}; flown by `lpv-sysid chain` / "
            "`lpv-sysid fly phase2` (docs/px4_chain.md)\n" + text
        )


def design_signals(config: Path, out_dir: Path, echo: Callable[[str], None]) -> Path:
    """The phase-2 reference and excitation of ``config`` (``lpv-sysid signals``) written to
    ``out_dir`` (signals.npz, summary.yaml); returns ``out_dir``."""
    from lpv_sysid.signals.multisine import design, load_config
    from lpv_sysid.signals.store import write_signal_set

    sig = design(load_config(str(config)))
    # force: the chain synthesises the gains that refer to this set right after, in this run
    for path in write_signal_set(str(out_dir), sig, force=True):
        echo(f"wrote {path}")
    return out_dir


def synthesize_for_loop(
    models: Path,
    config: Path,
    summary: Path,
    out: Path,
    loop_s: float,
    echo: Callable[[str], None],
) -> tuple[bool, list[dict]]:
    """``out/gains.yaml`` whose certificate covers the loop phase 2 flies (``loop_s``, the
    controller's configured loop delay): :func:`lpv_sysid.synthesis.gains.cover_loop` over
    :func:`synthesize_and_verify`; the config used is ``out/synthesis.yaml``."""
    from lpv_sysid.synthesis.gains import cover_loop

    def attempt(cfg: Path) -> tuple[bool, Path]:
        return synthesize_and_verify(
            models, cfg, summary, out / "gains.yaml", echo
        ), out / "gains.yaml"

    return cover_loop(config, out / "synthesis.yaml", loop_s, attempt, lambda s: echo("  " + s))


def synthesize_and_verify(
    models: Path, config: Path, summary: Path, out: Path, echo: Callable[[str], None]
) -> bool:
    """``lpv-sysid synthesize``'s steps: gains ``out`` for ``models`` and their independent
    verification; True when the verification passed. Runs in a child process
    (:func:`lpv_sysid.parallel.run_in_child`): the vehicle hovers meanwhile, and the LMI
    solvers take SIGINT for themselves, so in this process an operator's Ctrl-C was lost and
    the chain went on to phase 2; now it ends the synthesis and the chain (hand-back, the
    parameters set back) at once."""
    from lpv_sysid.parallel import run_in_child

    passed, lines = run_in_child(_synthesis_job, str(models), str(config), str(summary), str(out))
    for line in lines:
        echo(line)
    return passed


def _synthesis_job(models: str, config: str, summary: str, out: str) -> tuple[bool, list[str]]:
    """The work of :func:`synthesize_and_verify` (in its child): (verification passed, the
    lines to show)."""
    from lpv_sysid.synthesis.gains import (
        describe_problem,
        load_inputs,
        synthesize,
        verify_written,
        write_gains,
    )

    inp = load_inputs(models, config, summary)
    lines = list(inp.notes + describe_problem(inp))
    written = write_gains(Path(out), models, inp, synthesize(inp))
    lines += written.lines + [f"wrote {written.gains}", f"wrote {written.sidecar}"]
    rep = verify_written(written.gains, models, inp)
    lines.append(rep.table())
    return rep.passed, lines
