"""The reference the flight runtime puts in front of the law (:class:`ReferenceLimiter`):
v_d limited to the rate and acceleration envelope the gains were designed for, so a
reference step cannot become a feedforward spike."""

from __future__ import annotations

from typing import Optional

import numpy as np

from lpv_sysid.configuration.fields import is_finite_number
from lpv_sysid.errors import ConfigError


class ReferenceLimiter:
    """The reference the law follows: v_d limited in rate and acceleration to the design
    envelope of the gains (``certificate.design``, :class:`lpv_sysid.io.formats.DesignEnvelope`),
    updated once per reference message at its header stamp.

    Per axis, with rate bound ``R1`` [m/s^2], acceleration bound ``R2`` [m/s^3] and the
    table's knot interval ``T`` (the excitation node plays the table linearly interpolated,
    so the played v_d has slope jumps at the knots): the output y has ``|dy/dt| <= R1`` and its
    slope stays within ``R2 (T + dt)`` of a smooth rate ``w_c`` that itself changes by at most
    ``R2 dt`` per message -- over any window W the slope changes by at most
    ``R2 (W + 2 T + 2 dt)``.
    A reference inside the envelope passes unchanged (bit for bit): the chord slopes of the
    linear interpolant of a signal with ``|s''| <= R2`` stay within ``R2 (T + dt)`` of s', and
    ``|s'| <= R1``. Outside it, y approaches the reference at the bounds with time-optimal
    braking (no overshoot beyond one step), so a step 0 -> 4.9 m/s becomes a ramp whose
    feedforward acceleration never exceeds R1.

    :meth:`update` also reports when the *incoming* reference exceeds the envelope by
    ``margin``: chord slope ``|dv/dt| > margin R1``, or a slope change between consecutive
    messages beyond ``margin 2 R2 (dt + T)`` (the largest change a signal inside the envelope
    can show, mean-value theorem over the knots); the caller aborts on it.
    """

    def __init__(self, rate_max, accel_max, knot_interval: float, margin: float) -> None:
        self.R1 = np.asarray(rate_max, dtype=float)
        self.R2 = np.asarray(accel_max, dtype=float)
        if (
            self.R1.shape != self.R2.shape
            or self.R1.ndim != 1
            or not (
                np.all(self.R1 > 0)
                and np.all(self.R2 > 0)
                and np.all(np.isfinite(self.R1))
                and np.all(np.isfinite(self.R2))
            )
        ):
            raise ConfigError(
                f"reference limiter: rate {self.R1.tolist()} and acceleration "
                f"{self.R2.tolist()} bounds must be positive, finite, one per axis"
            )
        if not (is_finite_number(knot_interval) and knot_interval >= 0.0):
            raise ConfigError(
                f"reference limiter: knot interval must be >= 0, got {knot_interval!r}"
            )
        if not (is_finite_number(margin) and margin >= 1.0):
            raise ConfigError(f"reference limiter: margin must be >= 1, got {margin!r}")
        self.T = float(knot_interval)
        self.margin = float(margin)
        self.reset()

    def reset(self) -> None:
        self.y: Optional[np.ndarray] = None  # the limited reference
        self.w = np.zeros(self.R1.size)  # its slope
        self.wc = np.zeros(self.R1.size)  # the smooth rate it stays close to
        self.t: Optional[float] = None
        self.r_prev: Optional[np.ndarray] = None
        self.w_in: Optional[np.ndarray] = None  # chord slope of the incoming reference
        self.limited = 0  # messages on which the limiter acted

    def update(self, t: float, r) -> tuple[np.ndarray, Optional[str]]:
        """The limited reference after the message ``(t, r)``, and a description of how the
        incoming reference exceeds the envelope by the margin (None when it does not). A
        stamp not after the previous one changes nothing (the supervisor judges stamps)."""
        r = np.array(r, dtype=float)
        if self.y is None or self.t is None:
            self.y, self.t, self.r_prev = r.copy(), float(t), r
            return self.y, None
        dt = float(t) - self.t
        if not dt > 0.0:
            return self.y, None
        w_in = (r - self.r_prev) / dt
        excess = None
        over = np.flatnonzero(np.abs(w_in) > self.margin * self.R1)
        if over.size:
            k = int(over[0])
            excess = (
                f"reference[{k}] changes at {w_in[k]:.4g} m/s^2, beyond the design rate "
                f"{self.R1[k]:.4g} m/s^2 x margin {self.margin:g}"
            )
        elif self.w_in is not None:
            jump = np.abs(w_in - self.w_in)
            allowed = self.margin * 2.0 * self.R2 * (dt + self.T)
            over = np.flatnonzero(jump > allowed)
            if over.size:
                k = int(over[0])
                excess = (
                    f"reference[{k}] slope changed by {jump[k]:.4g} m/s^2 in {dt:.4g} s, "
                    f"beyond the design acceleration {self.R2[k]:.4g} m/s^3 x margin "
                    f"{self.margin:g} (allowed {allowed[k]:.4g} m/s^2)"
                )
        band = self.R2 * (self.T + dt)  # slope tolerance around the smooth rate
        step = self.R2 * dt  # change of the smooth rate per message
        w_des = (r - self.y) / dt
        if np.all(np.abs(w_des) <= self.R1) and np.all(np.abs(w_des - self.wc) <= step + band):
            y, w = r, w_des  # inside the envelope: followed exactly
        else:
            e0 = self.r_prev - self.y  # gap before this message
            catch = np.sign(e0) * np.minimum(np.abs(e0) / dt, np.sqrt(2.0 * self.R2 * np.abs(e0)))
            w = np.clip(
                np.clip(w_in, -self.R1, self.R1) + catch,
                self.wc - step - band,
                self.wc + step + band,
            )
            w = np.clip(w, -self.R1, self.R1)
            y = self.y + w * dt
            self.limited += 1
        self.wc = self.wc + np.clip(w - self.wc, -step, step)
        self.y, self.w, self.t, self.r_prev, self.w_in = y, w, float(t), r, w_in
        return self.y, excess
