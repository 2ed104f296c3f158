"""Seed 0 Eq. (6) for a PX4 multirotor: the documented variant ``px4`` and its identification.

Where the vehicle differs from the seed's, and what the variant does instead:

1. **Inputs.** No rotor speeds are measured; PX4 writes normalised motor outputs ``m_i``
   in [0, 1] (``rotor_speeds`` carries them through the estimator's lag,
   :mod:`~lpv_sysid.ident.nonlinear.px4_data`). PX4 linearises thrust in its output
   (``THR_MDL_FAC``; PX4's SIH applies ``T_i = SIH_T_MAX m_i`` exactly), so forces and
   moments are linear in the lagged outputs and the ``delta^2`` (``Mix Omega^2``) terms of
   Eq. (6) become the ``delta`` terms of the same mix, with PX4's quad-X signs
   (``models.quadrotor.mixer``): ``dt = m1+m2+m3+m4``, ``da = -m1+m2+m3-m4``,
   ``de = m1-m2+m3-m4``, ``dr = m1+m2-m3-m4``, each ``m_i`` through the motor lag ``tau``
   (seed 0 Eq. 8 with the vehicle's own time constant; identified here, see below).
2. **Outputs.** The mass and inertia of a PX4 vehicle are not known to the identifier:
   the regressions are on the IMU specific force ``f = F / m`` (Eq. 3c without the known
   kinematics) and on the angular acceleration ``omega'`` (Eq. 3d solved for it), so every
   coefficient is mass- or inertia-normalised (the "physical quantities" of
   :func:`physical_quantities`).
3. **Terms.** Per axis (``X`` .. ``N`` as in Eq. 6a-6f)::

       f_x  = X_u u                                  (6a: x_mu0 / m)
       f_y  = Y_v v                                  (6b: y_mu0 / m)
       f_z  = Z_T dt + Z_w w                         (6c: thrust, z_muw-like inflow drag)
       p'   = L_a da + L_p p + L_qr q r              (6d + Eq. 3d: (I_yy - I_zz)/I_xx)
       q'   = M_e de + M_q q + M_pr p r              (6e + Eq. 3d: (I_zz - I_xx)/I_yy)
       r'   = N_r dr + N_rr r + N_pq p q             (6f + Eq. 3d: (I_xx - I_yy)/I_zz)

   The blade-flapping / inflow products of Eq. (6) (``u w``, ``u dt``, ``v dt``,
   ``u^2 + v^2``, ``u dr`` ...) are left out: PX4's SIH has none, and inside the PX4 box
   (|u|, |v| <= 4 m/s around hover, dt nearly constant) ``u`` and ``u dt`` are correlated
   beyond 0.99 (seed 0 Fig. 10's problem), which makes both unidentifiable.
   ``intercept=True`` adds a constant per axis (an IMU bias, a thrust curve not through
   zero on a real vehicle).

**Motor time constant.** ``tau`` enters the regressors nonlinearly: it is found by a grid
over ``tau`` (log-spaced) minimising the concentrated likelihood
``sum_axes N log SSE_axis(tau)`` of the four rotor-driven axes, refined by a parabola through
the three best points. Its standard deviation is the Gauss-Newton one of each rotor axis
with the linearised regressor ``d(phi K)/d tau`` appended (coloured-residual covariance of
``equation_error.fit_row``), combined by inverse variance.

Standard deviations of the coefficients: ``equation_error.fit_row`` (SVD least squares,
wider of the white and the coloured-residual covariance). Regressor correlation per axis
(seed 0 Fig. 10): ``correlation.column_correlation``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.ident import equation_error as ee
from lpv_sysid.ident.nonlinear.correlation import column_correlation
from lpv_sysid.ident.nonlinear.data import AxisFit
from lpv_sysid.ident.nonlinear.px4_data import Px4Record, motor_lag

#: PX4 quad-X mix of the motor outputs (rows dt, da, de, dr; sign of models.quadrotor.mixer)
PX4_MIX = np.array(
    [[1.0, 1.0, 1.0, 1.0], [-1.0, 1.0, 1.0, -1.0], [1.0, -1.0, 1.0, -1.0], [1.0, 1.0, -1.0, -1.0]]
)
PX4_AXES = ("X", "Y", "Z", "L", "M", "N")
#: measured side of each axis (units)
PX4_OUTPUTS = {
    "X": ("f_x", "m/s^2"),
    "Y": ("f_y", "m/s^2"),
    "Z": ("f_z", "m/s^2"),
    "L": ("p_dot", "rad/s^2"),
    "M": ("q_dot", "rad/s^2"),
    "N": ("r_dot", "rad/s^2"),
}
#: (coefficient name, regressor label) per axis
PX4_REGRESSORS = {
    "X": (("X_u", "u"),),
    "Y": (("Y_v", "v"),),
    "Z": (("Z_T", "dt"), ("Z_w", "w")),
    "L": (("L_a", "da"), ("L_p", "p"), ("L_qr", "q r")),
    "M": (("M_e", "de"), ("M_q", "q"), ("M_pr", "p r")),
    "N": (("N_r", "dr"), ("N_rr", "r"), ("N_pq", "p q")),
}
ROTOR_AXES = ("Z", "L", "M", "N")
#: default grid of the motor time constant [s]
TAU_GRID = tuple(float(x) for x in np.geomspace(0.01, 0.3, 36))


def _columns(rec: Px4Record, tau: float) -> dict[str, np.ndarray]:
    """Unfiltered regressor matrices per axis for motor lag ``tau``."""
    m = motor_lag(rec.x_motor, rec.a_omega, tau, rec.dt)
    d = m @ PX4_MIX.T
    u, v, w = rec.v.T
    p, q, r = rec.omega.T
    return {
        "X": u[:, None],
        "Y": v[:, None],
        "Z": np.column_stack([d[:, 0], w]),
        "L": np.column_stack([d[:, 1], p, q * r]),
        "M": np.column_stack([d[:, 2], q, p * r]),
        "N": np.column_stack([d[:, 3], r, p * q]),
    }


def _measured(rec: Px4Record) -> dict[str, np.ndarray]:
    return {
        "X": rec.f[:, 0],
        "Y": rec.f[:, 1],
        "Z": rec.f[:, 2],
        "L": rec.omega_dot[:, 0],
        "M": rec.omega_dot[:, 1],
        "N": rec.omega_dot[:, 2],
    }


def design(
    records: list[Px4Record], tau: float, intercept: bool = False
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per axis ``(y, H)``: measured side and smoothed regressors, edges cut, records
    stacked (an intercept column last when asked)."""
    out: dict[str, tuple[list, list]] = {a: ([], []) for a in PX4_AXES}
    for rec in records:
        cols = _columns(rec, tau)
        meas = _measured(rec)
        for a in PX4_AXES:
            H = rec.smoother(cols[a])[rec.keep]
            if intercept:
                H = np.column_stack([H, np.ones(H.shape[0])])
            out[a][0].append(meas[a][rec.keep])
            out[a][1].append(H)
    return {a: (np.concatenate(ys), np.concatenate(Hs)) for a, (ys, Hs) in out.items()}


