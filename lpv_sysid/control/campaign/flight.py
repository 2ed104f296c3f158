"""The flying phases of the campaign: take-off, reposition to a run's start point, settle on
the vertex, trim, excitation and recover, with the altitude hold and the guards of a run
(the rules are in :mod:`lpv_sysid.control.campaign`)."""

from __future__ import annotations

import math

import numpy as np

from lpv_sysid.control.campaign.handback import CampaignHandback
from lpv_sysid.control.campaign.plan import LEVEL, make_excitation
from lpv_sysid.control.campaign.protocol import (
    EXCITATION,
    FINISHING,
    RECOVER,
    REPOSITION,
    SETTLE,
    TRIM,
    ActivateFloor,
    FinishBridge,
    RunEnded,
    RunStarted,
)
from lpv_sysid.control.campaign.results import RunResult


class CampaignFlight(CampaignHandback):
    """The phases of :class:`lpv_sysid.control.campaign.Campaign` in which it commands the
    vehicle (``takeoff`` to ``recover``)."""

    # ------------------------------------------------------------------ phases
    def _takeoff(self, now, s, h, out) -> None:
        cfg = self.cfg
        if now - self.t_phase > cfg.takeoff_timeout:
            return self._fault(
                now,
                f"take-off not complete within {cfg.takeoff_timeout:g} s "
                f"(height {h:.2f} m of {self._h_target:g} m)",
                out,
                self._vs,
            )
        v = self._goto(s, h)
        if self._dwell(
            now,
            abs(h - self._h_target) < cfg.altitude_tolerance
            and self._speed(s) < cfg.hover_tolerance,
        ):
            self.t_takeoff_done = now
            out.actions.append(ActivateFloor(f"take-off complete at {h:.1f} m"))
            self._next_run(now, s, h, out)
            return
        self._send(now, v, out)

    def _reposition(self, now, s, h, out) -> None:
        cfg = self.cfg
        if now - self.t_phase > cfg.reposition_timeout:
            return self._fault(
                now,
                f"{self._active_run.name}: start point not reached within reposition_timeout "
                f"{cfg.reposition_timeout:g} s (height {h:.1f} m, target "
                f"{self._h_target:.1f} m)",
                out,
                self._vs,
            )
        v = self._goto(s, h)
        d = float(np.linalg.norm(np.asarray(s.pos_ned)[:2] - self._xy_target))
        if self._dwell(
            now,
            abs(h - self._h_target) < cfg.altitude_tolerance
            and d < cfg.position_tolerance
            and self._speed(s) < cfg.hover_tolerance,
        ):
            run = self._active_run
            res = RunResult(run.name, run.vertex, run.kind, t_command=now, height_start=h)
            self.results.append(res)
            self._h_target = h
            self._ff = 0.0
            self._go(now, SETTLE, f"{run.name}: commanding vertex {list(run.vertex)} m/s", out)
            self._send(now, self._vertex_command(s, h), out)
            return
        self._send(now, v, out)

    def _settle(self, now, s, h, out) -> None:
        cfg = self.cfg
        run, res = self._active_run, self.results[-1]
        cmd = self._vertex_command(s, h)
        err = self._frame_velocity(s) - cmd
        inside = bool(np.all(np.abs(err) <= np.asarray(cfg.settle_tolerance)))
        if inside and self._dwell_since is None:
            self._dwell_since = now
            self._bias_sum, self._bias_n = 0.0, 0
        elif not inside:
            self._dwell_since = None
        if inside and self._last_cmd is not None:
            self._bias_sum += float(self._frame_velocity(s)[2] - self._last_cmd[0][2])
            self._bias_n += 1
        if self._dwell_since is not None and now - self._dwell_since >= cfg.settle_dwell:
            res.settle_time = self._dwell_since - res.t_command
            self._dwell_since = None
            if run.kind == LEVEL:
                # vertical velocity beyond the command over the dwell -> feedforward (docstring)
                bias = self._bias_sum / self._bias_n if self._bias_n else 0.0
                self._h_target = h
                self._ff = min(max(-bias, -cfg.hold_max), cfg.hold_max)
                self._frozen = np.array([0.0, 0.0, self._hold_dz(h)])
            else:
                self._frozen = np.zeros(3)
            res.hold_correction = float(self._frozen[2])
            res.t_start = now
            self._go(
                now,
                TRIM,
                f"{run.name}: settled after {res.settle_time:.2f} s; trim {cfg.trim_s:g} s",
                out,
            )
            out.actions.append(RunStarted(run, now))
            self._recording = True
            self._send(now, np.asarray(run.vertex) + self._frozen, out, force=True)
            return
        if now - res.t_command > cfg.settle_timeout:
            vf = self._frame_velocity(s)
            return self._fault(
                now,
                f"{run.name}: not settled within settle_timeout {cfg.settle_timeout:g} s: "
                f"velocity ({', '.join(f'{x:.2f}' for x in vf)}) of commanded "
                f"({', '.join(f'{x:.2f}' for x in cmd)}) m/s ({cfg.velocity_frame}), "
                f"tolerance {list(cfg.settle_tolerance)}",
                out,
                self._vs,
            )
        self._send(now, cmd, out)

    def _trim(self, now, s, h, out) -> None:
        run, res = self._active_run, self.results[-1]
        if now - res.t_start >= self.cfg.trim_s:
            self._finish_trim(res)
            t, u, names = self.table
            exc = make_excitation(
                t, u, names, start_time=now, ramp=self.cfg.ramp_s, periods=self.cfg.periods
            )
            self._exc = exc
            res.t_excite = now
            self._go(now, EXCITATION, f"{run.name}: excitation {exc.duration:.1f} s", out)
            return self._excitation(now, s, h, out)
        self._send(now, np.asarray(run.vertex) + self._frozen, out)

    def _excitation(self, now, s, h, out) -> None:
        run, res = self._active_run, self.results[-1]
        exc = self._exc
        if exc is None:  # abort() dropped it; the next step() runs the abort
            return
        if now >= exc.end_time:
            res.t_end = now
            res.complete = True
            self._finish_tracking(res)
            self._recording = False
            out.actions.append(RunEnded(run, now, True, res))
            self._h_target = min(max(h, self.cfg.altitude_min), self.cfg.altitude_max)
            self._ff = 0.0
            self._go(now, RECOVER, f"{run.name}: complete; returning to hover", out)
            return self._recover(now, s, h, out)
        ex = exc.sample(now)
        base = np.asarray(run.vertex) + (self._hold_vector(s, h) if run.kind == LEVEL else 0.0)
        self._send(now, base + ex.velocity, out, yaw_rate=float(ex.yaw_rate))

    def _recover(self, now, s, h, out) -> None:
        cfg = self.cfg
        if now - self.t_phase > cfg.recover_timeout:
            return self._fault(
                now,
                f"hover not regained within recover_timeout {cfg.recover_timeout:g} s "
                f"(speed {self._speed(s):.2f} m/s)",
                out,
                self._vs,
            )
        v = np.zeros(3) + self._hold_vector(s, h)
        if self._dwell(now, self._speed(s) < cfg.hover_tolerance):
            return self._next_run(now, s, h, out)
        self._send(now, v, out)

    # ------------------------------------------------------------- transitions
    def _next_run(self, now, s, h, out) -> None:
        self.run_index += 1
        run = self.run
        if run is None:
            mode = str(self.cfg.finish).upper()
            self._go(
                now,
                FINISHING,
                f"all {len(self.plan.runs)} runs complete; handing back in {mode}",
                out,
            )
            self.t_handback_request = now
            out.actions.append(FinishBridge(mode))
            return
        lo, hi = run.start_window
        self._h_target = min(max(h, lo), hi)
        if self.cfg.center_runs:
            psi = float(np.asarray(s.euler)[2])
            uv = np.asarray(run.vertex[:2], dtype=float)
            c, sn = math.cos(psi), math.sin(psi)
            d = np.array([c * uv[0] - sn * uv[1], sn * uv[0] + c * uv[1]]) * run.duration_nominal
            self._xy_target = self._home_ned[:2] - 0.5 * d
        else:
            self._xy_target = np.asarray(s.pos_ned, dtype=float)[:2].copy()
        self._go(
            now,
            REPOSITION,
            f"run {run.order}/{len(self.plan.runs)} {run.name}: start at "
            f"{self._h_target:.1f} m, {np.linalg.norm(self._xy_target - self._home_ned[:2]):.1f} "
            "m "
            "from home",
            out,
        )
        self._send(now, self._goto(s, h), out)

    # ------------------------------------------------------ commands and run guards
    def _goto(self, s, h) -> np.ndarray:
        """P loop to (xy target, height target) in NED, limited, in the command frame."""
        cfg = self.cfg
        pos = np.asarray(s.pos_ned, dtype=float)
        v = np.zeros(3)
        if self._xy_target is not None:
            e = cfg.position_gain * (self._xy_target - pos[:2])
            n = float(np.linalg.norm(e))
            v[:2] = e * (cfg.horizontal_speed / n) if n > cfg.horizontal_speed else e
        up = min(max(cfg.position_gain * (self._h_target - h), -cfg.descent_rate), cfg.climb_rate)
        v[2] = -up
        return self._to_frame(s, v)

    def _hold_dz(self, h: float) -> float:
        dz = self._ff + self.cfg.hold_gain * (h - self._h_target)
        return min(max(dz, -self.cfg.hold_max), self.cfg.hold_max)

    def _hold_vector(self, s, h) -> np.ndarray:
        """The altitude correction in the command frame (MAV_FRAME_BODY_NED keeps NED z)."""
        return np.array([0.0, 0.0, self._hold_dz(h)])

    def _vertex_command(self, s, h) -> np.ndarray:
        run = self._active_run
        v = np.asarray(run.vertex, dtype=float)
        return v + self._hold_vector(s, h) if run.kind == LEVEL else v

    def _dwell(self, now: float, ok: bool) -> bool:
        if not ok:
            self._dwell_since = None
            return False
        if self._dwell_since is None:
            self._dwell_since = now
        return now - self._dwell_since >= self.cfg.settle_dwell

    def _guard(self, now, s, h) -> str:
        cfg = self.cfg
        tol = cfg.altitude_margin
        if h < cfg.altitude_min - tol or h > cfg.altitude_max + tol:
            return (
                f"{self._active_run.name}: height {h:.1f} m left the altitude window "
                f"[{cfg.altitude_min:g}, {cfg.altitude_max:g}] m (+- margin {tol:g} m)"
            )
        d = float(np.linalg.norm(np.asarray(s.pos_ned)[:2] - self._home_ned[:2]))
        if d > cfg.radius:
            return (
                f"{self._active_run.name}: {d:.1f} m from home, outside campaign.radius "
                f"{cfg.radius:g} m"
            )
        if self.results:
            res = self.results[-1]
            res.height_min = min(res.height_min, h)
            res.height_max = max(res.height_max, h)
            res.distance_max = max(res.distance_max, d)
        return ""
