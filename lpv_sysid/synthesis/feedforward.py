"""Reference feedforward from the vertex models (seed 2 Sec. 5.1, Eq. 102, on seed 0 Eq. 16).

Seed 2 Sec. 5.1 turns the reference r into a state reference x_r and a feedforward input u_r that
make the reference a trajectory of the model, and applies ``u = u_r + K (x - x_r)`` (Eq. 102).
Seed 0's law ``u = u0(v_d) + K(v_d)(x - x0(v_d))`` (Eq. 31) uses the static trims only: they hold
v = v_d when v_d is constant, but a *changing* v_d needs a tilt and a thrust change the trims do
not contain, so feedback alone has to create them and the vehicle lags (Eq. 33 hides this: its
``x0'`` term, Eq. 34, moves the equilibrium for free).

For a desired body acceleration ``a = dv_d/dt`` the perturbation about the vertex trim that gives
``v' = a`` with ``omega' = 0`` and ``delta' = 0`` at ``Delta v = 0``, ``Delta omega = 0`` follows
from the rows of ``[A_i B_i]`` of the linear model ``Delta x' = A Delta x + B Delta u`` (Eq. 16):
the unknowns ``y = (Delta phi, Delta theta, Delta delta (4), Delta u (4))`` (10) solve

    [A_i[rows, free]  B_i[rows, :]] y = E a,     rows = (u, v, w | p, q, r, dt, da, de, dr),

with ``E`` the identity on the velocity rows and 0 on the held rows (10 equations, 10 unknowns).
So ``y = F_i a`` with ``F_i = M_i^-1 E`` (10 x 3). The kinematic rows (phi', theta') are not
imposed: with ``Delta omega = 0`` they are ~0 at trims with zero yaw rate (their residual is
reported by :func:`feedforward_residual`).

Row order of ``F_i`` (the ``F_ff`` entry of gains.yaml): the ``free_states`` in the order given
(quadrotor: phi, theta, dt, da, de, dr), then all inputs in input order (ut, ua, ue, ur); the
columns are the ``accelerated_states`` (u, v, w), i.e. the axes of v_d.

Jerk term (optional, ``kinematic_states``/``rate_states`` of the layout; on by default). With
omega = 0 imposed, F alone asks for an attitude that *changes* with a but not for the body
rates that change it; in body axes those rates act on the velocity through -omega x v (the
A[v, omega] entries are ~|v|, 5 m/s at the box corners), so at 0.4 rad/s the vehicle sees
~2 m/s^2 it was not asked for, and the feedback resists the rates (x_ref has omega = 0). With the
jerk j = da/dt the reference rates w_ff = A[kin, rate]^+ F[kin] j (kinematic rows phi, theta) and
the correction y_j = M^-1 (-A[rows, rate] w_ff) give ``F_jerk`` (rows: free states, inputs, rate
states): (dx_ff, du_ff) = F a + F_jerk j, with the rate states of dx_ff = w_ff. Measured on the
phase-2 demo (reference band 0.01-0.2 Hz): F alone left 0.7-0.8 m/s rms tracking error and the
flight left the box at 27 s; with the jerk term 0.2-0.4 m/s rms and the flight completed.

At runtime (control/law/controller.py) ``F(v_d) = sum_i alpha_i(v_d) F_i`` (Eq. 21 weights) and

    u = u0(v_d) + du_ff + K(v_d) (x - x0(v_d) - dx_ff) + R u_e,   (dx_ff, du_ff) = F(v_d) a.

``M_i`` is solved by least squares (scipy.linalg.lstsq, columns equilibrated to unit norm) so that
a rank-deficient identified model still gives the minimum-norm answer; the condition number of
the equilibrated matrix is checked (a warning above 1e6): above ``cond_max`` the
model cannot produce the requested acceleration reliably and :class:`ConfigError` names the
vertex (the caller may switch feedforward off in config/synthesis.yaml).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
import scipy.linalg

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import ConfigError
from lpv_sysid.io.formats import FeedforwardSpec

log = logging.getLogger(__name__)

#: largest accepted condition number of the 10 x 10 system (1/eps^(1/2) would lose half the
#: digits).
COND_MAX_DEFAULT = 1e10


def _states(default: tuple, doc: str) -> tuple:
    """A list of state names (distinct; may be empty), checked against the model's states
    when the layout is used (:meth:`FeedforwardLayout.indices`)."""
    return cf.texts(default, doc, nonempty=False, unique=True)


#: the jerk keys: absent from an explicit layout = no jerk term (older gains files)
_JERK_KEYS = ("kinematic_states", "rate_states")


@dataclass(frozen=True)
class FeedforwardLayout(FeedforwardSpec):
    """Which states are solved for, which are accelerated and which are held (module docstring):
    the gains.yaml ``feedforward`` layout (:class:`~lpv_sysid.io.formats.FeedforwardSpec`,
    which also gives ``has_jerk`` and ``to_dict``) with the quadrotor defaults."""

    free_states: tuple = _states(
        ("phi", "theta", "dt", "da", "de", "dr"), "the unknowns y besides the inputs"
    )
    accelerated_states: tuple = _states(("u", "v", "w"), "v' = a rows: the axes of v_d")
    held_states: tuple = _states(
        ("p", "q", "r", "dt", "da", "de", "dr"), "rows held at zero derivative"
    )
    kinematic_states: tuple = _states(
        ("phi", "theta"), "jerk term: attitude rows whose rate is imposed (empty: no jerk term)"
    )
    rate_states: tuple = _states(
        ("p", "q", "r"), "jerk term: the rate states that produce it (empty: no jerk term)"
    )

    @classmethod
    def from_dict(cls, d: Optional[dict], where: str = "feedforward") -> "FeedforwardLayout":
        """The layout of ``d`` (defaults for absent keys); an explicit layout without both
        jerk keys has no jerk term."""
        kw = cf.parse_fields(cls, d or {}, where)
        if kw and not all(k in kw for k in _JERK_KEYS):
            kw.update({k: () for k in _JERK_KEYS if k not in kw})
        return cls(**kw)

    def indices(self, state_names: Sequence[str]) -> tuple[list, list, list]:
        names = list(state_names)
        out = []
        for what in ("free_states", "accelerated_states", "held_states"):
            sel = getattr(self, what)
            missing = [s for s in sel if s not in names]
            if missing:
                raise ConfigError(
                    f"feedforward.{what}: {missing} not among the model states {names}"
                )
            if len(set(sel)) != len(sel):
                raise ConfigError(f"feedforward.{what}: duplicate names in {list(sel)}")
            out.append([names.index(s) for s in sel])
        if set(out[0]) & set(out[1]):
            raise ConfigError(
                "feedforward: a state cannot be both free and accelerated (Delta v = 0)"
            )
        return out[0], out[1], out[2]

    def jerk_indices(self, state_names: Sequence[str]) -> tuple[list, list]:
        names = list(state_names)
        out = []
        for what in ("kinematic_states", "rate_states"):
            sel = getattr(self, what)
            missing = [s for s in sel if s not in names]
            if missing:
                raise ConfigError(
                    f"feedforward.{what}: {missing} not among the model states {names}"
                )
            out.append([names.index(s) for s in sel])
        if not set(self.kinematic_states) <= set(self.free_states):
            raise ConfigError("feedforward.kinematic_states must be among the free states")
        return out[0], out[1]

    def n_rows(self, n_u: int) -> int:
        return len(self.free_states) + n_u


def _system(
    A: np.ndarray, B: np.ndarray, state_names: Sequence[str], layout: FeedforwardLayout, where: str
) -> tuple[np.ndarray, list, list, list]:
    """M = [A[rows, free] B[rows, :]] with rows = accelerated + held states (module docstring)."""
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    n, m = B.shape
    if A.shape != (n, n):
        raise ConfigError(f"{where}: A {A.shape} and B {B.shape} do not fit")
    free, acc, held = layout.indices(state_names)
    rows = acc + held
    M = np.hstack([A[np.ix_(rows, free)], B[rows, :]])
    if M.shape[0] != M.shape[1]:
        raise ConfigError(
            f"{where}: feedforward system is {M.shape[0]} x {M.shape[1]} "
            f"({len(rows)} imposed rows, {len(free)} free states + {m} inputs); it must be square"
        )
    return M, free, acc, rows


def _solve(M: np.ndarray, rhs: np.ndarray, cond_max: float, where: str) -> np.ndarray:
    # column equilibration: the motor rows carry b_Omega ~ 1.4e4 (seed 0 Eq. 15), so the raw
    # condition number (~1e6 for the quadrotor) says more about units than about solvability
    scale = np.linalg.norm(M, axis=0)
    scale[scale == 0.0] = 1.0
    # lstsq (not solve): a singular identified model gives the minimum-norm answer and its rank
    Fs, _, rank, sv = scipy.linalg.lstsq(M / scale, rhs, lapack_driver="gelsd")
    F = Fs / scale[:, None]
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    if rank < M.shape[0] or not cond <= cond_max:
        raise ConfigError(
            f"{where}: feedforward system [A[rows, free] B[rows]] is ill-conditioned "
            f"(rank {rank}/{M.shape[0]}, cond {cond:.3g} > {cond_max:.3g}): the model cannot "
            "produce the requested accelerations; set feedforward: false in the synthesis config"
        )
    if cond > 1e6:
        log.warning("%s: feedforward system condition number %.3g (> 1e6)", where, cond)
    if not np.all(np.isfinite(F)):
        raise ConfigError(f"{where}: feedforward matrix is not finite")
    return F


def feedforward_matrix(
    A: np.ndarray,
    B: np.ndarray,
    state_names: Sequence[str],
    layout: FeedforwardLayout = FeedforwardLayout(),
    cond_max: float = COND_MAX_DEFAULT,
    where: str = "model",
) -> np.ndarray:
    """F (n_free + n_u, n_acc) of the module docstring for one linear model (A, B)."""
    M, _, acc, rows = _system(A, B, state_names, layout, where)
    E = np.zeros((len(rows), len(acc)))
    E[np.arange(len(acc)), np.arange(len(acc))] = 1.0
    return _solve(M, E, cond_max, where)


def jerk_matrix(
    A: np.ndarray,
    B: np.ndarray,
    state_names: Sequence[str],
    F: np.ndarray,
    layout: FeedforwardLayout = FeedforwardLayout(),
    cond_max: float = COND_MAX_DEFAULT,
    where: str = "model",
) -> np.ndarray:
    """F_j (n_free + n_u + n_rate, n_acc) of the jerk term (module docstring) for one model.

    The attitude reference moves, (d/dt) dx_ff[kin] = F[kin] j (j = da/dt, dF/dt neglected), so
    the kinematic rows need the rates w_ff = A[kin, rate]^+ F[kin] j (minimum norm: r_ff = 0 for
    the quadrotor at zero yaw rate); those rates act on the imposed rows through A[rows, rate]
    (the -omega x v term of Eq. 3 in body axes: ~|v| per rad/s), which the free states and the
    inputs cancel: y_j = M^-1 (-A[rows, rate] w_ff). Rows: free states, inputs, rate states."""
    A = np.asarray(A, dtype=float)
    M, free, _, rows = _system(A, B, state_names, layout, where)
    kin, rate = layout.jerk_indices(state_names)
    F = np.asarray(F, dtype=float)
    F_kin = F[[free.index(k) for k in kin], :]
    A_kr = A[np.ix_(kin, rate)]
    Gw, _, rank, _ = scipy.linalg.lstsq(A_kr, F_kin)
    if rank < len(kin):
        raise ConfigError(
            f"{where}: the rate states {list(layout.rate_states)} cannot move the attitude rows "
            f"{list(layout.kinematic_states)} (rank {rank}); drop the jerk term"
        )
    Fj = _solve(M, -A[np.ix_(rows, rate)] @ Gw, cond_max, where)
    return np.vstack([Fj, Gw])


def vertex_feedforward(
    A: np.ndarray,
    B: np.ndarray,
    state_names: Sequence[str],
    layout: FeedforwardLayout = FeedforwardLayout(),
    cond_max: float = COND_MAX_DEFAULT,
) -> tuple[np.ndarray, Optional[np.ndarray]]:
    """(F_i (N, n_free + n_u, n_acc), F_jerk,i (N, n_free + n_u + n_rate, n_acc) or None) for every
    vertex; A (N, n, n), B (N, n, m) nominal models."""
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    F = np.array(
        [
            feedforward_matrix(A[i], B[i], state_names, layout, cond_max, f"vertex {i}")
            for i in range(A.shape[0])
        ]
    )
    if not layout.has_jerk:
        return F, None
    Fj = np.array(
        [
            jerk_matrix(A[i], B[i], state_names, F[i], layout, cond_max, f"vertex {i}")
            for i in range(A.shape[0])
        ]
    )
    return F, Fj


def split(F: np.ndarray, n_x: int, free_index: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """(Gx (..., n_x, p), Gu (..., m, p)) with dx_ff = Gx a, du_ff = Gu a (zero rows for the
    states that are not free). Works on one F (r, p) or a stack (N, r, p)."""
    F = np.asarray(F, dtype=float)
    nf = len(free_index)
    Gx = np.zeros(F.shape[:-2] + (n_x, F.shape[-1]))
    Gx[..., list(free_index), :] = F[..., :nf, :]
    return Gx, F[..., nf:, :].copy()


def feedforward_residual(
    A: np.ndarray,
    B: np.ndarray,
    F: np.ndarray,
    free_index: Sequence[int],
    acc_index: Sequence[int],
    a: np.ndarray,
) -> np.ndarray:
    """A dx_ff + B du_ff - (a on the accelerated rows): the full 12-row residual (kinematic rows
    included) for a test acceleration a."""
    A = np.asarray(A, dtype=float)
    Gx, Gu = split(F, A.shape[0], free_index)
    r = A @ (Gx @ a) + np.asarray(B, dtype=float) @ (Gu @ a)
    r[list(acc_index)] -= a
    return r