def _names(axis: str, intercept: bool) -> tuple[tuple[str, ...], tuple[str, ...]]:
    names = tuple(n for n, _ in PX4_REGRESSORS[axis])
    labels = tuple(lb for _, lb in PX4_REGRESSORS[axis])
    if intercept:
        names, labels = names + (f"{axis}_0",), labels + ("1",)
    return names, labels


@dataclass
class Px4AxisFit(AxisFit):
    """An axis of Eq. (6)'s fit (:class:`~lpv_sysid.ident.nonlinear.data.AxisFit`) and the
    number of samples it used."""

    n_samples: int = 0


@dataclass
class Px4Model:
    """The identified variant: coefficients with standard deviations, the motor lag."""

    K: dict[str, float]
    std: dict[str, float]
    tau: float
    tau_std: float
    axes: dict[str, Px4AxisFit]
    intercept: bool = False
    tau_profile: list[tuple[float, float]] = field(default_factory=list)
    timing_s: float = 0.0
    std_statistical: dict[str, float] = field(default_factory=dict)
    tau_std_statistical: float = float("nan")

    def to_dict(self) -> dict:
        return {
            "format": "lpv_sysid/nonlinear_model@1",
            "model": "seed 0 Eq. (6), PX4 variant (ident.nonlinear.px4_model)",
            "structure": "px4",
            "intercept": self.intercept,
            "tau": float(self.tau),
            "tau_std": float(self.tau_std),
            "tau_std_statistical": float(self.tau_std_statistical),
            "timing_s": float(self.timing_s),
            "K": {k: float(v) for k, v in self.K.items()},
            "std": {k: float(v) for k, v in self.std.items()},
            "std_statistical": {k: float(v) for k, v in self.std_statistical.items()},
            "axes": {
                a.axis: {
                    "output": PX4_OUTPUTS[a.axis][0],
                    "r2": float(a.r2),
                    "n_samples": int(a.n_samples),
                    "parameters": list(a.names),
                    "regressors": list(a.labels),
                    "correlation": np.where(
                        np.isfinite(a.correlation), a.correlation, 0.0
                    ).tolist(),
                }
                for a in self.axes.values()
            },
        }

    @classmethod
    def from_dict(cls, d: dict) -> "Px4Model":
        if d.get("structure") != "px4":
            raise ConfigError("nonlinear model file: not a 'px4' structure model")
        try:
            K = {str(k): float(v) for k, v in d["K"].items()}
            std = {str(k): float(v) for k, v in d["std"].items()}
            intercept = bool(d.get("intercept", False))
            axes = {}
            for a in PX4_AXES:
                names, labels = _names(a, intercept)
                ad = d["axes"][a]
                axes[a] = Px4AxisFit(
                    a,
                    names,
                    labels,
                    np.array([K[n] for n in names]),
                    np.array([std[n] for n in names]),
                    float(ad["r2"]),
                    np.asarray(ad["correlation"], dtype=float),
                    int(ad.get("n_samples", 0)),
                )
            return cls(K, std, float(d["tau"]), float(d["tau_std"]), axes, intercept)
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"nonlinear model file: missing or bad entry ({exc})") from None


