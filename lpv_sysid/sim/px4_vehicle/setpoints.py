"""Offboard setpoints received by the simulated vehicle: SET_POSITION_TARGET_LOCAL_NED
(velocity, position, yaw rate; LOCAL_NED or BODY frames rotated by yaw only, as PX4) and
SET_ATTITUDE_TARGET body rates + thrust, and whether they form a live stream (what PX4's
commander requires for OFFBOARD);
the behaviour is described in :mod:`lpv_sysid.sim.px4_vehicle.vehicle`."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from lpv_sysid.sim.px4_vehicle.state import Setpoint, VehicleState


class SetpointInput(VehicleState):
    """The newest setpoint and the times of the recent ones."""

    def _stream_alive(self, now: float) -> bool:
        self._sp_times = [t for t in self._sp_times if now - t <= 1.0]
        return (
            len(self._sp_times) >= 2
            and self.setpoint is not None
            and now - self._sp_times[-1] <= self.param("COM_OF_LOSS_T")
        )

    def _sp_received(self, now: float, sp: Setpoint) -> None:
        self.setpoint = sp
        self.setpoints_received += 1
        self._sp_times.append(now)
        if len(self._sp_times) > 200:
            self._sp_times = self._sp_times[-100:]

    def _position_target(self, m: Any, now: float) -> None:
        mask = m.type_mask
        frame = m.coordinate_frame
        if frame in (8, 12):  # BODY_NED / BODY_FRD: PX4 rotates by yaw only
            R = self._yaw_R()
        elif frame == 1:
            R = np.eye(3)
        else:
            return
        use_pos = not (mask & 0x7)
        use_vel = not (mask & 0x38)
        yaw_rate = 0.0 if mask & 0x800 else float(m.yaw_rate)
        vel = R @ np.array([m.vx, m.vy, m.vz], dtype=float)
        if not np.isfinite(vel).all() or not math.isfinite(yaw_rate):
            return
        if use_pos:
            pos = np.array([m.x, m.y, m.z], dtype=float)
            pos = (R @ pos + self.x[0:3]) if frame in (8, 12) else pos
            sp = Setpoint(
                "position", self.t, v_ned=vel if use_vel else None, pos_ned=pos, yaw_rate=yaw_rate
            )
        elif use_vel:
            sp = Setpoint("velocity", self.t, v_ned=vel, yaw_rate=yaw_rate)
        else:
            return
        sp.t = now
        self._sp_received(now, sp)

    def _attitude_target(self, m: Any, now: float) -> None:
        if not m.type_mask & 128:  # attitude quaternion setpoints: not modelled
            return
        rates = np.array([m.body_roll_rate, m.body_pitch_rate, m.body_yaw_rate], dtype=float)
        if not np.isfinite(rates).all() or not math.isfinite(m.thrust):
            return
        self._sp_received(now, Setpoint("rates", now, rates=rates, thrust=float(m.thrust)))
