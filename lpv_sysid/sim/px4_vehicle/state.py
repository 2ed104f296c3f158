"""The state of the simulated PX4 vehicle: :class:`VehicleState` creates every attribute
the layers of :class:`lpv_sysid.sim.px4_vehicle.vehicle.SimVehicle` share (one place) and holds
the reads they all use (parameters, stick input, attitude) and COMMAND_ACK;
the behaviour is described in :mod:`lpv_sysid.sim.px4_vehicle.vehicle`."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from lpv_sysid.io import frames
from lpv_sysid.mavlink import codec, px4
from lpv_sysid.mavlink.link import LinkConfig, MavlinkLink
from lpv_sysid.sim.px4_vehicle.config import (
    DEFAULT_PARAMS,
    DEFAULT_RATES,
    PARAMS,
    SimVehicleConfig,
)

MAV_TYPE_QUADROTOR = 2
MANUAL_CONTROL_TIMEOUT_S = 0.5  # a MAVLink joystick counts this long after its last message


@dataclass
class Setpoint:
    """The newest offboard setpoint (SET_POSITION_TARGET_LOCAL_NED or SET_ATTITUDE_TARGET)."""

    kind: str  # "velocity" | "position" | "rates"
    t: float
    v_ned: np.ndarray | None = None
    pos_ned: np.ndarray | None = None
    yaw_rate: float = 0.0
    rates: np.ndarray | None = None
    thrust: float = 0.0


class VehicleState:
    """State of the simulated vehicle and the reads every layer uses."""

    def __init__(
        self,
        config: SimVehicleConfig | None = None,
        model: Any = None,
        controller_factory: Callable[[], Any] | None = None,
        link: MavlinkLink | None = None,
    ) -> None:
        self.config = config or SimVehicleConfig()
        self.config.validate()
        if model is None:
            from lpv_sysid.models.quadrotor import Quadrotor

            model = Quadrotor()
        if controller_factory is None:
            from lpv_sysid.control.baseline import BaselineController, BaselineGains

            arm = float(getattr(getattr(model, "params", None), "arm_length", 0.225))
            controller_factory = lambda: BaselineController(BaselineGains(arm_length=arm))  # noqa: E731
        self.model = model
        self._controller_factory = controller_factory
        self.ctrl = controller_factory()
        self.params: dict[str, tuple[float, int]] = dict(DEFAULT_PARAMS)
        for k, v in self.config.params.items():
            self.params[k] = (v, PARAMS[k].ptype)
        self.link = link or MavlinkLink(
            LinkConfig(
                url=self.config.url,
                source_system=self.config.system_id,
                source_component=self.config.component_id,
                streams=(),
                signing_key_file=self.config.signing_key_file,
                allow_unsigned=self.config.allow_unsigned,
                mav_type=MAV_TYPE_QUADROTOR,
            )
        )
        self._rng = np.random.default_rng(self.config.seed)
        self.dt = 1.0 / self.config.physics_hz
        self.t = 0.0  # simulated time since boot [s]
        self.x = np.zeros(16)  # FULL_STATE_NAMES, on the ground, motors off
        self.u = np.zeros(4)
        self.armed = False
        self.mode = px4.mode_by_name(self.config.initial_mode)  # what the HEARTBEAT shows
        self.user_mode = self.mode  # the mode last chosen by a user (PX4 user intention)
        self.failsafe_active = False
        self.landed = True
        self.took_off = False
        self.t_armed = 0.0
        self.armed_s = 0.0  # time armed since boot [s] (battery drain)
        self.t_landed = 0.0
        self.hold_pos = np.zeros(3)
        self.descending = False  # emergency Descend task (stick mode without sticks)
        self.setpoint: Setpoint | None = None
        #: (time_boot_ms, thrust) of the attitude setpoint PX4's ATTITUDE_TARGET repeats in
        #: body-rate OFFBOARD (telemetry.py); None outside it
        self.att_sp_echo: tuple[int, float] | None = None
        self._sp_times: list[float] = []
        self.setpoints_received = 0
        self.mode_log: list[tuple[float, str, str]] = []  # (t, mode name, reason)
        self.px4_log: list[tuple[float, str]] = []  # what PX4 would print (errors, warnings)
        self.acks_sent: list[tuple[float, int, int]] = []  # (t, command, result)
        self.param_rejections: list[tuple[float, str]] = []
        self.failsafe_reason = ""
        self.gcs_last_heartbeat: float | None = None
        self.local_address: tuple[str, int] | None = None
        self._t_joystick = -math.inf
        self._verdicts: list[tuple[float, int, Callable[[], int]]] = []
        self.intervals: dict[int, float] = {}
        self._next_send: dict[int, float] = {}
        self._next_hb = 0.0
        self._opened = False
        mod = codec.dialect_module(codec.DEFAULT_DIALECT)
        self._mod = mod
        self._stream_ids = {
            name: (
                codec.MAVLINK_MSG_ID_ESC_STATUS
                if name == "ESC_STATUS"
                else getattr(mod, f"MAVLINK_MSG_ID_{name}")
            )
            for name in DEFAULT_RATES
        }
        rates = {**DEFAULT_RATES, **dict(self.config.stream_rates)}
        for name, rate in rates.items():
            self.intervals[self._stream_ids[name]] = 1.0 / rate if rate > 0 else -1.0
        self._esc_cls = codec.esc_status_class(codec.DEFAULT_DIALECT)

    def param(self, name: str) -> float:
        return float(self.params[name][0])

    @staticmethod
    def _R(x: np.ndarray) -> np.ndarray:
        """R_IB of seed 0 Eq. (1) (ZYX Euler), via io/frames."""
        return frames.rotation_from_euler(x[3:6])

    def _yaw_R(self) -> np.ndarray:
        c, s = math.cos(self.x[5]), math.sin(self.x[5])
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def sticks_available(self, now: float | None = None) -> bool:
        """Manual control input as PX4 sees it (RC and/or MAVLink joystick, COM_RC_IN_MODE)."""
        t = self.t if now is None else now
        joystick = t - self._t_joystick <= MANUAL_CONTROL_TIMEOUT_S
        return px4.sticks_available(
            int(self.param("COM_RC_IN_MODE")), self.config.rc_present, joystick
        )

    def _ack(self, cmd: int, result: int) -> None:
        self.acks_sent.append((self.t, cmd, result))
        for _ in range(2 if self.config.duplicate_acks else 1):
            self.link.send(self.link.codec.command_ack_encode(cmd, result, 0, 0, 0, 0))
