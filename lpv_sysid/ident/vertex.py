"""Per-vertex identification pipeline, seed 0 Sec. IV (Tables 1-3) -> ``vertex_models.yaml``.

For each scheduling vertex ``v_d`` (one phase-1 maneuver):

1. the flown trim ``x0, u0`` = mean over the trim-averaging window (seed 0 Table 1);
2. the same global smoother is applied to states and inputs and the states are
   differentiated (:mod:`lpv_sysid.ident.derivatives`), edges of the record are dropped;
3. perturbation variables ``dx = x - x0``, ``du = u - u0`` over the excitation segment;
4. known elements of ``A, B`` (kinematics, gravity, ``v x omega``, ``I omega x omega``) from
   the model's analytic linearisation, unknown masks from ``Quadrotor.unknown_masks()``
   (seed 0 Appendix A); equation-error LS (Appendix B), by default (``model: taylor2``) with
   the known part nonlinear and the exact second-order remainders of Eq. (6) as nuisance
   regressors (:mod:`lpv_sysid.ident.taylor`), an intercept per row, and the rotor reaction
   torque on the measured rotor acceleration;
5. the motor constants ``a_Omega, b_Omega`` of Eq. (8) from the rotor speeds
   (:func:`_motor_design`: per rotor, stacked, gated while a rotor is pinned at a speed
   limit, with the command-to-rotor latency), where the data allow; otherwise uncertain with
   the estimate pooled over the other maneuvers (:func:`identify_vertices`);
6. all rows' covariance jointly (:func:`lpv_sysid.ident.equation_error.solve_rows`: stacked-
   score EWC sandwich, Student-t dof);
7. the flown trim is *not* an equilibrium (the vehicle fluctuates about it and the dynamics
   are nonlinear: the identified model's derivative there is a few cm/s^2, and the flown mean
   rotor speed sits 1-3 rad/s above trim), so the second-order model is re-expanded about its
   own equilibrium at the flown velocity (seed 0 Eq. 13), with the delta-method covariance of
   the Jacobians there (:func:`lpv_sysid.ident.taylor.reexpand`); that equilibrium is the
   vertex's ``x0, u0``;
8. intervals ``nominal +/- k std`` of every identified element (Eq. 22, std widened for the
   Student-t dof) and the reduced uncertain vertex systems (Eq. 23),
   :mod:`lpv_sysid.ident.uncertainty`.

The result serialises to the ``vertices`` entries of ``vertex_models.yaml`` (format ``@2``,
:mod:`lpv_sysid.io.formats`).  Truth coverage on simulated airframes:
:mod:`lpv_sysid.ident.coverage` and docs/identification_coverage.md.
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
from lpv_sysid.models.quadrotor import (
    INPUT_NAMES,
    INPUT_UNITS,
    SCHEDULING_NAMES,
    STATE_NAMES,
    STATE_UNITS,
)
from lpv_sysid.config_fields import check_keys, is_count, is_finite_number

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class IdentificationConfig:
    """``config/identification.yaml`` (all sections optional)."""

    derivatives: deriv.DerivativeConfig = field(default_factory=deriv.DerivativeConfig)
    uncertainty: unc.UncertaintyConfig = field(default_factory=unc.UncertaintyConfig)
    trim_duration: float = 10.0  # s of steady reference before the excitation (seed 0 Sec. IV)
    trim_average: float = 5.0  # s at the end of the trim segment averaged for x0, u0
    edge: float = 0.5  # s dropped at both ends of the fit segment (smoother end effects)
    min_fit_duration: float = 5.0  # s, shorter excitation segments are refused
    sample_rate: float = 100.0  # Hz, common grid of dataprep
    max_lag: int | None = None  # residual autocorrelation lags (covariance.method residual_acf)
    intercept: bool = True  # per-row bias term (Klein & Morelli), see equation_error
    model: str = "taylor2"  # "taylor2" (ident.taylor) or "appendix_b" (plain seed 0 App. B)
    covariance: ee.CovarianceConfig = field(default_factory=ee.CovarianceConfig)
    equilibrium: bool = True  # taylor2: re-expand about the identified equilibrium (Eq. 13)
    motor: str = "identify"  # a_Omega, b_Omega: "identify" (motor rows, Eq. 8) or "known"
    motor_max_pinned: float = 0.01  # identify a_Omega, b_Omega only if no rotor is pinned at a
    # speed limit longer than this fraction of the fit segment
    motor_std: tuple[float, float] | None = None  # std of a_Omega, b_Omega where not identifiable
    instruments: bool = False  # taylor2: rotor speeds instrumented by the motor model (EIV check)
    motor_instrument: bool = True  # motor rows: measured speeds instrumented by the model's (EIV)
    measurement_noise: dict = field(
        default_factory=dict
    )  # EIV: {state or "rotor": std | [std, rate_hz]}
    excitation_threshold: float = 1e-6  # |u_e| above which the excitation counts as on
    vmin: tuple[float, float, float] = (-5.0, -5.0, -5.0)
    vmax: tuple[float, float, float] = (5.0, 5.0, 5.0)
    validation: str = "hover"  # name pattern of the validation bag
    quadrotor: dict = field(default_factory=dict)  # QuadrotorParams overrides (known elements)

    @classmethod
    def from_dict(cls, d: dict | None) -> "IdentificationConfig":
        if d is None:
            d = {}
        if not isinstance(d, dict):
            raise ConfigError(f"identification config must be a mapping, got {type(d).__name__}")
        from lpv_sysid.signals.config import MAX_SAMPLE_RATE

        d = d.get("identification", d)
        if not isinstance(d, dict):
            raise ConfigError(f"identification: expected a mapping, got {type(d).__name__}")
        d = dict(d)
        check_keys(d, cls.__dataclass_fields__, "identification", list_allowed=True)
        kw: dict = {}
        kw["derivatives"] = deriv.DerivativeConfig.from_dict(d.pop("derivatives", None))
        kw["uncertainty"] = unc.UncertaintyConfig.from_dict(d.pop("uncertainty", None))
        kw["covariance"] = ee.CovarianceConfig.from_dict(d.pop("covariance", None))
        for key in (
            "trim_duration",
            "trim_average",
            "edge",
            "min_fit_duration",
            "sample_rate",
            "excitation_threshold",
            "motor_max_pinned",
        ):
            if key in d:
                v = d.pop(key)
                if not is_finite_number(v) or v < 0:
                    raise ConfigError(
                        f"identification.{key} must be a finite number >= 0, got {v!r}"
                    )
                if (
                    key == "sample_rate" and v > MAX_SAMPLE_RATE
                ):  # the common grid is allocated from it
                    raise ConfigError(
                        f"identification.sample_rate: {v:g} Hz exceeds the limit of "
                        f"{MAX_SAMPLE_RATE:g} Hz"
                    )
                kw[key] = float(v)
        if "max_lag" in d:
            v = d.pop("max_lag")
            if v is not None and not is_count(v):
                raise ConfigError(
                    f"identification.max_lag must be null or an integer >= 0, got {v!r}"
                )
            kw["max_lag"] = v
        for key in ("vmin", "vmax"):
            if key in d:
                v = d.pop(key)
                if not isinstance(v, (list, tuple)) or len(v) != 3:
                    raise ConfigError(
                        f"identification.{key} must be a list of 3 numbers, got {v!r}"
                    )
                kw[key] = tuple(float(a) for a in v)
        for key in ("intercept", "equilibrium", "instruments", "motor_instrument"):
            if key in d:
                v = d.pop(key)
                if not isinstance(v, bool):
                    raise ConfigError(f"identification.{key} must be true or false, got {v!r}")
                kw[key] = v
        if "measurement_noise" in d:
            kw["measurement_noise"] = parse_measurement_noise(d.pop("measurement_noise"))
        if "motor_std" in d:
            v = d.pop("motor_std")
            if v is not None and (
                not isinstance(v, (list, tuple))
                or len(v) != 2
                or not all(is_finite_number(a) and a > 0 for a in v)
            ):
                raise ConfigError(
                    f"identification.motor_std must be null or [std a_Omega, std b_Omega] > 0, "
                    f"got {v!r}"
                )
            kw["motor_std"] = None if v is None else (float(v[0]), float(v[1]))
        if "motor" in d:
            v = d.pop("motor")
            if v not in ("identify", "known"):
                raise ConfigError(f"identification.motor must be 'identify' or 'known', got {v!r}")
            kw["motor"] = v
        if "model" in d:
            v = d.pop("model")
            if v not in ("taylor2", "appendix_b"):
                raise ConfigError(
                    f"identification.model must be 'taylor2' or 'appendix_b', got {v!r}"
                )
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


def parse_measurement_noise(v) -> dict:
    """``measurement_noise``: state name (STATE_NAMES) or ``rotor`` -> white-noise std per sample,
    or ``[std, rate_hz]`` (the rate the channel was sampled at; default the grid rate)."""
    if v is None:
        return {}
    if not isinstance(v, dict):
        raise ConfigError(
            f"identification.measurement_noise must be a mapping, got {type(v).__name__}"
        )
    out = {}
    for k, x in v.items():
        if k not in STATE_NAMES and k != "rotor":
            raise ConfigError(
                f"identification.measurement_noise: unknown channel {k!r}; "
                f"allowed: {list(STATE_NAMES) + ['rotor']}"
            )
        pair = list(x) if isinstance(x, (list, tuple)) else [x, None]
        if (
            len(pair) != 2
            or not is_finite_number(pair[0])
            or pair[0] < 0
            or (pair[1] is not None and (not is_finite_number(pair[1]) or pair[1] <= 0))
        ):
            raise ConfigError(
                f"identification.measurement_noise.{k} must be std >= 0 or [std, rate_hz > 0], "
                f"got {x!r}"
            )
        out[k] = (float(pair[0]), None if pair[1] is None else float(pair[1]))
    return out


def regressor_noise_var(
    cfg: IdentificationConfig, params, dt: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """Errors-in-variables input: ``(var (12,), var of d/dt (12,), rotor-speed var)`` of the
    *smoothed* measured states (white noise of std ``s`` sampled at ``r`` Hz has the one-sided
    density ``2 s^2 / r``; the smoother passes ``int L(f)^2 df``, the differentiator
    ``int (2 pi f)^2 L(f)^2 df``; ``delta = Mix Omega`` when only the rotor noise is given)."""
    from lpv_sysid.models.quadrotor import mixer

    f = np.linspace(0.0, 0.5 / dt, 4001)
    if cfg.derivatives.method == "fourier":
        L2 = deriv.fourier_gain(f, cfg.derivatives.f_cut, cfg.derivatives.taper) ** 2
    else:
        w = deriv._savgol_window(cfg.derivatives.window_s, dt, cfg.derivatives.polyorder, 10**6)
        L2 = deriv.savgol_gain(f, dt, w, cfg.derivatives.polyorder, deriv=0) ** 2
    g0 = float(np.trapz(L2, f))
    g1 = float(np.trapz((2 * np.pi * f) ** 2 * L2, f))
    var, dvar = np.zeros(12), np.zeros(12)
    noise = cfg.measurement_noise
    rotor = 0.0
    if "rotor" in noise:
        s, r = noise["rotor"]
        rotor = 2 * s**2 / (r or 1.0 / dt)
        mix = mixer(params.arm_length)
        var[8:12] = rotor * g0 * np.sum(mix**2, axis=1)
        dvar[8:12] = rotor * g1 * np.sum(mix**2, axis=1)
    for k, (s, r) in noise.items():
        if k != "rotor":
            j = STATE_NAMES.index(k)
            dens = 2 * s**2 / (r or 1.0 / dt)
            var[j], dvar[j] = dens * g0, dens * g1
    return var, dvar, rotor * g0


def _design_noise(labels, var: np.ndarray, dvar: np.ndarray) -> np.ndarray | None:
    """Per regressor column its measurement-error variance: ``x<j>`` the smoothed state's, ``aux``
    the rotor acceleration's (d delta_r / dt); commands, intercepts and the second-order
    nuisance columns are taken as exact (their noise enters only at second order)."""
    out = np.zeros(len(labels))
    for k, lab in enumerate(labels):
        if lab.startswith("x"):
            out[k] = var[int(lab[1:])]
        elif lab == "aux":
            out[k] = dvar[11]
    return out if np.any(out > 0) else None


@dataclass(frozen=True)
class VertexData:
    """Aligned arrays of one phase-1 maneuver on a uniform grid (from dataprep or a simulator)."""

    t: np.ndarray  # (N,) s
    x: np.ndarray  # (N, 12) STATE_NAMES
    u: np.ndarray  # (N, 4) INPUT_NAMES
    scheduling: np.ndarray  # (3,) commanded vertex v_d
    trim: tuple[float, float]  # [t_start, t_end) of the trim segment
    fit: tuple[float, float]  # [t_start, t_end) of the excitation (fit) segment
    name: str = ""
    u_eff: np.ndarray | None = None  # (N, 4) command after the ESC clip of Eq. (8) (None: from u)
    motor_identifiable: bool = True  # rotor speeds measured and u independent of them


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
    x0: np.ndarray  # operating point of the model (the identified equilibrium, taylor2)
    u0: np.ndarray
    fit: ee.Fit
    uncertain: unc.UncertainVertex
    r2_axes: dict
    validation: dict = field(default_factory=dict)
    x_flown: np.ndarray | None = None  # mean over the trim window (seed 0 Table 1)
    u_flown: np.ndarray | None = None
    xdot_flown: np.ndarray | None = (
        None  # identified model's derivative there (not an equilibrium)
    )
    motor: dict = field(default_factory=lambda: {"mode": "known"})  # how a_Omega, b_Omega entered

    def to_dict(self) -> dict:
        """One ``vertices`` entry of ``vertex_models.yaml`` (format ``@2``, io/formats.py).

        ``uncertain`` lists every identified element (aerodynamic rows and, when identified,
        the motor rows ``A[8:12, 8:12] = -a_Omega I``, ``B[8:12, :] = b_Omega I``) with its
        calibrated standard error and the interval ``nominal +/- k std`` of Eq. (22), ``k`` =
        ``meta.k_sigma`` (``meta.uncertainty.k_applied`` when raised by ``joint_alpha``).  The
        reduced polytope of :mod:`lpv_sysid.ident.uncertainty` is not stored; a consumer that
        wants it applies the reduction to these intervals.
        """
        fit = {"r2": {k: float(v) for k, v in self.r2_axes.items()}}
        for key in ("tic", "nrmse"):
            if key in self.validation:
                fit[key] = {k: float(v) for k, v in self.validation[key].items()}
        return {
            "scheduling": [float(v) for v in self.scheduling],
            "x0": [float(v) for v in self.x0],
            "u0": [float(v) for v in self.u0],
            "A": self.fit.A.tolist(),
            "B": self.fit.B.tolist(),
            "uncertain": [iv.to_dict() for iv in self.uncertain.intervals],
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


def _input(data: VertexData, params) -> np.ndarray:
    """The input the rotors act on: ``Mix clip(Mix^-1 u, 0, 1)`` (Eq. 8), unless given."""
    if data.u_eff is not None:
        return np.asarray(data.u_eff, dtype=float)
    from lpv_sysid.models.quadrotor import mixer

    mix = mixer(params.arm_length)
    return np.clip(np.asarray(data.u, dtype=float) @ np.linalg.inv(mix).T, 0.0, 1.0) @ mix.T


def pinned(
    e: np.ndarray,
    Om_start: np.ndarray,
    dt: float,
    params,
    a: float | None = None,
    b: float | None = None,
    speeds: bool = False,
):
    """(N, 4) fraction of the interval ``[t_k - dt/2, t_k + dt/2)`` during which rotor i is
    held at a speed limit, where Eq. (8) does not hold (the speed is clamped).

    Decided on the motor model's noise-free response to the command ``e`` (held over each
    interval), not on the noisy telemetry (a rotor decelerating through a noise band above
    ``omega_min`` would be taken as pinned), and exactly within an interval: with ``e`` held,
    ``Omega(t) = Omega_inf + (Omega_s - Omega_inf) exp(-a t)``, ``Omega_inf = b e / a``, reaches a
    limit after ``ln((Omega_s - Omega_inf) / (limit - Omega_inf)) / a``; a pinned rotor is released
    as soon as ``Omega_inf`` is back inside the limits.  The fraction, not a 0/1 flag per sample,
    keeps the gated regressors free of the half-sample bias at every entry into the pin.
    ``speeds``: also return the model's rotor speeds at the sample times (N, 4), the noise-free
    instrument of the motor regression.
    """
    import math

    a = params.a_omega if a is None else a
    b = params.b_omega if b is None else b
    lo, hi = params.omega_min, params.omega_max
    ad = math.exp(-a * dt)
    E = np.asarray(e, dtype=float)
    out = np.zeros(E.shape)
    start = np.zeros(E.shape)  # model speed at each interval start
    for i in range(E.shape[1]):
        Om = min(max(float(Om_start[i]), lo), hi)
        col = E[:, i].tolist()
        frac = out[:, i]
        st = start[:, i]
        for k, ek in enumerate(col):
            st[k] = Om
            inf = b * ek / a
            if (Om <= lo and inf <= lo) or (Om >= hi and inf >= hi):
                frac[k] = 1.0  # pinned through the interval
                continue
            nxt = inf + (Om - inf) * ad
            if nxt < lo or nxt > hi:  # reaches the limit inside the interval
                lim = lo if nxt < lo else hi
                t_hit = math.log((Om - inf) / (lim - inf)) / a
                frac[k] = max(0.0, 1.0 - t_hit / dt)
                Om = lim
            else:
                Om = nxt
    if not speeds:
        return out
    mid = 0.5 * (start + np.vstack([start[1:], start[-1:]]))  # at t_k, mid-interval
    return out, mid


def motor_response(u: np.ndarray, delta_start: np.ndarray, dt: float, params) -> np.ndarray:
    """Virtual actuators of the motor model Eq. (8), ``delta' = -a_Omega delta + b_Omega u``,
    driven by ``u`` (N, 4) from ``delta_start`` (exact for an input held over each step)."""
    from scipy.signal import lfilter

    ad = np.exp(-params.a_omega * dt)
    g = (1.0 - ad) * params.b_omega / params.a_omega
    u = np.asarray(u, dtype=float)
    zi = np.asarray(delta_start, dtype=float)[None, :]
    return lfilter([0.0, g], [1.0, -ad], u, axis=0, zi=zi)[0]


def _smooth_keep(
    x: np.ndarray, dt: float, cfg: IdentificationConfig, keep
) -> tuple[np.ndarray, np.ndarray]:
    xs, xd = deriv.smooth_and_differentiate(x, dt, cfg.derivatives)
    return xs[keep], xd[keep]


def _motor_design(
    data: VertexData,
    cfg: IdentificationConfig,
    params,
    full,
    keep,
    x0,
    u0,
    u_in: np.ndarray,
    max_delay: float = 0.05,
    rotor_var: float = 0.0,
):
    """The motor model Eq. (8) per rotor, ``Omega_i' = g_i(t) [theta_a (Omega_i - Omega_i0)
    + theta_b (e_i(t - tau) - e_i0) + c_i]`` with ``e = Mix^-1 u`` after the ESC clip, stacked
    over the four rotors (one ``theta_a = -a_Omega``, ``theta_b = b_Omega``, seed 0 Eq. 15).

    ``g_i = 0`` while rotor i is :func:`pinned` at a speed limit (there ``Omega_i' = 0``): the
    gated regressors are formed *before* smoothing, so the filtered equation holds at every
    sample and nothing has to be cut out.  ``c_i`` absorbs the offset of the flown mean from
    rest; ``tau`` is the command-to-rotor latency (ESC, telemetry, command hold; with
    ``a_Omega ~ 12 /s`` 0.1 ms already biases ``a, b`` by ~0.1 %, more than their standard
    error on a 30 s record), found by Gauss-Newton (the regressor of a latency increment is
    ``-b g e'``) and kept as the column ``delay`` (increment ~ 0 at convergence) so that its
    uncertainty enters the covariance.  ``rotor_var``: variance of the smoothed rotor-speed
    telemetry noise (errors in variables of the ``a`` column, bias-compensated in the latency
    search too).  Returns ``(RowDesign with stack=4, tau)`` or ``(None, reason)`` when the data
    do not allow it.
    """
    from scipy.interpolate import CubicSpline

    from lpv_sysid.models.quadrotor import mixer

    if cfg.motor == "known":
        return None, "configured as known"
    if not data.motor_identifiable:
        return None, "rotor speeds not measured independently of the command"
    dt = float(np.median(np.diff(data.t)))
    mi = np.linalg.inv(mixer(params.arm_length))
    Om = np.asarray(data.x, dtype=float)[full, 8:12] @ mi.T
    e = np.asarray(u_in, dtype=float)[full] @ mi.T
    Om0, e0 = mi @ x0[8:12], mi @ u0
    t = np.asarray(data.t, dtype=float)[full]
    spline = CubicSpline(t, e, axis=0)
    n = int(np.arange(full.size)[keep].size)
    y = np.concatenate([_smooth_keep(Om[:, i], dt, cfg, keep)[1] for i in range(4)])
    ab = (params.a_omega, params.b_omega)

    def gated(ab):
        frac, Om_model = pinned(e, Om[0], dt, params, *ab, speeds=True)
        g = 1.0 - frac
        Xa = np.concatenate(
            [_smooth_keep(g[:, i] * (Om[:, i] - Om0[i]), dt, cfg, keep)[0] for i in range(4)]
        )
        # instrument of the measured speeds: the model's own, uncorrelated with telemetry noise
        Za = np.concatenate(
            [_smooth_keep(g[:, i] * (Om_model[:, i] - Om0[i]), dt, cfg, keep)[0] for i in range(4)]
        )
        Xc = np.zeros((4 * n, 4))
        for i in range(4):
            Xc[i * n : (i + 1) * n, i] = _smooth_keep(g[:, i], dt, cfg, keep)[0]
        return g, (Xa, Za), Xc

    def inputs(tau):
        es, ed = spline(t - tau), spline(t - tau, 1)
        Xb = np.concatenate(
            [_smooth_keep(g[:, i] * (es[:, i] - e0[i]), dt, cfg, keep)[0] for i in range(4)]
        )
        Xd = np.concatenate([_smooth_keep(g[:, i] * ed[:, i], dt, cfg, keep)[0] for i in range(4)])
        return Xb, Xd

    def fit(Xa, Xc, tau, b_est):
        """Gauss-Newton on the latency for a fixed gate: ``(theta, tau, b)``."""
        th = None
        for _ in range(12):
            Xb, Xd = inputs(tau)
            H = np.column_stack([Xa[0], Xb, Xc] + ([-b_est * Xd] if b_est is not None else []))
            if cfg.motor_instrument:
                Z = H.copy()
                Z[:, 0] = Xa[1]
                th = np.linalg.solve(Z.T @ H, Z.T @ y)
            elif rotor_var > 0:
                M = H.T @ H
                M[0, 0] -= H.shape[0] * rotor_var  # bias-compensated (errors in variables)
                th = np.linalg.solve(M, H.T @ y)
            else:
                th = np.linalg.lstsq(H, y, rcond=None)[0]
            b_est = float(th[1])
            step = float(th[6]) if th.size > 6 else 0.0
            tau = float(np.clip(tau + step, -max_delay, max_delay))
            if th.size > 6 and abs(step) < 1e-8:
                break
        return th, tau, b_est

    g, Xa, Xc = gated(ab)
    tau, b_est = 0.0, None
    for _ in range(8):  # the pinned intervals of the identified motors (a fixed point)
        th, tau, b_est = fit(Xa, Xc, tau, b_est)
        if not np.any(g == 0) or not th[0] < 0 < th[1]:
            break
        g_new, Xa_new, Xc_new = gated((-float(th[0]), b_est))
        if np.array_equal(g_new, g):
            break
        g, Xa, Xc = g_new, Xa_new, Xc_new
    assert b_est is not None  # the loop above fits at least once
    held = float(np.max(1.0 - np.mean(g[keep], axis=0)))
    if held > cfg.motor_max_pinned:
        return None, f"a rotor at its speed limit {100 * held:.1f} % of the time"
    if abs(tau) >= max_delay:
        return None, f"latency at the search bound {max_delay:g} s"
    Xb, Xd = inputs(tau)
    H = np.column_stack([Xa[0], Xb, Xc, -b_est * Xd])
    labels = ("a", "b", "bias0", "bias1", "bias2", "bias3", "delay")
    if cfg.motor_instrument:
        Z = H.copy()
        Z[:, 0] = Xa[1]
        return ee.RowDesign(8, y, H, (), (), labels, stack=4, Z=Z), tau
    noise = np.array([rotor_var] + [0.0] * 6) if rotor_var > 0 else None
    return ee.RowDesign(8, y, H, (), (), labels, stack=4, noise_var=noise), tau


def _fit_taylor2(
    data: VertexData, x0, u0, known: KnownModel, cfg: IdentificationConfig, motor_prior=None
):
    """Equation error with the known part nonlinear and second-order nuisance regressors
    (:mod:`lpv_sysid.ident.taylor`), re-expanded about the identified equilibrium.

    Returns ``(Fit, x_e, u_e, xdot_flown, motor)``.  In the moment rows the rotor reaction
    torque ``J_z delta_r'`` is regressed on the *measured* rotor acceleration (``aux``), so the
    rows stay exact when a rotor saturates; its linearisation ``J_z (-a_Omega d delta_r +
    b_Omega du_r)`` enters ``A[., dr]``, ``B[., ur]`` through the (identified) delta_r row.
    """
    params = _params(cfg)
    rows = list(taylor.ROWS)
    x0 = np.asarray(x0, dtype=float)
    widths = {}

    def nonlin(x_raw):
        kr = taylor.known_rigid_body(x_raw, params)
        rem = taylor.remainders(x0, x_raw - x0, params)
        widths.update({a: r.shape[1] for a, r in rem.items()})
        return np.concatenate(
            [kr] + [rem[a] for a in taylor.FORCE_AXES + taylor.MOMENT_AXES], axis=1
        )

    dt, full, keep = _fit_indices(data, cfg)
    u_in = _input(data, params)
    _, xdot, dx, du, nl_s = prepare(data, cfg, x0, u0, nonlin, u=u_in)
    x0 = np.asarray(x0, dtype=float)
    u0 = np.asarray(u0, dtype=float)
    rem, off = {}, 6
    for a in taylor.FORCE_AXES + taylor.MOMENT_AXES:
        rem[a] = nl_s[:, off : off + widths[a]]
        off += widths[a]
    iv = None
    if cfg.instruments:
        # the same regressors with the measured rotor speeds replaced by the motor model's response
        # to the command (Eq. 8): uncorrelated with telemetry noise and aliasing (errors in
        # variables)
        x_iv = np.array(data.x, dtype=float)
        x_iv[:, 8:12] = motor_response(u_in, x_iv[0, 8:12], dt, params)
        _, _, dx_iv, _, nl_iv = prepare(
            dataclasses.replace(data, x=x_iv), cfg, x0, u0, nonlin, u=u_in
        )
        rem_iv, off = {}, 6
        for a in taylor.FORCE_AXES + taylor.MOMENT_AXES:
            rem_iv[a] = nl_iv[:, off : off + widths[a]]
            off += widths[a]
        iv = (dx_iv, rem_iv)
    nuis_idx = taylor.nuisance_index(rem, params)
    nvar, ndvar, rotor_var = regressor_noise_var(cfg, params, dt)
    designs, nuis_kept = [], {}
    n = dx.shape[0]
    for k, row in enumerate(rows):
        ja = [int(j) for j in np.nonzero(known.maskA[row])[0]]
        kb = [int(c) for c in np.nonzero(known.maskB[row])[0]]
        y = xdot[:, row] - nl_s[:, k]
        H = [dx[:, ja]]
        labels = [f"x{j}" for j in ja]
        aux = 3 in kb  # J_z delta_r' (seed 0 Eq. 6f): the measured rotor acceleration
        kb = [c for c in kb if c != 3]
        H.append(du[:, kb])
        labels += [f"u{c}" for c in kb]
        H.append(np.ones((n, 1)))
        labels.append("bias")
        if aux:
            H.append(xdot[:, 11:12])
            labels.append("aux")
        Hm = np.concatenate(H, axis=1)
        Z = None
        if iv is not None:
            Z = Hm.copy()
            Z[:, : len(ja)] = iv[0][:, ja]
        cols = nuis_idx[row]
        if cols:
            E = np.stack([rem[a][:, c] for a, c in cols], axis=1)
            Hm, chosen = ee._append_independent(Hm, E)
            labels += [f"nuisance{c}" for c in chosen]
            if iv is not None and Z is not None:
                Z = np.concatenate(
                    [Z] + [iv[1][cols[c][0]][:, cols[c][1] : cols[c][1] + 1] for c in chosen],
                    axis=1,
                )
        designs.append(
            ee.RowDesign(
                row,
                y,
                Hm,
                tuple(ja),
                tuple(kb),
                tuple(labels),
                Z=Z,
                noise_var=None if Z is not None else _design_noise(labels, nvar, ndvar),
            )
        )
        nuis_kept[row] = cols
    motor_d, info = _motor_design(data, cfg, params, full, keep, x0, u0, u_in, rotor_var=rotor_var)
    fits, joint, dof = ee.solve_rows(
        designs + ([motor_d] if motor_d is not None else []), cfg.covariance, dt
    )
    if joint is None:  # solve_rows has no covariance only without designs
        raise ConfigError("vertex identification: no state rows to fit")
    motor = (
        {"mode": "identified", "delay": info}
        if motor_d is not None
        else {"mode": "known", "reason": info}
    )
    if motor_d is None and motor_prior is not None:
        # a_Omega, b_Omega not identifiable here: uncertain with the prior (seed 0 Sec. IV values)
        (a, sa), (b, sb) = motor_prior
        P = joint.shape[0]
        prior = ee.RowFit(
            8,
            (),
            (),
            np.array([-a, b]),
            np.diag([sa**2, sb**2]),
            np.diag([sa**2, sb**2]),
            np.diag([sa**2, sb**2]),
            0.0,
            float("nan"),
            0,
            0,
            taylor.MOTOR_LABELS,
            P,
            dof,
        )
        fits = list(fits) + [prior]
        joint = np.block([[joint, np.zeros((P, 2))], [np.zeros((2, P)), prior.cov]])
        motor = {"mode": "prior", "reason": info, "a_omega": [a, sa], "b_omega": [b, sb]}
    maskA, maskB = known.maskA.copy(), known.maskB.copy()
    if motor["mode"] != "known":
        for j in range(4):
            maskA[8 + j, 8 + j] = True
            maskB[8 + j, j] = True
    model = taylor.IdentifiedModel(x0, u0, fits, nuis_kept, params)
    theta = np.concatenate([rf.theta for rf in fits])
    psi_dot = float((np.sin(x0[0]) * x0[6] + np.cos(x0[0]) * x0[7]) / np.cos(x0[1]))
    if cfg.equilibrium:
        rx = taylor.reexpand(model, theta, joint, x0[2:5], psi_dot, maskA, maskB)
        x_e, u_e, A, B, sA, sB, flown = (
            rx.x_e,
            rx.u_e,
            rx.A,
            rx.B,
            rx.std_A,
            rx.std_B,
            rx.xdot_flown,
        )
        log.debug(
            "%s: equilibrium re-expansion in %d Newton steps, shift %s",
            data.name,
            rx.iterations,
            np.round(x_e - x0, 4).tolist(),
        )
    else:
        flown = np.concatenate(
            [
                [0.0, 0.0],
                model.residual(np.concatenate([x0[:2], x0[8:12], u0]), theta, x0[2:5], psi_dot),
            ]
        )
        A, B = model.jacobians(x0, u0, theta)
        x_e, u_e = x0, np.asarray(u0, dtype=float)
        sA, sB = _direct_std(model, theta, joint, x0, u0, maskA, maskB)
    f = ee.Fit(A, B, sA, sB, maskA, maskB, tuple(fits), joint, dof, cfg.covariance.method)
    return f, x_e, u_e, flown, motor


def _direct_std(model, theta, cov, x, u, maskA, maskB):
    """Delta-method standard errors of the Jacobians at a fixed point (no re-expansion)."""
    idx = [
        (m, i, int(j))
        for i in range(maskA.shape[0])
        for m, msk in (("A", maskA), ("B", maskB))
        for j in np.nonzero(msk[i])[0]
    ]

    def elems(th):
        Aw, Bw = model.jacobians(x, u, th)
        return np.array([(Aw if m == "A" else Bw)[i, j] for m, i, j in idx])

    D = np.zeros((len(idx), theta.size))
    for p in range(theta.size):
        e = np.zeros(theta.size)
        e[p] = max(abs(theta[p]), 1e-12) * 1e-6
        D[:, p] = (elems(theta + e) - elems(theta - e)) / (2 * e[p])
    std = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", D, cov, D), 0.0))
    sA, sB = np.zeros(maskA.shape), np.zeros(maskB.shape)
    for (m, i, j), s_ in zip(idx, std):
        (sA if m == "A" else sB)[i, j] = s_
    return sA, sB


def _segment(t: np.ndarray, a: float, b: float, what: str, min_len: float) -> np.ndarray:
    idx = np.nonzero((t >= a) & (t < b))[0]
    if idx.size < 2 or (t[idx[-1]] - t[idx[0]]) < min_len:
        have = 0.0 if idx.size < 2 else t[idx[-1]] - t[idx[0]]
        raise ConfigError(
            f"{what}: segment [{a:.2f}, {b:.2f}) s has {have:.2f} s of data, "
            f"need at least {min_len:.2f} s"
        )
    return idx


def trim_window(trim: tuple[float, float], cfg: IdentificationConfig) -> tuple[float, float]:
    """Averaging window for x0, u0: the last ``trim_average`` s, at most half the trim segment."""
    a, b = trim
    return b - min(cfg.trim_average, 0.5 * (b - a)), b


def equilibrium(data: VertexData, cfg: IdentificationConfig) -> tuple[np.ndarray, np.ndarray]:
    """``x0, u0`` = means over the last ``trim_average`` seconds (at most half) of the trim
    segment (the vehicle may still be converging to the new reference at its start), seed 0
    Table 1.  This flown mean is *not* an equilibrium (the dynamics are nonlinear and the
    vehicle fluctuates about it); ``taylor2`` identification re-expands about the equilibrium."""
    a, b = trim_window(data.trim, cfg)
    idx = _segment(data.t, a, b, f"{data.name or 'vertex'} trim", min(0.5, b - a))
    return data.x[idx].mean(axis=0), data.u[idx].mean(axis=0)


def _fit_indices(data: VertexData, cfg: IdentificationConfig):
    """``(dt, full, keep)``: sample indices differentiated (a little more than the fit segment,
    FFT-friendly) and the slice of them kept after cutting the smoother's edges."""
    t = np.asarray(data.t, dtype=float)
    dt = float(np.median(np.diff(t)))
    if not np.allclose(np.diff(t), dt, rtol=1e-6, atol=1e-9):
        raise ConfigError(f"{data.name or 'vertex'}: samples must be on a uniform grid")
    a, b = data.fit
    full = _segment(
        t, a, b, f"{data.name or 'vertex'} excitation", cfg.min_fit_duration + 2 * cfg.edge
    )
    if cfg.derivatives.method == "fourier":
        full = full[: deriv.fast_length(full.size)]  # FFT-friendly length, drops < 2 % (n > 2000)
    n_edge = int(round(cfg.edge / dt))
    return dt, full, slice(n_edge, full.size - n_edge)


def prepare(
    data: VertexData,
    cfg: IdentificationConfig,
    x0: np.ndarray,
    u0: np.ndarray,
    nonlinear=None,
    u: np.ndarray | None = None,
):
    """Smoothed perturbations and derivatives over the fit segment: ``(t, dxdot, dx, du)``.

    ``nonlinear(x_raw) -> (N, k)``: optional function of the *raw* states whose value is
    smoothed with the same filter and appended to the return tuple.  Nonlinear regressors
    must be computed before smoothing - ``L[r(x)]``, not ``r(L[x])`` - so that the filtered
    equation ``L[x'] = A L[x] + L[r(x)]`` still holds exactly.  ``u``: the input to use
    instead of ``data.u`` (e.g. after the ESC clip).
    """
    dt, full, keep = _fit_indices(data, cfg)
    xs, xdot = deriv.smooth_and_differentiate(data.x[full], dt, cfg.derivatives)
    us = deriv.smooth((data.u if u is None else u)[full], dt, cfg.derivatives)
    out: tuple[np.ndarray, ...] = (
        np.asarray(data.t, dtype=float)[full][keep],
        xdot[keep],
        xs[keep] - x0,
        us[keep] - u0,
    )
    if nonlinear is not None:
        out = out + (deriv.smooth(nonlinear(data.x[full]), dt, cfg.derivatives)[keep],)
    return out


def identify_vertex(
    data: VertexData, cfg: IdentificationConfig, known: KnownModel | None = None, motor_prior=None
) -> VertexResult:
    """Full pipeline for one vertex (see module docstring).  ``motor_prior``:
    ``((a_Omega, std), (b_Omega, std))`` used when this maneuver cannot identify them."""
    x = np.asarray(data.x, dtype=float)
    u = np.asarray(data.u, dtype=float)
    if (
        x.ndim != 2
        or x.shape[1] != 12
        or u.ndim != 2
        or u.shape[1] != 4
        or x.shape[0] != u.shape[0]
        or x.shape[0] != np.asarray(data.t).size
    ):
        raise ConfigError(
            f"{data.name}: need t (N,), x (N, 12), u (N, 4); got {np.shape(data.t)}, "
            f"{x.shape}, {u.shape}"
        )
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(u))):
        raise ConfigError(f"{data.name}: states or inputs contain NaN/inf")
    x0, u0 = equilibrium(data, cfg)
    if known is None:
        known = known_from_quadrotor(x0, cfg.quadrotor)
    x_flown, u_flown, flown, motor = x0, u0, None, {"mode": "known", "reason": "model appendix_b"}
    if cfg.model == "taylor2":
        if motor_prior is None and cfg.motor_std is not None:
            p = _params(cfg)
            motor_prior = ((p.a_omega, cfg.motor_std[0]), (p.b_omega, cfg.motor_std[1]))
        fit, x0, u0, flown, motor = _fit_taylor2(data, x0, u0, known, cfg, motor_prior)
    else:
        _, xdot, dx, du = prepare(data, cfg, x0, u0, u=_input(data, _params(cfg)))
        dt = float(np.median(np.diff(data.t)))
        var, dvar, _ = regressor_noise_var(cfg, _params(cfg), dt)
        designs, A0, B0 = ee.row_designs(
            xdot, dx, du, known.A, known.B, known.maskA, known.maskB, cfg.intercept
        )
        designs = [
            dataclasses.replace(d, noise_var=_design_noise(d.labels, var, dvar)) for d in designs
        ]
        fits, joint, dof = ee.solve_rows(designs, cfg.covariance, dt)
        fit = ee.assemble(
            fits, A0, B0, known.maskA, known.maskB, joint, dof, cfg.covariance.method
        )
    uv = unc.build(fit.A, fit.B, fit.elements(), cfg.uncertainty, dof=fit.dof)
    r2 = {a: fit.r2.get(i, float("nan")) for a, i in zip(metrics.AXES, metrics.AXIS_INDEX)}
    log.info(
        "%s: %d identified elements, M=%d uncertain systems", data.name, len(uv.intervals), uv.M
    )
    return VertexResult(
        data.name,
        np.asarray(data.scheduling, dtype=float),
        x0,
        u0,
        fit,
        uv,
        r2,
        x_flown=x_flown,
        u_flown=u_flown,
        xdot_flown=flown,
        motor=motor,
    )


