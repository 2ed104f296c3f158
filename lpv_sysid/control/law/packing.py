"""The gain schedule packed for the runtime law of :mod:`lpv_sysid.control.law.controller`.

The law (seed 0 Eq. 31, with the reference feedforward of seed 2 Eq. 102) is affine in the
multilinear weights alpha (Eq. 21), so every matrix it blends is stored as one row per vertex
and one product ``alpha @ W`` interpolates them all. The column blocks of each packed matrix
are named (:class:`VertexColumns`, :class:`StepLayout`), so no use site slices by offsets:

- :class:`VertexStack` ``W``: per vertex ``[vec K_i | x0_i | u0_i | vec G_i]`` with the dense
  feedforward map ``G_i = [G_x,i; G_u,i]`` ((n + m) x 2p): ``[a; j] -> (dx_ff over all n
  states, du_ff)``, F_ff and F_jerk scattered onto the state rows once here;
- :func:`step_matrix` ``W_step``: per vertex ``[gain_i | xref_i]`` with ``gain_i = [K_i | R |
  G_u,i | u0_i]`` (m x c) -- with a mixer followed by ``Mix^-1 gain_i`` (the ESC commands the
  saturation test needs, seed 0 Eq. 7) -- and ``xref_i = [G_x,i | x0_i]`` (n x (q + 1)), so a
  step is ``u = gain(alpha) @ b`` with ``b = [x - x_ref; u_e; [a; j]; 1]`` and ``x_ref =
  xref(alpha) @ [[a; j]; 1]``. R rides on the blend: sum alpha_i = 1, the result equals R u_e
  to rounding. ``q`` = p (F_ff), 2p (F_ff and F_jerk), 0 (no feedforward: xref_i = x0_i).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional, Sequence

import numpy as np

from lpv_sysid.errors import ConfigError


def _blocks(widths: Sequence[int]) -> list[slice]:
    """Consecutive blocks of the given widths: ``[slice(0, w0), slice(w0, w0 + w1), ...]``."""
    out, start = [], 0
    for w in widths:
        out.append(slice(start, start + w))
        start += w
    return out


def schedule_arrays(schedule: Any) -> tuple:
    """(K, x0, u0, R, Q, gamma, vmin, vmax): the attributes of io.formats.GainSchedule."""
    K = np.asarray(schedule.K, dtype=float)
    x0 = np.asarray(schedule.x0, dtype=float)
    u0 = np.asarray(schedule.u0, dtype=float)
    vmin, vmax = schedule.vmin, schedule.vmax
    return (
        K,
        x0,
        u0,
        np.asarray(schedule.R, float),
        np.asarray(schedule.Q, float),
        float(schedule.gamma),
        np.asarray(vmin, float),
        np.asarray(vmax, float),
    )


def feedforward_arrays(schedule: Any, n_x: int) -> Optional[tuple]:
    """(F (N, r, p), free state indices, F_jerk (N, r + n_rate, p) or None, rate state indices)
    of a schedule with feedforward, else None.

    ``schedule.feedforward`` is the io.formats.FeedforwardSpec of the gains file (any other
    layout object is refused); state names from ``schedule.state_names`` (quadrotor layout when
    the schedule has none)."""
    from lpv_sysid.io.formats import FeedforwardSpec

    F = getattr(schedule, "F_ff", None)
    spec = getattr(schedule, "feedforward", None)
    if F is None or spec is None:
        return None
    if not isinstance(spec, FeedforwardSpec):
        raise ConfigError(
            "gain schedule: feedforward must be the io.formats FeedforwardSpec of a gains file "
            f"read by io.formats.GainSchedule, got {type(spec).__name__}"
        )
    from lpv_sysid.models.quadrotor import STATE_NAMES

    free = list(spec.free_states)
    names = list(getattr(schedule, "state_names", None) or STATE_NAMES)
    rate = list(spec.rate_states)
    Fj = getattr(schedule, "F_jerk", None)
    if len(names) != n_x or any(s not in names for s in list(free) + list(rate)):
        raise ConfigError(
            f"feedforward states {list(free) + list(rate)} not among the schedule's states {names}"
        )
    if Fj is None or not rate:
        Fj, rate = None, []
    return (
        np.asarray(F, dtype=float),
        [names.index(s) for s in free],
        None if Fj is None else np.asarray(Fj, dtype=float),
        [names.index(s) for s in rate],
    )


@dataclass(frozen=True)
class VertexColumns:
    """Column blocks of a :class:`VertexStack` row (one vertex)."""

    K: slice  # vec K_i, row-major (m, n)
    x0: slice  # x0_i (n)
    u0: slice  # u0_i (m)
    G: slice  # vec [G_x,i; G_u,i], row-major (n + m, 2p); empty without feedforward


@dataclass(frozen=True)
class VertexStack:
    """``W`` (N, width): per vertex ``[vec K_i | x0_i | u0_i | vec G_i]`` (module docstring)."""

    W: np.ndarray
    cols: VertexColumns
    n_x: int
    n_u: int
    n_p: int
    has_ff: bool
    has_jerk: bool

    @property
    def K(self) -> np.ndarray:
        """(N, m, n) vertex gains."""
        return self.W[:, self.cols.K].reshape(self.W.shape[0], self.n_u, self.n_x)

    @property
    def x0(self) -> np.ndarray:
        """(N, n) vertex trim states."""
        return self.W[:, self.cols.x0]

    @property
    def u0(self) -> np.ndarray:
        """(N, m) vertex trim inputs."""
        return self.W[:, self.cols.u0]

    @property
    def G(self) -> np.ndarray:
        """(N, n + m, 2p) feedforward maps ``[a; j] -> [dx_ff; du_ff]`` (jerk columns zero
        without F_jerk); (N, n + m, 0) without feedforward."""
        q = 2 * self.n_p if self.has_ff else 0
        return self.W[:, self.cols.G].reshape(self.W.shape[0], self.n_x + self.n_u, q)

    @property
    def Gx(self) -> np.ndarray:
        """(N, n, 2p): state rows of :attr:`G` (dx_ff)."""
        return self.G[:, : self.n_x, :]

    @property
    def Gu(self) -> np.ndarray:
        """(N, m, 2p): input rows of :attr:`G` (du_ff)."""
        return self.G[:, self.n_x :, :]


def vertex_stack(
    K: np.ndarray, x0: np.ndarray, u0: np.ndarray, n_p: int, ff: Optional[tuple]
) -> VertexStack:
    """The :class:`VertexStack` of vertex gains ``K`` (N, m, n), trims ``x0``, ``u0`` and the
    feedforward of :func:`feedforward_arrays` (None: none); ConfigError on inconsistent
    feedforward shapes."""
    N, m, n = K.shape
    p = n_p
    # W = [vec K_i | x0_i | u0_i]: one product alpha @ W interpolates everything (Eq. 31)
    stack = [K.reshape(N, m * n), x0, u0]
    has_jerk = False
    if ff is not None:
        F, free, Fj, rate = ff
        if F.shape != (N, len(free) + m, p):
            raise ConfigError(
                f"gain schedule: F_ff has shape {F.shape}, expected ({N}, {len(free) + m}, {p})"
            )
        if not np.all(np.isfinite(F)):
            raise ConfigError("gain schedule: F_ff contains NaN/inf")
        ff_free = np.array(free, dtype=int)
        # dense per-vertex maps [a; j] -> (dx_ff over all n states, du_ff): scattered once
        # here so the step needs one small product each (G_x (n x 2p), G_u (m x 2p))
        nf = len(free)
        Gx = np.zeros((N, n, 2 * p))
        Gu = np.zeros((N, m, 2 * p))
        Gx[:, ff_free, :p] = F[:, :nf, :]
        Gu[:, :, :p] = F[:, nf:, :]
        if Fj is not None:
            if Fj.shape != (N, len(free) + m + len(rate), p) or not np.all(np.isfinite(Fj)):
                raise ConfigError(
                    f"gain schedule: F_jerk has shape {Fj.shape} (expected "
                    f"({N}, {len(free) + m + len(rate)}, {p})) or is not finite"
                )
            has_jerk = True
            fj_x = np.array(list(free) + list(rate), dtype=int)  # state rows of F_jerk
            Gx[:, fj_x, p:] = np.concatenate([Fj[:, :nf, :], Fj[:, nf + m :, :]], axis=1)
            Gu[:, :, p:] = Fj[:, nf : nf + m, :]
        # G(v_d) = sum alpha_i G_i, G_i = [G_x; G_u], rides on the same product as K, x0, u0
        stack.append(np.concatenate([Gx, Gu], axis=1).reshape(N, -1))
    g_width = (n + m) * 2 * p if ff is not None else 0
    k, x, u, g = _blocks([m * n, n, m, g_width])
    return VertexStack(
        W=np.ascontiguousarray(np.hstack(stack)),
        cols=VertexColumns(K=k, x0=x, u0=u, G=g),
        n_x=n,
        n_u=m,
        n_p=p,
        has_ff=ff is not None,
        has_jerk=has_jerk,
    )


@dataclass(frozen=True)
class StepLayout:
    """Where each blended matrix sits in a row of ``W_step`` (and so in ``alpha @ W_step``),
    and the blocks of the step's right-hand side ``b = [x - x_ref; u_e; [a; j]; 1]``
    (module docstring)."""

    n_x: int
    q: int  # feedforward rate columns: p (F_ff), 2p (F_ff and F_jerk), 0 (none)
    c: int  # columns of gain = entries of b = n + n_e + q + 1
    gain_rows: int  # m, or 2m with the ESC rows of a mixer
    gain: slice  # [K | R | G_u | u0] (m x c) [; Mix^-1 of it (m x c)], row-major
    xref: slice  # [G_x | x0] (n x (q + 1)), row-major; x0 (n) without feedforward
    u_rows: slice  # rows of gain @ b that are u (seed 0 Eq. 31)
    esc_rows: slice  # rows of gain @ b that are Mix^-1 u (seed 0 Eq. 7); empty without a mixer
    b_dx: slice  # x - x_ref
    b_ue: slice  # u_e
    b_rates: slice  # [a; j] (q)
    b_rates_one: slice  # [a; j; 1]
    b_one: int  # the constant 1 (picks u0)

    @property
    def width(self) -> int:
        return self.xref.stop


def step_matrix(
    stack: VertexStack, R: np.ndarray, mix_inv: Optional[np.ndarray]
) -> tuple[np.ndarray, StepLayout]:
    """``(W_step, layout)`` (module docstring): everything the step can precompute from the
    schedule, the excitation map ``R`` (m x n_e) and the inverse mixer (None: no ESC rows)."""
    N, n, m, p, ne = stack.W.shape[0], stack.n_x, stack.n_u, stack.n_p, R.shape[1]
    K, x0, u0 = stack.K, stack.x0, stack.u0
    q = 0
    if stack.has_ff:
        q = 2 * p if stack.has_jerk else p
        Gx, Gu = stack.Gx[:, :, :q], stack.Gu[:, :, :q]
    else:
        Gx, Gu = np.zeros((N, n, 0)), np.zeros((N, m, 0))
    c = n + ne + q + 1
    gain = np.concatenate([K, np.broadcast_to(R, (N, m, ne)), Gu, u0[:, :, None]], axis=2)
    if mix_inv is not None:
        gain = np.concatenate([gain, np.einsum("ij,njk->nik", mix_inv, gain)], axis=1)
    rows = gain.shape[1]
    parts = [gain.reshape(N, rows * c)]
    if stack.has_ff:
        parts.append(np.concatenate([Gx, x0[:, :, None]], axis=2).reshape(N, n * (q + 1)))
    else:
        parts.append(x0)
    gain_cols, xref_cols = _blocks([rows * c, parts[1].shape[1]])
    b_dx, b_ue, b_rates, _ = _blocks([n, ne, q, 1])
    layout = StepLayout(
        n_x=n,
        q=q,
        c=c,
        gain_rows=rows,
        gain=gain_cols,
        xref=xref_cols,
        u_rows=slice(0, m),
        esc_rows=slice(m, rows),
        b_dx=b_dx,
        b_ue=b_ue,
        b_rates=b_rates,
        b_rates_one=slice(b_rates.start, c),
        b_one=c - 1,
    )
    return np.ascontiguousarray(np.hstack(parts)), layout
