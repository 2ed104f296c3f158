"""Truth coverage of the identified vertex models on simulated airframes (issue 13 study).

Question answered: do the intervals ``nominal +/- k std`` of ``vertex_models.yaml`` (seed 0
Eq. 22, ``k = 3``) contain the true vertex model as often as they claim (99.73 % per
element), on vehicles whose parameters the package never saw?

Study:

1. ``airframes`` vehicles drawn around the configured one (:func:`random_airframe`): mass,
   each principal inertia, arm length, motor constants ``a_Omega, b_Omega``, rotor inertia
   ``J_z`` and every lumped aerodynamic parameter ``K`` of :mod:`lpv_sysid.models.quadrotor`
   multiplied by independent factors ``1 + U(-spread, spread)`` (default +/-25 %); an airframe
   that has no trim at some vertex or that the baseline cannot fly is redrawn;
2. each flies the phase-1 experiment of :mod:`lpv_sysid.sim.phase1` (full durations: the
   statistic of a biased estimator depends on the record length, so the flights are not
   shortened) at the chosen vertices with its own sensor-noise seed per run;
3. identification (:mod:`lpv_sysid.ident.vertex`) is told only what an experimenter knows:
   mass, inertia, arm length, rotor-speed limits; ``K``, ``J_z`` and the motor constants it
   is given are the nominal ones (the motor constants are identified);
4. the truth is the analytic linearisation (``Quadrotor.linearize``) of the airframe at its
   equilibrium at the commanded vertex velocity v_d (what the LPV model is scheduled on; the
   identification re-expands there, ``expand_at: commanded``), or with ``expand_at: flown`` at
   the flown velocity: ``Quadrotor.trim(v, yaw_rate)`` with the yaw rate (and ``v_flown``) the
   means of the *true* states over the trim-averaging window - seed 0
   Eq. (13): the vertex model is the expansion about the equilibrium;
5. per identified element ``z = (nominal - truth) / std`` with the stored (calibrated)
   ``std``; covered when ``|z| <= k``.

:func:`ablations` re-identifies the same flights with parts of the method switched off, to
show what each part contributes.
"""

from __future__ import annotations

import math
import dataclasses
import logging
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from lpv_sysid.control.campaign import run_name
from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import ConfigError, SafetyError, SolverError
from lpv_sysid.parallel import map_tasks
from lpv_sysid.synthesis.uncertainty_set import DEFAULT_BOX_INFLATION
from lpv_sysid.ident.vertex import DEFAULT_JOINT_PROBABILITY
from lpv_sysid.models.quadrotor import (
    INPUT_NAMES,
    STATE_NAMES,
    Quadrotor,
    QuadrotorParams,
    reduced_state,
)

log = logging.getLogger(__name__)

#: what the experimenter is assumed to know about an airframe (passed to identification)
KNOWN_KEYS = ("mass", "inertia", "arm_length", "hub_height", "omega_min", "omega_max", "g")


def random_airframe(
    base: QuadrotorParams, rng: np.random.Generator, spread: float = 0.25
) -> QuadrotorParams:
    """``base`` with mass, principal inertias, arm, motor constants, ``J_z`` and every ``K``
    multiplied by independent ``1 + U(-spread, spread)`` factors."""
    if not 0 <= spread < 1:
        raise ConfigError(f"coverage.spread must be in [0, 1), got {spread!r}")

    def f() -> float:
        return float(1.0 + rng.uniform(-spread, spread))

    inertia = np.array(base.inertia, dtype=float)
    off_diagonal = inertia - np.diag(np.diag(inertia))
    inertia = np.diag([inertia[i, i] * f() for i in range(3)]) + off_diagonal
    return dataclasses.replace(
        base,
        mass=base.mass * f(),
        inertia=tuple(map(tuple, inertia)),
        arm_length=base.arm_length * f(),
        a_omega=base.a_omega * f(),
        b_omega=base.b_omega * f(),
        j_rotor=base.j_rotor * f(),
        K={k: v * f() for k, v in base.K.items()},
    )


def identification_params(true: QuadrotorParams, nominal: QuadrotorParams) -> dict:
    """The ``quadrotor`` section identification gets: the known keys of the true airframe,
    the nominal (not the true) ``K``, ``J_z`` and motor constants."""
    d = nominal.to_dict()
    t = true.to_dict()
    d.update({k: t[k] for k in KNOWN_KEYS})
    return d


def sensor_noise(sensors) -> dict:
    """``measurement_noise`` of the identification (errors-in-variables compensation) from the
    simulated sensors (:class:`lpv_sysid.sim.vehicle.SensorConfig`): white-noise std per sample at
    the estimator / ESC-telemetry rates (vibration and aliasing are not in it)."""
    att = float(np.radians(sensors.att_std_deg))
    out = {k: [att, sensors.state_hz] for k in ("phi", "theta")}
    out.update({k: [sensors.vel_std, sensors.state_hz] for k in ("u", "v", "w")})
    out.update({k: [sensors.rate_std, sensors.state_hz] for k in ("p", "q", "r")})
    out["rotor"] = [sensors.rotor_std, sensors.rotor_hz]
    return out


