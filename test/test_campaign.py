"""Phase-1 campaign sequencer (lpv_sysid/control/campaign/sequencer.py): plan and runtime logic.

The plan is checked against analytic numbers (segment room |w| T + excitation span + 2
margins, displacement of a sine A / (pi f)); the runtime against a kinematic stand-in
vehicle (first-order velocity lag, yaw-rotated commands as PX4's MAV_FRAME_BODY_NED) and
a stand-in bridge, on a simulated clock. The flights against the simulated PX4 over UDP are
in test_fly_cli.py.
"""

from __future__ import annotations

import math
import os
from types import SimpleNamespace

import numpy as np
import pytest

from lpv_sysid.control import campaign
from lpv_sysid.control.envelope import EnvelopeConfig
from lpv_sysid.errors import ConfigError
from lpv_sysid.signals.excitation import phase1_signals


@pytest.fixture(scope="module")
def table30():
    s = phase1_signals(duration=30.0)
    return s.t, s.u, tuple(s.names)


@pytest.fixture(scope="module")
def table6():
    s = phase1_signals(duration=6.0, peaks=(0.4, 0.4, 0.2, 0.3))
    return s.t, s.u, tuple(s.names)


# ============================================================================ plan
def test_default_plan_alternates_climbs_and_descents_with_opposing_directions(table30):
    cfg = campaign.CampaignConfig()
    prof = campaign.ExcitationProfile.from_table(*table30, ramp=cfg.ramp_s)
    assert prof.duration == pytest.approx(30.0 + 2 * cfg.ramp_s)
    plan = campaign.plan_campaign(cfg, prof, EnvelopeConfig())
    runs = plan.runs
    assert [r.order for r in runs] == list(range(1, 10))
    assert sorted(r.table_index for r in runs[:8]) == list(range(1, 9))
    assert runs[-1].name == "hover_validation" and runs[-1].vertex == (0.0, 0.0, 0.0)
    kinds = [r.kind for r in runs[:8]]
    # take-off is low
    assert all(a != b for a, b in zip(kinds, kinds[1:])) and kinds[0] == campaign.CLIMB
    for a, b in zip(runs[0:8:2], runs[1:8:2]):  # horizontal displacements cancel pairwise
        np.testing.assert_array_equal(np.add(a.vertex[:2], b.vertex[:2]), [0.0, 0.0])
    # room of a w segment: |w| (settle_timeout + trim + excitation) + span + 2 margins
    T = cfg.settle_timeout + cfg.trim_s + prof.duration
    r = runs[0]
    assert r.duration_worst == pytest.approx(T)
    assert r.altitude_room == pytest.approx(0.7 * T + prof.span[2] + 2 * cfg.altitude_margin)
    assert r.start_window == pytest.approx(
        (
            cfg.altitude_min + cfg.altitude_margin,
            cfg.altitude_max - cfg.altitude_margin - 0.7 * T - prof.span[2],
        )
    )
    d = runs[1]
    assert d.kind == campaign.DESCENT and d.start_window[1] == pytest.approx(
        cfg.altitude_max - cfg.altitude_margin
    )
    # centred runs: half of |(u, v)| T + excitation + margin from home
    assert r.horizontal_extent == pytest.approx(
        0.5 * math.hypot(3, 3) * T + math.hypot(*prof.span[:2]) + 2.0
    )
    assert "vertex_m3_m3_m0.7" in plan.describe()


def test_table_order_keeps_seed0_table1_order(table6):
    cfg = campaign.CampaignConfig.from_dict(
        {
            "order": "table",
            "box_min": [-1, -1, -0.2],
            "box_max": [1, 1, 0.2],
            "settle_timeout": 5.0,
            "trim_s": 2.0,
            "trim_average_s": 1.0,
        }
    )
    plan = campaign.plan_campaign(cfg, campaign.ExcitationProfile.from_table(*table6, ramp=0.5))
    assert [r.table_index for r in plan.runs] == [1, 2, 3, 4, 5, 6, 7, 8, None]
    assert plan.runs[1].vertex == (1.0, -1.0, -0.2)  # u fastest


