"""Seed 1 (Zangarini) VRFT benchmarks as data generators: Table 5.3 (Eqs. 5.4-5.5), LV100 (Eqs.
5.1-5.3).

The plants are used only to *generate* data and to evaluate the tuned loop; VRFT never sees them.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from lpv_sysid.vrft.tf import first_order_model

# Eq. (5.4): G(z) = K0 / (z - 0.9048), Ts = 1 s
TABLE53_K0 = np.array([[0.09516, 0.03807], [-0.02974, 0.04758]])
TABLE53_POLE = 0.9048
TABLE53_M_POLE = 0.9  # Eq. (5.5): M = 0.1/(z-0.9) I
# Table 5.3, MIMO column: C_ij = (a_ij z - b_ij)/(z - 1)
TABLE53_MIMO_A = np.array([[0.8406, -0.6726], [0.5254, 1.681]])
TABLE53_MIMO_B = np.array([[0.7606, -0.6086], [0.4754, 1.521]])
# Table 5.3, SISO column (decentralised tuning on the thesis' own unpublished data set)
TABLE53_SISO_A = np.array([1.082, 2.223])
TABLE53_SISO_B = np.array([1.023, 2.057])


def table53_plant_ss():
    """State space (A, B, C, D) of Eq. (5.4): x+ = 0.9048 x + K0 u, y = x."""
    return (TABLE53_POLE * np.eye(2), TABLE53_K0.copy(), np.eye(2), np.zeros((2, 2)))


def table53_ideal_pi() -> tuple[np.ndarray, np.ndarray]:
    """Ideal controller C* = G^-1 M (I - M)^-1 (seed 1 Eq. 3.3) = K0^-1 (0.1 z - 0.1*0.9048)/(z -
    1).

    Returns (a, b) of C_ij = (a_ij z - b_ij)/(z - 1); it lies in the 2x2 PI class, so VRFT is
    exact.
    """
    Ki = np.linalg.inv(TABLE53_K0)
    g = 1.0 - TABLE53_M_POLE
    return g * Ki, g * TABLE53_POLE * Ki


def prbs(
    n: int, channels: int, rng: np.random.Generator, min_hold: int = 1, max_hold: int = 5
) -> np.ndarray:
    """+-1 random binary sequence with random hold times in [min_hold, max_hold] samples."""
    out = np.empty((n, channels))
    for c in range(channels):
        k = 0
        level = rng.choice([-1.0, 1.0])
        while k < n:
            h = int(rng.integers(min_hold, max_hold + 1))
            out[k : k + h, c] = level
            level = -level
            k += h
    return out


def table53_data(n: int = 500, seed: int = 0, noise_std: float = 0.0):
    """Open-loop PRBS experiment on Eq. (5.4) from rest: returns (t, u, y, y_clean)."""
    rng = np.random.default_rng(seed)
    u = prbs(n, 2, rng)
    A, B, C, D = table53_plant_ss()
    _, y, _ = signal.dlsim(signal.dlti(A, B, C, D, dt=1.0), u)
    y_clean = np.asarray(y)
    y_meas = y_clean + noise_std * rng.standard_normal(y_clean.shape)
    return np.arange(n, dtype=float), u, y_meas, y_clean


def table53_model():
    return first_order_model([TABLE53_M_POLE, TABLE53_M_POLE])


# ---------------------------------------------------------------------------------------------
# LV100 gas turbine, Eqs. (5.1)-(5.3)
# ---------------------------------------------------------------------------------------------
LV100_A = np.array(
    [
        [-1.4, -0.055, 0.0, 43.0, 6.3],
        [0.093, -0.11, 0.0, 4.2, -0.76],
        [-7.8, -0.26, -3.3, 300.0, -4.5],
        [0.0, 0.0, 0.0, -25.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, -33.0],
    ]
)
LV100_B = np.vstack([np.zeros((3, 2)), np.eye(2)])
LV100_C = np.array([[1.0, 0, 0, 0, 0], [0, 0, 1.0, 0, 0]])
LV100_TS = 0.1
LV100_M_POLE = 0.6  # Eq. (5.3): 0.4/(z - 0.6) I
LV100_C0_K = np.array([[1.0, 0.1], [-1.0, 1.0]])  # Eq. (5.2): C0 = C0_K (z - 0.99)/(z - 1)
# Table 5.2, N = 1e4 column: mean (sigma) of Kp, Ki for entries (1,1), (2,1), (1,2), (2,2)
LV100_T52_KP = {
    (0, 0): (0.075, 0.031),
    (1, 0): (18.698, 0.925),
    (0, 1): (0.288, 0.014),
    (1, 1): (2.149, 0.117),
}
LV100_T52_KI = {
    (0, 0): (2.823, 0.132),
    (1, 0): (6.238, 0.443),
    (0, 1): (1.086, 0.050),
    (1, 1): (9.268, 0.439),
}


def lv100_plant_ss():
    """Eq. (5.1) discretised with Tustin at Ts = 0.1 s, as in the thesis."""
    A, B, C, D, _ = signal.cont2discrete(
        (LV100_A, LV100_B, LV100_C, np.zeros((2, 2))), LV100_TS, method="bilinear"
    )
    return A, B, C, D


def lv100_data(
    n: int = 5000,
    seed: int = 0,
    noise_var: float = 0.0025,
    amplitude: float = 1.0,
    closed_loop: bool = True,
    noise_seed: int | None = None,
    c0_gain: np.ndarray | None = None,
):
    """PRBS experiment on the LV100 (seed 1 Sec. 5.1.1): returns (t, u, y_meas, excitation).

    Closed loop with C0 of Eq. (5.2), PRBS injected at the plant input (Fig. 3.2, u = C0 e +
    u_bar),
    the two channels excited one after the other, white measurement noise of variance ``noise_var``
    fed back through C0. With ``closed_loop=False`` u = u_bar (open loop). ``noise_seed`` (default:
    ``seed``) draws the noise separately, so the same PRBS can be reused across noise realisations.
    ``c0_gain`` replaces the matrix gain of Eq. (5.2) (the printed one does not stabilise Eq. 5.1,
    see :func:`lv100_c0_spectral_radius`).
    """
    rng = np.random.default_rng(seed)
    nrng = rng if noise_seed is None else np.random.default_rng([seed, noise_seed])
    A, B, C, D = lv100_plant_ss()
    ub = np.zeros((n, 2))
    h = n // 2
    ub[:h, 0] = amplitude * prbs(h, 1, rng, 1, 3)[:, 0]
    ub[h:, 1] = amplitude * prbs(n - h, 1, rng, 1, 3)[:, 0]
    v = np.sqrt(noise_var) * nrng.standard_normal((n, 2))
    x = np.zeros(A.shape[0])
    u = np.zeros((n, 2))
    y = np.zeros((n, 2))
    uc_prev = np.zeros(2)
    e_prev = np.zeros(2)
    K = (
        (LV100_C0_K if c0_gain is None else np.asarray(c0_gain, float))
        if closed_loop
        else np.zeros((2, 2))
    )
    # C0: uc(k) = uc(k-1) + K (e(k) - 0.99 e(k-1)), e = -(y + v); y = Cx + D u (algebraic loop)
    S = np.linalg.inv(np.eye(2) + K @ D)
    for k in range(n):
        free = uc_prev - 0.99 * K @ e_prev + K @ (-(C @ x) - v[k])
        uk = S @ (free + ub[k]) if closed_loop else ub[k]
        uc = uk - ub[k]
        yk = C @ x + D @ uk
        e_prev = -(yk + v[k])
        uc_prev = uc
        u[k], y[k] = uk, yk
        x = A @ x + B @ uk
    return np.arange(n) * LV100_TS, u, y + v, ub


def lv100_model():
    return first_order_model([LV100_M_POLE, LV100_M_POLE])


def lv100_c0_spectral_radius(K: np.ndarray = LV100_C0_K) -> float:
    """Largest |eigenvalue| of the loop {Tustin LV100, C0 = K (z - 0.99)/(z - 1), u = C0 (r - y)}.

    With the printed Eq. (5.2) this is > 1: the thesis' initial controller does not stabilise the
    printed Eq. (5.1) plant, so the closed-loop experiment cannot be replicated as written.
    """
    A, B, C, D = lv100_plant_ss()
    # controller state xc (2): xc+ = xc + e, uc = K(1 - 0.99) xc + K e  ==  K (z - 0.99)/(z - 1)
    Ac, Bc, Cc, Dc = np.eye(2), np.eye(2), 0.01 * K, K
    # e = -y = -(C x + D u), u = Cc xc + Dc e  ->  u = S (Cc xc - Dc C x), S = (I + Dc D)^-1
    S = np.linalg.inv(np.eye(2) + Dc @ D)
    Ku_x, Ku_c = -S @ Dc @ C, S @ Cc
    Ae_x = -(C + D @ Ku_x)
    Ae_c = -D @ Ku_c
    Acl = np.block([[A + B @ Ku_x, B @ Ku_c], [Bc @ Ae_x, Ac + Bc @ Ae_c]])
    return float(np.max(np.abs(np.linalg.eigvals(Acl))))


#: bounds of the example studies (checked before anything is allocated)
MAX_RUNS = 10_000
MAX_SAMPLES = 10_000_000


def lv100_statistics(
    n: int,
    runs: int,
    method: str = "eiv",
    window: int = 20,
    seed: int = 0,
    eiv_weight: str = "identity",
):
    """Table 5.2 protocol: one PRBS input, ``runs`` noise realisations; mean and std of Kp, Ki.

    Returns (mean_Kp, std_Kp, mean_Ki, std_Ki), each 2x2, for the PI class of Sec. 5.1.1.
    """
    from lpv_sysid.errors import ConfigError
    from lpv_sysid.vrft.controller_class import pid_class
    from lpv_sysid.vrft.tuning import vrft

    if not 2 <= runs <= MAX_RUNS:
        raise ConfigError(
            f"runs {runs}: need 2 .. {MAX_RUNS} noise realisations (each is one VRFT "
            "identification)"
        )
    if not 50 <= n <= MAX_SAMPLES:
        raise ConfigError(f"--n {n}: the examples take 50 .. {MAX_SAMPLES} samples")
    cls = pid_class(2, 2, LV100_TS, ("p", "i"))
    kps, kis = [], []
    for r in range(runs):
        _, u, y, _ = lv100_data(n, seed, closed_loop=False, noise_seed=r)
        res = vrft(u, y, lv100_model(), cls, method=method, window=window, eiv_weight=eiv_weight)
        kps.append(res.K[0])
        kis.append(res.K[1])
    kp, ki = np.array(kps), np.array(kis)
    return kp.mean(0), kp.std(0, ddof=1), ki.mean(0), ki.std(0, ddof=1)


#: seed 1 Table 5.2 at N = 1e3: (theta, sigma) of Kp and Ki per entry (i, j)
LV100_T52_N1E3 = {
    "Kp": {
        (0, 0): (0.070, 0.116),
        (1, 0): (14.037, 1.172),
        (0, 1): (0.310, 0.022),
        (1, 1): (1.477, 0.175),
    },
    "Ki": {
        (0, 0): (2.874, 0.189),
        (1, 0): (6.449, 1.006),
        (0, 1): (1.121, 0.060),
        (1, 1): (8.579, 0.510),
    },
}