def eiv_shift(results) -> float:
    """Largest ``|LS - bias-compensated| / std`` over the regression coefficients of the
    results (0 when no measurement noise was given)."""
    worst = 0.0
    for r in results:
        for rf in r.fit.rows:
            if rf.eiv_bias is not None:
                s = np.sqrt(np.maximum(np.diag(rf.cov), 1e-300))
                worst = max(worst, float(np.max(np.abs(rf.eiv_bias) / s)))
    return worst


def truth_model(
    params: QuadrotorParams, rec, trim_window: tuple[float, float], at: str = "commanded"
):
    """``(A, B, x_e)``: linearisation of the airframe at its equilibrium at the commanded vertex
    velocity ``rec.v_d`` (``at="commanded"``, what the LPV model is scheduled on) or at the mean
    true velocity over ``trim_window`` (``"flown"``), with the mean true yaw rate there
    (module docstring, step 4)."""
    q = Quadrotor(params)
    sel = (rec.state_t >= trim_window[0]) & (rec.state_t < trim_window[1])
    if not sel.any():
        raise ConfigError(f"run {rec.name}: no true states in the trim window {trim_window}")
    xs = rec.state_true[sel]
    reduced = reduced_state(xs, params.arm_length)
    phi, th, q_, r_ = reduced[:, 0], reduced[:, 1], reduced[:, 6], reduced[:, 7]
    psi_dot = float(np.mean((np.sin(phi) * q_ + np.cos(phi) * r_) / np.cos(th)))
    v = np.asarray(rec.v_d, dtype=float) if at == "commanded" else reduced[:, 2:5].mean(axis=0)
    tr = q.trim(v, psi_dot)
    A, B = q.linearize(tr)
    return A, B, tr.x0


def element_label(matrix: str, row: int, col: int) -> str:
    cols = STATE_NAMES if matrix == "A" else INPUT_NAMES
    return f"{matrix}[{STATE_NAMES[row]},{cols[col]}]"


def z_scores(result, A: np.ndarray, B: np.ndarray) -> dict[str, float]:
    """``(nominal - truth) / std`` per identified element of a ``VertexResult``."""
    out = {}
    for iv in result.uncertain.intervals:
        truth = (A if iv.matrix == "A" else B)[iv.row, iv.col]
        out[element_label(iv.matrix, iv.row, iv.col)] = (
            float((iv.nominal - truth) / iv.std)
            if iv.std > 0
            else (0.0 if iv.nominal == truth else float("inf"))
        )
    return out


#: most airframes of one study (each is a simulated phase-1 campaign and identification)
MAX_AIRFRAMES = 1000


@dataclass(frozen=True)
class CoverageConfig:
    """A coverage study: how many simulated airframes, how far from the nominal one."""

    airframes: int = cf.count(
        3,
        "simulated airframes (each a full phase-1 campaign, minutes of CPU)",
        lo=1,
        hi=MAX_AIRFRAMES,
    )
    spread: float = cf.number(
        0.25, "relative spread of every physical parameter", lo=0.0, hi=1.0, hi_open=True
    )
    seed: int = cf.count(0, "seed of the airframe draws")
    vertices: tuple[int, ...] | None = cf.counts(
        None, "1-based seed 0 Table 1 indices (null: all 8)", lo=1, optional=True
    )
    max_draws: int = cf.count(20, "redraws of an airframe that cannot be flown", lo=1)
    joint_probability: float = cf.number(
        DEFAULT_JOINT_PROBABILITY,
        "that of the certified box (the joint rate is judged against it)",
        lo=0.0,
        lo_open=True,
        hi=1.0,
        hi_open=True,
    )
    box_inflation: float = cf.number(
        DEFAULT_BOX_INFLATION, "that of the certified box", lo=0.0, hi=1.0
    )
    interior: int = cf.count(
        12, "random interior scheduling points besides hover (0: no interior check)", hi=10_000
    )

    def __post_init__(self) -> None:
        cf.normalize_fields(self, "coverage")


@dataclass
class VertexCoverage:
    name: str
    vertex: tuple[float, float, float]
    z: dict[str, float]
    k_sigma: float
    dof: float | None = None  # Student-t dof of the vertex's standard errors (Fit.dof)

    @property
    def covered(self) -> int:
        return int(sum(abs(v) <= self.k_sigma for v in self.z.values()))

    @property
    def n(self) -> int:
        return len(self.z)


