"""`lpv-sysid coverage`: do the identified intervals cover the truth? (issue 13 study)

    lpv-sysid coverage --airframes 3 --out coverage_out

Draws airframes around ``--config`` (mass, inertia, arm, motor constants, J_z and every
lumped K varied by +/- ``--spread``), flies the phase-1 experiment on each, identifies the
vertex models exactly as ``lpv-sysid identify`` does, and counts the identified elements whose
``k``-sigma interval contains the true linearisation at the flown equilibrium
(:mod:`lpv_sysid.studies.coverage`).  Writes ``coverage.yaml`` and ``coverage.md`` (the table of
docs/identification_coverage.md).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from lpv_sysid.parallel import BACKENDS

COMMAND = "coverage"
HELP = "truth coverage of the identified vertex-model intervals on simulated airframes"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--airframes", type=int, default=3, help="number of random airframes (default 3)"
    )
    parser.add_argument("--out", required=True, type=Path, help="output directory (created)")
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        help="vehicle, controller, sensors and phase-1 YAML (default config/quadrotor.yaml)",
    )
    parser.add_argument(
        "--identification",
        type=Path,
        default=None,
        help="identification YAML (default config/identification.yaml)",
    )
    parser.add_argument(
        "--spread",
        type=float,
        default=0.25,
        help="parameter variation +/- fraction (default 0.25)",
    )
    parser.add_argument(
        "--joint-probability",
        type=float,
        default=0.95,
        help="joint probability of the simultaneous intervals whose joint rate over airframes "
        "is reported (default 0.95, that of the certified box)",
    )
    parser.add_argument(
        "--seed", type=int, default=0, help="study seed: airframes and sensor noise (default 0)"
    )
    parser.add_argument(
        "--vertices",
        type=int,
        nargs="+",
        default=None,
        metavar="I",
        help="1-based vertex indices in seed 0 Table 1 order (default: all 8)",
    )
    parser.add_argument(
        "--eiv",
        action="store_true",
        help="give identification the simulated sensors' noise (errors-in-variables "
        "compensation, identification.measurement_noise) and report its largest shift",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="processes flying and identifying the airframes (default: every core this process "
        "may use; 1 = serial; the numbers do not depend on it)",
    )
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default="process",
        help="where the --workers run: process (a local process pool, default) or dask (the "
        "active dask.distributed client, else Dask's local processes; dask must be installed)",
    )
    parser.add_argument(
        "--synthesis",
        type=Path,
        default=None,
        metavar="YAML",
        help="also synthesize gains for each airframe's identification with this synthesis "
        "config (e.g. config/synthesis.yaml) and evaluate the stored LMI at the airframe's true "
        "plants (vertices, hover, interior points; coverage.yaml lmi_at_truth)",
    )
    parser.add_argument(
        "--ablations",
        action="store_true",
        help="also re-identify the same flights without the re-expansion and with the "
        "residual-ACF standard errors",
    )


def run(args: argparse.Namespace) -> int:
    import yaml

    from lpv_sysid.cli.design.identify import load_config
    from lpv_sysid.configuration.defaults import config_file
    from lpv_sysid.errors import ConfigError
    from lpv_sysid.parallel import resolve_workers
    from lpv_sysid.sim import phase1
    from lpv_sysid.studies import coverage as cv

    cfg = cv.CoverageConfig(
        airframes=args.airframes,
        spread=args.spread,
        seed=args.seed,
        vertices=tuple(args.vertices) if args.vertices else None,
        joint_probability=args.joint_probability,
    )
    resolve_workers(args.workers)
    if args.seed < 0:
        raise ConfigError(f"--seed must be >= 0, got {args.seed}")
    if args.vertices and any(not 1 <= i <= 8 for i in args.vertices):
        raise ConfigError(f"--vertices: indices must be in 1..8, got {args.vertices}")
    qp, gains, sensors, ph1 = phase1.load_config(args.config or config_file("quadrotor.yaml"))
    ident_cfg = load_config(args.identification or config_file("identification.yaml"))
    if args.eiv:
        import dataclasses

        from lpv_sysid.ident.vertex import parse_measurement_noise

        ident_cfg = dataclasses.replace(
            ident_cfg, measurement_noise=parse_measurement_noise(cv.sensor_noise(sensors))
        )
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"--out {out}: cannot create ({exc.strerror})") from None
    t0 = time.perf_counter()
    airframes, runs = cv.run_study(
        cfg,
        qp,
        gains,
        sensors,
        ph1,
        ident_cfg,
        progress=print,
        keep_runs=args.ablations,
        workers=args.workers,
        backend=args.backend,
        synthesis=str(args.synthesis) if args.synthesis else None,
    )
    ablation = (
        cv.ablations(runs, airframes, qp, ident_cfg, workers=args.workers, backend=args.backend)
        if args.ablations
        else None
    )
    doc = cv.summary_dict(airframes, qp, cfg, ablation)
    table = cv.markdown_table(airframes, qp, ablation)
    (out / "coverage.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    o = doc["overall"]
    (out / "coverage.md").write_text(
        f"{table}\n\nAll: {o['covered']} of {o['elements']} identified elements within "
        f"{doc['study']['k_sigma']:g} sigma ({100 * o['fraction']:.2f} %; a calibrated Gaussian "
        f"estimate: {100 * o['expected_fraction']:.2f} %), z mean {o['z_mean']:+.3f}, z std "
        f"{o['z_std']:.3f}.\n\nJoint: {doc['joint']['airframes_all_inside']} of "
        f"{doc['joint']['airframes']} airframes with all elements inside the simultaneous "
        f"intervals at joint probability {doc['joint']['probability']:g} (rate "
        f"{100 * doc['joint']['rate']:.1f} %).\n"
    )
    print(table)
    print(
        f"all: {o['covered']}/{o['elements']} = {100 * o['fraction']:.2f} % within "
        f"{doc['study']['k_sigma']:g} "
        f"sigma (calibrated: {100 * o['expected_fraction']:.2f} %), z std {o['z_std']:.3f}; "
        f"{time.perf_counter() - t0:.0f} s"
    )
    j = doc["joint"]
    print(
        f"joint: {j['airframes_all_inside']}/{j['airframes']} airframes with ALL elements inside "
        f"the simultaneous intervals (joint probability {j['probability']:g}): rate "
        f"{100 * j['rate']:.1f} %"
    )
    it = doc.get("interior") or {}
    if it.get("points"):
        print(
            f"interior: truth inside the interpolated certified set at {it['truth_inside']}/"
            f"{it['points']} points (hover + random); with the interpolation pad "
            f"(uncertainty.interpolation): {it['truth_inside_with_interpolation_pad']}/"
            f"{it['points']}"
        )
        if args.synthesis:
            pad = _pad_configured(args.synthesis)
            n_in = it["truth_inside_with_interpolation_pad" if pad else "truth_inside"]
            print(
                f"interior, the set the --synthesis config certifies (interpolation pad "
                f"{'on' if pad else 'off'}): truth inside at {n_in}/{it['points']} points"
            )
    lt = doc.get("lmi_at_truth")
    if lt:
        print(
            f"lmi at the truth: the stored LMI holds (lambda_max < 0 at gamma_achieved) at "
            f"{lt['holds']}/{lt['plants']} true plants; worst lambda_max "
            f"{lt['worst_lambda_max']:.3g}; airframes with all plants inside the proof: "
            f"{lt['airframes_all_hold']}/{len(airframes)}"
        )
    so = doc.get("steady_offset")
    if so:
        print(
            f"steady offset at constant v_d (true plants, linearised): max |v - v_d| "
            f"{so['max_abs_m_s']:.4f} m/s over {so['plants']} plants"
        )
    print(f"wrote {out / 'coverage.yaml'}")
    print(f"wrote {out / 'coverage.md'}")
    return 0


def _pad_configured(synthesis: Path) -> bool:
    """``uncertainty.interpolation`` of a synthesis config (its declared default when absent)."""
    import yaml

    from lpv_sysid.synthesis.uncertainty_set import UncertaintySettings

    doc = yaml.safe_load(Path(synthesis).read_text()) or {}
    return bool(UncertaintySettings.from_dict(doc.get("uncertainty")).interpolation)