def test_plan_refuses_a_window_too_small_with_the_numbers(table30):
    cfg = campaign.CampaignConfig.from_dict({"altitude_max": 45.0})
    prof = campaign.ExcitationProfile.from_table(*table30, ramp=cfg.ramp_s)
    with pytest.raises(ConfigError) as e:
        campaign.plan_campaign(cfg, prof)
    T = cfg.settle_timeout + cfg.trim_s + prof.duration
    msg = str(e.value)
    assert "does not fit the altitude window [15, 45] m (30 m)" in msg
    assert f"= {0.7 * T:.1f} m" in msg and f"= {0.7 * T + prof.span[2] + 4:.1f} m" in msg
    # the seed's +-5 m/s box: 5 m/s x 62 s
    with pytest.raises(ConfigError, match="310.0 m"):
        campaign.plan_campaign(
            campaign.CampaignConfig.from_dict({"box_min": [-5, -5, -5], "box_max": [5, 5, 5]}),
            prof,
        )


def test_plan_refusals_name_the_conflict(table30):
    prof = campaign.ExcitationProfile.from_table(*table30, ramp=1.0)
    env = EnvelopeConfig()
    with pytest.raises(ConfigError, match="predictive floor .* would trip"):
        campaign.plan_campaign(
            campaign.CampaignConfig.from_dict(
                {"altitude_min": 8.0, "takeoff_altitude": 10.0, "altitude_max": 70.0}
            ),
            prof,
            env,
        )
    with pytest.raises(ConfigError, match="predictive ceiling trips"):
        campaign.plan_campaign(
            campaign.CampaignConfig.from_dict({"altitude_max": 76.0}), prof, env
        )
    with pytest.raises(ConfigError, match="above the envelope's min"):
        campaign.plan_campaign(
            campaign.CampaignConfig.from_dict(
                {
                    "box_min": [-9, -9, -0.2],
                    "box_max": [9, 9, 0.2],
                    "radius": 300.0,
                    "trim_s": 1.0,
                    "trim_average_s": 1.0,
                    "settle_timeout": 2.0,
                }
            ),
            prof,
            EnvelopeConfig(radius=2000.0),
        )
    with pytest.raises(ConfigError, match="campaign.radius is 100"):
        campaign.plan_campaign(campaign.CampaignConfig.from_dict({"radius": 100.0}), prof, env)
    with pytest.raises(ConfigError, match="local_ned"):
        campaign.CampaignConfig.from_dict({"velocity_frame": "local_ned"})
    with pytest.raises(ConfigError, match="0.25 m/s"):
        campaign.CampaignConfig.from_dict({"hold_max": 0.3})
    with pytest.raises(ConfigError, match="unknown key"):
        campaign.CampaignConfig.from_dict({"trim": 3.0})
    with pytest.raises(ConfigError, match="takeoff_altitude"):
        campaign.CampaignConfig.from_dict({"takeoff_altitude": 90.0})


def test_excitation_profile_displacement_of_a_sine_is_a_over_pi_f():
    T, fs, f, A = 10.0, 50.0, 0.5, 0.8
    t = np.arange(0.0, T, 1.0 / fs)
    u = np.zeros((t.size, 4))
    u[:, 0] = A * np.sin(2 * np.pi * f * t)
    u[:, 3] = 0.25 * np.cos(2 * np.pi * 0.2 * t)
    prof = campaign.ExcitationProfile.from_table(
        t, u, ("u_ref", "v_ref", "w_ref", "r_ref"), ramp=0.0
    )
    assert prof.duration == pytest.approx(T)
    assert prof.span[0] == pytest.approx(
        A / (np.pi * f), rel=2e-3
    )  # int A sin = A (1 - cos)/(2 pi f)
    assert prof.span[1] == 0.0 and prof.span[2] == 0.0
    assert prof.peak[0] == pytest.approx(A, rel=1e-3) and prof.yaw_peak == pytest.approx(
        0.25, rel=1e-3
    )


