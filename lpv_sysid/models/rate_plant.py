"""The "rate plant": a multicopter *with PX4's rate loop inside*, as flown over MAVLink.

PX4 >= 1.14 takes no actuator setpoints over MAVLink; what SET_ATTITUDE_TARGET delivers is
collective thrust + body-rate setpoints, tracked by PX4's own rate controller (P, I, D, FF,
allocation, motors). Instead of inverting that loop (omega_sp = omega + tau / K_p,
:class:`lpv_sysid.mavlink.bridge.transport.AttitudeRateTransport`) this model takes the loop as
part of the plant, so the seed 0 design (Lemma 1) and its certificate are about the inputs that
really go out (docs/px4_chain.md):

    x = (phi, theta, u, v, w, p, q, r)          Euler roll/pitch [rad], FRD body velocity [m/s],
                                                FRD body rates [rad/s]
    u = (thrust, p_sp, q_sp, r_sp)              normalised collective thrust [0, 1] and body-rate
                                                setpoints [rad/s], as sent in SET_ATTITUDE_TARGET

Dynamics (heading and position do not enter; seed 0 Eqs. (2)-(3) with the attitude and
velocity rows kept and the rotor/moment rows replaced by the closed rate loop)::

    phi'   = p + tan(theta) (sin(phi) q + cos(phi) r)                      (kinematics, known)
    theta' = cos(phi) q - sin(phi) r
    u'     = r v - q w - g sin(theta)            + X_u u + c_u             (Coriolis, gravity
    known;
    v'     = p w - r u + g cos(theta) sin(phi)   + Y_v v + c_v              drag X_u, Y_v, Z_w,
    w'     = q u - p v + g cos(theta) cos(phi)   + Z_w w + Z_T thrust + c_w  thrust gain Z_T,
    offsets c)
    p'     = L_p p + L_sp p_sp + c_p             (closed rate loop, first order, identified)
    q'     = M_q q + M_sp q_sp + c_q
    r'     = N_r r + N_sp r_sp + c_r

:class:`RatePlantParams` holds the identified coefficients; :func:`trim` the equilibrium at a
body velocity, :func:`linearize` the Jacobians there (numerical central differences of
:func:`dynamics`, checked against the analytic ones in the tests), :func:`polytope` the
vertex models of the scheduling box (seed 0 Eqs. 20-23) with optional intervals on the
identified entries. The scheduling is the body-velocity reference v_d as in seed 0; each
vertex has its own identified coefficients (lpv_sysid/ident/rate_plant.py, per-vertex fits as
seed 0 Tables 1-2) on top of the kinematic (Coriolis, gravity) terms evaluated at its trim;
one common parameter set (a pooled fit) is the special case where a vertex lacks data.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Optional, Sequence

import numpy as np

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import ConfigError

STATE_NAMES = ("phi", "theta", "u", "v", "w", "p", "q", "r")
STATE_UNITS = ("rad", "rad", "m/s", "m/s", "m/s", "rad/s", "rad/s", "rad/s")
#: same names and order as lpv_sysid.mavlink.bridge.transport.RATE_INPUT_NAMES (one fact:
#: imported there)
INPUT_NAMES = ("thrust", "p_sp", "q_sp", "r_sp")
INPUT_UNITS = ("1", "rad/s", "rad/s", "rad/s")
SCHEDULING_NAMES = ("u_d", "v_d", "w_d")
VELOCITY_INDEX = (2, 3, 4)
RATE_INDEX = (5, 6, 7)
GRAVITY = 9.80665
DESIGN = "rate_plant"  # gains.yaml / report: which plant the law was designed for
DESIGN_TEXT = (
    "rate plant: PX4 rate loop inside the model; inputs thrust + body-rate setpoints "
    "(SET_ATTITUDE_TARGET), states phi, theta, u, v, w, p, q, r"
)

#: identified coefficients: name -> (matrix, row, col) of the linear model they appear in
#: (None: an offset, enters the trim only)
PARAM_ENTRIES: dict[str, Optional[tuple[str, int, int]]] = {
    "X_u": ("A", 2, 2),
    "Y_v": ("A", 3, 3),
    "Z_w": ("A", 4, 4),
    "Z_T": ("B", 4, 0),
    "L_p": ("A", 5, 5),
    "L_sp": ("B", 5, 1),
    "M_q": ("A", 6, 6),
    "M_sp": ("B", 6, 2),
    "N_r": ("A", 7, 7),
    "N_sp": ("B", 7, 3),
    "c_u": None,
    "c_v": None,
    "c_w": None,
    "c_p": None,
    "c_q": None,
    "c_r": None,
}


def _coefficient(doc: str, **kw: Any) -> Any:
    return cf.number(doc=doc, **kw)


def _offset(doc: str) -> Any:
    return cf.number(0.0, f"{doc} (enters the trim only)")


@dataclass(frozen=True)
class RatePlantParams:
    """Identified coefficients (module docstring), checked on every construction; ``std``
    holds their standard deviations. The signs the model needs are declared: thrust
    accelerates up (Z_T < 0), each rate loop follows its setpoint (L_sp, M_sp, N_sp > 0)."""

    X_u: float = _coefficient("u drag [1/s]")
    Y_v: float = _coefficient("v drag [1/s]")
    Z_w: float = _coefficient("w drag [1/s]")
    Z_T: float = _coefficient(
        "thrust gain [m/s^2 per unit thrust], < 0 (thrust accelerates up, -w)",
        hi=0.0,
        hi_open=True,
    )
    L_p: float = _coefficient("closed roll-rate loop pole [1/s]")
    L_sp: float = _coefficient("roll-rate setpoint gain [1/s], > 0", lo=0.0, lo_open=True)
    M_q: float = _coefficient("closed pitch-rate loop pole [1/s]")
    M_sp: float = _coefficient("pitch-rate setpoint gain [1/s], > 0", lo=0.0, lo_open=True)
    N_r: float = _coefficient("closed yaw-rate loop pole [1/s]")
    N_sp: float = _coefficient("yaw-rate setpoint gain [1/s], > 0", lo=0.0, lo_open=True)
    c_u: float = _offset("u offset [m/s^2]")
    c_v: float = _offset("v offset [m/s^2]")
    c_w: float = _offset("w offset [m/s^2]")
    c_p: float = _offset("p offset [rad/s^2]")
    c_q: float = _offset("q offset [rad/s^2]")
    c_r: float = _offset("r offset [rad/s^2]")
    std: Mapping[str, float] = cf.table(
        {},
        "standard deviation of each identified coefficient, name: std >= 0",
        item=cf.FieldSpec(cf.NUMBER, lo=0.0),
        choices=tuple(PARAM_ENTRIES),
    )

    def __post_init__(self) -> None:
        cf.normalize_fields(self, "rate_plant")

    def as_dict(self) -> dict:
        d: dict[str, Any] = {k: float(getattr(self, k)) for k in PARAM_ENTRIES}
        d["std"] = {k: float(v) for k, v in self.std.items()}
        return d

    @classmethod
    def from_dict(cls, d: Mapping, where: str = "rate_plant") -> "RatePlantParams":
        return cls(**cf.parse_fields(cls, d, where))


def dynamics(x: np.ndarray, u: np.ndarray, P: RatePlantParams, g: float = GRAVITY) -> np.ndarray:
    """x' of the module docstring (8 states, 4 inputs)."""
    phi, th, ub, vb, wb, p, q, r = (float(a) for a in x)
    T, psp, qsp, rsp = (float(a) for a in u)
    sf, cf, st, ct = math.sin(phi), math.cos(phi), math.sin(th), math.cos(th)
    return np.array(
        [
            p + math.tan(th) * (sf * q + cf * r),
            cf * q - sf * r,
            r * vb - q * wb - g * st + P.X_u * ub + P.c_u,
            p * wb - r * ub + g * ct * sf + P.Y_v * vb + P.c_v,
            q * ub - p * vb + g * ct * cf + P.Z_w * wb + P.Z_T * T + P.c_w,
            P.L_p * p + P.L_sp * psp + P.c_p,
            P.M_q * q + P.M_sp * qsp + P.c_q,
            P.N_r * r + P.N_sp * rsp + P.c_r,
        ]
    )


