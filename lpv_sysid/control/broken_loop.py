"""Broken-loop excitation of the rate plant PX4 executes (issue 21 item 3b): a *stabilised*
run with a multisine superposed on the body-rate and thrust setpoints (the inputs of
lpv_sysid/models/rate_plant.py, sent as SET_ATTITUDE_TARGET), so the rate loops and the
heave row are excited independently of the state -- the excitation seed 0 applies to the
actuators and that cannot be commanded over MAVLink/MAVROS (PX4 >= 1.14 takes no actuator
setpoints). Identified by lpv_sysid/ident/rate_plant_dynamics.py.

Command at time t (state x = (phi, theta, u, v, w, p, q, r), FRD)::

    thrust = T_hover + k_w w            + a_T  s_T(t)     (w > 0 is down: more thrust)
    p_sp   = -k_att phi - k_v v         + a_p  s_p(t)
    q_sp   = -k_att theta + k_v u       + a_q  s_q(t)
    r_sp   =                              a_r  s_r(t)

The stabiliser (proportional attitude and a weak velocity and heave damping) keeps the
vehicle inside the envelope; its gains are low, so over the multisine band the setpoints are
dominated by the excitation. ``s_*`` are unit-peak Schroeder-phase multisines on disjoint
harmonics of ``1 / period`` in ``[f_min, f_max]`` (channel k takes every fourth harmonic,
offset k: uncorrelated channels, seed 0 Sec. IV zippered design), faded in and out over
``ramp_s`` by a raised cosine. Envelope: |phi|, |theta| <= ``max_tilt_deg``, |body velocity|
<= ``max_speed``; outside it the excitation is switched off for good (the stabiliser alone
flies, ``aborted`` is set with the reason) -- the caller hands back to PX4 as with every run.
Setpoints are clipped to ``max_rate`` and ``[thrust_min, thrust_max]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import ConfigError


@dataclass(frozen=True)
class BrokenLoopConfig:
    """The broken-loop run (module docstring), declared once."""

    duration_s: float = cf.number(
        60.0, "run length including both fades", lo=5.0, hi=600.0, unit=" s"
    )
    ramp_s: float = cf.number(3.0, "raised-cosine fade in and out", lo=0.0, hi=60.0, unit=" s")
    period_s: float = cf.number(
        20.0, "multisine period (frequency resolution 1/period)", lo=1.0, hi=600.0, unit=" s"
    )
    f_min: float = cf.number(0.2, "lowest excited frequency", lo=0.0, unit=" Hz")
    f_max: float = cf.number(
        6.0, "highest excited frequency (past the rate loops' resonance)", lo=0.0, unit=" Hz"
    )
    rate_amplitude: tuple = cf.numbers(
        (0.4, 0.4, 0.3), "peak multisine on p_sp, q_sp, r_sp", lo=0.0, hi=3.0, unit=" rad/s"
    )
    thrust_amplitude: float = cf.number(
        0.1,
        "peak multisine on the normalised thrust (0.05 left Z_T -12 % off on the simulated "
        "vehicle: the rate excitation's tilt dominated the heave row)",
        lo=0.0,
        hi=0.3,
    )
    k_att: float = cf.number(2.0, "attitude stabiliser gain", lo=0.0, hi=20.0, unit=" 1/s")
    k_v: float = cf.number(
        0.05, "horizontal velocity damping", lo=0.0, hi=2.0, unit=" rad/s per m/s"
    )
    k_w: float = cf.number(0.02, "heave damping (thrust per m/s of w)", lo=0.0, hi=1.0)
    max_tilt_deg: float = cf.number(
        25.0, "envelope: roll/pitch limit", lo=1.0, hi=60.0, unit=" deg"
    )
    max_speed: float = cf.number(3.0, "envelope: body speed limit", lo=0.1, hi=20.0, unit=" m/s")
    max_rate: float = cf.number(2.0, "body-rate setpoint clip", lo=0.1, hi=10.0, unit=" rad/s")
    thrust_min: float = cf.number(0.1, "thrust setpoint clip, low", lo=0.0, hi=1.0)
    thrust_max: float = cf.number(0.9, "thrust setpoint clip, high", lo=0.0, hi=1.0)

    def __post_init__(self) -> None:
        cf.normalize_fields(self, "broken_loop")
        if len(self.rate_amplitude) != 3:
            raise ConfigError(
                f"broken_loop: rate_amplitude needs 3 values (p, q, r), "
                f"got {list(self.rate_amplitude)}"
            )
        if not 0.0 < self.f_min < self.f_max:
            raise ConfigError(
                f"broken_loop: need 0 < f_min < f_max, got {self.f_min}, {self.f_max}"
            )
        if (self.f_max - self.f_min) * self.period_s < 8:
            raise ConfigError(
                "broken_loop: band x period must hold >= 8 harmonics (2 per channel), got "
                f"({self.f_max} - {self.f_min}) Hz x {self.period_s} s"
            )
        if not self.thrust_min < self.thrust_max:
            raise ConfigError(
                f"broken_loop: thrust_min {self.thrust_min} must be < thrust_max {self.thrust_max}"
            )
        if 2 * self.ramp_s >= self.duration_s:
            raise ConfigError(
                f"broken_loop: the fades (2 x {self.ramp_s} s) must be shorter than the run "
                f"({self.duration_s} s)"
            )


def multisine_channels(cfg: BrokenLoopConfig) -> tuple[np.ndarray, np.ndarray]:
    """(freqs (4, K), phases (4, K)) of the unit-peak-normalised channels (thrust, p, q, r):
    harmonic indices of ``1 / period`` in the band, channel k every fourth from offset k;
    Schroeder phases per channel."""
    f0 = 1.0 / cfg.period_s
    idx = np.arange(int(math.ceil(cfg.f_min / f0)), int(math.floor(cfg.f_max / f0)) + 1)
    per = [idx[k::4] for k in range(4)]
    K = min(len(h) for h in per)
    freqs = np.array([h[:K] * f0 for h in per])
    j = np.arange(1, K + 1)
    phases = np.tile(-np.pi * j * (j - 1) / K, (4, 1))
    return freqs, phases


class BrokenLoopRun:
    """Setpoints of one broken-loop run (module docstring): :meth:`command` per control tick."""

    def __init__(self, cfg: BrokenLoopConfig, hover_thrust: float) -> None:
        if not cfg.thrust_min < hover_thrust < cfg.thrust_max:
            raise ConfigError(
                f"broken_loop: hover thrust {hover_thrust} outside "
                f"({cfg.thrust_min}, {cfg.thrust_max})"
            )
        self.cfg = cfg
        self.hover_thrust = float(hover_thrust)
        self.freqs, self.phases = multisine_channels(cfg)
        # unit peak per channel over one period (numerical, fine grid)
        tg = np.arange(0.0, cfg.period_s, 1.0 / max(50.0, 10 * cfg.f_max))
        peaks = [
            float(np.max(np.abs(np.sin(2 * np.pi * np.outer(tg, f) + ph).sum(axis=1))))
            for f, ph in zip(self.freqs, self.phases)
        ]
        self.scale = np.array([cfg.thrust_amplitude, *cfg.rate_amplitude], dtype=float) / np.array(
            peaks
        )
        self.aborted: Optional[str] = None

    def excitation(self, t: float) -> np.ndarray:
        """Faded multisine (thrust, p_sp, q_sp, r_sp) at run time t (0 outside the run)."""
        c = self.cfg
        if not 0.0 <= t <= c.duration_s:
            return np.zeros(4)
        fade = 1.0
        if c.ramp_s > 0:
            edge = min(t, c.duration_s - t) / c.ramp_s
            if edge < 1.0:
                fade = 0.5 - 0.5 * math.cos(math.pi * edge)
        s = np.sin(2 * np.pi * self.freqs * t + self.phases).sum(axis=1)
        return fade * self.scale * s

    def command(self, t: float, x) -> np.ndarray:
        """(thrust, p_sp, q_sp, r_sp) for state ``x`` (phi, theta, u, v, w, p, q, r) at run time
        ``t``; checks the envelope first (outside: excitation off for good, ``aborted``)."""
        c = self.cfg
        phi, th, ub, vb, wb = (float(a) for a in np.asarray(x, dtype=float)[:5])
        if self.aborted is None:
            tilt = math.degrees(max(abs(phi), abs(th)))
            speed = math.sqrt(ub * ub + vb * vb + wb * wb)
            if not (math.isfinite(tilt) and math.isfinite(speed)):
                self.aborted = "state not finite"
            elif tilt > c.max_tilt_deg:
                self.aborted = f"tilt {tilt:.1f} deg > {c.max_tilt_deg} deg"
            elif speed > c.max_speed:
                self.aborted = f"speed {speed:.2f} m/s > {c.max_speed} m/s"
        e = self.excitation(t) if self.aborted is None else np.zeros(4)
        if not (math.isfinite(phi) and math.isfinite(th)):
            phi = th = ub = vb = wb = 0.0
        cmd = np.array(
            [
                self.hover_thrust + c.k_w * wb + e[0],
                -c.k_att * phi - c.k_v * vb + e[1],
                -c.k_att * th + c.k_v * ub + e[2],
                e[3],
            ]
        )
        cmd[0] = min(max(cmd[0], c.thrust_min), c.thrust_max)
        cmd[1:] = np.clip(cmd[1:], -c.max_rate, c.max_rate)
        return cmd