@dataclass
class AirframeCoverage:
    index: int
    params: QuadrotorParams
    vertices: list[VertexCoverage] = field(default_factory=list)
    eiv_shift: float = 0.0  # largest errors-in-variables correction in std (eiv_shift)
    # issue 20 item 2: per interior point (hover first) the worst excess of the truth over the
    # interpolated certified set in half-widths (<= 0 inside) and the element, without and
    # with the interpolation pad of ident.vertex.interpolation added
    interior: list = field(default_factory=list)
    interior_padded: list = field(default_factory=list)
    # issue 20 round 2 item 2: the certificate synthesized for THIS airframe's identification
    # (``synthesis`` config of run_study) checked at its true plants: per plant (label,
    # lambda_max of the stored LMI at gamma_achieved; < 0: the proof holds there)
    lmi_truth: list = field(default_factory=list)
    lmi_gamma: float = float("nan")
    lmi_note: str = ""
    # per true plant: max |v - v_d| [m/s] the law with those gains settles at, constant v_d
    offsets: list = field(default_factory=list)

    @property
    def covered(self) -> int:
        return sum(v.covered for v in self.vertices)

    @property
    def n(self) -> int:
        return sum(v.n for v in self.vertices)

    @property
    def fraction(self) -> float:
        return self.covered / self.n if self.n else float("nan")

    def joint_k(self, probability: float) -> list[float]:
        """Per vertex, the half-width in stored std of the certified box for this airframe's
        identification: the Sidak value over all its elements
        (:func:`lpv_sysid.ident.vertex.joint_k`), never below the stored ``k_sigma``
        (synthesis.uncertainty_set.joint_widen keeps a wider stored interval)."""
        from lpv_sysid.ident.vertex import joint_k

        return [
            max(v.k_sigma, joint_k(self.n, probability, v.dof, v.k_sigma)) for v in self.vertices
        ]

    def jointly_covered(self, probability: float) -> bool:
        """True when ALL identified elements of the airframe lie in their simultaneous
        intervals at once (the event the certificate's joint probability is about)."""
        return all(
            abs(z) <= k
            for v, k in zip(self.vertices, self.joint_k(probability))
            for z in v.z.values()
        )

    def worst_joint_ratio(self, probability: float) -> float:
        """max |z| / k_joint over all elements (<= 1: jointly covered)."""
        return max(
            (
                abs(z) / k
                for v, k in zip(self.vertices, self.joint_k(probability))
                for z in v.z.values()
            ),
            default=0.0,
        )

    def factors(self, base: QuadrotorParams) -> dict[str, float]:
        """Parameter ratios to the base airframe (for the table)."""
        inertia, inertia_base = np.array(self.params.inertia), np.array(base.inertia)
        K = [self.params.K[k] / base.K[k] for k in base.K if base.K[k] != 0]
        return {
            "mass": self.params.mass / base.mass,
            "Ixx": inertia[0, 0] / inertia_base[0, 0],
            "Iyy": inertia[1, 1] / inertia_base[1, 1],
            "Izz": inertia[2, 2] / inertia_base[2, 2],
            "arm": self.params.arm_length / base.arm_length,
            "a_Omega": self.params.a_omega / base.a_omega,
            "b_Omega": self.params.b_omega / base.b_omega,
            "J_z": self.params.j_rotor / base.j_rotor if base.j_rotor else 1.0,
            "K_min": float(min(K)),
            "K_max": float(max(K)),
        }


def fly_airframe(
    params: QuadrotorParams,
    gains,
    sensors,
    phase1_cfg,
    vertices: Sequence[int],
    seed: int,
    signals=None,
) -> list:
    """Phase-1 runs of one airframe at ``vertices`` (1-based), noise seed ``seed + i``."""
    from lpv_sysid.sim import phase1 as p1

    model = Quadrotor(params)
    signals = signals if signals is not None else p1.design_excitation(phase1_cfg)
    verts = phase1_cfg.vertices()
    return [
        p1.simulate_run(
            model,
            gains,
            sensors,
            phase1_cfg,
            verts[i - 1],
            run_name(verts[i - 1]),
            seed=seed + i,
            signals=signals,
        )
        for i in vertices
    ]


def draw_flyable(
    base: QuadrotorParams,
    k: int,
    cfg: CoverageConfig,
    gains,
    sensors,
    phase1_cfg,
    vertices: Sequence[int],
    signals=None,
):
    """Airframe ``k`` (1-based) and its runs; redrawn while a trim is missing or a run fails."""
    rng = np.random.default_rng([cfg.seed, k])
    last = None
    for _ in range(cfg.max_draws):
        params = random_airframe(base, rng, cfg.spread)
        try:
            runs = fly_airframe(
                params,
                gains,
                sensors,
                phase1_cfg,
                vertices,
                10_000 * (cfg.seed + 1) + 100 * k,
                signals,
            )
            return params, runs
        except (SolverError, SafetyError, ConfigError) as exc:
            last = exc
            log.info("airframe %d redrawn: %s", k, exc)
    raise SolverError(f"airframe {k}: no flyable draw in {cfg.max_draws} tries (last: {last})")