def _sse(y: np.ndarray, H: np.ndarray) -> float:
    theta, *_ = np.linalg.lstsq(H, y, rcond=None)
    e = y - H @ theta
    return float(e @ e)


def _profile(records, tau: float, intercept: bool) -> float:
    des = design(records, tau, intercept)
    return float(sum(des[a][0].size * np.log(_sse(*des[a])) for a in ROTOR_AXES))


def identify_px4(
    records: list[Px4Record],
    tau_grid=TAU_GRID,
    intercept: bool = False,
    max_lag: int | None = None,
    timing_s: float | None = None,
) -> Px4Model:
    """The variant of this module's docstring, fitted to ``records`` (stacked).

    ``timing_s``: width of the unresolved timing of the motor outputs against the states
    (default: the records' motor-output sample interval; 0: none). PX4 streams its outputs
    at 50 Hz, sub-sampled from the rate loop and held, so their time is known to a
    sample interval ``T_s``; a shift ``d`` of the outputs trades almost exactly against the
    lag (``tau + d`` is what the data fix). Each coefficient's std gets the term of a shift
    uniform in ``+-T_s / 2``: ``|K(+T_s/2) - K(-T_s/2)| / (2 sqrt 3)``, from two refits
    with the outputs shifted (``std_statistical`` keeps the fit's own).
    """
    if not records:
        raise ConfigError("identify_px4: no flight records")
    base = _identify(records, tau_grid, intercept, max_lag)
    ts = (
        float(np.median([rec.motor_period for rec in records]))
        if timing_s is None
        else float(timing_s)
    )
    base.timing_s = ts
    if ts <= 0:
        return base
    plus = _identify([_shifted(r, 0.5 * ts) for r in records], tau_grid, intercept, max_lag)
    minus = _identify([_shifted(r, -0.5 * ts) for r in records], tau_grid, intercept, max_lag)
    base.std_statistical = dict(base.std)
    for k in base.K:
        st = abs(plus.K[k] - minus.K[k]) / (2 * np.sqrt(3.0))
        base.std[k] = float(np.hypot(base.std[k], st))
    base.tau_std_statistical = base.tau_std
    base.tau_std = float(np.hypot(base.tau_std, abs(plus.tau - minus.tau) / (2 * np.sqrt(3.0))))
    for a in base.axes.values():
        a.std = np.array([base.std[n] for n in a.names])
    return base


def _shifted(rec: Px4Record, d: float) -> Px4Record:
    """``rec`` with its motor outputs ``d`` s later (linear interpolation, ends held)."""
    import dataclasses

    x = np.stack([np.interp(rec.t - d, rec.t, rec.x_motor[:, j]) for j in range(4)], axis=1)
    return dataclasses.replace(rec, x_motor=x)


