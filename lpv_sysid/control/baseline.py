"""PX4-like cascaded baseline velocity controller (seed 0 Sec. IV, phase-1 flights).

Structure (after PX4 ``mc_pos_control`` / ``mc_att_control`` / ``mc_rate_control``):

1. Velocity loop (``velocity_rate_hz``): body-velocity reference v_d (FRD) and the measured
   body velocity are rotated into the heading frame (roll/pitch removed, yaw kept, seed 0
   Eq. 2 with psi = 0; the reference with a low-passed attitude, time constant
   ``ref_att_tau``, as a MAVROS body-frame setpoint converted at a low rate would be),
   PID -> acceleration setpoint, plus the optional PX4 vertical
   speed limits. Acceleration -> specific thrust f = a_sp - g e3 -> tilt-limited body z
   axis -> roll/pitch setpoint, collective ``ut = ut_hover sqrt(|f| / g)`` (thrust
   proportional to Omega^2, i.e. PX4 THR_MDL_FAC = 1). PX4's horizontal anti-windup
   (tracking of the tilt-limited acceleration) and vertical anti-windup (stop integrating
   into thrust saturation) are reproduced.
2. Attitude P loop: Euler-angle error -> Euler-rate demand -> body-rate setpoint through
   the inverse of Eq. (2); the yaw-rate reference is the body yaw-rate setpoint.
3. Rate PID (derivative on the filtered measured rate) -> virtual commands
   ``[ut, ua, ue, ur]`` of seed 0 Eq. (8), conditional-integration anti-windup.
4. Output mixing with PX4-like desaturation: the per-motor command Mix^-1 u must lie in
   [0, 1]; yaw authority is given up first, then collective is shifted, then roll/pitch
   are scaled.

The controller is a pure core: ``step(t, state, v_ref, r_ref) -> u``; no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Mapping

import numpy as np

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import SafetyError
from lpv_sysid.models.quadrotor import mixer


def _gain(default: float, doc: str) -> Any:
    return cf.number(default, doc, lo=0.0)


def _positive(default: float, doc: str, **kw: Any) -> Any:
    return cf.number(default, doc, lo=0.0, lo_open=True, **kw)


def _thrust(default: float, doc: str) -> Any:
    """A normalised collective (PX4 MPC_THR_*): in [0, 1]."""
    return cf.number(default, doc, lo=0.0, hi=1.0)


@dataclass(frozen=True)
class BaselineGains:
    """Gains and limits (PX4 parameter in brackets where one exists), checked on every
    construction (``config/quadrotor.yaml`` section ``controller``)."""

    vel_p_xy: float = _gain(1.8, "[MPC_XY_VEL_P_ACC] 1/s")
    vel_i_xy: float = _gain(0.4, "[MPC_XY_VEL_I_ACC] 1/s^2")
    vel_d_xy: float = _gain(0.2, "[MPC_XY_VEL_D_ACC] -")
    vel_p_z: float = _gain(4.0, "[MPC_Z_VEL_P_ACC] 1/s")
    vel_i_z: float = _gain(2.0, "[MPC_Z_VEL_I_ACC] 1/s^2")
    vel_d_z: float = _gain(0.0, "[MPC_Z_VEL_D_ACC] -")
    vel_int_limit: float = _gain(6.0, "|integral| per axis [m/s^2]")
    vel_d_cutoff_hz: float = _gain(5.0, "velocity derivative filter cutoff [Hz]")
    ref_att_tau: float = _gain(
        2.0, "low-pass time constant of the attitude that rotates v_d [s] (module doc)"
    )
    max_vel_up: float = _gain(8.0, "[MPC_Z_VEL_MAX_UP] world frame [m/s]")
    max_vel_down: float = _gain(8.0, "[MPC_Z_VEL_MAX_DN] world frame [m/s]")
    tilt_max_deg: float = _positive(
        35.0, "[MPC_TILTMAX_AIR] [deg], below 89 deg", hi=89.0, hi_open=True, unit=" deg"
    )
    hover_thrust: float = _thrust(0.54, "[MPC_THR_HOVER] collective u_t at hover")
    thr_min: float = _thrust(0.12, "[MPC_THR_MIN]")
    thr_max: float = _thrust(0.90, "[MPC_THR_MAX]")
    att_p_roll: float = _gain(5.0, "[MC_ROLL_P] 1/s")
    att_p_pitch: float = _gain(5.0, "[MC_PITCH_P] 1/s")
    rate_max_rp_deg: float = _gain(220.0, "[MC_ROLLRATE_MAX] [deg/s]")
    rate_max_yaw_deg: float = _gain(200.0, "[MC_YAWRATE_MAX] [deg/s]")
    rate_p_roll: float = _gain(0.030, "m / (rad/s) of virtual command u_a")
    rate_i_roll: float = _gain(0.030, "m / rad of u_a")
    rate_d_roll: float = _gain(0.0008, "m / (rad/s^2) of u_a")
    rate_p_pitch: float = _gain(0.030, "m / (rad/s) of u_e")
    rate_i_pitch: float = _gain(0.030, "m / rad of u_e")
    rate_d_pitch: float = _gain(0.0008, "m / (rad/s^2) of u_e")
    rate_p_yaw: float = _gain(0.60, "1 / (rad/s) of u_r")
    rate_i_yaw: float = _gain(0.30, "1 / rad of u_r")
    rate_d_yaw: float = _gain(0.0, "1 / (rad/s^2) of u_r")
    rate_int_limit_rp: float = _gain(0.05, "|rate integral| of u_a, u_e [m]")
    rate_int_limit_yaw: float = _gain(0.6, "|rate integral| of u_r")
    rate_d_cutoff_hz: float = _gain(30.0, "rate derivative filter cutoff [Hz]")
    rate_hz: float = _positive(250.0, "attitude + rate loop [Hz]")
    velocity_rate_hz: float = _positive(50.0, "velocity loop [Hz], at most rate_hz")
    arm_length: float = _positive(0.225, "arm length of the output mixer (seed 0 Eq. 7) [m]")

    def __post_init__(self) -> None:
        """The declared fields, then: thr_min < hover_thrust < thr_max, the velocity loop no
        faster than the rate loop."""
        cf.normalize_fields(self, "controller")
        if not self.thr_min < self.hover_thrust < self.thr_max:
            raise cf.error(
                "controller",
                "hover_thrust",
                f"need thr_min < hover_thrust < thr_max, got {self.thr_min:g}, "
                f"{self.hover_thrust:g}, {self.thr_max:g}",
            )
        if self.velocity_rate_hz > self.rate_hz:
            raise cf.error("controller", "velocity_rate_hz", "must not exceed rate_hz")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "controller") -> "BaselineGains":
        return cls(**cf.parse_fields(cls, d, where))

    def to_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


#: the leading STATE_NAMES the controller reads: attitude, body velocity, body rates
_RIGID_BODY_STATES = ("phi", "theta", "u", "v", "w", "p", "q", "r")


def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else (hi if x > hi else x)


class BaselineController:
    """PX4-like cascaded velocity -> attitude -> rate controller (pure core)."""

    def __init__(self, gains: BaselineGains | None = None) -> None:
        self.gains = gains if gains is not None else BaselineGains()
        g = self.gains
        self.mix = mixer(g.arm_length)
        self.mix_inv = np.linalg.inv(self.mix)
        self._mi = [list(map(float, r)) for r in self.mix_inv]
        self.grav = 9.80665
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        self.vel_int = [0.0, 0.0, 0.0]  # heading-frame acceleration integral, m/s^2
        self.rate_int = [0.0, 0.0, 0.0]  # output units (m, m, 1)
        self._vel_f: list[float] | None = None  # filtered heading-frame velocity (for D)
        self._vel_d = [0.0, 0.0, 0.0]
        self._rate_prev: list[float] | None = None
        self._rate_d = [0.0, 0.0, 0.0]
        self._n_step = 0
        self._att_f: list[float] | None = None
        self.att_sp = (0.0, 0.0)  # roll, pitch setpoint, rad
        self.thrust_sp = self.gains.hover_thrust
        self.rate_sp = (0.0, 0.0, 0.0)
        self._sat = {"thrust_lo": False, "thrust_hi": False, "tilt": False}

    def warm_start(self, state, u0, v_ref, r_ref: float = 0.0) -> None:
        """Set the integrators so that ``state`` with command ``u0`` is a steady state.

        Emulates a recording that starts with the vehicle already established at the
        reference condition (seed 0 Sec. IV: 10 s of constant reference before excitation).
        """
        self.reset()
        state = np.asarray(state, dtype=float)
        u0 = np.asarray(u0, dtype=float)
        phi, th = float(state[0]), float(state[1])
        g = self.gains
        fmag = self.grav * (float(u0[0]) / g.hover_thrust) ** 2
        zb = (math.cos(phi) * math.sin(th), -math.sin(phi), math.cos(phi) * math.cos(th))
        f = [-fmag * c for c in zb]
        acc = [f[0], f[1], f[2] + self.grav]
        e_h = self._heading(phi, th, [float(a) - float(b) for a, b in zip(v_ref, state[2:5])])
        self._att_f = [phi, th]
        kp = (g.vel_p_xy, g.vel_p_xy, g.vel_p_z)
        self.vel_int = [acc[i] - kp[i] * e_h[i] for i in range(3)]
        self.rate_int = [float(u0[1]), float(u0[2]), float(u0[3])]
        self.att_sp = (phi, th)
        self.thrust_sp = float(u0[0])
        self._rate_prev = [float(v) for v in state[5:8]]

    @staticmethod
    def _heading(phi: float, th: float, vb) -> list[float]:
        """Body (FRD) -> heading frame: R_IB of seed 0 Eq. (2) with psi = 0."""
        sf, cf, st, ct = math.sin(phi), math.cos(phi), math.sin(th), math.cos(th)
        return [
            ct * vb[0] + sf * st * vb[1] + cf * st * vb[2],
            cf * vb[1] - sf * vb[2],
            -st * vb[0] + sf * ct * vb[1] + cf * ct * vb[2],
        ]

    # ------------------------------------------------------------------ loops
    def _velocity_loop(self, dt: float, phi: float, th: float, v, v_ref) -> None:
        g = self.gains
        # The body-velocity reference is rotated with a low-passed attitude: rotating it
        # with the instantaneous attitude closes a fast positive loop (a tilt d_phi
        # changes the body-frame velocity by w d_phi, which the loop answers with more
        # tilt); the slow filter leaves a fixed-point iteration with gain ~0.2.
        if self._att_f is None:
            self._att_f = [phi, th]
        a_f = dt / (dt + g.ref_att_tau)
        self._att_f[0] += a_f * (phi - self._att_f[0])
        self._att_f[1] += a_f * (th - self._att_f[1])
        v_sp = self._heading(self._att_f[0], self._att_f[1], v_ref)
        v_sp[2] = _clip(v_sp[2], -g.max_vel_up, g.max_vel_down)
        v_h = self._heading(phi, th, v)
        e = [v_sp[i] - v_h[i] for i in range(3)]
        # D on the (first-order filtered) measured velocity, as PX4 (no derivative kick)
        alpha = dt / (dt + 1.0 / (2 * math.pi * g.vel_d_cutoff_hz))
        if self._vel_f is None:
            self._vel_f = list(v_h)
        for i in range(3):
            new = self._vel_f[i] + alpha * (v_h[i] - self._vel_f[i])
            self._vel_d[i] = -(new - self._vel_f[i]) / dt
            self._vel_f[i] = new
        kp = (g.vel_p_xy, g.vel_p_xy, g.vel_p_z)
        ki = (g.vel_i_xy, g.vel_i_xy, g.vel_i_z)
        kd = (g.vel_d_xy, g.vel_d_xy, g.vel_d_z)
        acc = [kp[i] * e[i] + self.vel_int[i] + kd[i] * self._vel_d[i] for i in range(3)]
        # specific thrust and tilt limit (PX4 ControlMath::limitTilt)
        f = [acc[0], acc[1], acc[2] - self.grav]
        fz = min(f[2], -0.1 * self.grav)
        horiz = math.hypot(f[0], f[1])
        tmax = math.tan(math.radians(g.tilt_max_deg))
        tilt_sat = horiz > -fz * tmax
        if tilt_sat:
            s = -fz * tmax / horiz
            f[0] *= s
            f[1] *= s
        f[2] = fz
        fmag = math.sqrt(f[0] ** 2 + f[1] ** 2 + f[2] ** 2)
        thr = g.hover_thrust * math.sqrt(fmag / self.grav)
        thr_c = _clip(thr, g.thr_min, g.thr_max)
        # integrators with PX4-style anti-windup
        acc_lim = [f[0], f[1], f[2] + self.grav]
        for i in (0, 1):
            e_i = e[i]
            if tilt_sat and kp[i] > 0:
                e_i = e[i] - (acc[i] - acc_lim[i]) * (2.0 / kp[i])
            self.vel_int[i] = _clip(
                self.vel_int[i] + ki[i] * e_i * dt, -g.vel_int_limit, g.vel_int_limit
            )
        # NED z: negative e pushes thrust up; stop integrating into saturation
        if not ((thr > g.thr_max and e[2] < 0) or (thr < g.thr_min and e[2] > 0)):
            self.vel_int[2] = _clip(
                self.vel_int[2] + ki[2] * e[2] * dt, -g.vel_int_limit, g.vel_int_limit
            )
        zb = [-c / fmag for c in f]
        phi_d = math.asin(_clip(-zb[1], -1.0, 1.0))
        th_d = math.atan2(zb[0], zb[2])
        self.att_sp = (phi_d, th_d)
        self.thrust_sp = thr_c

    def _desaturate(self, ut: float, ua: float, ue: float, ur: float):
        """PX4-like mixer desaturation; returns the feasible command and saturation flags."""
        mi = self._mi

        def esc(t, a, e, r):
            return [mi[i][0] * t + mi[i][1] * a + mi[i][2] * e + mi[i][3] * r for i in range(4)]

        sat = [False, False, False]
        m = esc(ut, ua, ue, ur)
        if min(m) >= 0.0 and max(m) <= 1.0:
            return (ut, ua, ue, ur), sat
        # 1) give up yaw
        m0 = esc(ut, ua, ue, 0.0)
        my = [mi[i][3] * ur for i in range(4)]
        k = 1.0
        for i in range(4):
            if m0[i] + my[i] > 1.0 and my[i] > 0:
                k = min(k, max(0.0, (1.0 - m0[i]) / my[i]))
            if m0[i] + my[i] < 0.0 and my[i] < 0:
                k = min(k, max(0.0, -m0[i] / my[i]))
        if k < 1.0:
            ur *= k
            sat[2] = True
        m = esc(ut, ua, ue, ur)
        if min(m) >= 0.0 and max(m) <= 1.0:
            return (ut, ua, ue, ur), sat
        # 2) shift collective if the spread fits, 3) otherwise scale roll/pitch/yaw
        spread = max(m) - min(m)
        if spread <= 1.0:
            shift = -min(m) if min(m) < 0 else 1.0 - max(m)
            ut += shift  # column 0 of Mix^-1 is all ones: u_t shifts every motor equally
            return (ut, ua, ue, ur), sat
        s = 1.0 / spread
        ua, ue, ur = ua * s, ue * s, ur * s
        m = esc(ut, ua, ue, ur)
        ut += -min(m) if min(m) < 0 else (1.0 - max(m) if max(m) > 1 else 0.0)
        return (ut, ua, ue, ur), [True, True, True]

    def step(self, t: float, state, v_ref, r_ref: float = 0.0) -> np.ndarray:
        """One attitude/rate update at ``rate_hz``; the velocity loop runs at its own rate.

        state: measured controller state in STATE_NAMES order; only its leading
            ``_RIGID_BODY_STATES`` are read (the delta entries may be left out).
        A non-finite measurement or reference raises SafetyError (the caller hands control
        back / holds position) instead of producing a NaN command.
        v_ref: body-velocity reference (FRD, m/s); r_ref: yaw-rate reference (rad/s, FRD).
        Returns the virtual actuator command u = [ut, ua, ue, ur] (seed 0 Eq. 8).
        """
        g = self.gains
        for i, name in enumerate(_RIGID_BODY_STATES):
            if not math.isfinite(float(state[i])):
                raise SafetyError(f"baseline controller: measured state {name} is not finite")
        for i, name in enumerate(("u_d", "v_d", "w_d")):
            if not math.isfinite(float(v_ref[i])):
                raise SafetyError(f"baseline controller: reference {name} is not finite")
        if not math.isfinite(float(r_ref)):
            raise SafetyError("baseline controller: yaw-rate reference is not finite")
        phi, th = float(state[0]), float(state[1])
        v = (float(state[2]), float(state[3]), float(state[4]))
        p, q, r = float(state[5]), float(state[6]), float(state[7])
        n_dec = max(1, int(round(g.rate_hz / g.velocity_rate_hz)))
        if self._n_step % n_dec == 0:
            self._velocity_loop(n_dec / g.rate_hz, phi, th, v, v_ref)
        self._n_step += 1
        dt = 1.0 / g.rate_hz
        # attitude P -> Euler rates -> body rates (inverse of seed 0 Eq. 2)
        phid = g.att_p_roll * (self.att_sp[0] - phi)
        thd = g.att_p_pitch * (self.att_sp[1] - th)
        sf, cf, st, ct = math.sin(phi), math.cos(phi), math.sin(th), math.cos(th)
        psid = float(r_ref) / max(cf * ct, 0.2)
        rmax = math.radians(g.rate_max_rp_deg)
        ymax = math.radians(g.rate_max_yaw_deg)
        p_sp = _clip(phid - st * psid, -rmax, rmax)
        q_sp = _clip(cf * thd + sf * ct * psid, -rmax, rmax)
        r_sp = _clip(-sf * thd + cf * ct * psid, -ymax, ymax)
        self.rate_sp = (p_sp, q_sp, r_sp)
        # rate PID, derivative on the filtered measurement
        meas = (p, q, r)
        if self._rate_prev is None:
            self._rate_prev = list(meas)
        alpha = dt / (dt + 1.0 / (2 * math.pi * g.rate_d_cutoff_hz))
        for i in range(3):
            self._rate_d[i] += alpha * ((meas[i] - self._rate_prev[i]) / dt - self._rate_d[i])
            self._rate_prev[i] = meas[i]
        kp = (g.rate_p_roll, g.rate_p_pitch, g.rate_p_yaw)
        ki = (g.rate_i_roll, g.rate_i_pitch, g.rate_i_yaw)
        kd = (g.rate_d_roll, g.rate_d_pitch, g.rate_d_yaw)
        lim = (g.rate_int_limit_rp, g.rate_int_limit_rp, g.rate_int_limit_yaw)
        e = (p_sp - p, q_sp - q, r_sp - r)
        out = [kp[i] * e[i] + self.rate_int[i] - kd[i] * self._rate_d[i] for i in range(3)]
        cmd, sat = self._desaturate(self.thrust_sp, out[0], out[1], out[2])
        for i in range(3):
            if sat[i] and (e[i] * out[i] > 0):
                continue  # conditional integration: do not wind up into saturation
            self.rate_int[i] = _clip(self.rate_int[i] + ki[i] * e[i] * dt, -lim[i], lim[i])
        return np.array(cmd)
