"""Per-vertex identification pipeline, seed 0 Sec. IV (Tables 1-3) -> ``vertex_models.yaml``.

For each scheduling vertex ``v_d`` (one phase-1 maneuver):

1. equilibrium ``x0, u0`` = mean over the trim segment (seed 0 Table 1);
2. the same global smoother is applied to states and inputs and the states are
   differentiated (:mod:`lpv_sysid.ident.derivatives`), edges of the record are dropped;
3. perturbation variables ``dx = x - x0``, ``du = u - u0`` over the excitation segment;
4. known elements of ``A, B`` (kinematics, gravity, ``v x omega``, ``I omega x omega``, motor
   rows) from the model's analytic linearisation at the *measured* trim, unknown masks from
   ``Quadrotor.unknown_masks()`` (seed 0 Appendix A); equation-error LS (Appendix B);
5. intervals and uncertain vertex systems (Eqs. 22-23), :mod:`lpv_sysid.ident.uncertainty`.

The result serialises to the ``vertices`` entries of ARCHITECTURE.md section 5.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.ident import derivatives as deriv
from lpv_sysid.ident import equation_error as ee
from lpv_sysid.ident import metrics
from lpv_sysid.ident import taylor
from lpv_sysid.ident import uncertainty as unc

log = logging.getLogger(__name__)

from lpv_sysid.models.quadrotor import (INPUT_NAMES, INPUT_UNITS, SCHEDULING_NAMES, STATE_NAMES,
                                        STATE_UNITS)
from lpv_sysid.validation import check_keys, is_count, is_finite_number

FORMAT = "lpv_sysid/vertex_models@1"


@dataclass(frozen=True)
class IdentificationConfig:
    """``config/identification.yaml`` (all sections optional)."""

    derivatives: deriv.DerivativeConfig = field(default_factory=deriv.DerivativeConfig)
    uncertainty: unc.UncertaintyConfig = field(default_factory=unc.UncertaintyConfig)
    trim_duration: float = 10.0        # s of steady reference before the excitation (seed 0 Sec. IV)
    trim_average: float = 5.0          # s at the end of the trim segment averaged for x0, u0
    edge: float = 0.5                  # s dropped at both ends of the fit segment (smoother end effects)
    min_fit_duration: float = 5.0      # s, shorter excitation segments are refused
    sample_rate: float = 100.0         # Hz, common grid of dataprep
    max_lag: int | None = None         # residual autocorrelation lags (None: automatic)
    intercept: bool = True             # per-row bias term (Klein & Morelli), see equation_error
    model: str = "taylor2"             # "taylor2" (ident.taylor) or "appendix_b" (plain seed 0 App. B)
    excitation_threshold: float = 1e-6 # |u_e| above which the excitation counts as on
    vmin: tuple[float, float, float] = (-5.0, -5.0, -5.0)
    vmax: tuple[float, float, float] = (5.0, 5.0, 5.0)
    validation: str = "hover"          # name pattern of the validation bag
    quadrotor: dict = field(default_factory=dict)  # QuadrotorParams overrides (known elements)

    @classmethod
    def from_dict(cls, d: dict | None) -> "IdentificationConfig":
        if d is None:
            d = {}
        if not isinstance(d, dict):
            raise ConfigError(f"identification config must be a mapping, got {type(d).__name__}")
        d = d.get("identification", d)
        if not isinstance(d, dict):
            raise ConfigError(f"identification: expected a mapping, got {type(d).__name__}")
        d = dict(d)
        check_keys(d, cls.__dataclass_fields__, "identification", list_allowed=True)
        kw: dict = {}
        kw["derivatives"] = deriv.DerivativeConfig.from_dict(d.pop("derivatives", None))
        kw["uncertainty"] = unc.UncertaintyConfig.from_dict(d.pop("uncertainty", None))
        for key in ("trim_duration", "trim_average", "edge", "min_fit_duration", "sample_rate",
                    "excitation_threshold"):
            if key in d:
                v = d.pop(key)
                if not is_finite_number(v) or v < 0:
                    raise ConfigError(f"identification.{key} must be a finite number >= 0, got {v!r}")
                kw[key] = float(v)
        if "max_lag" in d:
            v = d.pop("max_lag")
            if v is not None and not is_count(v):
                raise ConfigError(f"identification.max_lag must be null or an integer >= 0, got {v!r}")
            kw["max_lag"] = v
        for key in ("vmin", "vmax"):
            if key in d:
                v = d.pop(key)
                if not isinstance(v, (list, tuple)) or len(v) != 3:
                    raise ConfigError(f"identification.{key} must be a list of 3 numbers, got {v!r}")
                kw[key] = tuple(float(a) for a in v)
        if "intercept" in d:
            v = d.pop("intercept")
            if not isinstance(v, bool):
                raise ConfigError(f"identification.intercept must be true or false, got {v!r}")
            kw["intercept"] = v
        if "model" in d:
            v = d.pop("model")
            if v not in ("taylor2", "appendix_b"):
                raise ConfigError(f"identification.model must be 'taylor2' or 'appendix_b', got {v!r}")
            kw["model"] = v
        if "validation" in d:
            kw["validation"] = str(d.pop("validation"))
        if "quadrotor" in d:
            q = d.pop("quadrotor")
            if not isinstance(q, dict):
                raise ConfigError("identification.quadrotor must be a mapping")
            kw["quadrotor"] = q
        cfg = cls(**kw)
        if cfg.sample_rate <= 0:
            raise ConfigError("identification.sample_rate must be > 0")
        if any(a >= b for a, b in zip(cfg.vmin, cfg.vmax)):
            raise ConfigError(f"identification.vmin {cfg.vmin} must be below vmax {cfg.vmax}")
        return cfg


@dataclass(frozen=True)
class VertexData:
    """Aligned arrays of one phase-1 maneuver on a uniform grid (from dataprep or a simulator)."""

    t: np.ndarray            # (N,) s
    x: np.ndarray            # (N, 12) STATE_NAMES
    u: np.ndarray            # (N, 4) INPUT_NAMES
    scheduling: np.ndarray   # (3,) commanded vertex v_d
    trim: tuple[float, float]  # [t_start, t_end) of the trim segment
    fit: tuple[float, float]   # [t_start, t_end) of the excitation (fit) segment
    name: str = ""


@dataclass(frozen=True)
class KnownModel:
    """Known elements and unknown masks of the perturbation model (seed 0 Appendix A/B)."""

    A: np.ndarray
    B: np.ndarray
    maskA: np.ndarray
    maskB: np.ndarray


@dataclass(frozen=True)
class VertexResult:
    name: str
    scheduling: np.ndarray
    x0: np.ndarray
    u0: np.ndarray
    fit: ee.Fit
    uncertain: unc.UncertainVertex
    r2_axes: dict
    validation: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """One ``vertices`` entry of ``vertex_models.yaml`` (ARCHITECTURE.md section 5).

        ``uncertain`` lists every identified element with its standard error.  Its
        ``lower``/``upper`` are the interval that spans the uncertain systems of Eq. (23): the
        corner parameters carry their (possibly widened) interval, the others
        ``lower = upper = nominal`` - so ``io.formats.VertexModels.to_polytopic`` (corner
        enumeration of the free elements) regenerates exactly the ``M_i`` systems of
        :mod:`lpv_sysid.ident.uncertainty` (methods 'box' and 'influence').  The full
        ``nominal +/- k std`` box of Eq. (22) follows from ``std`` and ``meta.k_sigma``.
        """
        fit = {"r2": {k: float(v) for k, v in self.r2_axes.items()}}
        for key in ("tic", "nrmse"):
            if key in self.validation:
                fit[key] = {k: float(v) for k, v in self.validation[key].items()}
        unc_list = []
        for iv in self.uncertain.intervals:
            d = iv.as_dict()
            if not iv.corner:
                d["lower"] = d["upper"] = d["nominal"]
            unc_list.append(d)
        return {
            "scheduling": [float(v) for v in self.scheduling],
            "x0": [float(v) for v in self.x0],
            "u0": [float(v) for v in self.u0],
            "A": self.fit.A.tolist(),
            "B": self.fit.B.tolist(),
            "uncertain": unc_list,
            "fit": fit,
        }


def known_from_quadrotor(x0: np.ndarray, params: dict | None = None) -> KnownModel:
    """Known elements = the truth model's linearisation at the measured trim ``x0`` at every
    element that does not depend on the aerodynamic parameters K (``unknown_masks``)."""
    from lpv_sysid.models.quadrotor import Quadrotor, QuadrotorParams

    model = Quadrotor(QuadrotorParams.from_dict(params) if params else QuadrotorParams())
    A, B = model.linearize(np.asarray(x0, dtype=float))
    maskA, maskB = model.unknown_masks()
    return KnownModel(np.where(maskA, 0.0, A), np.where(maskB, 0.0, B), maskA, maskB)


def _params(cfg: IdentificationConfig):
    from lpv_sysid.models.quadrotor import QuadrotorParams

    return QuadrotorParams.from_dict(cfg.quadrotor) if cfg.quadrotor else QuadrotorParams()


def _fit_taylor2(data: VertexData, x0, u0, known: KnownModel, cfg: IdentificationConfig) -> ee.Fit:
    """Equation error with the known part nonlinear and second-order nuisance regressors
    (:mod:`lpv_sysid.ident.taylor`); returns the Fit of the full ``A, B`` (Eq. 15)."""
    params = _params(cfg)
    rows = list(taylor.ROWS)
    A0, B0 = taylor.known_linear(x0, params)
    x0 = np.asarray(x0, dtype=float)
    widths = {}

    def nonlin(x_raw):
        kr = taylor.known_rigid_body(x_raw, params)
        rem = taylor.remainders(x0, x_raw - x0, params)
        widths.update({a: r.shape[1] for a, r in rem.items()})
        return np.concatenate([kr] + [rem[a] for a in taylor.FORCE_AXES + taylor.MOMENT_AXES], axis=1)

    _, xdot, dx, du, nl_s = prepare(data, cfg, x0, u0, nonlin)
    y = xdot.copy()
    y[:, rows] = xdot[:, rows] - nl_s[:, :6]
    off = 6
    rem = {}
    for a in taylor.FORCE_AXES + taylor.MOMENT_AXES:
        rem[a] = nl_s[:, off: off + widths[a]]
        off += widths[a]
    extra = taylor.select_nuisance(rem, params)
    A_kn = np.where(known.maskA, 0.0, known.A)
    B_kn = np.where(known.maskB, 0.0, known.B)
    A_kn[rows] = 0.0            # the known part of these rows is already in y (nonlinear)
    B_kn[rows] = 0.0
    f = ee.fit(y, dx, du, A_kn, B_kn, known.maskA, known.maskB, cfg.max_lag, True, extra)
    A, B = f.A.copy(), f.B.copy()
    A[rows] += A0[rows]
    B[rows] += B0[rows]
    return dataclasses.replace(f, A=A, B=B)


def _segment(t: np.ndarray, a: float, b: float, what: str, min_len: float) -> np.ndarray:
    idx = np.nonzero((t >= a) & (t < b))[0]
    if idx.size < 2 or (t[idx[-1]] - t[idx[0]]) < min_len:
        have = 0.0 if idx.size < 2 else t[idx[-1]] - t[idx[0]]
        raise ConfigError(f"{what}: segment [{a:.2f}, {b:.2f}) s has {have:.2f} s of data, "
                          f"need at least {min_len:.2f} s")
    return idx


def trim_window(trim: tuple[float, float], cfg: IdentificationConfig) -> tuple[float, float]:
    """Averaging window for x0, u0: the last ``trim_average`` s, at most half the trim segment."""
    a, b = trim
    return b - min(cfg.trim_average, 0.5 * (b - a)), b


def equilibrium(data: VertexData, cfg: IdentificationConfig) -> tuple[np.ndarray, np.ndarray]:
    """``x0, u0`` = means over the last ``trim_average`` seconds (at most half) of the trim
    segment (the vehicle may still be converging to the new reference at its start), seed 0
    Table 1."""
    a, b = trim_window(data.trim, cfg)
    idx = _segment(data.t, a, b, f"{data.name or 'vertex'} trim", min(0.5, b - a))
    return data.x[idx].mean(axis=0), data.u[idx].mean(axis=0)


def prepare(data: VertexData, cfg: IdentificationConfig, x0: np.ndarray, u0: np.ndarray,
            nonlinear=None):
    """Smoothed perturbations and derivatives over the fit segment: ``(t, dxdot, dx, du)``.

    ``nonlinear(x_raw) -> (N, k)``: optional function of the *raw* states whose value is
    smoothed with the same filter and appended to the return tuple.  Nonlinear regressors
    must be computed before smoothing - ``L[r(x)]``, not ``r(L[x])`` - so that the filtered
    equation ``L[x'] = A L[x] + L[r(x)]`` still holds exactly.
    """
    t = np.asarray(data.t, dtype=float)
    dt = float(np.median(np.diff(t)))
    if not np.allclose(np.diff(t), dt, rtol=1e-6, atol=1e-9):
        raise ConfigError(f"{data.name or 'vertex'}: samples must be on a uniform grid")
    a, b = data.fit
    # differentiate a little more than the fit segment so the smoother's end effects fall
    # outside it, then cut the edges
    full = _segment(t, a, b, f"{data.name or 'vertex'} excitation", cfg.min_fit_duration + 2 * cfg.edge)
    if cfg.derivatives.method == "fourier":
        full = full[: deriv.fast_length(full.size)]      # FFT-friendly length, drops < 2 % (n > 2000)
    xs, xdot = deriv.smooth_and_differentiate(data.x[full], dt, cfg.derivatives)
    us = deriv.smooth(data.u[full], dt, cfg.derivatives)
    n_edge = int(round(cfg.edge / dt))
    keep = slice(n_edge, full.size - n_edge)
    out = (t[full][keep], xdot[keep], xs[keep] - x0, us[keep] - u0)
    if nonlinear is not None:
        out = out + (deriv.smooth(nonlinear(data.x[full]), dt, cfg.derivatives)[keep],)
    return out


def identify_vertex(data: VertexData, cfg: IdentificationConfig,
                    known: KnownModel | None = None) -> VertexResult:
    """Full pipeline for one vertex (see module docstring)."""
    x = np.asarray(data.x, dtype=float)
    u = np.asarray(data.u, dtype=float)
    if x.ndim != 2 or x.shape[1] != 12 or u.ndim != 2 or u.shape[1] != 4 or x.shape[0] != u.shape[0] \
            or x.shape[0] != np.asarray(data.t).size:
        raise ConfigError(f"{data.name}: need t (N,), x (N, 12), u (N, 4); got {np.shape(data.t)}, "
                          f"{x.shape}, {u.shape}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(u))):
        raise ConfigError(f"{data.name}: states or inputs contain NaN/inf")
    x0, u0 = equilibrium(data, cfg)
    if known is None:
        known = known_from_quadrotor(x0, cfg.quadrotor)
    if cfg.model == "taylor2":
        fit = _fit_taylor2(data, x0, u0, known, cfg)
    else:
        _, xdot, dx, du = prepare(data, cfg, x0, u0)
        fit = ee.fit(xdot, dx, du, known.A, known.B, known.maskA, known.maskB, cfg.max_lag, cfg.intercept)
    uv = unc.build(fit.A, fit.B, fit.elements(), cfg.uncertainty)
    r2 = {a: fit.r2.get(i, float("nan")) for a, i in zip(metrics.AXES, metrics.AXIS_INDEX)}
    log.info("%s: %d identified elements, M=%d uncertain systems", data.name, len(uv.intervals), uv.M)
    return VertexResult(data.name, np.asarray(data.scheduling, dtype=float), x0, u0, fit, uv, r2)


def validate(results: Sequence[VertexResult], data: VertexData, cfg: IdentificationConfig) -> dict:
    """Independent validation (seed 0 Table 3): modelled vs measured derivatives on ``data``.

    The LPV model (Eq. 19 at nominal theta, multilinear weights of Eq. 21 at the maneuver's
    commanded ``v_d``) is evaluated on the measured states and inputs:
    ``xdot_m = A(v_d) (x - x0(v_d)) + B(v_d) (u - u0(v_d))``; ``xdot_f`` is the smoothed
    derivative of the measured states.  Returns metrics and the time series.
    """
    from lpv_sysid.models.lpv import multilinear_weights

    order = vertex_order(results, cfg)
    w, outside = multilinear_weights(np.asarray(data.scheduling, dtype=float), cfg.vmin, cfg.vmax)
    if outside:
        raise ConfigError(f"validation maneuver v_d={list(data.scheduling)} outside the box")
    A = sum(wi * results[k].fit.A for wi, k in zip(w, order))
    B = sum(wi * results[k].fit.B for wi, k in zip(w, order))
    x0 = sum(wi * results[k].x0 for wi, k in zip(w, order))
    u0 = sum(wi * results[k].u0 for wi, k in zip(w, order))
    t, xdot_f, dx, du = prepare(data, cfg, x0, u0)
    xdot_m = dx @ A.T + du @ B.T
    out = metrics.axis_metrics(xdot_m, xdot_f)
    out.update({"t": t, "xdot_m": xdot_m, "xdot_f": xdot_f})
    return out


def vertex_order(results: Sequence[VertexResult], cfg: IdentificationConfig) -> list[int]:
    """Index into ``results`` for every box vertex in the order of ``models.lpv.box_vertices``."""
    from lpv_sysid.models.lpv import box_vertices

    corners = box_vertices(cfg.vmin, cfg.vmax)
    order = []
    for c in corners:
        hits = [k for k, r in enumerate(results) if np.allclose(r.scheduling, c)]
        if len(hits) != 1:
            raise ConfigError(f"need exactly one identified maneuver at vertex {c.tolist()}, found {len(hits)}")
        order.append(hits[0])
    return order


def vertex_models_dict(results: Sequence[VertexResult], cfg: IdentificationConfig,
                       validation: dict | None = None) -> dict:
    """The ``vertex_models.yaml`` document (ARCHITECTURE.md section 5), vertices in box order.

    ``meta`` records how the file was made: the method, ``k_sigma`` of Eq. (22), the
    polytope reduction and ``M_i`` per vertex, and the independent validation (Table 3).
    """
    order = vertex_order(results, cfg)
    meta = {
        "generator": "lpv_sysid.ident (seed 0 Sec. IV, Appendix B)",
        "model": cfg.model,
        "derivatives": dataclasses.asdict(cfg.derivatives),
        "k_sigma": cfg.uncertainty.k_sigma,
        "joint_alpha": cfg.uncertainty.joint_alpha,
        "uncertainty": {"method": cfg.uncertainty.method, "p_max": cfg.uncertainty.p_max,
                        "M": [results[k].uncertain.M for k in order],
                        "inflation": [results[k].uncertain.inflation for k in order]},
    }
    if validation:
        meta["validation"] = {"maneuver": validation.get("name", ""),
                              "tic": {k: float(v) for k, v in validation["tic"].items()},
                              "nrmse": {k: float(v) for k, v in validation["nrmse"].items()}}
    return {
        "format": FORMAT,
        "time": "continuous",
        "states": [{"name": n, "unit": s} for n, s in zip(STATE_NAMES, STATE_UNITS)],
        "inputs": [{"name": n, "unit": s} for n, s in zip(INPUT_NAMES, INPUT_UNITS)],
        "scheduling": {"names": list(SCHEDULING_NAMES), "min": list(cfg.vmin), "max": list(cfg.vmax)},
        "vertices": [results[k].to_dict() for k in order],
        "meta": meta,
    }


def in_sample_metrics(result: VertexResult, data: VertexData, cfg: IdentificationConfig) -> dict:
    """TIC/NRMSE (Eqs. 24-25) of the vertex model on its own maneuver (per-vertex ``fit``)."""
    t, xdot_f, dx, du = prepare(data, cfg, result.x0, result.u0)
    return metrics.axis_metrics(dx @ result.fit.A.T + du @ result.fit.B.T, xdot_f)


def box_corners(cfg: IdentificationConfig) -> np.ndarray:
    """The 2^3 scheduling vertices in box order (``models.lpv.box_vertices``)."""
    from lpv_sysid.models.lpv import box_vertices

    return box_vertices(cfg.vmin, cfg.vmax)