def identify_runs(runs, params: QuadrotorParams, nominal: QuadrotorParams, ident_cfg) -> list:
    """``VertexResult`` per run (the identification sees :func:`identification_params`)."""
    from lpv_sysid.ident import dataprep as dp
    from lpv_sysid.ident import vertex as vx

    cfg = dataclasses.replace(ident_cfg, quadrotor=identification_params(params, nominal))
    qp = QuadrotorParams.from_dict(cfg.quadrotor)
    datas = [dp.align(dp.streams_from_record(rec), cfg, params=qp).vertex for rec in runs]
    return vx.identify_vertices(datas, cfg)


def score(runs, results, params: QuadrotorParams, ident_cfg) -> list[VertexCoverage]:
    from lpv_sysid.ident import vertex as vx
    from lpv_sysid.ident.vertex import uncertainty as unc

    out = []
    for rec, res in zip(runs, results):
        at = "commanded" if ident_cfg.expand_at == "commanded" else "flown"
        A, B, _ = truth_model(params, rec, vx.trim_window((0.0, rec.t_excite), ident_cfg), at)
        k = unc.applied_k(ident_cfg.uncertainty, len(res.uncertain.intervals))
        u_d, v_d, w_d = (float(c) for c in rec.v_d)
        dof = res.fit.dof
        out.append(
            VertexCoverage(
                rec.name,
                (u_d, v_d, w_d),
                z_scores(res, A, B),
                k,
                None if dof is None else float(dof),
            )
        )
    return out


def run_study(
    cfg: CoverageConfig,
    base: QuadrotorParams,
    gains,
    sensors,
    phase1_cfg,
    ident_cfg,
    progress: Callable[[str], None] | None = None,
    keep_runs: bool = False,
    workers: int | None = 1,
    backend: str = "process",
    synthesis: str | None = None,
):
    """The study of the module docstring: ``(airframes, runs per airframe or None)``.

    ``synthesis`` (a synthesis config, e.g. config/synthesis.yaml): each airframe's vertex
    models are also synthesized and the stored LMI is evaluated at the airframe's true plants
    (:func:`truth_lmi`; ``AirframeCoverage.lmi_truth``).

    The airframes are independent tasks (each draws from its own stream
    ``default_rng([seed, k])`` and flies with its own noise seeds): they run on ``workers``
    processes (:func:`lpv_sysid.parallel.map_tasks`; ``None``: every core) with the same
    numbers as the serial run; ``progress`` lines come in airframe order. ``backend``:
    ``process`` or ``dask`` (:data:`lpv_sysid.parallel.BACKENDS`)."""
    from lpv_sysid.sim import phase1 as p1

    vertices = list(cfg.vertices) if cfg.vertices else list(range(1, 9))
    signals = p1.design_excitation(phase1_cfg)
    tasks = [
        (
            k,
            cfg,
            base,
            gains,
            sensors,
            phase1_cfg,
            ident_cfg,
            vertices,
            signals,
            keep_runs,
            synthesis,
        )
        for k in range(1, cfg.airframes + 1)
    ]

    def report(_: int, result: tuple) -> None:
        af = result[0]
        if progress:
            progress(
                f"airframe {af.index}: {af.covered}/{af.n} elements within "
                f"{af.vertices[0].k_sigma:g} sigma ({100 * af.fraction:.2f} %)"
            )

    done = map_tasks(_airframe_task, tasks, workers, backend, on_result=report)
    return [af for af, _ in done], [runs for _, runs in done]


def _airframe_task(task: tuple) -> tuple:
    """Airframe ``k`` of :func:`run_study`: drawn, flown, identified, scored (module level: it
    runs in a worker process). Returns ``(AirframeCoverage, runs or None)``."""
    k, cfg, base, gains, sensors, phase1_cfg, ident_cfg, vertices, signals, keep_runs, synth = task
    params, runs = draw_flyable(base, k, cfg, gains, sensors, phase1_cfg, vertices, signals)
    results = identify_runs(runs, params, base, ident_cfg)
    af = AirframeCoverage(k, params, score(runs, results, params, ident_cfg), eiv_shift(results))
    if cfg.interior and len(results) == 8:
        from lpv_sysid.ident.vertex.interpolation import interpolation_pad

        verts = certified_bounds(results, cfg.joint_probability, cfg.box_inflation)
        pts = interior_points(verts, cfg.interior, np.random.default_rng([cfg.seed, k, 7]))
        af.interior = interior_excess(params, verts, pts)
        ip = interpolation_pad(results, cfg.joint_probability)
        if ip is not None:
            pad = np.concatenate([np.array(ip["pad_A"]), np.array(ip["pad_B"])], axis=1)
            padded = certified_bounds(results, cfg.joint_probability, cfg.box_inflation, pad)
            af.interior_padded = interior_excess(params, padded, pts)
        if synth:
            truths = [
                _truth_at(params, r.scheduling, _yaw_rate(params, rec, ident_cfg))
                for rec, r in zip(runs, results)
            ]
            truths += [_truth_at(params, v, 0.0) for v in pts]
            labels = (
                [rec.name for rec in runs]
                + ["hover"]
                + [f"interior {i}" for i in range(1, len(pts))]
            )
            af.lmi_gamma, lams, af.lmi_note, K = truth_lmi(
                results, ident_cfg, synth, [t[:3] for t in truths]
            )
            af.lmi_truth = list(zip(labels, lams))
            if K is not None:
                af.offsets = [
                    (lab, float(np.max(np.abs(steady_offset(results, K, *t)))))
                    for lab, t in zip(labels, truths)
                ]
    return af, (runs if keep_runs else None)


