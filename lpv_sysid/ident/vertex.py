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
    max_lag: int | None = None         # residual autocorrelation lags (covariance.method residual_acf)
    intercept: bool = True             # per-row bias term (Klein & Morelli), see equation_error
    model: str = "taylor2"             # "taylor2" (ident.taylor) or "appendix_b" (plain seed 0 App. B)
    covariance: ee.CovarianceConfig = field(default_factory=ee.CovarianceConfig)
    equilibrium: bool = True           # taylor2: re-expand about the identified equilibrium (Eq. 13)
    motor: str = "identify"            # a_Omega, b_Omega: "identify" (motor rows, Eq. 8) or "known"
    motor_limit_margin: float = 15.0   # rad/s: samples this close to omega_min/max are not used ...
    motor_pad: float = 0.5             # s: ... nor this long around them (smoother support)
    instruments: bool = True           # taylor2: rotor speeds instrumented by the motor model (EIV)
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
        for key in ("trim_duration", "trim_average", "edge", "min_fit_duration", "sample_rate",
                    "excitation_threshold", "motor_limit_margin", "motor_pad"):
            if key in d:
                v = d.pop(key)
                if not is_finite_number(v) or v < 0:
                    raise ConfigError(f"identification.{key} must be a finite number >= 0, got {v!r}")
                if key == "sample_rate" and v > MAX_SAMPLE_RATE:     # the common grid is allocated from it
                    raise ConfigError(f"identification.sample_rate: {v:g} Hz exceeds the limit of "
                                      f"{MAX_SAMPLE_RATE:g} Hz")
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
        for key in ("intercept", "equilibrium", "instruments"):
            if key in d:
                v = d.pop(key)
                if not isinstance(v, bool):
                    raise ConfigError(f"identification.{key} must be true or false, got {v!r}")
                kw[key] = v
        if "motor" in d:
            v = d.pop("motor")
            if v not in ("identify", "known"):
                raise ConfigError(f"identification.motor must be 'identify' or 'known', got {v!r}")
            kw["motor"] = v
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
    u_eff: np.ndarray | None = None   # (N, 4) command after the ESC clip of Eq. (8) (None: from u)
    motor_identifiable: bool = True   # rotor speeds measured and u independent of them


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
    x0: np.ndarray               # operating point of the model (the identified equilibrium, taylor2)
    u0: np.ndarray
    fit: ee.Fit
    uncertain: unc.UncertainVertex
    r2_axes: dict
    validation: dict = field(default_factory=dict)
    x_flown: np.ndarray | None = None     # mean over the trim window (seed 0 Table 1)
    u_flown: np.ndarray | None = None
    xdot_flown: np.ndarray | None = None  # identified model's derivative there (not an equilibrium)
    motor: str = "known"                  # how a_Omega, b_Omega entered: "identified" or "known"

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


def motor_samples(data: VertexData, cfg: IdentificationConfig, params, idx: np.ndarray) -> np.ndarray:
    """Samples ``idx`` usable for the motor rows: every rotor speed at least
    ``motor_limit_margin`` from ``[omega_min, omega_max]`` (where Eq. 8 holds: at the limits
    the speed is clamped), ``motor_pad`` seconds around such events excluded as well."""
    from lpv_sysid.models.quadrotor import mixer

    Om = np.asarray(data.x, dtype=float)[:, 8:12] @ np.linalg.inv(mixer(params.arm_length)).T
    m = cfg.motor_limit_margin
    bad = np.any((Om < params.omega_min + m) | (Om > params.omega_max - m), axis=1)
    dt = float(np.median(np.diff(data.t)))
    pad = int(round(cfg.motor_pad / dt))
    if pad > 0 and bad.any():
        bad = np.convolve(bad.astype(float), np.ones(2 * pad + 1), mode="same") > 0
    return ~bad[idx]


def motor_response(u: np.ndarray, delta_start: np.ndarray, dt: float, params) -> np.ndarray:
    """Virtual actuators of the motor model Eq. (8), ``delta' = -a_Omega delta + b_Omega u``,
    driven by ``u`` (N, 4) from ``delta_start`` (exact for an input held over each step)."""
    from scipy.signal import lfilter

    ad = np.exp(-params.a_omega * dt)
    g = (1.0 - ad) * params.b_omega / params.a_omega
    u = np.asarray(u, dtype=float)
    zi = np.asarray(delta_start, dtype=float)[None, :]
    return lfilter([0.0, g], [1.0, -ad], u, axis=0, zi=zi)[0]


def _shifted_input(t: np.ndarray, u: np.ndarray, tau: float, cfg: IdentificationConfig):
    """``u(t - tau)`` (cubic spline of the raw samples) smoothed and differentiated with the
    filter of the states: ``(L[u(t - tau)], d/dt L[u(t - tau)])``."""
    from scipy.interpolate import CubicSpline

    us = CubicSpline(t, u, axis=0)(t - tau) if tau != 0.0 else u
    return deriv.smooth_and_differentiate(us, float(t[1] - t[0]), cfg.derivatives)