# =========================================================================== runtime
class StandIn:
    """Kinematic vehicle + bridge on a simulated clock (see module docstring)."""

    def __init__(
        self,
        sequencer,
        tau=0.4,
        gain=1.0,
        sink=0.0,
        psi=0.4,
        handback_delay=0.3,
        handback_mode="HOLD",
        dt=0.02,
        handback_end="DONE",
    ):
        self.c = sequencer
        self.tau, self.gain, self.sink, self.psi = tau, gain, sink, psi
        self.pos = np.zeros(3)
        self.vel = np.zeros(3)
        self.t = 0.0
        self.dt = dt
        self.state = "IDLE"
        self.reason = ""
        self.mode = "HOLD"
        self.armed = False
        self.t_state = 0.0
        self.cmd = np.zeros(3)
        self.handback_delay = handback_delay
        self.handback_mode = handback_mode
        self.target = None
        self.actions: list = []
        self.events: list = []
        self.commands: list = []  # (t, phase, v, r)
        self.violation = None
        self.hook = None
        self.handback_end = (
            handback_end  # DONE | FAILED (fault, confirmed) | LOST (nothing confirmed)
        )
        self.confirmed = None

    def _go(self, state, reason=""):
        self.state, self.reason, self.t_state = state, reason, self.t

    def sample(self):
        c, s = math.cos(self.psi), math.sin(self.psi)
        R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        return SimpleNamespace(
            t=self.t,
            pos_ned=self.pos.copy(),
            euler=np.array([0.0, 0.0, self.psi]),
            vel_ned=self.vel.copy(),
            v_body=R.T @ self.vel,
            omega=np.zeros(3),
        )

    def status(self):
        return campaign.VehicleStatus(
            self.state, self.reason, self.mode, self.armed, None, self.violation, self.confirmed
        )

    def handle(self, out):
        self.events += out.events
        for a in out.actions:
            self.actions.append((self.t, a))
            if isinstance(a, campaign.StartBridge):
                self._go("PRESTREAM")
            elif isinstance(a, campaign.AbortBridge):
                self.target = "HOLD" if self.handback_mode == "HOLD" else self.handback_mode
                self._go("HANDBACK", a.reason)
            elif isinstance(a, campaign.FinishBridge):
                self.target = a.mode if self.handback_mode == "HOLD" else self.handback_mode
                self._go("HANDBACK", "finish")
        if out.command is not None:
            v, r = out.command
            self.cmd = np.asarray(v, float)
            self.commands.append((self.t, self.c.phase, self.cmd.copy(), r))

    def physics(self):
        dt = self.dt
        if self.state == "PRESTREAM" and self.t - self.t_state > 1.5:
            self.mode, self.armed = "OFFBOARD", True
            self._go("OFFBOARD_ACTIVE", "armed")
        if self.state == "HANDBACK" and self.t - self.t_state > self.handback_delay:
            if self.handback_end == "LOST":
                self._go(
                    "FAILED",
                    "hand-back NOT confirmed: HOLD: no COMMAND_ACK; PX4 failsafe in charge",
                )
            else:
                self.mode = self.confirmed = self.target
                self._go(self.handback_end, f"hand-back confirmed: vehicle in {self.target}")
        if self.mode == "OFFBOARD":
            c, s = math.cos(self.psi), math.sin(self.psi)
            want = np.array(
                [c * self.cmd[0] - s * self.cmd[1], s * self.cmd[0] + c * self.cmd[1], self.cmd[2]]
            )
            want = want * self.gain
        elif self.mode == "LAND":
            want = np.array([0.0, 0.0, 0.7])
        else:
            want = np.zeros(3)
        if self.armed:
            self.vel += (want - self.vel) * dt / self.tau
            self.vel[2] += self.sink * dt / self.tau
        self.pos += self.vel * dt
        if self.pos[2] >= 0.0:
            self.pos[2] = 0.0
            self.vel[:] = 0.0
            if self.mode == "LAND":
                self.armed = False

    def run(self, t_end=2000.0):
        self.handle(self.c.start(self.t))
        while not self.c.finished and self.t < t_end:
            self.t += self.dt
            self.physics()
            if self.hook is not None:
                self.hook(self)
            self.c.on_state(self.sample())
            self.handle(self.c.step(self.t, self.status()))
        return self

    def phases(self):
        out = []
        for e in self.events:
            if not out or out[-1] != e.phase:
                out.append(e.phase)
        return out


def small_campaign(table, **kw):
    d = dict(
        box_min=[-1.0, -1.0, -0.3],
        box_max=[1.0, 1.0, 0.3],
        trim_s=2.0,
        trim_average_s=1.0,
        settle_timeout=4.0,
        settle_dwell=0.4,
        takeoff_altitude=8.0,
        altitude_min=5.0,
        altitude_max=22.0,
        altitude_margin=1.0,
        ramp_s=0.5,
        radius=80.0,
        finish="LAND",
        land_timeout=40.0,
        rate_hz=25.0,
    )
    d.update(kw)
    cfg = campaign.CampaignConfig.from_dict(d)
    plan = campaign.plan_campaign(
        cfg,
        campaign.ExcitationProfile.from_table(*table, ramp=cfg.ramp_s),
        EnvelopeConfig(floor=2.0, ceiling=30.0, lookahead=2.0, radius=100.0),
    )
    return campaign.Campaign(plan, table)