def _yaw_rate(params: QuadrotorParams, rec, ident_cfg) -> float:
    """Mean true yaw rate over the trim window (the truth's, :func:`truth_model`)."""
    from lpv_sysid.ident import vertex as vx

    a, b = vx.trim_window((0.0, rec.t_excite), ident_cfg)
    sel = (rec.state_t >= a) & (rec.state_t < b)
    x = reduced_state(rec.state_true[sel], params.arm_length)
    return float(
        np.mean((np.sin(x[:, 0]) * x[:, 6] + np.cos(x[:, 0]) * x[:, 7]) / np.cos(x[:, 1]))
    )


def _truth_at(params: QuadrotorParams, v, yaw_rate: float) -> tuple:
    """``(v, A, B, x_e, u_e)``: the airframe's equilibrium at body velocity ``v`` and its
    linearisation."""
    q = Quadrotor(params)
    tr = q.trim(np.asarray(v, dtype=float), yaw_rate)
    A, B = q.linearize(tr)
    return np.asarray(v, dtype=float), A, B, tr.x0, tr.u0


def steady_offset(results, K: np.ndarray, v, A, B, x_e, u_e) -> np.ndarray:
    """``v - v_d`` [m/s] where the flown law ``u = u0(v_d) + K(v_d) (x - x0(v_d))`` (seed 0
    Eq. 31; x0, u0, K interpolated multilinearly from the identified vertices, Eq. 21) settles
    on the TRUE plant at constant ``v_d = v`` (no feedforward: dv_d/dt = 0), linearised about
    the true equilibrium ``(x_e, u_e)`` at ``v``: ``(A + B K) dx = -B (u0 - u_e + K (x_e -
    x0))`` and ``v - v_d = dx[u, v, w]`` (the true equilibrium flies exactly ``v_d``). The
    offset is what the model's equilibrium error costs; gamma does not bound it."""
    S = np.array([np.asarray(r.scheduling, dtype=float) for r in results])
    from lpv_sysid.models.lpv import multilinear_weights

    alpha, _ = multilinear_weights(np.asarray(v, dtype=float), S.min(axis=0), S.max(axis=0))
    order = _box_order(S)
    x0 = sum(a * results[i].x0 for a, i in zip(alpha, order))
    u0 = sum(a * results[i].u0 for a, i in zip(alpha, order))
    Ka = np.tensordot(alpha, K, axes=1)
    dx = -np.linalg.solve(A + B @ Ka, B @ (u0 - u_e + Ka @ (x_e - x0)))
    return dx[2:5]


def _box_order(S: np.ndarray) -> list:
    """Index of the result at each corner of :func:`lpv_sysid.models.lpv.box_vertices`."""
    from lpv_sysid.models.lpv import box_vertices

    V = box_vertices(S.min(axis=0), S.max(axis=0))
    return [int(np.argmin(np.abs(S - c).sum(axis=1))) for c in V]


def truth_lmi(results, ident_cfg, synthesis: str, truths: list) -> tuple:
    """Synthesize gains for the vertex ``results`` with the synthesis config ``synthesis`` (the
    ``lpv-sysid identify`` models file, ``lpv-sysid synthesize``'s pipeline, its gains and
    sidecar written to a temporary directory), then evaluate the STORED LMI (the sidecar read
    back) at every ``(v, A_true, B_true)`` of ``truths`` at the certified ``gamma_achieved``
    (:func:`lpv_sysid.synthesis.verify.lmi_at_plant`). Returns ``(gamma_achieved, lambda_max
    per truth, note, K per box corner or None)``; a synthesis that fails gives nan values and
    the reason."""
    import tempfile
    from pathlib import Path

    from lpv_sysid.ident import vertex as vx
    from lpv_sysid.io.formats import VertexModels, load_certificate_npz
    from lpv_sysid.synthesis.gains import load_inputs, synthesize, write_gains
    from lpv_sysid.synthesis.verify import lmi_at_plant

    with tempfile.TemporaryDirectory() as tmp:
        models = Path(tmp) / "vertex_models.yaml"
        VertexModels.from_dict(vx.vertex_models_dict(results, ident_cfg)).save(models)
        try:
            inp = load_inputs(str(models), synthesis)
            res = synthesize(inp)
            written = write_gains(Path(tmp) / "gains.yaml", str(models), inp, res)
        except (SolverError, ConfigError) as exc:
            return float("nan"), [float("nan")] * len(truths), f"synthesis failed: {exc}", None
        cert = load_certificate_npz(written.sidecar)
        g = float(res.gamma_certified)
        vmin, vmax = inp.model.vmin, inp.model.vmax
        lams = [lmi_at_plant(cert, vmin, vmax, v, A, B, inp.R, inp.C, g) for v, A, B in truths]
    form = int(np.asarray(cert.get("lmi_form", 0)))
    note = "" if form in (1, 2, 3) else "corner certificate: no element-box LMI to evaluate"
    return g, lams, note, np.asarray(res.K, dtype=float)


