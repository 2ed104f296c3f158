"""Synthetic LTI identification data with a known truth (oracle for tests and benchmarks).

A known ``(A, B)`` is driven by a Schroeder-phased multisine (harmonics of ``1/T`` in
``band_hz``, assigned round-robin to the inputs so the inputs are mutually orthogonal, the
idea of seed 0 Sec. V / Morelli's ``mkmsswp``; the product's signal designer lives in
``lpv_sysid.signals``, this is a self-contained stand-in so identification tests do not
depend on it).  The state is computed with ``scipy.signal.lsim`` (first-order hold: exact
for the piecewise-linear input), the exact derivative is ``A x + B u``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lsim

from lpv_sysid.errors import ConfigError


@dataclass(frozen=True)
class LtiData:
    t: np.ndarray
    x: np.ndarray  # (N, n_x) exact states
    u: np.ndarray  # (N, n_u)
    xdot: np.ndarray  # (N, n_x) exact derivatives A x + B u


def multisine(
    t: np.ndarray,
    n_u: int,
    band_hz=(0.2, 2.0),
    amplitude: float = 1.0,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Orthogonal Schroeder-phased multisine, one harmonic set per input, (N, n_u)."""
    t = np.asarray(t, dtype=float)
    T = t[-1] - t[0] + (t[1] - t[0])
    k = np.arange(max(1, int(np.ceil(band_hz[0] * T))), int(np.floor(band_hz[1] * T)) + 1)
    if k.size < n_u:
        raise ConfigError(f"record too short for {n_u} orthogonal inputs in {band_hz} Hz")
    u = np.zeros((t.size, n_u))
    for j in range(n_u):
        kj = k[j::n_u]
        m = kj.size
        phase = -np.pi * np.arange(1, m + 1) * np.arange(m) / m  # Schroeder phases
        if rng is not None:
            phase = phase + rng.uniform(0, 2 * np.pi)
        sig = np.sin(2 * np.pi * np.outer(t - t[0], kj) / T + phase).sum(axis=1)
        u[:, j] = amplitude * sig / np.max(np.abs(sig))
    return u


def simulate(
    A: np.ndarray, B: np.ndarray, u: np.ndarray, t: np.ndarray, x0: np.ndarray | None = None
) -> LtiData:
    """Exact FOH simulation of ``xdot = A x + B u`` with ``scipy.signal.lsim``."""
    n = A.shape[0]
    C = np.eye(n)
    D = np.zeros((n, B.shape[1]))
    _, _, x = lsim((A, B, C, D), u, t, X0=x0, interp=True)
    x = np.asarray(x).reshape(t.size, n)
    return LtiData(t, x, u, x @ A.T + u @ B.T)


def random_stable_system(
    n_x: int, n_u: int, rng: np.random.Generator, max_real: float = -0.3
) -> tuple[np.ndarray, np.ndarray]:
    """A random well-damped ``(A, B)``: eigenvalues with real part <= ``max_real``."""
    Q, _ = np.linalg.qr(rng.normal(size=(n_x, n_x)))
    lam = -rng.uniform(-max_real, 3.0, size=n_x)
    A = Q @ np.diag(lam) @ Q.T + 0.5 * rng.normal(size=(n_x, n_x)) * (np.eye(n_x) == 0) * 0.3
    ev = np.linalg.eigvals(A)
    if np.max(ev.real) > max_real:
        A = A - (np.max(ev.real) - max_real) * np.eye(n_x)
    B = rng.normal(size=(n_x, n_u))
    return A, B


def closed_loop(
    A: np.ndarray,
    B: np.ndarray,
    t: np.ndarray,
    excitation: np.ndarray,
    Q: np.ndarray | None = None,
    R: np.ndarray | None = None,
) -> tuple[LtiData, np.ndarray]:
    """Perturbation data of ``A, B`` under an LQR state feedback plus excitation.

    ``du = K dx + e`` with ``K = -R^-1 B^T P`` (``scipy.linalg.solve_continuous_are``), the
    closed loop ``A + B K`` driven through ``B`` by ``e`` (seed 0 Eq. 17, ``u = u_c + R u_e``)
    is simulated exactly (FOH), and the open-loop derivative ``A dx + B du`` is returned -
    the phase-1 situation (a stabilising baseline plus excitation) with a linear plant.
    Returns ``(LtiData(t, dx, du, dxdot), K)``.
    """
    from scipy.linalg import solve_continuous_are

    n, m = B.shape
    Q = np.eye(n) if Q is None else Q
    R = np.eye(m) if R is None else R
    P = solve_continuous_are(A, B, Q, R)
    K = -np.linalg.solve(R, B.T @ P)
    cl = simulate(A + B @ K, B, excitation, t)
    du = cl.x @ K.T + excitation
    return LtiData(t, cl.x, du, cl.x @ A.T + du @ B.T), K


def nonlinear_flight(
    model,
    t: np.ndarray,
    v_ref: np.ndarray,
    excitation: np.ndarray,
    controller=None,
    x16_0: np.ndarray | None = None,
):
    """Closed-loop flight of the nonlinear quadrotor (``models.quadrotor``) for identification
    oracles: RK4 at the grid step with the command held (ZOH) over each step, command
    ``u = controller.step(t, state, v_ref) + excitation``. Returns ``(x16 (N,16), u (N,4),
    xdot16 (N,16))`` with the exact model derivative at every sample."""
    from lpv_sysid.control.baseline import BaselineController
    from lpv_sysid.models.quadrotor import reduced_state

    ctrl = controller or BaselineController()
    dt = float(t[1] - t[0])
    if x16_0 is None:
        tr = model.trim(v_ref[0])
        x16_0 = tr.full_state
        ctrl.warm_start(tr.x0, tr.u0, v_ref[0])
    x = np.array(x16_0, dtype=float)
    n = t.size
    X = np.empty((n, 16))
    U = np.empty((n, 4))
    XD = np.empty((n, 16))
    arm = model.params.arm_length
    for k in range(n):
        uk = (
            np.asarray(ctrl.step(t[k], reduced_state(x, arm), v_ref[k]), dtype=float)
            + excitation[k]
        )
        X[k], U[k] = x, uk
        f = model.derivatives
        k1 = f(x, uk)
        XD[k] = k1
        k2 = f(x + 0.5 * dt * k1, uk)
        k3 = f(x + 0.5 * dt * k2, uk)
        k4 = f(x + dt * k3, uk)
        x = x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        if not np.all(np.isfinite(x)):
            raise ConfigError(f"nonlinear flight diverged at t={t[k]:.2f} s")
    return X, U, XD