def pooled_motor(
    results: Sequence[VertexResult],
) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """``((a_Omega, std), (b_Omega, std))`` over the vertices that identified them: the mean,
    with a std covering both the single-vertex errors and the scatter between vertices (the
    constants may change with the flight condition, e.g. battery voltage)."""
    vals = []
    for r in results:
        if r.motor.get("mode") == "identified":
            a, sa = -r.fit.A[8, 8], r.fit.std_A[8, 8]
            b, sb = r.fit.B[8, 0], r.fit.std_B[8, 0]
            vals.append((a, sa, b, sb))
    if not vals:
        return None
    v = np.array(vals)
    out = []
    for m, s_ in ((v[:, 0], v[:, 1]), (v[:, 2], v[:, 3])):
        spread = float(np.std(m, ddof=1)) if m.size > 1 else 0.0
        out.append((float(np.mean(m)), float(np.sqrt(np.mean(s_**2) + spread**2))))
    return out[0], out[1]


def identify_vertices(
    datas: Sequence[VertexData], cfg: IdentificationConfig
) -> list[VertexResult]:
    """:func:`identify_vertex` for every maneuver; where a maneuver cannot identify the motor
    constants (a rotor pinned at a speed limit longer than ``motor_max_pinned``, no independent
    rotor-speed measurement), they enter as uncertain with the :func:`pooled_motor` estimate of
    the maneuvers that did.  When none did, every maneuver is tried again with the pinned
    rotors only gated out (no ``motor_max_pinned`` limit) and all use the pooled estimate of
    those, whose spread between maneuvers then enters its standard error."""
    results = [identify_vertex(d, cfg) for d in datas]
    if cfg.model != "taylor2" or cfg.motor != "identify":
        return results
    prior = pooled_motor(results)
    redo = [r.motor.get("mode") != "identified" for r in results]
    if prior is None:
        relaxed = dataclasses.replace(cfg, motor_max_pinned=1.0)
        tried = [identify_vertex(d, relaxed) for d in datas]
        prior = pooled_motor(tried)
        redo = [True] * len(datas)
    if prior is None:
        return results
    out = []
    for d, r, again in zip(datas, results, redo):
        if again:
            log.debug(
                "%s: a_Omega, b_Omega not identifiable (%s): pooled estimate of the maneuvers",
                d.name,
                r.motor.get("reason"),
            )
            reason = r.motor.get("reason", "")
            r = identify_vertex(d, dataclasses.replace(cfg, motor="known"), motor_prior=prior)
            r.motor["reason"] = f"{reason}; pooled estimate of the maneuvers that identified them"
        out.append(r)
    return out


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
            raise ConfigError(
                f"need exactly one identified maneuver at vertex {c.tolist()}, found {len(hits)}"
            )
        order.append(hits[0])
    return order