#: re-identification variants of :func:`ablations` (name -> IdentificationConfig changes)
ABLATIONS: dict[str, dict[str, Any]] = {
    "no re-expansion (Jacobian at the flown mean)": {"equilibrium": False},
    "residual-ACF standard errors (no EWC, no Student-t)": {"covariance": "residual_acf"},
}


def ablations(
    runs_per_airframe,
    airframes: Sequence[AirframeCoverage],
    base: QuadrotorParams,
    ident_cfg,
    workers: int | None = 1,
    backend: str = "process",
) -> dict:
    """Coverage fraction per airframe of each :data:`ABLATIONS` variant on the same flights;
    each (variant, airframe) re-identification is a task on ``workers`` processes (the
    numbers of the serial run)."""
    from lpv_sysid.ident import equation_error as ee

    cfgs = {}
    for name, change in ABLATIONS.items():
        kw = dict(change)
        if kw.get("covariance") == "residual_acf":
            kw["covariance"] = ee.CovarianceConfig(
                method="residual_acf", max_lag=ident_cfg.max_lag
            )
        cfgs[name] = dataclasses.replace(ident_cfg, **kw)
    tasks = [
        (runs, af.params, base, cfg)
        for cfg in cfgs.values()
        for af, runs in zip(airframes, runs_per_airframe)
    ]
    fractions = iter(map_tasks(_ablation_task, tasks, workers, backend))
    return {name: [next(fractions) for _ in airframes] for name in cfgs}


def _ablation_task(task: tuple) -> float:
    """One airframe re-identified under one ablation config: its coverage fraction."""
    runs, params, base, cfg = task
    vc = score(runs, identify_runs(runs, params, base, cfg), params, cfg)
    return sum(v.covered for v in vc) / max(1, sum(v.n for v in vc))