def trim(
    v_body: Sequence[float], P: RatePlantParams, g: float = GRAVITY
) -> tuple[np.ndarray, np.ndarray]:
    """Equilibrium (x0, u0) at body velocity ``v_body`` with zero body rates: the attitude that
    balances drag by gravity and the thrust that holds w (module docstring rows set to 0)."""
    ub, vb, wb = (float(a) for a in v_body)
    s_th = (P.X_u * ub + P.c_u) / g
    if abs(s_th) >= 0.9:
        raise ConfigError(
            f"rate plant: no trim at v = {list(v_body)}: pitch would need sin(theta) = {s_th:.2f}"
        )
    th = math.asin(s_th)
    s_phi = -(P.Y_v * vb + P.c_v) / (g * math.cos(th))
    if abs(s_phi) >= 0.9:
        raise ConfigError(
            f"rate plant: no trim at v = {list(v_body)}: roll would need sin(phi) = {s_phi:.2f}"
        )
    phi = math.asin(s_phi)
    T = -(g * math.cos(th) * math.cos(phi) + P.Z_w * wb + P.c_w) / P.Z_T
    if not 0.0 < T < 1.0:
        raise ConfigError(
            f"rate plant: trim thrust {T:.3f} at v = {list(v_body)} is outside (0, 1)"
        )
    x0 = np.array([phi, th, ub, vb, wb, 0.0, 0.0, 0.0])
    u0 = np.array([T, -P.c_p / P.L_sp, -P.c_q / P.M_sp, -P.c_r / P.N_sp])
    return x0, u0


