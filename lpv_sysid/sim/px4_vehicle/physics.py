"""Physics of the simulated vehicle: the seed 0 quadrotor (RK4 at ``physics_hz``) on flat
ground, driven by the flight task of the current mode (velocity setpoints for the PX4-like
cascaded controller of control/baseline.py, or the PX4 rate loop for body-rate setpoints);
the behaviour is described in :mod:`lpv_sysid.sim.px4_vehicle.vehicle`."""

from __future__ import annotations

import numpy as np

from lpv_sysid.mavlink import px4
from lpv_sysid.sim.px4_vehicle.commander import Commander
from lpv_sysid.sim.px4_vehicle.state import Setpoint


class FlightPhysics(Commander):
    """One fixed physics step at a time, with the mode's flight task."""

    def _physics_step(self) -> None:
        dt = self.dt
        x = self.x
        if not self.armed:
            self.u = np.zeros(4)
            x[12:16] = 0.0
            if self.landed:
                self.t += dt
                return
        else:
            self.u = self._control()
        u = self.u.tolist()
        f = self.model.derivatives_list
        xl = x.tolist()
        k1 = f(xl, u)
        k2 = f([a + 0.5 * dt * b for a, b in zip(xl, k1)], u)
        k3 = f([a + 0.5 * dt * b for a, b in zip(xl, k2)], u)
        k4 = f([a + dt * b for a, b in zip(xl, k3)], u)
        xn = np.array(
            [
                a + dt / 6.0 * (b1 + 2 * b2 + 2 * b3 + b4)
                for a, b1, b2, b3, b4 in zip(xl, k1, k2, k3, k4)
            ]
        )
        if not self.armed:
            xn[12:16] = 0.0
        self.t += dt
        # flat ground at z = 0 (NED): no penetration, no bounce, level on contact
        if xn[2] >= 0.0:
            v_ned = self._R(xn) @ xn[6:9]
            if v_ned[2] >= 0.0:
                xn[2] = 0.0
                xn[3:5] = 0.0
                xn[6:12] = 0.0
                if not self.landed:
                    self.landed, self.t_landed = True, self.t
        elif xn[2] < -0.1:
            if self.landed and self.armed:
                self.took_off = True
            self.landed = False
        self.x = xn

    def _control(self) -> np.ndarray:
        """Virtual actuator command for the current mode (PX4 flight-task stand-in)."""
        x = self.x
        sp = self.setpoint
        if self.mode == px4.OFFBOARD and sp is not None and sp.kind == "rates":
            return self._rate_mode(sp)
        v_ned, yaw_rate = self._velocity_setpoint()
        if self.landed and v_ned[2] > -0.2:
            self.ctrl.reset()  # PX4 keeps idle and resets integrators on ground
            return self.model.mix @ np.full(4, 0.1)
        v_body = self._R(x).T @ v_ned
        # STATE_NAMES order: phi, theta, body velocity, body rates, delta (unused) = 0
        controller_state = np.concatenate([x[3:5], x[6:12], np.zeros(4)])
        return np.asarray(self.ctrl.step(self.t, controller_state, v_body, yaw_rate), dtype=float)

    def _velocity_setpoint(self) -> tuple[np.ndarray, float]:
        x = self.x
        pos = x[0:3]
        m = self.mode
        if self.descending:
            # FlightTaskDescend: vertical speed MPC_LAND_SPEED, zero horizontal acceleration
            # (the horizontal reference follows the vehicle: nothing holds or brakes it)
            v = self._R(x) @ x[6:9]
            return np.array([v[0], v[1], self.param("MPC_LAND_SPEED")]), 0.0
        if m == px4.OFFBOARD and self.setpoint is not None:
            sp = self.setpoint
            if sp.kind == "velocity" and sp.v_ned is not None:
                return sp.v_ned.copy(), sp.yaw_rate
            if sp.kind == "position" and sp.pos_ned is not None:
                v = 1.0 * (sp.pos_ned - pos) + (sp.v_ned if sp.v_ned is not None else 0.0)
                return _clip_norm(v, 5.0), sp.yaw_rate
        if m == px4.LAND:
            v = _clip_norm(1.0 * (self.hold_pos - pos), 2.0)
            v[2] = self.param("MPC_LAND_SPEED")
            return v, 0.0
        if m == px4.RTL:
            d = -pos
            d[2] = 0.0
            if np.linalg.norm(d) > 0.5:
                v = _clip_norm(1.0 * d, 3.0)
                v[2] = 0.0
                return v, 0.0
            v = np.array([0.0, 0.0, self.param("MPC_LAND_SPEED")])
            return v, 0.0
        if m == px4.TAKEOFF:
            target = self.hold_pos.copy()
            target[2] = -self.param("MIS_TAKEOFF_ALT")
            if abs(pos[2] - target[2]) < 0.1:
                self._set_mode(px4.HOLD, self.t, "takeoff complete")
            return _clip_norm(1.0 * (target - pos), 2.0), 0.0
        # HOLD, POSCTL/ALTCTL/STABILIZED with centred sticks, OFFBOARD without setpoint
        v = _clip_norm(1.0 * (self.hold_pos - pos), 3.0)
        if m in (px4.ALTCTL, px4.MANUAL, px4.STABILIZED):
            v[0:2] = 0.0
        return v, 0.0

    def _rate_mode(self, sp: Setpoint) -> np.ndarray:
        """PX4 rate loop, P term: tau = K_p (omega_sp - omega); unit quad-X allocation."""
        kp = np.array(
            [self.param("MC_ROLLRATE_P"), self.param("MC_PITCHRATE_P"), self.param("MC_YAWRATE_P")]
        )
        rates = sp.rates if sp.rates is not None else np.zeros(3)  # set with kind "rates"
        tau = kp * (rates - self.x[9:12])
        alloc = np.array(
            [
                [1.0, -1.0, 1.0, 1.0],
                [1.0, 1.0, -1.0, 1.0],
                [1.0, 1.0, 1.0, -1.0],
                [1.0, -1.0, -1.0, -1.0],
            ]
        )
        u_esc = np.clip(alloc @ np.r_[sp.thrust, tau], 0.0, 1.0)
        return self.model.mix @ u_esc


def _clip_norm(v: np.ndarray, vmax: float) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v * (vmax / n) if n > vmax else v