def summary_dict(
    airframes: Sequence[AirframeCoverage],
    base: QuadrotorParams,
    cfg: CoverageConfig,
    ablation: dict | None = None,
) -> dict:
    """``coverage.yaml``: per airframe its parameter factors, per vertex the count and the
    elements outside ``k`` sigma with their z."""
    all_z = np.array([z for af in airframes for v in af.vertices for z in v.z.values()])
    k = airframes[0].vertices[0].k_sigma if airframes and airframes[0].vertices else 3.0
    d: dict[str, Any] = {
        "format": "lpv_sysid/identification_coverage@1",
        "study": {
            "airframes": cfg.airframes,
            "spread": cfg.spread,
            "seed": cfg.seed,
            "vertices": list(cfg.vertices) if cfg.vertices else list(range(1, 9)),
            "k_sigma": float(k),
            "joint_probability": float(cfg.joint_probability),
        },
        "overall": {
            "covered": int(np.sum(np.abs(all_z) <= k)),
            "elements": int(all_z.size),
            "fraction": float(np.mean(np.abs(all_z) <= k)) if all_z.size else float("nan"),
            "z_mean": float(np.mean(all_z)) if all_z.size else float("nan"),
            "z_std": float(np.std(all_z)) if all_z.size else float("nan"),
            "expected_fraction": float(_normal_coverage(k)),
        },
        "airframes": [],
    }
    P = float(cfg.joint_probability)
    joint = [af.jointly_covered(P) for af in airframes]
    d["joint"] = {
        "probability": P,
        "airframes_all_inside": int(sum(joint)),
        "airframes": len(airframes),
        "rate": float(np.mean(joint)) if joint else float("nan"),
        "meaning": "fraction of airframes with ALL identified elements inside the simultaneous "
        "intervals of the certified box (Sidak k over the airframe's element count, "
        "ident.vertex.joint_k), the event the certificate's joint probability is about",
    }
    inside = [sum(e <= 0 for e, _ in af.interior) for af in airframes]
    inside_p = [sum(e <= 0 for e, _ in af.interior_padded) for af in airframes]
    d["interior"] = {
        "points_per_airframe": max((len(af.interior) for af in airframes), default=0),
        "truth_inside": int(sum(inside)),
        "truth_inside_with_interpolation_pad": int(sum(inside_p)),
        "points": int(sum(len(af.interior) for af in airframes)),
        "meaning": "true linearisation at hover and random interior v_d inside the interpolated "
        "certified set [sum alpha_i lo_i, sum alpha_i hi_i] (joint, inflated box; B hull); "
        "'with interpolation pad': every half-width + the pad of ident.vertex.interpolation "
        "(the vertex models re-expanded on a grid), uncertainty.interpolation: true",
    }
    lam = [x for af in airframes for _, x in af.lmi_truth]
    if lam:
        d["lmi_at_truth"] = {
            "plants": len(lam),
            "holds": int(sum(x < 0 for x in lam)),
            "worst_lambda_max": float(np.nanmax(lam)) if np.any(np.isfinite(lam)) else None,
            "airframes_all_hold": int(
                sum(bool(af.lmi_truth) and all(x < 0 for _, x in af.lmi_truth) for af in airframes)
            ),
            "meaning": "per airframe gains synthesized for its own identification (the "
            "--synthesis config), the stored LMI (sidecar X, S, H, multipliers) evaluated at the "
            "airframe's true plants (vertices at v_d with the flown yaw rate, hover, interior "
            "points) at gamma_achieved: lambda_max < 0 means the stored proof holds there "
            "(synthesis.verify.lmi_at_plant)",
        }
    off = [x for af in airframes for _, x in af.offsets]
    if off:
        d["steady_offset"] = {
            "plants": len(off),
            "max_abs_m_s": float(np.max(off)),
            "meaning": "max over u, v, w of |v - v_d| where the law (gains synthesized per "
            "airframe, x0/u0/K interpolated from the identified vertices) settles on the TRUE "
            "plant at constant v_d, linearised about the true equilibrium (steady_offset)",
        }
    for af, jc in zip(airframes, joint):
        d["airframes"].append(
            {
                "index": af.index,
                "factors": {n: round(float(v), 4) for n, v in af.factors(base).items()},
                "covered": af.covered,
                "elements": af.n,
                "fraction": float(af.fraction),
                "joint_k": [round(k, 4) for k in af.joint_k(P)],
                "jointly_covered": bool(jc),
                "worst_z_over_joint_k": float(af.worst_joint_ratio(P)),
                "interior_excess": [[round(e, 3), lab] for e, lab in af.interior],
                "interior_excess_with_interpolation_pad": [
                    [round(e, 3), lab] for e, lab in af.interior_padded
                ],
                "eiv_max_shift_std": float(af.eiv_shift),
                # null: not synthesized for this airframe (no --synthesis)
                "lmi_gamma_achieved": (
                    float(af.lmi_gamma) if math.isfinite(af.lmi_gamma) else None
                ),
                "lmi_at_truth": [[lab, float(x)] for lab, x in af.lmi_truth],
                "lmi_note": af.lmi_note,
                "steady_offset_m_s": [[lab, round(x, 5)] for lab, x in af.offsets],
                "vertices": [
                    {
                        "run": v.name,
                        "vertex": list(v.vertex),
                        "covered": v.covered,
                        "elements": v.n,
                        "outside": {
                            lab: round(z, 2) for lab, z in v.z.items() if abs(z) > v.k_sigma
                        },
                    }
                    for v in af.vertices
                ],
            }
        )
    if ablation:
        d["ablations"] = {n: [float(x) for x in fr] for n, fr in ablation.items()}
    return d


def _normal_coverage(k: float) -> float:
    from scipy.stats import norm

    return float(2 * norm.cdf(k) - 1)


def markdown_table(
    airframes: Sequence[AirframeCoverage], base: QuadrotorParams, ablation: dict | None = None
) -> str:
    """The coverage table (one row per airframe, plus the ablations as extra columns)."""
    k = airframes[0].vertices[0].k_sigma
    ablation = ablation or {}
    names = list(ablation)
    head = (
        f"| airframe | mass | Ixx | Iyy | Izz | arm | a_Omega | b_Omega | K range | elements | "
        f"within {k:g} sigma |" + "".join(f" {n} |" for n in names)
    )
    lines = [head, "|" + "---|" * (11 + len(names))]
    for i, af in enumerate(airframes):
        f = af.factors(base)
        cells = [str(af.index)] + [
            f"{f[n]:.2f}" for n in ("mass", "Ixx", "Iyy", "Izz", "arm", "a_Omega", "b_Omega")
        ]
        cells += [
            f"{f['K_min']:.2f}-{f['K_max']:.2f}",
            str(af.n),
            f"{af.covered} ({100 * af.fraction:.2f} %)",
        ]
        cells += [f"{100 * ablation[n][i]:.2f} %" for n in names]
        lines.append("| " + " | ".join(cells) + " |")
    cov = sum(a.covered for a in airframes)
    n = sum(a.n for a in airframes)
    tot = ["all", "", "", "", "", "", "", "", "", str(n), f"{cov} ({100 * cov / n:.2f} %)"]
    if names:
        ws = [a.n for a in airframes]
        tot += [f"{100 * np.average(ablation[nm], weights=ws):.2f} %" for nm in names]
    lines.append("| " + " | ".join(tot) + " |")
    return "\n".join(lines)


