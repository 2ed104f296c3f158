"""The campaign sequencer's state and its primitives: phase transitions, the rate-limited
velocity command, a state sample measured in the command frame, the per-run statistics.
The phases build on it (:mod:`lpv_sysid.control.campaign.handback`,
:mod:`lpv_sysid.control.campaign.flight`); the public class is
:class:`lpv_sysid.control.campaign.Campaign`."""

from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from lpv_sysid.control.campaign.plan import CampaignPlan, PlannedRun
from lpv_sysid.control.campaign.protocol import (
    IDLE,
    TERMINAL,
    TRIM,
    CampaignEvent,
    CampaignOutput,
    VehicleStatus,
)
from lpv_sysid.control.campaign.results import RunResult
from lpv_sysid.io import frames

if TYPE_CHECKING:
    from lpv_sysid.signals.excitation import ExcitationCore

log = logging.getLogger(__name__)


class CampaignState:
    """State of one campaign over a :class:`CampaignPlan` (the base of
    :class:`lpv_sysid.control.campaign.Campaign`)."""

    def __init__(self, plan: CampaignPlan, excitation_table: tuple) -> None:
        self.plan = plan
        self.cfg = plan.config
        self.table = excitation_table
        self.phase = IDLE
        self.reason = ""
        self.ok: bool | None = None
        self.results: list[RunResult] = []
        self.run_index = -1
        self.state: Any = None
        self.home: np.ndarray | None = None
        self.t_phase = 0.0
        self.t_handback_request = math.nan
        self.t_handback_done = math.nan
        self.handback_mode = ""
        self.t_land_done = math.nan
        self.t_takeoff_done = math.nan
        self._next_cmd = -math.inf
        self._dwell_since: float | None = None
        self._h_target = math.nan
        self._xy_target: np.ndarray | None = None
        self._frozen = np.zeros(3)  # the trim/hold offset of the run, set when it settles
        self._ff = 0.0
        self._bias_sum, self._bias_n = 0.0, 0
        self._exc: ExcitationCore | None = None
        self._last_cmd: tuple | None = None
        self._recording = False
        self._rotor: tuple | None = None
        self._abort_request: str | None = None
        self._vs = VehicleStatus("IDLE")
        self._arm_length = self.cfg.arm_length if self.cfg.arm_length is not None else None

    # ------------------------------------------------------------- current run
    @property
    def finished(self) -> bool:
        return self.phase in TERMINAL

    @property
    def run(self) -> PlannedRun | None:
        return (
            self.plan.runs[self.run_index] if 0 <= self.run_index < len(self.plan.runs) else None
        )

    @property
    def _active_run(self) -> PlannedRun:
        """The run of a run phase (REPOSITION to EXCITATION), which always has one."""
        run = self.run
        if run is None:
            raise RuntimeError(f"campaign: phase {self.phase} has no current run")
        return run

    @property
    def _home_ned(self) -> np.ndarray:
        """Home (NED, m), known before the take-off starts."""
        if self.home is None:
            raise RuntimeError(f"campaign: phase {self.phase} needs the home position")
        return self.home

    def _go(
        self, now: float, phase: str, message: str, out: CampaignOutput, level: str = "info"
    ) -> None:
        self.phase = phase
        self.t_phase = now
        self._dwell_since = None
        log.debug("campaign %s: %s (%s)", phase, message, level)  # the runners present events
        out.events.append(CampaignEvent(now, phase, message, level))

    # ------------------------------------------------------------- helpers
    def _fresh(self, now: float) -> bool:
        return self.state is not None and now - float(self.state.t) <= self.cfg.state_timeout

    def _height(self, s) -> float:
        return float(self._home_ned[2] - float(s.pos_ned[2]))

    def _vel_ned(self, s) -> np.ndarray:
        v = getattr(s, "vel_ned", None)
        return (
            np.asarray(v, dtype=float)
            if v is not None
            else frames.body_to_world(s.v_body, s.euler)
        )

    def _speed(self, s) -> float:
        return float(np.linalg.norm(self._vel_ned(s)))

    def _frame_velocity(self, s) -> np.ndarray:
        """Measured velocity in the command frame: NED rotated by yaw (MAV_FRAME_BODY_NED)."""
        psi = float(np.asarray(s.euler)[2])
        v = self._vel_ned(s)
        c, sn = math.cos(psi), math.sin(psi)
        return np.array([c * v[0] + sn * v[1], -sn * v[0] + c * v[1], v[2]])

    def _to_frame(self, s, v_ned: np.ndarray) -> np.ndarray:
        psi = float(np.asarray(s.euler)[2])
        c, sn = math.cos(psi), math.sin(psi)
        return np.array([c * v_ned[0] + sn * v_ned[1], -sn * v_ned[0] + c * v_ned[1], v_ned[2]])

    def _send(
        self,
        now: float,
        v: np.ndarray,
        out: CampaignOutput,
        yaw_rate: float = 0.0,
        force: bool = False,
    ) -> None:
        if not force and now < self._next_cmd:
            return
        period = 1.0 / self.cfg.rate_hz
        self._next_cmd = (
            self._next_cmd + period if 0 <= now - self._next_cmd < period else now + period
        )
        cmd = (np.asarray(v, dtype=float).copy(), float(yaw_rate))
        self._last_cmd = cmd
        out.command = cmd

    # ------------------------------------------------------------- statistics
    def _accumulate(self, s) -> None:
        res = self.results[-1]
        if self._last_cmd is None:
            return
        vf = self._frame_velocity(s)
        e = np.r_[vf - self._last_cmd[0], float(np.asarray(s.omega)[2]) - self._last_cmd[1]]
        res._sq += e * e
        res._n += 1
        if (
            self.phase == TRIM
            and float(s.t) >= res.t_start + self.cfg.trim_s - self.cfg.trim_average_s
        ):
            res._trim_v.append(np.asarray(s.v_body, dtype=float))
            res._trim_vf.append(vf)
            res._trim_e.append(np.asarray(s.euler, dtype=float))

    def _finish_trim(self, res: RunResult) -> None:
        if not res._trim_v:
            return
        v = np.mean(res._trim_v, axis=0)
        e = np.degrees(np.mean(res._trim_e, axis=0))
        res.achieved_frame = tuple(float(x) for x in np.mean(res._trim_vf, axis=0))
        ach = {"u0": v[0], "v0": v[1], "w0": v[2], "phi0_deg": e[0], "theta0_deg": e[1]}
        if res._trim_rotor:
            from lpv_sysid.models.quadrotor import QuadrotorParams, mixer

            arm = (
                self._arm_length if self._arm_length is not None else QuadrotorParams().arm_length
            )
            delta = mixer(arm) @ np.mean(res._trim_rotor, axis=0)
            ach.update(dict(zip(("dt0", "da0", "de0", "dr0"), delta)))
        res.achieved = {k: float(x) for k, x in ach.items()}

    def _finish_tracking(self, res: RunResult) -> None:
        if res._n:
            rms = np.sqrt(res._sq / res._n)
            res.tracking_rms = {k: float(x) for k, x in zip(("u", "v", "w", "r"), rms)}