def test_whole_sequence_on_a_stand_in_vehicle(table6):
    c = small_campaign(table6, vertices=[2, 7], settle_dwell=1.5)
    sim = StandIn(c, sink=0.03).run()
    assert c.phase == campaign.DONE and c.ok, c.reason
    ph = sim.phases()
    assert ph[:3] == [campaign.STARTING, campaign.TAKEOFF, campaign.REPOSITION]
    assert ph[-3:] == [campaign.FINISHING, campaign.LANDING, campaign.DONE]
    assert ph.count(campaign.EXCITATION) == 3 and ph.count(campaign.SETTLE) == 3
    started = [a for _, a in sim.actions if isinstance(a, campaign.RunStarted)]
    ended = [a for _, a in sim.actions if isinstance(a, campaign.RunEnded)]
    assert (
        [a.run.name for a in started]
        == [a.run.name for a in ended]
        == [r.name for r in c.plan.runs]
    )
    assert all(a.complete for a in ended)
    assert [
        type(a).__name__
        for _, a in sim.actions
        if not isinstance(a, (campaign.RunStarted, campaign.RunEnded))
    ] == ["StartBridge", "ActivateFloor", "FinishBridge"]
    assert not sim.armed and sim.mode == "LAND" and sim.pos[2] == 0.0
    for res, run in zip(c.results, c.plan.runs):
        assert res.complete and 0.0 <= res.settle_time < 4.0 - 1.5
        assert res.t_excite == pytest.approx(res.t_start + 2.0, abs=0.021)
        # the recorded run: trim reference constant (vertex + frozen hold), then the excitation
        trim = [cmd for t, ph, cmd, r in sim.commands if res.t_start <= t < res.t_excite]
        assert len(trim) >= 2.0 * 25 - 2
        assert np.ptp(np.array(trim), axis=0).max() == 0.0
        np.testing.assert_allclose(
            trim[0], np.asarray(run.vertex) + [0, 0, res.hold_correction], atol=1e-12
        )
        exc = np.array([cmd for t, ph, cmd, r in sim.commands if res.t_excite <= t < res.t_end])
        assert np.ptp(exc, axis=0).max() > 0.1
        # tracking of a first-order lag is not perfect but bounded by the excitation size
        assert 0.0 < res.tracking_rms["u"] < 0.4 and set(res.tracking_rms) == {"u", "v", "w", "r"}
    hover = c.results[-1]
    assert hover.name == "hover_validation" and hover.kind == campaign.LEVEL
    # the stand-in sinks 0.03 m/s beyond its command: the frozen feedforward climbs against it
    assert hover.hold_correction == pytest.approx(-0.03, abs=0.01)
    # level runs held their height, climb/descent runs travelled |w| x (trim + excitation)
    assert hover.height_max - hover.height_min < 0.3
    climb = next(r for r in c.results if r.kind == campaign.CLIMB)
    assert climb.height_max - climb.height_start == pytest.approx(
        0.3 * (climb.t_end - climb.t_command), abs=0.5
    )
    s = c.summary()
    assert (
        s["ok"]
        and s["handback"]["mode"] == "LAND"
        and s["handback"]["duration_s"] == pytest.approx(0.3, abs=0.05)
    )
    rows = campaign.trim_rows(c.results)
    assert [r["run"] for r in rows] == [r.name for r in c.plan.runs]


def test_settle_timeout_aborts_with_the_errors_and_waits_for_the_handback(table6):
    c = small_campaign(table6, vertices=[2], settle_tolerance=[0.05, 0.05, 0.05])
    sim = StandIn(c, gain=0.8).run()  # reaches only 80 % of every vertex
    assert c.phase == campaign.ABORTED and c.ok is False
    assert (
        "not settled within settle_timeout 4 s" in c.reason and "(0.80, -0.80, -0.24)" in c.reason
    )
    aborts = [(t, a) for t, a in sim.actions if isinstance(a, campaign.AbortBridge)]
    assert len(aborts) == 1 and "not settled" in aborts[0][1].reason
    res = c.results[0]
    assert not res.complete and math.isnan(res.t_start)  # never recorded
    assert not any(isinstance(a, campaign.RunStarted) for _, a in sim.actions)
    assert aborts[0][0] - res.t_command == pytest.approx(4.0, abs=0.03)
    assert c.summary()["handback"]["duration_s"] == pytest.approx(0.3, abs=0.05)
    assert sim.mode == "HOLD" and sim.armed  # PX4 holds; nothing commanded any more
    assert not [cm for cm in sim.commands if cm[0] > aborts[0][0]]