# ----------------------------------------------------------------- interior of the box (item 2)
def certified_bounds(results, probability: float, inflation: float, pad=None) -> list:
    """Per vertex ``(scheduling, lo, hi)`` of ``[A, B]`` (12 x 16) as the synthesis box states
    them (synthesis.uncertainty_set): every element with a std in ``max(stored half, k_joint
    std)`` about its interval centre (Sidak over all elements of the airframe), plus ``pad``
    (the interpolation pad of ident.vertex.interpolation, 12 x 16), times ``1 + inflation``;
    the other elements at their value (+/- pad)."""
    from lpv_sysid.ident.vertex import joint_k

    p = sum(len(r.uncertain.intervals) for r in results)
    out = []
    for r in results:
        AB = np.concatenate([r.fit.A, r.fit.B], axis=1)
        lo, hi = AB.copy(), AB.copy()
        k_st = float(r.uncertain.intervals[0].upper - r.uncertain.intervals[0].nominal) / max(
            r.uncertain.intervals[0].std, 1e-300
        )
        k_j = joint_k(p, probability, r.fit.dof, k_st) if r.uncertain.intervals else 0.0
        for iv in r.uncertain.intervals:
            c = iv.col if iv.matrix == "A" else 12 + iv.col
            a, b = (
                min(iv.lower, iv.nominal - k_j * iv.std),
                max(iv.upper, iv.nominal + k_j * iv.std),
            )
            m, h = 0.5 * (a + b), 0.5 * (b - a)
            lo[iv.row, c], hi[iv.row, c] = m - h, m + h
        if pad is not None:
            lo, hi = lo - pad, hi + pad
        m, h = 0.5 * (lo + hi), 0.5 * (hi - lo) * (1.0 + inflation)
        lo, hi = m - h, m + h
        out.append((np.asarray(r.scheduling, dtype=float), lo, hi))
    # B: one hull common to all vertices (models.lpv.input_hull)
    bl = np.min([lo[:, 12:] for _, lo, _ in out], axis=0)
    bh = np.max([hi[:, 12:] for _, _, hi in out], axis=0)
    for _, lo, hi in out:
        lo[:, 12:], hi[:, 12:] = bl, bh
    return out


def _weights(v: np.ndarray, verts: list) -> np.ndarray:
    """Multilinear weights (seed 0 Eq. 21) of ``v`` for vertices at the corners of their box."""
    S = np.array([s for s, _, _ in verts])
    vmin, vmax = S.min(axis=0), S.max(axis=0)
    t = (v - vmin) / (vmax - vmin)
    return np.array([np.prod(np.where(s == vmax, t, 1.0 - t)) for s in S])


def interior_points(verts: list, n: int, rng: np.random.Generator) -> list:
    """Hover (the box centre) and ``n`` uniform random interior scheduling points."""
    S = np.array([s for s, _, _ in verts])
    vmin, vmax = S.min(axis=0), S.max(axis=0)
    return [0.5 * (vmin + vmax)] + [
        vmin + rng.uniform(size=vmin.size) * (vmax - vmin) for _ in range(n)
    ]


def interior_excess(params: QuadrotorParams, verts: list, points: list, pad=None) -> list:
    """Per point the worst excess of the true linearisation (at the equilibrium at v, yaw rate
    0) over the interpolated certified set ``[sum alpha_i lo_i, sum alpha_i hi_i]`` (the set
    is elementwise affine in alpha), in units of the set's half-width there (the element's
    value where the set has none); <= 0: inside. ``pad`` (12 x 16): added to every half-width
    (the measured interpolation residual)."""
    q = Quadrotor(params)
    out = []
    for v in points:
        a = _weights(np.asarray(v, dtype=float), verts)
        lo = sum(ai * lo_i for ai, (_, lo_i, _) in zip(a, verts))
        hi = sum(ai * hi_i for ai, (_, _, hi_i) in zip(a, verts))
        if pad is not None:
            lo, hi = lo - pad, hi + pad
        A, B = q.linearize(q.trim(np.asarray(v, dtype=float), 0.0))
        T = np.concatenate([A, B], axis=1)
        half = 0.5 * (hi - lo)
        scale = np.where(half > 0, half, np.maximum(np.abs(T), 1e-9))
        # rounding tolerance for the elements that are exact (lo = hi = the structural value)
        exc = (np.maximum(lo - T, T - hi) - 1e-9 * np.maximum(1.0, np.abs(T))) / scale
        k = int(np.argmax(exc))
        i, j = np.unravel_index(k, exc.shape)
        out.append(
            (
                float(exc[i, j]),
                element_label("A" if j < 12 else "B", int(i), int(j % 12 if j >= 12 else j)),
            )
        )
    return out
