"""Message-level behaviour of campaign_node (no rclpy here).

:class:`CampaignRuntime` drives :class:`lpv_sysid.control.campaign.Campaign` (the core of
``lpv-sysid fly phase1``) from ROS messages: the node shell forwards its inputs (``state``,
``rotor_speeds``, ``imu`` parsed by :data:`PARSERS`; the bridge's ``status`` raw), its step
timer and its services, and gets back ``[(key, payload), ...]``: messages to publish on
``velocity_reference``, ``excitation`` (zeros: phase 1 has no u_e) and ``status``, or
``("call", "start" | "abort")``, a call of the bridge node's service. Log lines are queued
(:meth:`CampaignRuntime.take_log`) for the node's logger.

The bridge is followed through its ``status`` values (:func:`vehicle_status`). With
``out_dir`` one rosbag2 per run is recorded (:class:`lpv_sysid.cli.vehicle.fly.CampaignRecorder`);
a recording failure aborts the campaign; at the end ``campaign_summary.yaml`` and
``trims.yaml`` are written. A ``finish: LAND`` is flown as HOLD (the bridge node has no
finish service: the campaign ends with its hand-back chain).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from lpv_sysid.configuration import parameters
from lpv_sysid.control import campaign
from lpv_sysid.errors import LpvSysidError
from lpv_sysid.io import messages


@dataclass(frozen=True)
class CampaignNodeSettings(parameters.Settings):
    """The parameters of campaign_node, declared once."""

    WHERE = "campaign"

    campaign_file: str = parameters.text(
        "campaign.yaml", "config/campaign.yaml (campaign, bridge_config, signals_config)"
    )
    signals_file: str = parameters.text(
        "", "phase-1 signals.npz (empty: designed from signals_config)"
    )
    out_dir: str = parameters.text(
        "", "directory for one rosbag2 per run (empty: no per-run bags)"
    )
    bridge_node: str = parameters.text(
        "mavlink_bridge",
        "name of the bridge node in this namespace (its start/abort services and status)",
    )
    rate_hz: float = parameters.double(
        100.0, "campaign step rate [Hz] (references go out at campaign.rate_hz)", 10.0, 1000.0
    )
    status_rate_hz: float = parameters.double(2.0, "status publication rate [Hz]", 0.1, 100.0)
    auto_start: bool = parameters.flag(False, "start the campaign without the service")


Output = list[tuple[str, Any]]
#: after the bridge's start service is called, an IDLE bridge status is taken as the status
#: from before the call (published at status_rate_hz, after a DDS service round trip: 0.9 s
#: from call to "start requested" measured under real Jazzy at load ~10) for this long
START_ANSWER_S = 5.0


def parse_rotor_speeds(msg) -> tuple[float, np.ndarray, str]:
    """``rotor_speeds`` -> ``(t, omega, source)`` (source: esc | estimated)."""
    t, omega = messages.rotor_speeds_from_joint_state(msg)
    return t, omega, messages.rotor_source_of(msg)


#: the input topics parsed by the shell (``ShellNode.parse_input``: a bad message is dropped
#: with a throttled warning) before :meth:`CampaignRuntime.on_sample`
def parse_rate_setpoint(msg) -> tuple[float, np.ndarray]:
    """``rate_setpoint`` (the bridge's echo of PX4's ATTITUDE_TARGET: thrust, p_sp, q_sp,
    r_sp) -> ``(t, u)``."""
    from lpv_sysid.models.rate_plant import INPUT_NAMES

    t, u = messages.channels_from_joint_state(msg, INPUT_NAMES)
    return t, np.asarray(u, dtype=float)


PARSERS = {
    "state": messages.state_from_odometry,
    "rotor_speeds": parse_rotor_speeds,
    "imu": messages.imu_from_msg,
    "rate_setpoint": parse_rate_setpoint,
}


def vehicle_status(values: Mapping[str, str]) -> campaign.VehicleStatus:
    """:class:`~lpv_sysid.control.campaign.VehicleStatus` from the bridge node's status
    values (``BridgeCore.status``: strings)."""
    home = None
    text = values.get("envelope_home", "")
    if text and text != "unset":
        try:
            xyz = [float(v) for v in text.rsplit(": ", 1)[-1].split()]
            home = np.array(xyz) if len(xyz) == 3 and all(math.isfinite(v) for v in xyz) else None
        except ValueError:
            home = None
    mode = values.get("vehicle_mode") or None
    return campaign.VehicleStatus(
        values.get("state", "IDLE"),
        values.get("reason", ""),
        None if mode in (None, "unknown") else mode,
        values.get("armed") == "True",
        home,
        values.get("envelope_violation") or None,
        values.get("confirmed_mode") or None,
    )


class CampaignRuntime:
    """See module docstring. ``bridge_name``: the bridge node's fully qualified name;
    ``service_ready(which)``: whether its ``start`` / ``abort`` service is available."""

    def __init__(
        self,
        settings: CampaignNodeSettings,
        factory: messages.MsgFactory,
        name: str,
        bridge_name: str,
        service_ready: Callable[[str], bool],
    ) -> None:
        from lpv_sysid.flight.campaign.config import FlyConfig, bridge_config_for, load_signals

        self._log: list[tuple[str, str]] = []
        cfg = FlyConfig.load(settings.campaign_file)
        ccfg = cfg.campaign
        if str(ccfg.finish).upper() == "LAND":
            self._log.append(
                (
                    "warn",
                    "campaign finish LAND: mavlink_bridge_node has no finish service; "
                    "the campaign ends with the bridge's hand-back chain (HOLD)",
                )
            )
            ccfg = dataclasses.replace(ccfg, finish="HOLD")
        bcfg = bridge_config_for(cfg.bridge_config, None, ccfg)
        self.table = load_signals(settings.signals_file or None, cfg.signals_config)
        prof = campaign.ExcitationProfile.from_table(
            *self.table, ramp=ccfg.ramp_s, periods=ccfg.periods
        )
        self.plan = campaign.plan_campaign(ccfg, prof, bcfg.envelope)
        self.campaign = campaign.Campaign(self.plan, self.table)
        self.fly_cfg = cfg
        self.settings, self.f, self.name = settings, factory, name
        self.bridge_name = bridge_name
        self.service_ready = service_ready
        self.bridge_values: dict = {}
        self.rec: Any = None  # CampaignRecorder once started with out_dir
        #: the bridge's latest vehicle record (``vehicle_record``), for the runs'
        #: ``experiment.yaml`` ``vehicle`` (as ``fly phase1`` writes it)
        self.vehicle: dict | None = None
        self.out_dir = Path(settings.out_dir) if settings.out_dir else None
        self._written = False
        self._record_error_logged = False
        self._auto_start = settings.auto_start  # once the bridge's services are up
        self._start_called_at: float | None = None
        self._log.append(
            (
                "info",
                f"{len(self.plan.runs)} runs planned, excitation {prof.duration:.1f} s; "
                f"bridge {self.bridge_name}\n{self.plan.describe()}",
            )
        )

    def take_log(self) -> list[tuple[str, str]]:
        """Queued ``(level, text)`` lines (level: info | warn | error), oldest first."""
        out, self._log = self._log, []
        return out

    @property
    def recording(self) -> bool:
        """A run's bag is open (inputs are recorded)."""
        return self.rec is not None and self.rec.active is not None

    # -- inputs ---------------------------------------------------------------------------
    def wants(self, key: str) -> bool:
        """Whether an input is used now (``imu`` only while a run is recorded)."""
        return key not in ("imu", "rate_setpoint") or self.recording

    def on_sample(self, key: str, parsed: Any, now: float) -> Output:
        """An input parsed by :data:`PARSERS` ``[key]``."""
        out: Output = []
        rec = self.rec
        if key == "state":
            s = parsed
            self.campaign.on_state(s)
            if self.recording:
                self._record(
                    now, out, lambda: rec.state(s.t, s.pos_ned, s.euler, s.v_body, s.omega)
                )
        elif key == "rotor_speeds":
            t, omega, src = parsed
            self.campaign.on_rotor(t, omega)
            if self.recording:
                self._record(now, out, lambda: rec.rotors(t, omega, src))
        elif key == "imu" and self.recording:
            i = parsed
            self._record(now, out, lambda: rec.imu(i.t, i.specific_force, i.omega))
        elif key == "rate_setpoint" and self.recording:
            t_sp, u = parsed
            self._record(now, out, lambda: rec.rate_setpoint(t_sp, u))
        return out

    def on_status(self, msg: Any) -> None:
        """A ``status`` array: the bridge's values are kept (other nodes' are ignored)."""
        try:
            _, statuses = messages.status_from_diagnostic_array(msg)
        except LpvSysidError:
            return
        for st in statuses:
            if st.name == self.bridge_name:
                self.bridge_values = dict(st.values)

    def on_vehicle_record(self, msg: Any) -> None:
        """The bridge's ``vehicle_record``: kept, and written to the recording's
        ``experiment.yaml`` (``vehicle``) when one is open; a bad message is logged."""
        try:
            _, self.vehicle = messages.vehicle_record_from_msg(msg)
            if self.rec is not None:
                self.rec.annotate("vehicle", self.vehicle)
        except LpvSysidError as exc:
            self._log.append(("warn", f"vehicle_record ignored: {exc}"))

    # -- services -------------------------------------------------------------------------
    def _start(self, now: float, out: Output) -> str:
        if self.campaign.phase != campaign.IDLE:
            return f"already {self.campaign.phase}"
        if not (self.service_ready("start") and self.service_ready("abort")):
            return (
                f"not started: the bridge services {self.bridge_name}/start|abort "
                "are not available"
            )
        if self.out_dir is not None:
            from lpv_sysid.flight.campaign.recorder import CampaignRecorder

            self.rec = CampaignRecorder(
                self.out_dir,
                self.fly_cfg.storage,
                False,
                description="campaign_node: one bag per run",
                rate_setpoints=True,  # the echo of PX4's setpoints: identify --plant px4-rate
            )
            self.rec.start(now)
            if self.vehicle is not None:
                self.rec.annotate("vehicle", self.vehicle)
        self._handle(now, self.campaign.start(now), out)
        return f"campaign started: {len(self.plan.runs)} runs"

    def start(self, now: float) -> tuple[bool, str, Output]:
        """The ``~/start`` service: ``(success, message, output)``."""
        out: Output = []
        try:
            message = self._start(now, out)
            success = self.campaign.phase != campaign.IDLE
        except LpvSysidError as exc:
            success, message = False, str(exc)
        self._log.append(("info", f"start: {message}"))
        return success, message, out

    def abort(self, now: float, reason: str = "abort service") -> tuple[bool, str, Output]:
        """The ``~/abort`` service: excitation off, hand back; ``(success, message, output)``."""
        out: Output = []
        self._handle(now, self.campaign.abort(now, reason), out)
        message = f"campaign {self.campaign.phase}: excitation off, handing back"
        self._log.append(("warn", message))
        return True, message, out

    # -- loop -----------------------------------------------------------------------------
    def on_timer(self, now: float) -> Output:
        """The step timer: the auto start once the bridge answers, then a campaign step."""
        out: Output = []
        if self._auto_start and self.bridge_values and self.service_ready("start"):
            self._auto_start = False
            self._log.append(("info", f"auto start: {self._start(now, out)}"))
        if self.campaign.phase == campaign.IDLE:
            return out
        if not self.campaign.finished:
            vs = vehicle_status(self.bridge_values)
            if (
                vs.bridge_state == "IDLE"
                and self._start_called_at is not None
                and now - self._start_called_at < START_ANSWER_S
            ):
                # the bridge's status (2 Hz, after a service round trip) still shows the IDLE
                # from before the start call: not a refusal yet
                vs = dataclasses.replace(vs, bridge_state="START_REQUESTED")
            self._handle(now, self.campaign.step(now, vs), out)
        if self.campaign.finished and not self._written:
            self._finish(now)
        return out

    def _handle(self, now: float, co: campaign.CampaignOutput, out: Output) -> None:
        for a in co.actions:
            if isinstance(a, campaign.StartBridge):
                out.append(("call", "start"))
                self._start_called_at = now
            elif isinstance(a, (campaign.AbortBridge, campaign.FinishBridge)):
                out.append(("call", "abort"))
            elif isinstance(a, campaign.RunStarted) and self.rec is not None:
                name = a.run.name
                self._record(
                    now,
                    out,
                    lambda: self._log.append(
                        ("info", f"recording {name} -> {self.rec.begin_run(name)}")
                    ),
                )
            elif isinstance(a, campaign.RunEnded) and self.rec is not None:
                self.rec.end_run()
        if co.command is not None and not self.campaign.finished:
            v, r = co.command
            ns = round(now * 1e9)
            out.append(("velocity_reference", messages.twist_reference_msg(self.f, ns, v, r)))
            out.append(("excitation", messages.excitation_msg(self.f, ns, (0.0, 0.0, 0.0, 0.0))))
            if self.recording:
                rec = self.rec
                self._record(now, out, lambda: rec.reference(now, v, r))
        if co.events:
            out += self.status(now, co.events)

    def _record(self, now: float, out: Output, fn: Callable[[], Any]) -> None:
        try:
            fn()
        except LpvSysidError as exc:
            if not self._record_error_logged:  # the first failure only
                self._record_error_logged = True
                self._log.append(("error", f"recording failed: {exc}"))
            if not self.campaign.finished:
                self._handle(now, self.campaign.abort(now, f"recording failed: {exc}"), out)

    def _finish(self, now: float) -> None:
        self._written = True
        c = self.campaign
        self._log.append(("info" if c.ok else "error", f"campaign {c.phase}: {c.reason or 'ok'}"))
        if self.rec is None or self.out_dir is None:
            return
        errors = self.rec.close(now)
        import yaml

        from lpv_sysid.flight.campaign.outputs import _plain
        from lpv_sysid.sim.phase1 import write_trim_table

        summary = {**c.summary(), "bags": dict(self.rec.bags), "recording_errors": errors or None}
        try:
            (self.out_dir / "campaign_summary.yaml").write_text(
                yaml.safe_dump(_plain(summary), sort_keys=False)
            )
            rows = campaign.trim_rows(c.results)
            if rows:
                write_trim_table(rows, self.out_dir)
        except OSError as exc:
            self._log.append(
                ("error", f"cannot write the campaign summary in {self.out_dir}: {exc}")
            )

    def status(self, now: float, events: Sequence[Any] = ()) -> Output:
        """The ``status`` array: phase, run, runs done; level and message of the last
        warn/error event (else OK / ERROR by the campaign's outcome); events are logged."""
        c = self.campaign
        level, message = ("OK" if c.ok is not False else "ERROR"), f"campaign {c.phase}"
        for ev in events:
            self._log.append((ev.level, f"{ev.phase}: {ev.message}"))
            if ev.level in ("warn", "error"):
                level = "ERROR" if ev.level == "error" or level == "ERROR" else "WARN"
                message = ev.message
        run = c.run
        values = {
            "phase": c.phase,
            "run": run.name if run is not None else "",
            "runs_done": sum(1 for r in c.results if r.complete),
            "runs": len(self.plan.runs),
            "reason": c.reason,
        }
        if run is not None and c.phase in (campaign.TRIM, campaign.EXCITATION):
            values["v_d"] = " ".join(f"{x:g}" for x in run.vertex)
        st = messages.diagnostic_status(self.f, level, self.name, message, values)
        return [("status", messages.diagnostic_array(self.f, round(now * 1e9), [st]))]

    # -- orderly shutdown -----------------------------------------------------------------
    def shutdown(self, now: float) -> Output:
        """Abort a campaign under way (excitation off, hand back)."""
        out: Output = []
        if not self.shutdown_complete():
            self._handle(now, self.campaign.abort(now, "shutdown"), out)
        return out

    def shutdown_complete(self) -> bool:
        phase = self.campaign.phase
        return phase in campaign.TERMINAL or phase == campaign.IDLE

    def shutdown_state(self) -> str:
        return f"campaign {self.campaign.phase}: {self.campaign.reason}"

    def close(self, now: float) -> None:
        """The node is destroyed: a recording not yet finished is closed and summarised."""
        if self.rec is not None and not self._written:
            self._finish(now)
