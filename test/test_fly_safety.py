"""`lpv-sysid fly` asks before it arms, leaves PX4's parameters as it found them, and its
preflight looks at battery, GPS/EKF, home and PX4's velocity/tilt limits against the
planned box (issue 24 item 6), against the package's simulated PX4 (lock-step, 127.0.0.1;
the vehicle models what preflight reads: config options battery_remaining, gps_fix,
ekf_healthy, home_set, and PX4's parameters)."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest
import test_fly_cli as flycli

from lpv_sysid.cli.main import main as cli_main
from lpv_sysid.control.campaign import BATTERY_RESERVE_PCT, FlightDemands
from lpv_sysid.flight.campaign import FlyConfig, plan_flight
from lpv_sysid.mavlink.link import LinkConfig, MavlinkLink, free_udp_port
from lpv_sysid.mavlink.preflight import GO, NOGO, WARN, run_checks, verdict
from lpv_sysid.sim.px4_vehicle import SimVehicle, SimVehicleConfig

CONFIG = flycli.CONFIG


@pytest.fixture
def vehicles():
    made = []
    yield made
    for v in made:
        v.close()


def preflight(vehicle: dict, demands=None, battery_needed_pct=None):
    """run_checks against a simulated PX4 configured with ``vehicle`` (lock-step)."""
    port = free_udp_port()
    veh = SimVehicle(SimVehicleConfig(url=f"udpout:127.0.0.1:{port}", **vehicle))
    veh.open()
    link = MavlinkLink(LinkConfig(url=f"udpin:127.0.0.1:{port}"))
    link.open(0.0)
    clock = {"t": 0.0}

    def sleep(_dt):
        clock["t"] += 0.004
        veh.step(clock["t"])

    try:
        checks = run_checks(
            link,
            timeout=4.0,
            clock=lambda: clock["t"],
            sleep=sleep,
            demands=demands,
            battery_needed_pct=battery_needed_pct,
        )
    finally:
        link.close()
        veh.close()
    return checks, {c.name: c for c in checks}


HOLD = {"COM_OBL_RC_ACT": 5}


def test_healthy_sim_vehicle_is_go_and_reports_what_preflight_reads():
    checks, by = preflight({"params": HOLD}, FlightDemands(5.0, 1.5, 1.2, 30.0), 45.0)
    assert verdict(checks), [c for c in checks if c.verdict == NOGO]
    assert by["battery"].value == "80 % (16.00 V)" and by["battery"].verdict == GO
    assert by["GPS"].value == "fix type 3, 12 sats"
    assert by["EKF"].verdict == GO and by["home position"].verdict == GO
    assert by["home position"].value == "47.397742, 8.545594, 488.0 m"  # PX4 SITL's home
    # PX4 v1.16 defaults against the demands
    assert (
        by["MPC_XY_VEL_MAX"].value == "12 m/s" and by["MPC_XY_VEL_MAX"].expected == ">= 5.00 m/s"
    )
    assert by["MPC_TILTMAX_AIR"].value == "45 deg" and by["MPC_TILTMAX_AIR"].verdict == GO


@pytest.mark.parametrize(
    "vehicle, check, note",
    [
        ({"battery_remaining": 40}, "battery", "40 % < 45 %"),
        ({"home_set": False}, "home position", "no HOME_POSITION"),
        ({"ekf_healthy": False}, "EKF", "not valid: horizontal velocity"),
        ({"gps_fix": 1, "ekf_healthy": False}, "GPS", "no GPS fix and no other"),
        (
            {"params": {**HOLD, "MPC_XY_VEL_MAX": 4.0}},
            "MPC_XY_VEL_MAX",
            "param set MPC_XY_VEL_MAX 5",
        ),
        (
            {"params": {**HOLD, "MPC_Z_VEL_MAX_DN": 1.0}},
            "MPC_Z_VEL_MAX_DN",
            "descent speed 1.20 m/s; PX4 would clip it: `param set MPC_Z_VEL_MAX_DN 1.2`",
        ),
        (
            {"params": {**HOLD, "MPC_TILTMAX_AIR": 25.0}},
            "MPC_TILTMAX_AIR",
            "`param set MPC_TILTMAX_AIR 30`",
        ),
    ],
)
def test_each_unfit_vehicle_state_is_nogo_naming_the_fix(vehicle, check, note):
    vehicle = {"params": HOLD, **vehicle}
    checks, by = preflight(vehicle, FlightDemands(5.0, 1.5, 1.2, 30.0), 45.0)
    assert by[check].verdict == NOGO and note in by[check].note, by[check]
    assert not verdict(checks)
    assert [c.name for c in checks if c.verdict == NOGO] == [check] or check in ("GPS", "EKF")


def test_gps_without_fix_but_ekf_position_is_a_warning_indoors():
    _, by = preflight({"params": HOLD, "gps_fix": 0})
    assert by["GPS"].verdict == WARN and by["EKF"].verdict == GO


def test_demands_and_budget_of_the_shipped_campaign_from_its_printed_columns():
    cfg = FlyConfig.load(CONFIG / "campaign.yaml")
    plan = plan_flight(cfg, None)
    c, ex = cfg.campaign, plan.excitation
    d = plan.demands()
    # horizontal: the largest |u| + peak_u, |v| + peak_v of the vertices, as a speed
    want = max(
        math.hypot(abs(r.vertex[0]) + ex.peak[0], abs(r.vertex[1]) + ex.peak[1]) for r in plan.runs
    )
    assert d.horizontal_speed == pytest.approx(want)
    assert d.horizontal_speed >= math.hypot(3.0, 3.0)  # the 3 m/s corners of the box
    assert d.climb_speed >= 0.7 + ex.peak[2] and d.descent_speed >= 0.7 + ex.peak[2]
    assert d.tilt_deg > 10.0  # trim tilt at 4+ m/s plus the 10 deg margin
    b = plan.budget(15 * 60.0)
    total = (
        c.takeoff_altitude / c.climb_rate
        + sum(r.duration_worst for r in plan.runs)
        + sum(r.altitude_room for r in plan.runs) / min(c.climb_rate, c.descent_rate)
        + c.altitude_max / 0.7
    )
    assert b.time_worst_s == pytest.approx(total)
    assert b.battery_worst_pct == pytest.approx(100 * total / 900.0)
    assert b.battery_needed_pct == pytest.approx(b.battery_worst_pct + BATTERY_RESERVE_PCT)
    assert b.radius_m == max(r.horizontal_extent for r in plan.runs)
    # the issue measured ~953 s for the default campaign: it does not fit one 15-min battery
    assert 850 < b.time_nominal_s < b.time_worst_s and b.battery_needed_pct > 100
    assert "NOT ON ONE BATTERY" in b.describe()


def test_dry_run_prints_time_battery_airspace_and_explains_the_columns(capsys, tmp_path):
    argv = ["fly", "phase1", "--connect", "udpin:127.0.0.1:14540", "--config"]
    argv += [str(CONFIG / "campaign.yaml"), "--out", str(tmp_path / "o"), "--dry-run"]
    assert cli_main(argv + ["--endurance-min", "25"]) == 0
    out = capsys.readouterr().out
    for text in (
        "room = height the run sweeps",
        "extent = worst horizontal distance from home",
        "T_worst = settle_timeout + trim_s + excitation",
        "total time: ",
        "of a pack that hovers 25 min",
        "airspace: a cylinder of radius 135 m around the take-off point, 15 m to 70 m",
        "MPC_XY_VEL_MAX >= 5.",
    ):
        assert text in out, text
    assert "NOT ON ONE BATTERY" not in out  # 25 min packs carry it
    assert cli_main(argv + ["--endurance-min", "0"]) == 2


def test_without_a_terminal_fly_refuses_unless_yes(tmp_path):
    """stdin from /dev/null: no one can confirm; exit 2 before any connection is made (phase
    2: a missing gains file is named first, its files are checked before the question)."""
    argv = [sys.executable, "-m", "lpv_sysid.cli", "fly", "phase1", "--connect"]
    argv += [f"udpin:127.0.0.1:{free_udp_port()}", "--config", str(CONFIG / "campaign.yaml")]
    argv += ["--out", str(tmp_path / "o")]
    r = subprocess.run(argv, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert "refusing to fly without confirmation: stdin is not a terminal; pass --yes" in r.stderr
    assert not (tmp_path / "o").exists()
    r = subprocess.run(
        argv[:4]
        + ["phase2", "--connect", "udpin:127.0.0.1:9", "--gains", "g", "--signals", "s"]
        + ["--out", str(tmp_path / "p")],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=120,
    )
    # phase 2 checks its files first (test_phase2_one_path: the question comes after them)
    assert r.returncode == 2 and "g: cannot read" in r.stderr, r.stderr


def test_not_confirmed_nothing_arms_and_parameters_are_restored(tmp_path, vehicles):
    asked = []
    res, veh, _, lines = flycli.fly_locked(
        tmp_path,
        vehicles,
        params={"COM_OBL_RC_ACT": 5.0},
        confirm=lambda q: asked.append(q) or False,
    )
    assert res.status == 1 and res.reason == "not confirmed by the operator: nothing armed"
    assert len(asked) == 1 and asked[0].startswith("arm and take off to 8 m")
    assert not veh.armed and veh.armed_s == 0.0 and veh.setpoints_received == 0
    assert veh.param("COM_OBL_RC_ACT") == 0  # the --set-param value was taken back
    assert res.summary["params_restored"] == [
        {"name": "COM_OBL_RC_ACT", "value": 0, "restored": True}
    ]


def test_battery_nogo_refuses_to_fly_and_restores(tmp_path, vehicles):
    res, veh, _, lines = flycli.fly_locked(
        tmp_path,
        vehicles,
        params={"COM_OBL_RC_ACT": 5.0},
        vehicle={"battery_remaining": 20},
        confirm=lambda q: pytest.fail("asked although preflight said NO-GO"),
    )
    assert res.status == 1 and "preflight NO-GO" in res.reason and "battery (20 %" in res.reason
    assert not veh.armed and veh.param("COM_OBL_RC_ACT") == 0


def test_confirmed_flight_drains_the_simulated_battery(tmp_path, vehicles):
    res, veh, _, lines = flycli.fly_locked(
        tmp_path,
        vehicles,
        params={"COM_OBL_RC_ACT": 5.0},
        confirm=lambda q: True,
        campaign={"vertices": [1]},
    )
    assert res.status == 0, (res.reason, lines[-20:])
    assert veh.armed_s > 30.0
    assert veh.battery_remaining() == math.floor(80 - 6.0 * veh.armed_s / 60.0)
    assert veh.param("COM_OBL_RC_ACT") == 0
