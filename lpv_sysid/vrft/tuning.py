"""The VRFT estimate (:func:`vrft`, seed 1 Eqs. 3.17-3.31) from the filtered virtual signals
(:func:`vrft_filtered_signals`); the method is the :mod:`lpv_sysid.vrft` docstring."""

from __future__ import annotations

import logging

import numpy as np

from lpv_sysid.errors import ConfigError, SolverError
from lpv_sysid.vrft.controller import VrftResult
from lpv_sysid.vrft.controller_class import ControllerClass
from lpv_sysid.vrft.tf import (
    ONE,
    Tf,
    TfMatrix,
    _adj,
    _apply,
    _as_data,
    _check_model,
    _det,
    _is_scalar_identity,
    diagonal_model,
)

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------------------------
# the algorithm
# ----------------------------------------------------------------------------------------------


def vrft_filtered_signals(u, y, M: TfMatrix, prefilter: Tf | None = None):
    """(u_L, e_L) of seed 1 Eqs. (3.10)-(3.11) with L = M (Eq. 3.18), see module docstring."""
    u = _as_data(u, "u")
    y = _as_data(y, "y")
    n_y = _check_model(M)
    if y.shape[1] != n_y:
        raise ConfigError(f"y has {y.shape[1]} channels but the reference model is {n_y} x {n_y}")
    if u.shape[0] != y.shape[0]:
        raise ConfigError(f"u has {u.shape[0]} samples but y has {y.shape[0]}")
    if _is_scalar_identity(M):
        L = M[0][0]
        LMinv = diagonal_model([ONE] * n_y)
    else:
        L = _det(M)
        if L.is_zero:
            raise ConfigError(
                "reference model M is singular (det M = 0): no virtual reference exists"
            )
        LMinv = _adj(M)
    W = prefilter or ONE
    u_L = (W * L).filter(u)
    # e_L = W L (M^-1 - I) y = W (adj-or-I) y - W L y    (Eq. 3.8, 3.10; pseudo-code step 2)
    e_L = W.filter(_apply(LMinv, y)) - (W * L).filter(y)
    return u_L, e_L


def _regressor(e_L: np.ndarray, cls: ControllerClass) -> np.ndarray:
    """phi_L^T(k) stacked: array (N, n_u, n_theta), Eqs. (3.22)-(3.25)."""
    N = e_L.shape[0]
    idx = cls.param_index()
    filt = [b.filter(e_L) for b in cls.basis]  # (beta_q e_L)(k), (N, n_y)
    Phi = np.zeros((N, cls.n_u, len(idx)))
    for c, (q, i, j) in enumerate(idx):
        Phi[:, i, c] = filt[q][:, j]
    return Phi


def _rank_check(A: np.ndarray, names: list, what: str, rtol: float = 1e-9) -> float:
    s = np.linalg.svd(A, compute_uv=False)
    if s.size == 0 or s[0] == 0.0:
        raise SolverError(f"{what}: all regressors are zero (no excitation in the data)")
    if s[-1] <= rtol * s[0]:
        _, _, vt = np.linalg.svd(A)
        v = vt[-1]
        involved = [names[k] for k in np.argsort(-np.abs(v)) if abs(v[k]) > 0.1 * np.abs(v).max()]
        raise SolverError(
            f"{what} is rank deficient (sigma_min/sigma_max = {s[-1] / s[0]:.2e}): "
            f"collinear basis functions {involved}; excite more / use a smaller class"
        )
    return float(s[0] / s[-1])


def _assemble(theta: np.ndarray, cls: ControllerClass) -> list:
    K = [np.zeros((cls.n_u, cls.n_y)) for _ in cls.basis]
    for v, (q, i, j) in zip(theta, cls.param_index()):
        K[q][i, j] = v
    return K