def test_bridge_leaving_offboard_ends_the_run_without_a_second_abort(table6):
    c = small_campaign(table6, vertices=[2], hover_validation=False)

    def trip(sim):
        if c.phase == campaign.EXCITATION and sim.state == "OFFBOARD_ACTIVE":
            sim.violation = "floor: predictive floor ..."
            sim.target = "HOLD"
            sim._go("HANDBACK", "envelope violation (floor): predictive floor ...")

    sim = StandIn(c)
    sim.hook = trip
    sim.run()
    assert (
        c.phase == campaign.ABORTED
        and "bridge left OFFBOARD_ACTIVE (HANDBACK): envelope: floor" in c.reason
    )
    assert not any(isinstance(a, campaign.AbortBridge) for _, a in sim.actions)
    ended = [a for _, a in sim.actions if isinstance(a, campaign.RunEnded)]
    assert len(ended) == 1 and not ended[0].complete and "envelope" in ended[0].result.reason


def test_external_abort_while_finishing_still_waits_for_the_confirmation(table6):
    c = small_campaign(table6, vertices=[2], hover_validation=False)
    sim = StandIn(c, handback_delay=1.0)
    seen = {}

    def interrupt(sim):
        if c.phase == campaign.FINISHING and "t" not in seen:
            seen["t"] = sim.t
            c.abort(sim.t, "interrupted (SIGINT)")

    sim.hook = interrupt
    sim.run()
    assert c.phase == campaign.ABORTED and c.reason == "interrupted (SIGINT)"
    assert c.t_handback_done - seen["t"] == pytest.approx(1.0, abs=0.05)  # waited for DONE
    assert sim.mode == "LAND"  # the finish request itself was not withdrawn


def test_finish_hold_and_a_land_request_that_ends_elsewhere(table6):
    c = small_campaign(table6, vertices=[2], hover_validation=False, finish="HOLD")
    sim = StandIn(c).run()
    assert c.phase == campaign.DONE and c.ok and sim.mode == "HOLD" and sim.armed
    c = small_campaign(table6, vertices=[2], hover_validation=False, finish="LAND")
    sim = StandIn(c, handback_mode="POSCTL").run()  # the bridge's chain ended elsewhere
    assert (
        c.phase == campaign.FAILED
        and "finish LAND not confirmed: the hand-back ended in POSCTL" in c.reason
    )


def test_stale_state_and_start_timeout_abort(table6):
    c = small_campaign(table6, vertices=[2])

    def freeze(sim):
        if c.phase == campaign.TRIM:
            sim.c.on_state = lambda s: None  # telemetry stops

    sim = StandIn(c)
    sim.hook = freeze
    sim.run()
    assert c.phase == campaign.ABORTED and "no fresh state sample" in c.reason
    c = small_campaign(table6, vertices=[2], start_timeout=3.0)
    sim = StandIn(c)
    sim.physics = lambda: None  # the bridge never reaches OFFBOARD
    sim.run(t_end=10.0)
    assert (
        c.phase == campaign.ABORTING
        and "not in OFFBOARD and armed within start_timeout 3 s" in c.reason
    )


# =========================================================================== ROS node
def _rclpy_is_the_standin() -> bool:
    import importlib.util

    spec = importlib.util.find_spec("rclpy")
    return spec is not None and os.sep + os.path.join("test", "support") + os.sep in (
        spec.origin or ""
    )


def test_vehicle_status_from_the_bridge_node_status_values():
    from lpv_sysid.flight.campaign import vehicle_status

    vs = vehicle_status(
        {
            "state": "OFFBOARD_ACTIVE",
            "reason": "armed",
            "vehicle_mode": "OFFBOARD",
            "armed": "True",
            "envelope_home": "position at start: 1.00 -2.00 -0.50",
            "envelope_violation": "floor: height 4.90 m below the floor 5 m",
        }
    )
    assert (vs.bridge_state, vs.mode, vs.armed) == ("OFFBOARD_ACTIVE", "OFFBOARD", True)
    np.testing.assert_array_equal(vs.home_ned, [1.0, -2.0, -0.5])
    assert vs.violation.startswith("floor:")
    vs = vehicle_status(
        {
            "envelope_home": "position at start (armed, but no HOME_POSITION received: heights "
            "are above this point): 3.00 4.00 -12.00",
            "vehicle_mode": "unknown",
        }
    )
    np.testing.assert_array_equal(vs.home_ned, [3.0, 4.0, -12.0])
    assert vs.bridge_state == "IDLE" and vs.mode is None and vs.armed is False
    assert vehicle_status({"envelope_home": "unset"}).home_ned is None