def _identify(records, tau_grid, intercept: bool, max_lag) -> Px4Model:
    grid = np.asarray(sorted(tau_grid), dtype=float)
    prof = np.array([_profile(records, t, intercept) for t in grid])
    k = int(np.argmin(prof))
    tau = float(grid[k])
    if 0 < k < grid.size - 1:  # parabola in log tau through the three best points
        x = np.log(grid[k - 1 : k + 2])
        c = np.polyfit(x, prof[k - 1 : k + 2], 2)
        if c[0] > 0:
            tau = float(np.exp(np.clip(-c[1] / (2 * c[0]), x[0], x[2])))
    des = design(records, tau, intercept)
    K: dict[str, float] = {}
    std: dict[str, float] = {}
    axes = {}
    for i, a in enumerate(PX4_AXES):
        y, H = des[a]
        names, labels = _names(a, intercept)
        rf = ee.fit_row(i, y, H, tuple(range(H.shape[1])), (), max_lag)
        for j, n in enumerate(names):
            K[n], std[n] = float(rf.theta[j]), float(rf.std[j])
        axes[a] = Px4AxisFit(
            a, names, labels, rf.theta, rf.std, rf.r2, column_correlation(H), y.size
        )
    tau_std = _tau_std(records, tau, intercept, K, max_lag)
    return Px4Model(K, std, tau, tau_std, axes, intercept, list(zip(grid.tolist(), prof.tolist())))


def _tau_std(records, tau: float, intercept: bool, K: dict, max_lag) -> float:
    """Gauss-Newton std of tau per rotor axis (regressor ``K_input d(input)/d tau``
    appended), combined by inverse variance; inf when no axis resolves it."""
    h = 0.02 * tau
    dp, dm = design(records, tau + h, intercept), design(records, tau - h, intercept)
    des = design(records, tau, intercept)
    inv = 0.0
    for i, a in enumerate(ROTOR_AXES):
        y, H = des[a]
        gain = K[_names(a, intercept)[0][0]]
        col = gain * (dp[a][1][:, 0] - dm[a][1][:, 0]) / (2 * h)
        try:
            rf = ee.fit_row(
                i, y, np.column_stack([H, col]), tuple(range(H.shape[1] + 1)), (), max_lag
            )
        except Exception:  # noqa: BLE001 - an axis that cannot resolve tau adds nothing
            continue
        s = float(rf.std[-1])
        if np.isfinite(s) and s > 0:
            inv += 1.0 / s**2
    return float(1.0 / np.sqrt(inv)) if inv > 0 else float("inf")


@dataclass
class Prediction:
    """Model against measurement per axis on the stacked records (edges cut)."""

    t: np.ndarray
    measured: dict[str, np.ndarray]
    predicted: dict[str, np.ndarray]
    r2: dict[str, float]
    tic: dict[str, float]


def predict(model: Px4Model, records: list[Px4Record]) -> Prediction:
    """The specific forces and angular accelerations ``model`` predicts from the measured
    states and motor outputs of ``records`` (equation level, seed 0 Sec. VII), R^2 and TIC
    (seed 0 Eq. 24) per axis."""
    from lpv_sysid.ident.metrics import r_squared, tic

    des = design(records, model.tau, model.intercept)
    t = np.concatenate([rec.t[rec.keep] for rec in records])
    meas, pred, r2, tc = {}, {}, {}, {}
    for a in PX4_AXES:
        y, H = des[a]
        yh = H @ np.array([model.K[n] for n in _names(a, model.intercept)[0]])
        meas[a], pred[a] = y, yh
        r2[a], tc[a] = r_squared(y, yh), tic(yh, y)
    return Prediction(t, meas, pred, r2, tc)


#: physical quantities: name -> (description, unit, SIH expression)
PHYSICAL = {
    "drag_x": ("mass-normalised drag, x", "1/s", "SIH_KDV / SIH_MASS"),
    "drag_y": ("mass-normalised drag, y", "1/s", "SIH_KDV / SIH_MASS"),
    "drag_z": ("mass-normalised drag, z", "1/s", "SIH_KDV / SIH_MASS"),
    "thrust_eff": ("thrust per unit motor output sum / mass", "m/s^2", "SIH_T_MAX / SIH_MASS"),
    "roll_eff": ("roll torque per unit da / I_xx", "rad/s^2", "SIH_L_ROLL SIH_T_MAX / SIH_IXX"),
    "pitch_eff": (
        "pitch torque per unit de / I_yy",
        "rad/s^2",
        "SIH_L_PITCH SIH_T_MAX / SIH_IYY",
    ),
    "yaw_eff": ("yaw torque per unit dr / I_zz", "rad/s^2", "SIH_Q_MAX / SIH_IZZ"),
    "roll_over_pitch_eff": (
        "inertia ratio I_yy / I_xx times the arm ratio, from the torque effectiveness",
        "1",
        "SIH_L_ROLL SIH_IYY / (SIH_L_PITCH SIH_IXX)",
    ),
    "Iyy_over_Ixx": ("inertia ratio from the rate damping, L_p / M_q", "1", "SIH_IYY / SIH_IXX"),
    "Izz_over_Ixx": ("inertia ratio from the rate damping, L_p / N_rr", "1", "SIH_IZZ / SIH_IXX"),
    "tau": ("motor time constant", "s", "SIH_T_TAU"),
}