def vertex_models_dict(
    results: Sequence[VertexResult], cfg: IdentificationConfig, validation: dict | None = None
) -> dict:
    """The ``vertex_models.yaml`` document (format ``@2``, io/formats.py), vertices in box order.

    ``meta`` records how the file was made: the method, ``k_sigma`` of Eq. (22) (and the
    ``k`` applied per vertex when ``joint_alpha`` raises it), how the standard errors were
    estimated (covariance method, Student-t degrees of freedom and the resulting widening of
    the stored ``std``), how the motor constants entered, the operating point (the flown trim
    mean, the identified model's derivative there and the equilibrium it was re-expanded
    about), the reduction of Eq. (23) the identification would apply (``M_i``, absorption
    factor; the file itself stores the whole box), and the independent validation (Table 3).
    """
    from lpv_sysid.ident.equation_error import t_factor
    from lpv_sysid.io.formats import MODELS_FORMAT

    order = vertex_order(results, cfg)
    ks = [unc.applied_k(cfg.uncertainty, len(results[k].uncertain.intervals)) for k in order]
    dofs = [results[k].fit.dof for k in order]

    def vec(a):
        return None if a is None else [float(v) for v in a]

    meta = {
        "generator": "lpv_sysid.ident (seed 0 Sec. IV, Appendix B)",
        "model": cfg.model,
        "derivatives": dataclasses.asdict(cfg.derivatives),
        "k_sigma": cfg.uncertainty.k_sigma,
        "joint_alpha": cfg.uncertainty.joint_alpha,
        "intervals": "every identified element, lower/upper = nominal -/+ k std (Eq. 22)",
        "std": {
            "method": results[order[0]].fit.cov_method,
            "meaning": "standard error widened so that nominal +/- k std keeps the normal "
            "coverage 2 Phi(k) - 1 under Student-t(dof) errors",
            "dof": [None if d is None else float(d) for d in dofs],
            "t_factor": [t_factor(k, d) for k, d in zip(ks, dofs)],
        },
        "motor": [dict(results[k].motor) for k in order],
        "operating_point": {
            "x0": "equilibrium of the identified model at the flown velocity"
            if cfg.model == "taylor2" and cfg.equilibrium
            else "mean over the trim window (flown)",
            "x_flown": [vec(results[k].x_flown) for k in order],
            "u_flown": [vec(results[k].u_flown) for k in order],
            "xdot_flown": [vec(results[k].xdot_flown) for k in order],
        },
        "uncertainty": {
            "method": cfg.uncertainty.method,
            "p_max": cfg.uncertainty.p_max,
            "k_applied": ks,
            "M": [results[k].uncertain.M for k in order],
            "inflation": [results[k].uncertain.inflation for k in order],
        },
    }
    if validation:
        meta["validation"] = {
            "maneuver": validation.get("name", ""),
            "tic": {k: float(v) for k, v in validation["tic"].items()},
            "nrmse": {k: float(v) for k, v in validation["nrmse"].items()},
        }
    return {
        "format": MODELS_FORMAT,
        "time": "continuous",
        "states": [{"name": n, "unit": s} for n, s in zip(STATE_NAMES, STATE_UNITS)],
        "inputs": [{"name": n, "unit": s} for n, s in zip(INPUT_NAMES, INPUT_UNITS)],
        "scheduling": {
            "names": list(SCHEDULING_NAMES),
            "min": list(cfg.vmin),
            "max": list(cfg.vmax),
        },
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