def _motor_designs(data: VertexData, cfg: IdentificationConfig, params, full, keep, xdot, dx,
                   u_in: np.ndarray, u0: np.ndarray, dx_iv: np.ndarray | None = None,
                   max_delay: float = 0.05) -> tuple[list, str, list]:
    """Rows 8-11, ``delta_j' = -a_Omega d(delta_j) + b_Omega du_j(t - tau_j) + c_j`` (Eq. 8 in
    virtual actuators), one ``(a, b, c, tau)`` per row.

    ``tau_j`` is the command-to-rotor latency (ESC, telemetry, the hold of the command): with
    ``a_Omega ~ 12 /s`` a latency of 0.1 ms already biases ``a, b`` by ~0.1 %, more than their
    standard error on a 30 s record.  It is found by Gauss-Newton (the regressor of a delay
    increment is ``-b du_j'``) and kept in the design as the column ``delay`` (its increment
    ~ 0 at convergence) so that its uncertainty enters the covariance of ``a, b``.  Returns
    ``(designs, "identified" | "known", delays)``; none when the motor model is taken as known.
    """
    if cfg.motor == "known" or not data.motor_identifiable:
        return [], "known", []
    dt = float(np.median(np.diff(data.t)))
    use = motor_samples(data, cfg, params, full[keep])
    if use.sum() * dt < cfg.min_fit_duration:
        log.warning("%s: only %.1f s away from the rotor-speed limits: a_Omega, b_Omega taken as known",
                    data.name, use.sum() * dt)
        return [], "known", []
    t = np.asarray(data.t, dtype=float)[full]
    out, delays = [], []
    n = dx.shape[0]
    for j in range(4):
        row = 8 + j
        raw = np.asarray(u_in, dtype=float)[full, j]
        tau, b_est, H = 0.0, None, None
        for _ in range(12):
            us, ud = _shifted_input(t, raw, tau, cfg)
            cols = [dx[:, row], us[keep] - u0[j], np.ones(n)]
            if b_est is not None:
                cols.append(-b_est * ud[keep])
            H = np.stack(cols, axis=1)
            th = np.linalg.lstsq(H[use], xdot[use, row], rcond=None)[0]
            b_est = th[1]
            step = th[3] if th.size > 3 else 0.0
            tau = float(np.clip(tau + step, -max_delay, max_delay))
            if th.size > 3 and abs(step) < 1e-8:
                break
        if abs(tau) >= max_delay:
            log.warning("%s: motor row %d latency at the search bound %.3f s: a_Omega, b_Omega taken as known",
                        data.name, row, max_delay)
            return [], "known", []
        us, ud = _shifted_input(t, raw, tau, cfg)
        H = np.stack([dx[:, row], us[keep] - u0[j], np.ones(n), -b_est * ud[keep]], axis=1)
        Z = None
        if dx_iv is not None:
            Z = H.copy()
            Z[:, 0] = dx_iv[:, row]
        out.append(ee.RowDesign(row, xdot[:, row], H, (row,), (j,), (f"x{row}", f"u{j}", "bias", "delay"), use,
                                Z))
        delays.append(tau)
    return out, "identified", delays