def _ratio(a: float, sa: float, b: float, sb: float) -> tuple[float, float]:
    r = a / b
    return r, abs(r) * float(np.hypot(sa / a, sb / b))


def physical_quantities(model: Px4Model) -> dict[str, tuple[float, float]]:
    """Identified physical quantities ``name -> (value, std)`` (:data:`PHYSICAL`)."""
    K, s = model.K, model.std
    return {
        "drag_x": (-K["X_u"], s["X_u"]),
        "drag_y": (-K["Y_v"], s["Y_v"]),
        "drag_z": (-K["Z_w"], s["Z_w"]),
        "thrust_eff": (-K["Z_T"], s["Z_T"]),
        "roll_eff": (K["L_a"], s["L_a"]),
        "pitch_eff": (K["M_e"], s["M_e"]),
        "yaw_eff": (K["N_r"], s["N_r"]),
        "roll_over_pitch_eff": _ratio(K["L_a"], s["L_a"], K["M_e"], s["M_e"]),
        "Iyy_over_Ixx": _ratio(K["L_p"], s["L_p"], K["M_q"], s["M_q"]),
        "Izz_over_Ixx": _ratio(K["L_p"], s["L_p"], K["N_rr"], s["N_rr"]),
        "tau": (model.tau, model.tau_std),
    }


#: PX4 SIH defaults (PX4 v1.16 src/modules/simulation/simulator_sih/sih_params.c)
SIH_DEFAULTS = {
    "SIH_MASS": 1.0,
    "SIH_IXX": 0.025,
    "SIH_IYY": 0.025,
    "SIH_IZZ": 0.030,
    "SIH_T_MAX": 5.0,
    "SIH_Q_MAX": 0.1,
    "SIH_L_ROLL": 0.2,
    "SIH_L_PITCH": 0.2,
    "SIH_KDV": 1.0,
    "SIH_KDW": 0.025,
    "SIH_T_TAU": 0.05,
}


def sih_truth(sih: dict[str, float] | None = None) -> dict[str, float]:
    """The quantities of :data:`PHYSICAL` of a PX4 SIH quadrotor (``sih.cpp``
    ``generate_force_and_torques``: ``T = T_MAX sum m_i``, moments ``L_ROLL T_MAX da``,
    ``L_PITCH T_MAX de``, ``Q_MAX dr``, drag ``-KDV v``, damping ``-KDW omega``; the motor
    outputs through ``T_TAU``) for parameters ``sih`` over :data:`SIH_DEFAULTS`."""
    p = dict(SIH_DEFAULTS, **(sih or {}))
    kdv_m = p["SIH_KDV"] / p["SIH_MASS"]
    return {
        "drag_x": kdv_m,
        "drag_y": kdv_m,
        "drag_z": kdv_m,
        "thrust_eff": p["SIH_T_MAX"] / p["SIH_MASS"],
        "roll_eff": p["SIH_L_ROLL"] * p["SIH_T_MAX"] / p["SIH_IXX"],
        "pitch_eff": p["SIH_L_PITCH"] * p["SIH_T_MAX"] / p["SIH_IYY"],
        "yaw_eff": p["SIH_Q_MAX"] / p["SIH_IZZ"],
        "roll_over_pitch_eff": p["SIH_L_ROLL"] * p["SIH_IYY"] / (p["SIH_L_PITCH"] * p["SIH_IXX"]),
        "Iyy_over_Ixx": p["SIH_IYY"] / p["SIH_IXX"],
        "Izz_over_Ixx": p["SIH_IZZ"] / p["SIH_IXX"],
        "tau": p["SIH_T_TAU"],
    }
