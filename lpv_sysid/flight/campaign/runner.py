"""The loop of `lpv-sysid fly phase1` (:class:`FlightRunner`): polls the bridge, feeds the
campaign sequencer and the recorder, carries out the campaign's actions and sends its
velocity command, on an injectable clock."""

from __future__ import annotations

import logging
import math
import signal
from typing import Callable

from lpv_sysid.errors import LpvSysidError
from lpv_sysid.flight.campaign.recorder import CampaignRecorder

log = logging.getLogger(__name__)


class FlightRunner:
    """Drives bridge + campaign + recorder on ``clock`` (see module docstring)."""

    def __init__(
        self,
        bridge,
        campaign,
        recorder: CampaignRecorder | None,
        clock: Callable[[], float],
        sleep: Callable[[float], None],
        period: float = 0.005,
        status_period: float = 1.0,
        echo: Callable[[str], None] | None = None,
    ) -> None:
        self.bridge = bridge
        self.campaign = campaign
        self.rec = recorder
        self.clock = clock
        self.sleep = sleep
        self.period = period
        self.status_period = status_period
        self.echo = echo or (lambda s: None)
        self.interrupts = 0
        self.max_gap = 0.0
        self.late_loops = 0
        self._interrupts_handled = 0
        self.gave_up = False
        self.events: list[dict] = []
        self.t0 = clock()
        self._next_status = -math.inf
        self.rotor_sources: dict[str, int] = {}

    # ------------------------------------------------------------------ helpers
    def interrupt(self, signo: int = signal.SIGINT) -> None:
        self.interrupts += 1
        self._interrupt_name = signal.Signals(signo).name

    def _event(self, t: float, source: str, level: str, message: str, show: bool = False) -> None:
        self.events.append(
            {"t": round(t - self.t0, 3), "source": source, "level": level, "message": message}
        )
        if level != "info" or source == "campaign" or show:
            self.echo(f"[{t - self.t0:8.2f} s] {source}: {message}")
        if self.rec is not None and self.rec.started:
            self._safe(lambda: self.rec.status(t, level, f"{source}: {message}", self._values()))

    def _values(self) -> dict:
        c = self.campaign
        run = c.run
        st = self.bridge.machine
        d = {
            "phase": c.phase,
            "run": run.name
            if run is not None and c.phase in ("settle", "trim", "excitation")
            else "",
            "bridge_state": st.state.value,
            "vehicle_mode": st.vehicle_mode.name if st.vehicle_mode is not None else "unknown",
            "armed": st.armed,
        }
        if run is not None and c.phase in ("trim", "excitation"):
            d["v_d"] = " ".join(f"{x:g}" for x in run.vertex)
            res = c.results[-1] if c.results else None
            if res is not None and math.isfinite(res.t_excite):
                d["t_excite"] = res.t_excite
        d.update({k: v for k, v in self.bridge.envelope.status().items()})
        return d

    def _safe(self, fn) -> None:
        try:
            fn()
        except LpvSysidError as exc:
            if not self.campaign.finished:
                self.campaign.abort(self.clock(), f"recording failed: {exc}")
            log.error("recording failed: %s", exc)

    def _vehicle_status(self):
        from lpv_sysid.control.campaign import VehicleStatus

        m = self.bridge.machine
        env = self.bridge.envelope
        v = env.violation
        confirmed = getattr(m, "confirmed_mode", None)
        return VehicleStatus(
            m.state.value,
            m.reason,
            m.vehicle_mode.name if m.vehicle_mode is not None else None,
            bool(m.armed),
            env.home if env.home is not None else None,
            f"{v.kind}: {v.message}" if v is not None else None,
            confirmed.name if confirmed is not None else None,
        )

    # ------------------------------------------------------------------ loop
    def run(self) -> None:
        from lpv_sysid.control import campaign
        from lpv_sysid.mavlink.telemetry import ImuSample, RotorSample, StateSample

        c, b = self.campaign, self.bridge
        now = self.clock()
        self._handle(now, c.start(now))
        prev = now
        warn_gap = 0.5 * b.config.offboard.input_timeout
        while not c.finished:
            t_loop = self.clock()
            now = t_loop
            gap, prev = now - prev, now
            self.max_gap = max(self.max_gap, gap)
            if gap > warn_gap:
                # the computer did not keep up (load, swapping): PX4 got no setpoints meanwhile
                self.late_loops += 1
                self._event(
                    now,
                    "runner",
                    "warn",
                    f"loop stalled {gap:.3f} s (> {warn_gap:.3f} s = half the "
                    "bridge input_timeout): the companion computer is overloaded",
                )
            if self.interrupts > self._interrupts_handled and c.phase not in campaign.TERMINAL:
                self._interrupts_handled = self.interrupts
                if self.interrupts >= 2:
                    self._bridge_events(now, b.shutdown(now))
                    self.gave_up = True
                    self._event(
                        now,
                        "campaign",
                        "error",
                        "interrupted twice: stopped waiting for the "
                        "hand-back confirmation (HAND-BACK NOT CONFIRMED)",
                    )
                    break
                c.abort(now, f"interrupted ({getattr(self, '_interrupt_name', 'SIGINT')})")
            out = b.poll(now)
            for s in out.samples:
                if isinstance(s, StateSample):
                    c.on_state(s)
                    if self.rec is not None:
                        self._safe(
                            lambda s=s: self.rec.state(
                                s.t, s.pos_ned, s.euler, s.v_body, s.omega, s.t_vehicle
                            )
                        )
                elif isinstance(s, RotorSample):
                    c.on_rotor(s.t, s.omega)
                    src = getattr(s, "source", "esc")
                    self.rotor_sources[src] = self.rotor_sources.get(src, 0) + 1
                    if self.rec is not None:
                        self._safe(
                            lambda s=s, src=src: self.rec.rotors(s.t, s.omega, src, s.t_vehicle)
                        )
                elif isinstance(s, ImuSample) and self.rec is not None:
                    self._safe(lambda s=s: self.rec.imu(s.t, s.accel_frd, s.gyro_frd, s.t_vehicle))
            self._bridge_events(now, out.events)
            co = c.step(now, self._vehicle_status())
            self._handle(now, co)
            if self.rec is not None and now >= self._next_status:
                self._next_status = now + self.status_period
                self._safe(
                    lambda: self.rec.status(now, "info", f"campaign {c.phase}", self._values())
                )
            self.sleep(max(0.0, self.period - (self.clock() - t_loop)))
        from lpv_sysid.mavlink.offboard import STREAMING

        if b.machine.state in STREAMING:  # never leave a stream behind
            self.drain_handback(c.cfg.handback_timeout)

    def _bridge_events(self, now: float, events) -> None:
        for ev in events:
            level = getattr(ev, "level", "warn")
            text = getattr(ev, "reason", None)
            if text is None:
                text = f"{getattr(ev, 'kind', 'link')}: {getattr(ev, 'detail', '')}"
                level = "info" if getattr(ev, "kind", "") == "link_up" else "warn"
            prev, state = getattr(ev, "previous", None), getattr(ev, "state", None)
            moved = prev is not None and prev != state
            if moved:
                text = f"{prev} -> {state}: {text}"
            self._event(getattr(ev, "t", now), "bridge", level, text, show=moved)

    def _handle(self, now: float, co) -> None:
        from lpv_sysid.control import campaign

        b = self.bridge
        for ev in co.events:
            self._event(ev.t, "campaign", ev.level, f"{ev.phase}: {ev.message}")
        for a in co.actions:
            if isinstance(a, campaign.StartBridge):
                self._bridge_events(now, b.start(now))
            elif isinstance(a, campaign.AbortBridge):
                self._bridge_events(now, b.abort(now, a.reason))
            elif isinstance(a, campaign.FinishBridge):
                self._bridge_events(now, b.finish(now, a.mode))
            elif isinstance(a, campaign.ActivateFloor):
                b.envelope.activate_floor(now, a.reason)
            elif isinstance(a, campaign.RunStarted):
                if self.rec is not None:
                    self._safe(
                        lambda a=a: self.echo(
                            f"[{now - self.t0:8.2f} s] recording {a.run.name} -> "
                            f"{self.rec.begin_run(a.run.name)}"
                        )
                    )
            elif isinstance(a, campaign.RunEnded):
                if self.rec is not None:
                    self.rec.end_run()
        if co.command is not None and not self.campaign.finished:
            v, r = co.command
            if b.on_velocity_reference(now, v, r, stamp=now) and self.rec is not None:
                self._safe(lambda: self.rec.reference(now, v, r))

    def prime(self, timeout: float = 3.0) -> None:
        """Poll the bridge until the telemetry and a HEARTBEAT are in and, for a vehicle that is
        already armed, PX4's HOME_POSITION (requested once a second; the envelope's home),
        at most ``timeout``."""
        b = self.bridge
        t0 = self.clock()
        next_req = t0
        while self.clock() - t0 < timeout:
            now = self.clock()
            out = b.poll(now)
            for s in out.samples:
                if hasattr(s, "v_body"):
                    self.campaign.on_state(s)
            self._bridge_events(now, out.events)
            if (
                self.campaign.state is not None
                and b.machine.vehicle_mode is not None
                and (b.envelope.home_position is not None or not b.machine.armed)
            ):
                return  # disarmed: the home is where PX4 arms (envelope docstring)
            if now >= next_req:
                next_req = now + 1.0
                b.link.command_long(512, 242.0)  # MAV_CMD_REQUEST_MESSAGE HOME_POSITION
            self.sleep(self.period)

    def drain_handback(self, timeout: float) -> None:
        """After an exception: hand back at once and poll until confirmed (bounded)."""
        from lpv_sysid.mavlink.offboard import STREAMING, State

        b = self.bridge
        now = self.clock()
        self._bridge_events(now, b.shutdown(now))
        t0 = now
        while b.machine.state in STREAMING + (State.HANDBACK,) and self.clock() - t0 < timeout:
            now = self.clock()
            self._bridge_events(now, b.poll(now).events)
            self.sleep(self.period)