def linearize(
    x0: np.ndarray, u0: np.ndarray, P: RatePlantParams, h: float = 1e-6, g: float = GRAVITY
) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) = Jacobians of :func:`dynamics` at (x0, u0) (central differences; exact to
    ~1e-9 for these smooth trigonometric terms)."""
    n, m = len(STATE_NAMES), len(INPUT_NAMES)
    A, B = np.zeros((n, n)), np.zeros((n, m))
    for k in range(n):
        d = np.zeros(n)
        d[k] = h
        A[:, k] = (dynamics(x0 + d, u0, P, g) - dynamics(x0 - d, u0, P, g)) / (2 * h)
    for k in range(m):
        d = np.zeros(m)
        d[k] = h
        B[:, k] = (dynamics(x0, u0 + d, P, g) - dynamics(x0, u0 - d, P, g)) / (2 * h)
    return A, B


def polytope(
    P: RatePlantParams | Sequence[RatePlantParams],
    vmin: Sequence[float],
    vmax: Sequence[float],
    k_sigma: float = 0.0,
):
    """Vertex models at the box corners (``models.lpv.box_vertices`` order) as a
    :class:`~lpv_sysid.models.lpv.PolytopicModel`, plus the per-vertex uncertain elements
    (intervals ``nominal +- k_sigma * std`` of the identified linear entries; none when
    ``k_sigma`` is 0 or no std is known). ``P``: one parameter set for every corner, or one
    per corner (per-vertex identification, seed 0 Tables 1-2: each vertex its own
    coefficients and standard deviations, so the scheduling dependence of the identified
    entries is measured, not only that of the kinematics)."""
    from lpv_sysid.models.lpv import PolytopicModel, UncertainElement, box_vertices

    corners = box_vertices(vmin, vmax)
    per_vertex = [P] * len(corners) if isinstance(P, RatePlantParams) else list(P)
    if len(per_vertex) != len(corners):
        raise ConfigError(
            f"rate plant: {len(per_vertex)} parameter sets for {len(corners)} box corners"
        )
    As, Bs, x0s, u0s, els = [], [], [], [], []
    for vd, P in zip(corners, per_vertex):
        x0, u0 = trim(vd, P)
        A, B = linearize(x0, u0, P)
        As.append(A)
        Bs.append(B)
        x0s.append(x0)
        u0s.append(u0)
        row = []
        if k_sigma > 0:
            for name, where in PARAM_ENTRIES.items():
                s = float(P.std.get(name, 0.0))
                if where is None or not s > 0:
                    continue
                mat, i, j = where
                nom = float((A if mat == "A" else B)[i, j])
                row.append(UncertainElement(mat, i, j, nom - k_sigma * s, nom + k_sigma * s, nom))
        els.append(row)
    model = PolytopicModel(
        vmin=np.asarray(vmin, float),
        vmax=np.asarray(vmax, float),
        A=np.array(As),
        B=np.array(Bs),
        x0=np.array(x0s),
        u0=np.array(u0s),
        state_names=STATE_NAMES,
        input_names=INPUT_NAMES,
        scheduling_names=SCHEDULING_NAMES,
    )
    return model, els