def vrft(
    u,
    y,
    M: TfMatrix,
    cls: ControllerClass,
    *,
    method: str = "ls",
    prefilter: Tf | None = None,
    window: int = 5,
    instrument=None,
    y2=None,
    discard: int = 0,
    eiv_weight: str = "identity",
) -> VrftResult:
    """Identify theta of ``C(z; theta)`` so that the closed loop approaches ``M`` (seed 1 Sec.
    3.3).

    method:
      ``"ls"``  least squares, Eqs. (3.13)-(3.14);
      ``"eiv"`` extended IV, Eqs. (3.26)-(3.31) with zeta_L = [s_L(k+l) .. s_L(k-l)], l=window,
      where
              s = u (the thesis' choice, valid for open-loop data) or ``instrument`` (N x q, e.g.
              the
              external excitation of a closed-loop experiment, which is independent of the noise);
      ``"iv"``  second experiment / model-based instrument of Sec. 3.3.2: phi rebuilt from ``y2``
              (same input u, independent noise, or a model-simulated noise-free output).
    discard: samples dropped at the start of the regression (transient when data are not from
    rest).
    eiv_weight: ``"identity"`` (W = I, pseudo-code step 5) or ``"residual"``: two-step estimate of
      the residual covariance of Eq. (3.30), W = 1/N sum g g^T with g(k) = zeta_L(k) (x) eps(k) and
      eps the residual of the W = I solution, then Eq. (3.31) with that W.
    """
    u = _as_data(u, "u")
    y = _as_data(y, "y")
    if u.shape[1] != cls.n_u or y.shape[1] != cls.n_y:
        raise ConfigError(
            f"data have n_u={u.shape[1]}, n_y={y.shape[1]} but the controller class is "
            f"{cls.n_u} x {cls.n_y}"
        )
    names = cls.param_names()
    n_th = len(names)
    if n_th == 0:
        raise ConfigError("controller class has no free parameter (mask all False)")
    N = u.shape[0]
    window = int(window)
    if window < 0:
        raise ConfigError(f"EIV window l={window} must be >= 0")
    need = int(discard) + n_th + (2 * window + 1 if method == "eiv" else 0) + 10
    if N < need:
        raise ConfigError(
            f"data too short: N={N} samples, need at least {need} for {n_th} parameters"
            + (f" and EIV window l={window}" if method == "eiv" else "")
        )
    u_L, e_L = vrft_filtered_signals(u, y, M, prefilter)
    Phi = _regressor(e_L, cls)
    s = slice(int(discard), N)
    A = Phi[s].reshape(-1, n_th)
    b = u_L[s].reshape(-1)

    if method == "ls":
        cond = _rank_check(A, names, "VRFT regressor matrix (Eq. 3.14)")
        theta = np.linalg.lstsq(A, b, rcond=None)[0]
    elif method == "eiv":
        if instrument is None:
            z_L = u_L
        else:
            z = _as_data(instrument, "instrument")
            if z.shape[0] != N:
                raise ConfigError(f"instrument has {z.shape[0]} samples, data have {N}")
            z_L = _scalar_L(M, prefilter).filter(z)  # same filter as u_L (Eq. 3.26)
        # zeta_L(k) = [z_L(k+l); ...; z_L(k-l)] with l = window (Eq. 3.26)
        ks = np.arange(max(int(discard), window), N - window)
        Z = np.concatenate([z_L[ks + d] for d in range(window, -window - 1, -1)], axis=1)
        nk = ks.size
        R = np.einsum("ka,kbt->abt", Z, Phi[ks]).reshape(-1, n_th) / nk  # Eq. (3.28)
        r = np.einsum("ka,kb->ab", Z, u_L[ks]).reshape(-1) / nk  # Eq. (3.29)
        cond = _rank_check(R, names, "EIV correlation matrix R (Eq. 3.28)")
        theta = np.linalg.lstsq(R, r, rcond=None)[0]  # Eq. (3.31), W = I
        if eiv_weight == "residual":
            eps = u_L[ks] - np.einsum("kbt,t->kb", Phi[ks], theta)
            g = (Z[:, :, None] * eps[:, None, :]).reshape(nk, -1)  # zeta (x) eps
            W = g.T @ g / nk  # Eq. (3.30)
            W += 1e-9 * np.trace(W) / W.shape[0] * np.eye(W.shape[0])
            try:
                Lw = np.linalg.cholesky(W)
            except np.linalg.LinAlgError:
                raise SolverError(
                    "EIV residual covariance W (Eq. 3.30) is not positive definite"
                ) from None
            Rw = np.linalg.solve(Lw, R)
            cond = _rank_check(Rw, names, "weighted EIV matrix W^-1/2 R (Eq. 3.31)")
            theta = np.linalg.lstsq(Rw, np.linalg.solve(Lw, r), rcond=None)[0]
        elif eiv_weight != "identity":
            raise ConfigError(f"eiv_weight {eiv_weight!r}: use 'identity' or 'residual'")
    elif method == "iv":
        if y2 is None:
            raise ConfigError("method 'iv' needs a second output record y2 (same input u)")
        y2 = _as_data(y2, "y2")
        if y2.shape != y.shape:
            raise ConfigError(f"y2 has shape {y2.shape}, y has {y.shape}")
        _, e2 = vrft_filtered_signals(u, y2, M, prefilter)
        Z = _regressor(e2, cls)[s].reshape(-1, n_th)
        G = Z.T @ A
        cond = _rank_check(G, names, "IV matrix sum phi2 phi^T (Sec. 3.3.2)")
        theta = np.linalg.lstsq(G, Z.T @ b, rcond=None)[0]
    else:
        raise ConfigError(f"VRFT method {method!r}: use 'ls', 'eiv' or 'iv'")

    res = b - A @ theta
    J = float(res @ res / (N - int(discard)))
    log.debug("VRFT %s: N=%d, n_theta=%d, J_VR=%.3e, cond=%.2e", method, N, n_th, J, cond)
    return VrftResult(theta, _assemble(theta, cls), cls, method, J, N, cond, names)


def _scalar_L(M: TfMatrix, prefilter: Tf | None) -> Tf:
    L = M[0][0] if _is_scalar_identity(M) else _det(M)
    return (prefilter or ONE) * L
