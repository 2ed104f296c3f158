"""campaign_node: the phase-1 flight campaign in the ROS 2 graph (``launch/campaign.launch.py``).

Shell around :class:`lpv_sysid.control.campaign.Campaign` (the same core as
``lpv-sysid fly phase1``). It commands ``velocity_reference`` (TwistStamped, FLU) to the
``mavlink_bridge`` node, which streams it to PX4 and enforces the safety envelope, and
follows the bridge through its ``status`` (DiagnosticArray: ``state``, ``reason``,
``vehicle_mode``, ``armed``, ``envelope_home``, ``envelope_violation``). It calls the
bridge's ``start`` service to pre-stream, switch to OFFBOARD and arm (the bridge needs
``offboard.arm: true``), its ``abort`` service to hand back. Subscribes ``state``,
``rotor_speeds``, ``imu`` (best effort); publishes ``velocity_reference`` as flown (vertex,
altitude correction, multisine), ``excitation`` (zeros: phase 1 has no u_e) and ``status``.
Services ``~/start`` (fly the campaign) and ``~/abort`` (excitation off, hand back).

Per-run bags: with ``out_dir`` the node writes one rosbag2 per run (trim + excitation),
``out_dir/bag_NNNN`` with the data logger's topics (``lpv_sysid.cli.fly.CampaignRecorder``),
plus ``campaign_summary.yaml`` and ``trims.yaml`` at the end, so ``lpv-sysid identify --bags
out_dir`` runs on it; the data logger records the whole flight as usual.

The bridge node offers ``start`` and ``abort`` only: the campaign therefore ends with the
bridge's hand-back chain (``offboard.handback_chain``, HOLD first by default); a
``finish: LAND`` in the campaign file is flown as HOLD here (warned at start; use
``lpv-sysid fly phase1`` to land automatically). The envelope's floor activates by itself
above floor + margin (the explicit activation of the CLI needs no service).

    ros2 run lpv_sysid campaign_node --ros-args -p campaign_file:=config/campaign.yaml \
        -p out_dir:=flight_07_runs
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu, JointState
from std_srvs.srv import Trigger

from lpv_sysid.control import campaign
from lpv_sysid.errors import LpvSysidError
from lpv_sysid.io import messages
from lpv_sysid.nodes import shell

NODE_NAME = "campaign"
STRING = Parameter.Type.STRING

PARAMETERS = [
    (
        "campaign_file",
        "campaign.yaml",
        shell.typed(STRING, "config/campaign.yaml (campaign, bridge_config, signals_config)"),
    ),
    (
        "signals_file",
        "",
        shell.typed(STRING, "phase-1 signals.npz (empty: designed from signals_config)"),
    ),
    (
        "out_dir",
        "",
        shell.typed(STRING, "directory for one rosbag2 per run (empty: no per-run bags)"),
    ),
    (
        "bridge_node",
        "mavlink_bridge",
        shell.typed(
            STRING,
            "name of the bridge node in this namespace (its start/abort services and status)",
        ),
    ),
    (
        "rate_hz",
        100.0,
        shell.double(
            "campaign step rate [Hz] (references go out at campaign.rate_hz)", 10.0, 1000.0
        ),
    ),
    ("status_rate_hz", 2.0, shell.double("status publication rate [Hz]", 0.1, 100.0)),
    (
        "auto_start",
        False,
        shell.typed(Parameter.Type.BOOL, "start the campaign without the service"),
    ),
]


def vehicle_status(values: dict) -> campaign.VehicleStatus:
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


class CampaignNode(shell.ShellNode):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, PARAMETERS, **kwargs)
        from lpv_sysid.cli.fly import FlyConfig, bridge_config_for, load_signals

        p = self.params
        cfg = FlyConfig.load(p["campaign_file"])
        ccfg = cfg.campaign
        if str(ccfg.finish).upper() == "LAND":
            self.get_logger().warning(
                "campaign finish LAND: mavlink_bridge_node has no finish service; "
                "the campaign ends with the bridge's hand-back chain (HOLD)"
            )
            ccfg = dataclasses.replace(ccfg, finish="HOLD")
        bcfg = bridge_config_for(cfg.bridge_config, None, ccfg)
        self.table = load_signals(p["signals_file"] or None, cfg.signals_config)
        prof = campaign.ExcitationProfile.from_table(
            *self.table, ramp=ccfg.ramp_s, periods=ccfg.periods
        )
        self.plan = campaign.plan_campaign(ccfg, prof, bcfg.envelope)
        self.campaign = campaign.Campaign(self.plan, self.table)
        self.fly_cfg = cfg
        self.f = messages.MsgFactory.rclpy()
        self.bridge_name = self.resolve_topic_name(p["bridge_node"])
        self.bridge_values: dict = {}
        self.rec = None
        self.out_dir = Path(p["out_dir"]) if p["out_dir"] else None
        self._written = False
        self.pub_ref = self.create_publisher(
            TwistStamped, "velocity_reference", shell.qos_for("velocity_reference")
        )
        self.pub_exc = self.create_publisher(JointState, "excitation", shell.qos_for("excitation"))
        self.pub_status = shell.StatusPublisher(self)  # status and /diagnostics
        self.create_subscription(Odometry, "state", self.on_state, shell.qos_for("state"))
        self.create_subscription(
            JointState, "rotor_speeds", self.on_rotors, shell.qos_for("rotor_speeds")
        )
        self.create_subscription(Imu, "imu", self.on_imu, shell.qos_for("imu"))
        self.create_subscription(
            DiagnosticArray, "status", self.on_status, shell.qos_for("status")
        )
        self.cli_start = self.create_client(Trigger, f"{self.bridge_name}/start")
        self.cli_abort = self.create_client(Trigger, f"{self.bridge_name}/abort")
        self.create_service(Trigger, "~/start", self.on_start)
        self.create_service(Trigger, "~/abort", self.on_abort)
        self.create_timer(1.0 / p["rate_hz"], self.on_step)
        self.create_timer(1.0 / p["status_rate_hz"], lambda: self.publish_status([]))
        self.get_logger().info(
            f"{len(self.plan.runs)} runs planned, excitation {prof.duration:.1f} s; "
            f"bridge {self.bridge_name}\n{self.plan.describe()}"
        )
        self._auto_start = bool(p["auto_start"])  # once the bridge's services are up

    # -- inputs ---------------------------------------------------------------------
    def on_state(self, msg):
        s = self.parse_input("state", messages.state_from_odometry, msg)
        if s is None:
            return
        self.campaign.on_state(s)
        if self.rec is not None and self.rec.active is not None:
            self._record(lambda: self.rec.state(s.t, s.pos_ned, s.euler, s.v_body, s.omega))

    def on_rotors(self, msg):
        parsed = self.parse_input("rotor_speeds", messages.rotor_speeds_from_joint_state, msg)
        if parsed is None:
            return
        t, omega = parsed
        self.campaign.on_rotor(t, omega)
        if self.rec is not None and self.rec.active is not None:
            src = messages.rotor_source_of(msg)
            self._record(lambda: self.rec.rotors(t, omega, src))

    def on_imu(self, msg):
        if self.rec is None or self.rec.active is None:
            return
        s = self.parse_input("imu", messages.imu_from_msg, msg)
        if s is not None:
            self._record(lambda: self.rec.imu(s.t, s.specific_force, s.omega))

    def on_status(self, msg):
        try:
            _, statuses = messages.status_from_diagnostic_array(msg)
        except LpvSysidError:
            return
        for st in statuses:
            if st.name == self.bridge_name:
                self.bridge_values = dict(st.values)

    # -- services -------------------------------------------------------------------
    def _start(self) -> str:
        if self.campaign.phase != campaign.IDLE:
            return f"already {self.campaign.phase}"
        if not (self.cli_start.service_is_ready() and self.cli_abort.service_is_ready()):
            return (
                f"not started: the bridge services {self.bridge_name}/start|abort "
                "are not available"
            )
        now = self.now()
        if self.out_dir is not None:
            from lpv_sysid.cli.fly import CampaignRecorder

            self.rec = CampaignRecorder(
                self.out_dir,
                self.fly_cfg.storage,
                False,
                description="campaign_node: one bag per run",
            )
            self.rec.start(now)
        self._handle(now, self.campaign.start(now))
        return f"campaign started: {len(self.plan.runs)} runs"

    def on_start(self, request, response):
        try:
            response.message = self._start()
            response.success = self.campaign.phase != campaign.IDLE
        except LpvSysidError as exc:
            response.success, response.message = False, str(exc)
        self.get_logger().info(f"start: {response.message}")
        return response

    def on_abort(self, request, response):
        now = self.now()
        self._handle(now, self.campaign.abort(now, "abort service"))
        response.success = True
        response.message = f"campaign {self.campaign.phase}: excitation off, handing back"
        self.get_logger().warning(response.message)
        return response

    # -- loop -----------------------------------------------------------------------
    def on_step(self):
        if self._auto_start and self.bridge_values and self.cli_start.service_is_ready():
            self._auto_start = False
            self.get_logger().info(f"auto start: {self._start()}")
        if self.campaign.phase == campaign.IDLE:
            return
        now = self.now()
        if not self.campaign.finished:
            self._handle(now, self.campaign.step(now, vehicle_status(self.bridge_values)))
        if self.campaign.finished and not self._written:
            self._finish(now)

    def _handle(self, now: float, out) -> None:
        for a in out.actions:
            if isinstance(a, campaign.StartBridge):
                self._call(self.cli_start, "start")
            elif isinstance(a, (campaign.AbortBridge, campaign.FinishBridge)):
                self._call(self.cli_abort, "abort")
            elif isinstance(a, campaign.RunStarted) and self.rec is not None:
                self._record(
                    lambda: self.get_logger().info(
                        f"recording {a.run.name} -> {self.rec.begin_run(a.run.name)}"
                    )
                )
            elif isinstance(a, campaign.RunEnded) and self.rec is not None:
                self.rec.end_run()
        if out.command is not None and not self.campaign.finished:
            v, r = out.command
            ns = round(now * 1e9)
            self.pub_ref.publish(messages.twist_reference_msg(self.f, ns, v, r))
            self.pub_exc.publish(messages.excitation_msg(self.f, ns, (0.0, 0.0, 0.0, 0.0)))
            if self.rec is not None and self.rec.active is not None:
                self._record(lambda: self.rec.reference(now, v, r))
        if out.events:
            self.publish_status(out.events)

    def _call(self, client, what: str) -> None:
        if not client.service_is_ready():
            self.get_logger().error(f"bridge service {client.srv_name} not available ({what})")
        fut = client.call_async(Trigger.Request())
        fut.add_done_callback(
            lambda f: self.get_logger().info(
                f"bridge {what}: {f.result().message if f.result() is not None else 'no answer'}"
            )
        )

    def _record(self, fn) -> None:
        try:
            fn()
        except LpvSysidError as exc:
            self.get_logger().error(f"recording failed: {exc}", once=True)
            if not self.campaign.finished:
                self._handle(
                    self.now(), self.campaign.abort(self.now(), f"recording failed: {exc}")
                )

    def _finish(self, now: float) -> None:
        self._written = True
        c = self.campaign
        # one severity per call site: rclpy refuses to change it between calls
        if c.ok:
            self.get_logger().info(f"campaign {c.phase}: {c.reason or 'ok'}")
        else:
            self.get_logger().error(f"campaign {c.phase}: {c.reason or 'ok'}")
        if self.rec is None:
            return
        errors = self.rec.close(now)
        import yaml

        from lpv_sysid.cli.fly import _plain
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
            self.get_logger().error(f"cannot write the campaign summary in {self.out_dir}: {exc}")

    def publish_status(self, events):
        c = self.campaign
        level, message = ("OK" if c.ok is not False else "ERROR"), f"campaign {c.phase}"
        for ev in events:
            text = f"{ev.phase}: {ev.message}"
            if ev.level == "info":  # one severity per call site (rclpy's rule)
                self.get_logger().info(text)
            elif ev.level == "warn":
                self.get_logger().warning(text)
            else:
                self.get_logger().error(text)
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
        st = messages.diagnostic_status(
            self.f, level, self.get_fully_qualified_name(), message, values
        )
        self.pub_status.publish(messages.diagnostic_array(self.f, round(self.now() * 1e9), [st]))

    # -- orderly shutdown (nodes/shell.run) ----------------------------------------
    def begin_shutdown(self):
        now = self.now()
        if self.campaign.phase not in campaign.TERMINAL and self.campaign.phase != campaign.IDLE:
            self._handle(now, self.campaign.abort(now, "shutdown"))

    def shutdown_complete(self):
        return self.campaign.phase in campaign.TERMINAL or self.campaign.phase == campaign.IDLE

    def shutdown_state(self):
        return f"campaign {self.campaign.phase}: {self.campaign.reason}"

    def destroy_node(self):
        try:
            if self.rec is not None and not self._written:
                self._finish(self.now())
        finally:
            super().destroy_node()


def main(args=None):
    return shell.run(CampaignNode, args, NODE_NAME)


if __name__ == "__main__":
    main()