@pytest.mark.skipif(
    not _rclpy_is_the_standin(), reason="needs the simulated clock of the rclpy stand-in"
)
def test_campaign_node_flies_through_a_bridge_node_and_writes_one_bag_per_run(tmp_path, table6):
    import rclpy
    import yaml
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import TwistStamped
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import Imu, JointState
    from std_srvs.srv import Trigger

    from lpv_sysid.io import bag as iobag
    from lpv_sysid.io import messages
    from lpv_sysid.nodes import shell
    from lpv_sysid.nodes.campaign_node import CampaignNode
    from lpv_sysid.signals.store import save_npz

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    save_npz(str(tmp_path / "sig.npz"), *table6)
    bridge = yaml.safe_load(open(os.path.join(root, "config", "mavlink_bridge.yaml")))
    bridge["envelope"].update({"floor": 2.0, "ceiling": 30.0, "lookahead": 2.0, "radius": 100.0})
    (tmp_path / "bridge.yaml").write_text(yaml.safe_dump(bridge))
    (tmp_path / "campaign.yaml").write_text(
        yaml.safe_dump(
            {
                "bridge_config": "bridge.yaml",
                "campaign": dict(
                    box_min=[-1.0, -1.0, -0.3],
                    box_max=[1.0, 1.0, 0.3],
                    vertices=[2],
                    trim_s=2.0,
                    trim_average_s=1.0,
                    settle_timeout=4.0,
                    settle_dwell=0.4,
                    takeoff_altitude=8.0,
                    altitude_min=5.0,
                    altitude_max=22.0,
                    altitude_margin=1.0,
                    ramp_s=0.5,
                    radius=80.0,
                    finish="LAND",
                ),
            }
        )
    )

    class FakeBridge(Node):
        """mavlink_bridge_node stand-in: services, status values, a first-order vehicle."""

        def __init__(self, context):
            super().__init__("mavlink_bridge", namespace="lpv_sysid", context=context)
            self.f = messages.MsgFactory.rclpy()
            self.state, self.reason, self.mode, self.armed, self.t_state = (
                "IDLE",
                "",
                "HOLD",
                False,
                0.0,
            )
            self.pos, self.vel, self.cmd = np.zeros(3), np.zeros(3), np.zeros(3)
            self.refs = 0
            self.pub_state = self.create_publisher(Odometry, "state", shell.qos_for("state"))
            self.pub_rot = self.create_publisher(
                JointState, "rotor_speeds", shell.qos_for("rotor_speeds")
            )
            self.pub_imu = self.create_publisher(Imu, "imu", shell.qos_for("imu"))
            self.pub_status = self.create_publisher(
                DiagnosticArray, "status", shell.qos_for("status")
            )
            self.create_subscription(
                TwistStamped,
                "velocity_reference",
                self.on_ref,
                shell.qos_for("velocity_reference"),
            )
            self.create_service(Trigger, "~/start", self.on_start)
            self.create_service(Trigger, "~/abort", self.on_abort)
            self.create_timer(0.01, self.tick)

        def now(self):
            return self.get_clock().now().nanoseconds * 1e-9

        def go(self, state, reason):
            self.state, self.reason, self.t_state = state, reason, self.now()
            self.publish_status()

        def on_ref(self, msg):
            self.cmd = messages.reference_from_twist(msg)[1]
            self.refs += 1

        def on_start(self, req, resp):
            self.go("PRESTREAM", "start requested")
            resp.success = True
            return resp

        def on_abort(self, req, resp):
            self.go("HANDBACK", "abort service")
            resp.success = True
            return resp

        def publish_status(self):
            values = {
                "state": self.state,
                "reason": self.reason,
                "vehicle_mode": self.mode,
                "armed": str(self.armed),
                "envelope_home": "position at start: 0.00 0.00 0.00",
            }
            st = messages.diagnostic_status(
                self.f, "OK", self.get_fully_qualified_name(), self.state, values
            )
            self.pub_status.publish(
                messages.diagnostic_array(self.f, self.get_clock().now().nanoseconds, [st])
            )

        def tick(self):
            t = self.now()
            if self.state == "PRESTREAM" and t - self.t_state > 1.5:
                self.mode, self.armed = "OFFBOARD", True
                self.go("OFFBOARD_ACTIVE", "armed")
            if self.state == "HANDBACK" and t - self.t_state > 0.3:
                self.mode = "HOLD"
                self.go("DONE", "hand-back confirmed: vehicle in HOLD")
            want = self.cmd if self.mode == "OFFBOARD" else np.zeros(3)
            if self.armed:
                self.vel += (want - self.vel) * 0.01 / 0.4
            self.pos = self.pos + self.vel * 0.01
            self.pos[2] = min(self.pos[2], 0.0)
            ns = self.get_clock().now().nanoseconds
            self.pub_state.publish(
                messages.odometry_from_state(
                    self.f, ns, self.pos, np.zeros(3), self.vel, np.zeros(3)
                )
            )
            self.pub_rot.publish(messages.rotor_speeds_msg(self.f, ns, [600.0] * 4))
            self.pub_imu.publish(messages.imu_msg(self.f, ns, [0.0, 0.0, -9.81], [0.0, 0.0, 0.0]))

    from rclpy.context import Context

    ctx = Context()  # its own context: independent of other tests
    rclpy.init(
        args=[
            "node",
            "--ros-args",
            "-p",
            f"campaign_file:={tmp_path / 'campaign.yaml'}",
            "-p",
            f"signals_file:={tmp_path / 'sig.npz'}",
            "-p",
            f"out_dir:={tmp_path / 'runs'}",
        ],
        context=ctx,
    )
    try:
        fake = FakeBridge(ctx)
        node = CampaignNode(namespace="lpv_sysid", context=ctx)
        assert node.campaign.plan.config.finish == "HOLD"  # LAND needs the CLI (no finish service)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(fake)
        ex.add_node(node)
        cli = fake.create_client(Trigger, "/lpv_sysid/campaign/start")
        fut = cli.call_async(Trigger.Request())
        ex.spin_until_future_complete(fut, timeout_sec=1.0)
        assert fut.result().success
        for _ in range(400000):
            if node.campaign.finished:
                break
            ex.spin_once(timeout_sec=0.05)
        ex.spin_once(timeout_sec=0.05)
        c = node.campaign
        assert c.phase == "done" and c.ok, c.reason
        assert fake.state == "DONE" and fake.refs > 500
        runs = tmp_path / "runs"
        bags = sorted(p.name for p in runs.iterdir() if (p / "metadata.yaml").exists())
        assert bags == ["bag_0000", "bag_0001"]  # the vertex and the hover run
        info = iobag.topic_info(str(runs / "bag_0000"))
        assert (
            info["/lpv_sysid/velocity_reference"].count > 0 and info["/lpv_sysid/state"].count > 0
        )
        summary = yaml.safe_load((runs / "campaign_summary.yaml").read_text())
        assert [r["name"] for r in summary["runs"]] == ["vertex_p1_m1_m0.3", "hover_validation"]
        assert summary["bags"] == {"vertex_p1_m1_m0.3": "bag_0000", "hover_validation": "bag_0001"}
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.mark.parametrize(
    "end, phase",
    [("DONE", campaign.ABORTED), ("FAILED", campaign.ABORTED), ("LOST", campaign.FAILED)],
)
def test_fault_handback_confirmed_or_not(table6, end, phase):
    # the bridge ends a fault hand-back (stale input, link loss) in FAILED *with* the confirmed
    # mode; only FAILED without a confirmed mode means nothing is confirmed
    c = small_campaign(table6, vertices=[2], settle_tolerance=[0.01, 0.01, 0.01])
    StandIn(c, gain=0.8, handback_end=end).run()
    assert c.phase == phase and c.ok is False
    if phase == campaign.ABORTED:
        assert (
            c.handback_mode == "HOLD"
            and c.t_handback_done - c.t_handback_request == pytest.approx(0.3, abs=0.05)
        )
    else:
        assert "HAND-BACK NOT CONFIRMED" in c.summary()["reason"] or "hand-back FAILED" in c.reason
        assert math.isnan(c.t_handback_done)