def _fit_taylor2(data: VertexData, x0, u0, known: KnownModel, cfg: IdentificationConfig):
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
        return np.concatenate([kr] + [rem[a] for a in taylor.FORCE_AXES + taylor.MOMENT_AXES], axis=1)

    dt, full, keep = _fit_indices(data, cfg)
    u_in = _input(data, params)
    _, xdot, dx, du, nl_s = prepare(data, cfg, x0, u0, nonlin, u=u_in)
    rem, off = {}, 6
    for a in taylor.FORCE_AXES + taylor.MOMENT_AXES:
        rem[a] = nl_s[:, off: off + widths[a]]
        off += widths[a]
    iv = None
    if cfg.instruments:
        # the same regressors with the measured rotor speeds replaced by the motor model's response
        # to the command (Eq. 8): uncorrelated with telemetry noise and aliasing (errors in variables)
        x_iv = np.array(data.x, dtype=float)
        x_iv[:, 8:12] = motor_response(u_in, x_iv[0, 8:12], dt, params)
        _, _, dx_iv, _, nl_iv = prepare(dataclasses.replace(data, x=x_iv), cfg, x0, u0, nonlin, u=u_in)
        rem_iv, off = {}, 6
        for a in taylor.FORCE_AXES + taylor.MOMENT_AXES:
            rem_iv[a] = nl_iv[:, off: off + widths[a]]
            off += widths[a]
        iv = (dx_iv, rem_iv)
    nuis_idx = taylor.nuisance_index(rem, params)
    designs, nuis_kept = [], {}
    n = dx.shape[0]
    for k, row in enumerate(rows):
        ja = [int(j) for j in np.nonzero(known.maskA[row])[0]]
        kb = [int(c) for c in np.nonzero(known.maskB[row])[0]]
        y = xdot[:, row] - nl_s[:, k]
        H = [dx[:, ja]]
        labels = [f"x{j}" for j in ja]
        aux = 3 in kb             # J_z delta_r' (seed 0 Eq. 6f): the measured rotor acceleration
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
            Z[:, :len(ja)] = iv[0][:, ja]
        cols = nuis_idx[row]
        if cols:
            E = np.stack([rem[a][:, c] for a, c in cols], axis=1)
            Hm, chosen = ee._append_independent(Hm, E)
            labels += [f"nuisance{c}" for c in chosen]
            if Z is not None:
                Z = np.concatenate([Z] + [iv[1][cols[c][0]][:, cols[c][1]: cols[c][1] + 1] for c in chosen], axis=1)
        designs.append(ee.RowDesign(row, y, Hm, tuple(ja), tuple(kb), tuple(labels), Z=Z))
        nuis_kept[row] = cols
    motor_designs, motor, delays = _motor_designs(data, cfg, params, full, keep, xdot, dx, u_in, u0,
                                                  None if iv is None else iv[0])
    fits, joint, dof = ee.solve_rows(designs + motor_designs, cfg.covariance, dt)
    maskA, maskB = known.maskA.copy(), known.maskB.copy()
    if motor == "identified":
        for j in range(4):
            maskA[8 + j, 8 + j] = True
            maskB[8 + j, j] = True
    model = taylor.IdentifiedModel(x0, u0, fits, nuis_kept, params, motor == "known")
    theta = np.concatenate([rf.theta for rf in fits])
    psi_dot = float((np.sin(x0[0]) * x0[6] + np.cos(x0[0]) * x0[7]) / np.cos(x0[1]))
    if cfg.equilibrium:
        rx = taylor.reexpand(model, theta, joint, x0[2:5], psi_dot, maskA, maskB)
        x_e, u_e, A, B, sA, sB, flown = rx.x_e, rx.u_e, rx.A, rx.B, rx.std_A, rx.std_B, rx.xdot_flown
        log.info("%s: equilibrium re-expansion in %d Newton steps, shift %s", data.name, rx.iterations,
                 np.round(x_e - x0, 4).tolist())
    else:
        flown = np.concatenate([[0.0, 0.0], model.residual(np.concatenate([x0[:2], x0[8:12], u0]), theta,
                                                             x0[2:5], psi_dot)])
        A, B = model.jacobians(x0, u0, theta)
        x_e, u_e = x0, np.asarray(u0, dtype=float)
        sA, sB = _direct_std(model, theta, joint, x0, u0, maskA, maskB)
    f = ee.Fit(A, B, sA, sB, maskA, maskB, tuple(fits), joint, dof, cfg.covariance.method)
    return f, x_e, u_e, flown, motor


def _direct_std(model, theta, cov, x, u, maskA, maskB):
    """Delta-method standard errors of the Jacobians at a fixed point (no re-expansion)."""
    idx = [(m, i, int(j)) for i in range(maskA.shape[0])
           for m, msk in (("A", maskA), ("B", maskB)) for j in np.nonzero(msk[i])[0]]

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
    full = _segment(t, a, b, f"{data.name or 'vertex'} excitation", cfg.min_fit_duration + 2 * cfg.edge)
    if cfg.derivatives.method == "fourier":
        full = full[: deriv.fast_length(full.size)]      # FFT-friendly length, drops < 2 % (n > 2000)
    n_edge = int(round(cfg.edge / dt))
    return dt, full, slice(n_edge, full.size - n_edge)


def prepare(data: VertexData, cfg: IdentificationConfig, x0: np.ndarray, u0: np.ndarray,
            nonlinear=None, u: np.ndarray | None = None):
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
    out = (np.asarray(data.t, dtype=float)[full][keep], xdot[keep], xs[keep] - x0, us[keep] - u0)
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
    x_flown, u_flown, flown, motor = x0, u0, None, "known"
    if cfg.model == "taylor2":
        fit, x0, u0, flown, motor = _fit_taylor2(data, x0, u0, known, cfg)
    else:
        _, xdot, dx, du = prepare(data, cfg, x0, u0, u=_input(data, _params(cfg)))
        fit = ee.fit(xdot, dx, du, known.A, known.B, known.maskA, known.maskB, cfg.max_lag, cfg.intercept,
                     covariance=cfg.covariance, dt=float(np.median(np.diff(data.t))))
    uv = unc.build(fit.A, fit.B, fit.elements(), cfg.uncertainty, dof=fit.dof)
    r2 = {a: fit.r2.get(i, float("nan")) for a, i in zip(metrics.AXES, metrics.AXIS_INDEX)}
    log.info("%s: %d identified elements, M=%d uncertain systems", data.name, len(uv.intervals), uv.M)
    return VertexResult(data.name, np.asarray(data.scheduling, dtype=float), x0, u0, fit, uv, r2,
                        x_flown=x_flown, u_flown=u_flown, xdot_flown=flown, motor=motor)


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
