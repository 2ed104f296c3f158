"""The PX4 chain's phase-2 path (rate plant) against the package's simulated PX4 in lock-step,
the chain's phase-1 recording of PX4's rate setpoints on a real PX4 SITL (skips without
PX4_SITL_DIR), and the whole chain through the ROS graph under real ROS 2 Jazzy against a
real PX4 SITL (campaign.launch.py -> identify --plant px4-rate -> synthesize ->
phase2.launch.py; skips without either peer).

Lock-step: the runner's ``sleep`` advances the simulated vehicle (messages still travel
over 127.0.0.1 UDP), so the flights do not depend on machine load. The simulated vehicle
implements SET_ATTITUDE_TARGET body rates + thrust with a PX4-like rate loop
(lpv_sysid/sim/px4_vehicle/vehicle.py); the gains are synthesized (seed 0 Lemma 1, pole region)
for a rate plant with PX4-like coefficients, so what is checked is the path: OFFBOARD from
HOLD in the air, the law's commands arriving unchanged as rate setpoints, the bag, the
hand-back, the gain analysis -- not the sim's tracking quality.
"""

from __future__ import annotations

import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from support.lockstep import LockStep

from lpv_sysid.cli.main import main as cli_main
from lpv_sysid.errors import SafetyError
from lpv_sysid.flight.phase2 import Phase2Options, fly_phase2
from lpv_sysid.ident import rate_plant as rid
from lpv_sysid.io import bag as iobag
from lpv_sysid.io import messages
from lpv_sysid.io.files import save_yaml
from lpv_sysid.mavlink.link import free_udp_port
from lpv_sysid.models import rate_plant as rp
from lpv_sysid.sim.px4_vehicle import SimVehicle, SimVehicleConfig

ROOT = Path(__file__).resolve().parent.parent
#: this file's PX4 SITL instance (ports 14540 + 11, 14550 + 11) and its ROS_DOMAIN_ID
INSTANCE = 11
CONFIG = ROOT / "config"
sys.path.insert(0, str(ROOT / "test"))

P_SIM = rp.RatePlantParams(
    X_u=-0.3,
    Y_v=-0.3,
    Z_w=-0.3,
    Z_T=-19.6,
    L_p=-8.0,
    L_sp=8.0,
    M_q=-8.0,
    M_sp=8.0,
    N_r=-3.0,
    N_sp=3.0,
    c_w=0.0,
)


@pytest.fixture(scope="module")
def design(tmp_path_factory):
    d = tmp_path_factory.mktemp("design")
    save_yaml(
        rid.models_document(
            P_SIM, [-1.0, -1.0, -0.4], [1.0, 1.0, 0.4], 0.0, {"rows": {}, "runs": []}
        ),
        d / "vertex_models.yaml",
    )
    assert (
        cli_main(
            [
                "signals",
                "--config",
                str(CONFIG / "signals_chain_phase2.yaml"),
                "--out",
                str(d / "signals"),
            ]
        )
        == 0
    )
    assert (
        cli_main(
            [
                "synthesize",
                "--models",
                str(d / "vertex_models.yaml"),
                "--config",
                str(CONFIG / "synthesis_chain.yaml"),
                "--summary",
                str(d / "signals" / "summary.yaml"),
                "--out",
                str(d / "gains.yaml"),
            ]
        )
        == 0
    )
    return d


class RateLog:
    """LockStep hook: every new rates setpoint the vehicle received, (t, thrust, rates)."""

    def __init__(self) -> None:
        self.received: list = []

    def __call__(self, ls: LockStep) -> None:
        sp = ls.veh.setpoint
        if (
            sp is not None
            and getattr(sp, "kind", None) == "rates"
            and (not self.received or self.received[-1][0] != sp.t)
        ):
            self.received.append((sp.t, float(sp.thrust), np.array(sp.rates)))


def _lockstep(veh: SimVehicle) -> tuple[LockStep, RateLog]:
    ls = LockStep(veh, max_steps=200_000)
    ls.hook = log = RateLog()
    return ls, log


def _vehicle(tmp: Path, airborne: bool):
    port = free_udp_port()
    veh = SimVehicle(SimVehicleConfig(url=f"udpout:127.0.0.1:{port}", esc_telemetry=False))
    veh.open()
    if airborne:  # in the air in HOLD at 15 m (as after phase 1 with finish: HOLD)
        tr = veh.model.trim((0.0, 0.0, 0.0))
        veh.x[:] = tr.full_state
        veh.x[2] = -15.0
        veh._arm(0.0)
        veh.landed, veh.took_off = False, True
    bridge = yaml.safe_load((CONFIG / "mavlink_bridge_chain.yaml").read_text())
    bridge["link"]["url"] = f"udpin:127.0.0.1:{port}"
    (tmp / "bridge.yaml").write_text(yaml.safe_dump(bridge))
    return veh, tmp / "bridge.yaml"


def test_phase2_takes_the_airborne_vehicle_flies_the_law_and_lands(tmp_path, design):
    veh, bcfg = _vehicle(tmp_path, airborne=True)
    try:
        ls, rates = _lockstep(veh)
        lines: list[str] = []
        s = fly_phase2(
            design / "gains.yaml",
            design / "signals",
            tmp_path / "p2",
            models=design / "vertex_models.yaml",
            bridge_config=bcfg,
            opts=Phase2Options(duration=20.0, ramp_s=2.0, lead_in_s=1.0),
            clock=ls.clock,
            sleep=ls.sleep,
            echo=lines.append,
            handle_signals=False,
        )
    finally:
        veh.close()
    assert s["ok"], (s["reason"], lines[-15:])
    modes = [m for _, m, _ in veh.mode_log]
    assert (
        modes[0] == "OFFBOARD"
        and modes[-1] in ("LAND", "DISARMED")
        and s["handback"]["state"] == "DONE"
    )
    log = np.load(tmp_path / "p2" / "phase2_log.npz")
    # every command PX4 received is one the law computed (transport: no inversion, only clipping)
    sent = log["sent"]
    got = np.array([[th, *r] for _, th, r in rates.received])
    assert len(got) > 100
    for row in got[::25]:
        assert np.min(np.abs(sent - row).max(axis=1)) < 1e-6  # float32 on the wire
    # the signal was flown: v_d followed the fade, u_e non-zero, bag with the chain's topics
    assert s["flown_signal_s"] == pytest.approx(20.0, abs=0.1)
    assert np.abs(log["u_e"]).max() > 0 and np.abs(log["v_d"]).max() > 0.1
    bag = tmp_path / "p2" / "bag_0000"
    tops = {k: v.msgtype for k, v in iobag.topic_info(str(bag)).items()}
    assert (
        tops["/lpv_sysid/rate_setpoint"] == messages.TYPES["actuator_command"]
        and "/lpv_sysid/state" in tops
    )
    g = s["gain_u_e_to_z"]
    assert g["gamma"] == pytest.approx(
        yaml.safe_load((design / "gains.yaml").read_text())["gamma"]
    )
    assert math.isfinite(g["energy_ratio"]) and set(s["tracking_rms"]) == {"u", "v", "w"}
    assert s["design"] == "rate_plant"


def test_phase2_refuses_a_vehicle_on_the_ground_before_sending_anything(tmp_path, design):
    veh, bcfg = _vehicle(tmp_path, airborne=False)
    try:
        ls, rates = _lockstep(veh)
        with pytest.raises(SafetyError, match="not armed"):
            fly_phase2(
                design / "gains.yaml",
                design / "signals",
                tmp_path / "p2",
                bridge_config=bcfg,
                clock=ls.clock,
                sleep=ls.sleep,
                echo=lambda s: None,
                handle_signals=False,
            )
    finally:
        veh.close()
    assert veh.mode_log == [] and veh.setpoints_received == 0 and not veh.armed


def test_phase2_law_refuses_gains_of_another_plant(tmp_path, design):
    from lpv_sysid.errors import ConfigError
    from lpv_sysid.flight.phase2 import load_phase2_law
    from lpv_sysid.io.formats import certify_law

    doc = yaml.safe_load((design / "gains.yaml").read_text())
    doc["inputs"] = [
        {"name": n, "unit": "1"} for n in ("ut", "ua", "ue", "ur")
    ]  # virtual actuators
    (tmp_path / "g.yaml").write_text(yaml.safe_dump(certify_law(doc, layout=None)))
    with pytest.raises(ConfigError, match="are neither the virtual-actuator"):
        load_phase2_law(tmp_path / "g.yaml")
    ctrl, _ = load_phase2_law(design / "gains.yaml", design / "vertex_models.yaml")
    assert (ctrl.n_x, ctrl.n_u) == (8, 4)


def test_broken_loop_run_on_the_airborne_vehicle_excites_the_rate_setpoints(tmp_path):
    """Issue 21 item 3: the campaign's broken-loop run (flight/campaign/broken_loop.py) on
    the simulated PX4 in the air in HOLD: hover thrust taken from PX4's own thrust setpoint,
    OFFBOARD, the stabiliser + zippered multisines sent unchanged as SET_ATTITUDE_TARGET,
    hand-back HOLD confirmed; the bag reads as a rate-plant run, and the lag model's heave
    row identified from it has Z_T and Z_w of the simulated vehicle's rate mode (seed 0
    quadrotor at hover: Z_T -36.34, Z_w -0.494; test_rate_plant_dynamics.py's truth), within
    3 sigma + 20 % (thrust ~ Omega^2 linearised, the sim's rate loop is not the lag model)."""
    from lpv_sysid.control.broken_loop import BrokenLoopConfig
    from lpv_sysid.flight.campaign.broken_loop import fly_broken_loop
    from lpv_sysid.ident import rate_plant_dynamics as lag

    veh, bcfg = _vehicle(tmp_path, airborne=True)
    cfg = BrokenLoopConfig(duration_s=30.0, period_s=15.0, ramp_s=2.0, thrust_amplitude=0.08)
    try:
        ls, rates = _lockstep(veh)
        lines: list[str] = []
        s = fly_broken_loop(
            tmp_path / "bl",
            bcfg,
            cfg=cfg,
            clock=ls.clock,
            sleep=ls.sleep,
            echo=lines.append,
            min_height=5.0,
            # the simulated PX4 echoes ATTITUDE_TARGET only in OFFBOARD (real PX4 always):
            # its hover ESC command, as the seed 0 model trims it
            hover_thrust=float(
                np.linalg.solve(veh.model.mix, veh.model.trim((0.0, 0.0, 0.0)).u0).mean()
            ),
        )
    finally:
        veh.close()
    assert s["ok"], (s["reason"], lines[-15:])
    modes = [mo for _, mo, _ in veh.mode_log]
    assert modes[0] == "OFFBOARD" and modes[-1] == "HOLD", modes
    assert s["handback"]["state"] == "DONE" and 0.2 < s["hover_thrust"] < 0.8
    got = np.array([[th, *r] for _, th, r in rates.received])
    assert len(got) > 0.8 * 50 * cfg.duration_s
    # the multisine is on every channel (thrust and the three rates)
    assert got[:, 0].std() > 0.02 and (got[:, 1:].std(axis=0) > 0.05).all(), got.std(axis=0)
    run = rid.read_run(tmp_path / "bl" / s["bag"])
    start, _ = rid.identify([run])
    plant = lag.identify([run], start=start)
    h = plant.rows["w"]
    print(f"broken-loop heave: {h['params']} +- {h['std']}")
    for k, truth in (("Z_T", -36.34), ("Z_w", -0.494)):
        est, sd = h["params"][k], h["std"][k]
        assert abs(est - truth) < 3 * sd + 0.2 * abs(truth), (k, est, sd, truth)


def test_campaign_file_broken_loop_section_is_parsed_and_checked(tmp_path):
    """The chain flies the broken-loop run when the campaign file has a ``broken_loop``
    section (control/broken_loop.py's declared keys; the shipped chain file has one); a
    misspelt key or a bad value is a ConfigError naming it; no section: not flown."""
    from lpv_sysid.errors import ConfigError
    from lpv_sysid.flight.campaign import FlyConfig

    doc = yaml.safe_load((CONFIG / "campaign_chain.yaml").read_text())
    bl = FlyConfig.from_dict(doc, CONFIG).broken_loop
    assert (bl.duration_s, bl.period_s, bl.ramp_s, bl.thrust_amplitude) == (40.0, 20.0, 3.0, 0.1)
    assert FlyConfig.from_dict({**doc, "broken_loop": None}, CONFIG).broken_loop is None
    del doc["broken_loop"]
    assert FlyConfig.from_dict(doc, CONFIG).broken_loop is None
    for bad, word in (
        ({"duration_s": 40.0, "perod_s": 20.0}, "perod_s"),
        ({"ramp_s": -1}, "ramp_s"),
    ):
        doc["broken_loop"] = bad
        with pytest.raises(ConfigError, match=word):
            FlyConfig.from_dict(doc, CONFIG)


# ====================================================================== real PX4 SITL
def test_real_px4_phase1_records_rate_setpoints_and_identifies(tmp_path):
    from support.px4_sitl import Px4Sitl, find_px4

    d, why = find_px4()
    if d is None:
        pytest.skip(why)
    from lpv_sysid.flight.campaign import FlyConfig, fly

    cfg_doc = yaml.safe_load((CONFIG / "campaign_chain.yaml").read_text())
    cfg_doc["bridge_config"] = str(CONFIG / "mavlink_bridge_chain.yaml")
    cfg_doc["signals_config"] = str(CONFIG / "signals_phase1_chain.yaml")
    cfg_doc["identification_config"] = str(CONFIG / "identification.yaml")
    # state_timeout 1 s as the graph test below (0.5 s in the chain's file: the in-process
    # loop was starved 0.74 s at load 20 on 2 cores before the first run)
    cfg_doc["campaign"].update(
        {"vertices": [8], "hover_validation": False, "finish": "LAND", "state_timeout": 1.0}
    )
    (tmp_path / "campaign.yaml").write_text(yaml.safe_dump(cfg_doc))
    with Px4Sitl(d, instance=INSTANCE) as px4:
        res = fly(
            FlyConfig.load(tmp_path / "campaign.yaml"),
            px4.url,
            tmp_path / "out",
            params={"COM_OBL_RC_ACT": 5.0, "COM_OF_LOSS_T": 2.0},
            echo=lambda s: None,
            handle_signals=False,
            record_rate_setpoints=True,
        )
    if not res.summary.get("bags") and re.search(r"stale input|no fresh state", res.reason):
        # the companion loop stalled longer than input_timeout (seen at load 13-15 on 2 cores):
        # an overloaded host, not a result about the chain; the hand-back was confirmed
        pytest.skip(f"host overloaded, campaign handed back before the first run: {res.reason}")
    assert res.summary.get("bags"), res.reason
    bag = tmp_path / "out" / next(iter(res.summary["bags"].values()))
    run = rid.read_run(bag)
    # PX4 streamed its own thrust + body-rate setpoints at the requested ~50 Hz
    data = iobag.read_bag(str(bag), topics=["/lpv_sysid/rate_setpoint"])[
        "/lpv_sysid/rate_setpoint"
    ]
    t = np.array([st for st, _ in data]) * 1e-9
    assert len(t) / (t[-1] - t[0]) > 30.0
    assert 0.2 < float(np.median(run.u_raw[:, 0])) < 0.8  # hover thrust, normalised
    P, rep = rid.identify([run])
    assert P.Z_T < 0 and rep["rows"]["p"]["r2"] > 0.5 and rep["rows"]["q"]["r2"] > 0.5
    # lag dynamics (ident/rate_plant_dynamics.py) on PX4's own rate loop: a lag in the range of
    # SIH's motor time constant (SIH_T_TAU, default 0.05 s; the chain's 3-vertex flight gave
    # 0.027 s: PX4's rate D term and filters are in the identified loop too), and an output
    # error on the run at least as good as the first-order model's on the same windows
    from lpv_sysid.ident import rate_plant_dynamics as lag

    plant = lag.identify([run], start=P)
    for row in ("p", "q"):
        assert 0.01 < plant.rows[row]["params"]["tau"] < 0.1, plant.rows[row]
    oe_lag = lag.output_error(plant, run, window_s=rid.OUTPUT_ERROR_WINDOW_S)
    oe_first = rid.output_error(P, run)
    for row in ("p", "q", "r"):
        assert oe_lag[row] >= oe_first[row] - 0.01, (row, oe_lag, oe_first)


# ====================================================== the whole chain through the ROS graph
def _px4_param(d: Path, name: str, value) -> None:
    """``param set`` on the running SITL instance through PX4's own client."""
    import subprocess

    r = subprocess.run(
        [str(d / "bin" / "px4-param"), "--instance", str(INSTANCE), "set", name, str(value)],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert r.returncode == 0, (name, r.stdout, r.stderr)


def _bag_rates(out_dir: Path) -> dict:
    """{topic: (messages, Hz over the recording)} of a data logger's experiment directory."""
    meta = yaml.safe_load((out_dir / "experiment.yaml").read_text())
    return {
        t.rsplit("/", 1)[-1]: (int(v["count"]), round(float(v["rate_hz"]), 1))
        for t, v in meta["topics"].items()
    }


def _status_values(log_dir: Path, key: str) -> list:
    """The values of ``key`` in the controller status messages recorded in ``log_dir``."""
    from lpv_sysid.flight.controller.replay import bag_directories

    out = []
    for part in bag_directories(str(log_dir)):
        names = [n for n in iobag.topic_info(str(part)) if n.endswith("status")]
        for _, m in (x for rows in iobag.read_bag(str(part), topics=names).values() for x in rows):
            for st in m.status:
                out += [float(kv.value) for kv in st.values if kv.key == key]
    return out


def _loop_delay_max_ms(log_dir: Path) -> float:
    """The controller's largest loop delay of the flight [ms] (its status, recorded)."""
    return max(_status_values(log_dir, "loop_delay_max_ms"), default=0.0)


def test_real_ros_graph_whole_chain_on_px4_sitl(tmp_path):
    """Issue 21 item 6: under real ROS 2 Jazzy against PX4 SITL (SIH quad, instance 11),
    ``ros2 launch lpv_sysid campaign.launch.py`` flies phase 1 (one vertex, PX4's own rate
    setpoints recorded per run from the bridge's echo), ``lpv-sysid identify --plant
    px4-rate`` builds the rate plant from those bags, ``synthesize`` designs the gains, and
    ``ros2 launch lpv_sysid phase2.launch.py design:=rate_plant auto_start:=true`` flies the
    whole phase-2 signal under the LPV law: the sequencer starts the nodes in order, the
    excitation plays to its end, the bridge hands back with PX4's mode confirmed. The
    phase-2 bag holds state, imu, rotor_speeds, status, velocity_reference, excitation,
    actuator_command (setpoints sent) and rate_setpoint (PX4's echo) near their configured
    rates, and ``replay`` of that bag through the controller runtime (the code ``fly phase2``
    runs) computes the commands the node sent."""
    from support.px4_sitl import Px4Sitl, find_px4
    from support.ros_real import DomainId, RosEnv, build_package, find_ros

    d, why = find_px4()
    if d is None:
        pytest.skip(why)
    setup, why = find_ros()
    if setup is None:
        pytest.skip(why)
    ws = build_package(setup, tmp_path / "ws")
    dom = DomainId(40 + INSTANCE - 1)
    env = RosEnv(setup, ws, dom.value)
    # phase-1 inputs: the chain's campaign with one vertex, signals designed beforehand
    assert (
        cli_main(
            [
                "signals",
                "--config",
                str(CONFIG / "signals_phase1_chain.yaml"),
                "--out",
                str(tmp_path / "sig1"),
            ]
        )
        == 0
    )
    cfg_doc = yaml.safe_load((CONFIG / "campaign_chain.yaml").read_text())
    cfg_doc["bridge_config"] = str(CONFIG / "mavlink_bridge_chain.yaml")
    cfg_doc["signals_config"] = str(CONFIG / "signals_phase1_chain.yaml")
    cfg_doc["identification_config"] = str(CONFIG / "identification.yaml")
    # state_timeout: the state reaches campaign_node through the bridge node and DDS; gaps of
    # 0.51 s were seen at load ~15 on 2 cores (0.5 s in the chain's file; 1 s is the limit)
    cfg_doc["campaign"].update(
        {"vertices": [1, 8], "hover_validation": False, "state_timeout": 1.0}
    )
    (tmp_path / "campaign.yaml").write_text(yaml.safe_dump(cfg_doc))
    logs: dict = {}

    def launch(file: str, args: dict, name: str):
        argv = " ".join(f"{k}:={v}" for k, v in args.items())
        p = env.popen(f"ros2 launch lpv_sysid {file} {argv}", tmp_path / f"{name}.log")
        logs[name] = p
        return p

    def stop(p, nodes: int, timeout: float = 60.0) -> None:
        """SIGINT to the launch's process group (a terminal's Ctrl-C): every node exits 0
        (launch's own exit status is not judged: under load its asyncio loop printed "Task
        was destroyed but it is pending" on the second SIGINT and exited 1)."""
        p.sigint(group=True)
        try:
            rc = p.wait(timeout)
        except Exception:
            p.kill()
            rc = -9
        clean = re.findall(r"\[(\w+)-\d+\]: process has finished cleanly", p.log())
        assert len(set(clean)) == nodes, (rc, clean, p.log()[-3000:])

    # the installed parameter files with the timeouts of the chain's own bridge file
    # (config/mavlink_bridge_chain.yaml: a loaded 2-core SITL host stalls a Python loop for
    # 0.5-1.9 s; 0.5 s input_timeout and 1.5 s link_timeout handed back in phase 1 at load
    # 14-26) and the controller's staleness limits at 0.5 s (0.2 s shipped): the launches'
    # config_dir argument
    import shutil

    cfg_dir = tmp_path / "config"
    shutil.copytree(ws / "install" / "lpv_sysid" / "share" / "lpv_sysid" / "config", cfg_dir)
    # phase 1 needs state and PX4's setpoints only: the other streams at lower rates, so the
    # Python nodes of the graph keep up on a loaded host (the campaign aborted on a state
    # > 1 s old during take-off in 4 of 4 tries at load 14-26 with the full streams)
    cfg_dir1 = tmp_path / "config_phase1"
    shutil.copytree(cfg_dir, cfg_dir1)
    doc = yaml.safe_load((cfg_dir1 / "mavlink_bridge_node.yaml").read_text())
    (body,) = doc.values()
    body["ros__parameters"]["link"]["streams"].update(
        {"ATTITUDE_QUATERNION": 50.0, "HIGHRES_IMU": 10.0, "ESC_STATUS": 0.0}
    )
    body["ros__parameters"]["rotor_estimate"]["enabled"] = False
    body["ros__parameters"]["offboard"]["input_timeout"] = 1.5
    body["ros__parameters"]["link"]["link_timeout"] = 3.0
    (cfg_dir1 / "mavlink_bridge_node.yaml").write_text(yaml.safe_dump(doc))
    for file, section, values in (
        ("mavlink_bridge_node.yaml", "offboard", {"input_timeout": 1.5}),
        ("mavlink_bridge_node.yaml", "link", {"link_timeout": 3.0}),
        (
            "lpv_controller_px4.yaml",
            "",
            {f"{k}_timeout_s": 0.5 for k in ("state", "rotor", "reference", "excitation")},
        ),
    ):
        doc = yaml.safe_load((cfg_dir / file).read_text())
        (body,) = doc.values()
        sec = body["ros__parameters"]
        (sec[section] if section else sec).update(values)
        (cfg_dir / file).write_text(yaml.safe_dump(doc))
    try:
        with Px4Sitl(d, instance=INSTANCE) as px4:
            link = px4.url
            for name, value in (("COM_OBL_RC_ACT", 5), ("COM_OF_LOSS_T", 2.0)):
                _px4_param(d, name, value)
            # ---- phase 1 through the ROS graph
            p1 = launch(
                "campaign.launch.py",
                {
                    "campaign_file": tmp_path / "campaign.yaml",
                    "signals_file": tmp_path / "sig1" / "signals.npz",
                    "runs_dir": tmp_path / "runs",
                    "log_dir": tmp_path / "campaign_log",
                    "link_url": link,
                    "config_dir": cfg_dir1,
                },
                "campaign",
            )
            assert p1.wait_for("[lpv_sysid.mavlink_bridge]: link_up", 120.0), p1.log()[-4000:]
            assert p1.wait_for("[lpv_sysid.campaign]: ready", 120.0), p1.log()[-4000:]
            r = env.run(
                "ros2 service call /lpv_sysid/campaign/start std_srvs/srv/Trigger", timeout=90
            )
            assert "success=True" in r.stdout, (r.stdout, r.stderr, p1.log()[-4000:])
            # take-off, two vertices (settle + 5 s trim + 17 s excitation each), hand-back
            assert p1.wait_for("[lpv_sysid.campaign]: campaign ", 600.0), p1.log()[-6000:]
            if "campaign done: ok" not in p1.log():
                # a run cut short by the loaded host (a process of the graph starved > 1 s):
                # the runs recorded so far are identified, the vehicle is in HOLD in the air
                print("phase 1 ended early:", re.findall(r"campaign aborted: .*", p1.log()))
                if "complete; returning to hover" not in p1.log() and re.search(
                    r"no fresh state sample|stale input|link lost", p1.log()
                ):
                    # before the first run: as the in-process test above, an overloaded host
                    # (a process of the graph starved > 1 s), not a result about the chain
                    assert p1.wait_for("hand-back confirmed", 60.0), p1.log()[-4000:]
                    pytest.skip("host overloaded: phase 1 handed back before the first run")
            assert p1.wait_for("hand-back confirmed", 60.0), p1.log()[-4000:]
            stop(p1, 3)
            # ---- identify, signals, synthesize (the CLI, as docs/px4_chain.md); B per vertex
            # (common_b false): with two runs, common B was infeasible (gamma_min 4.29)
            synth = tmp_path / "synthesis.yaml"
            synth.write_text(
                (CONFIG / "synthesis_chain.yaml")
                .read_text()
                .replace("  common_b: true ", "  common_b: false ")
            )
            assert (
                cli_main(
                    [
                        "identify",
                        "--plant",
                        "px4-rate",
                        "--bags",
                        str(tmp_path / "runs"),
                        "--out",
                        str(tmp_path / "vertex_models.yaml"),
                        "--campaign",
                        str(tmp_path / "campaign.yaml"),
                        # nominal vertex models (48 LMI blocks): the synthesis of the default
                        # +-2 std intervals (384 blocks) took > 5 min at load 15-20
                        "--k-sigma",
                        "0",
                    ]
                )
                == 0
            )
            assert (
                cli_main(
                    [
                        "signals",
                        "--config",
                        str(CONFIG / "signals_chain_phase2.yaml"),
                        "--out",
                        str(tmp_path / "sig2"),
                    ]
                )
                == 0
            )
            # the controller refuses gains whose certified loop delay is below its configured
            # loop (control.safety.check_loop_delay, tested in test_certificate_delay): the
            # margin is a property of this flight's identified plant (29.9 ms once at load
            # 20, against 66-88 ms on other flights), so the synthesis is asked to cover the
            # loop (--loop-delay: a smaller pole region until it does); when no region does,
            # not flown, said so
            from lpv_sysid.control.safety import loop_delay_s

            (body,) = yaml.safe_load((cfg_dir / "lpv_controller_px4.yaml").read_text()).values()
            c = body["ros__parameters"]
            configured = loop_delay_s(
                c.get("tick_source", "state"),
                c["rate_hz"],
                c["state_rate_hz"],
                c["input_latency_s"],
            )
            rc_syn = cli_main(
                [
                    "synthesize",
                    "--loop-delay",
                    repr(configured),
                    "--models",
                    str(tmp_path / "vertex_models.yaml"),
                    "--config",
                    str(synth),
                    "--summary",
                    str(tmp_path / "sig2" / "summary.yaml"),
                    "--out",
                    str(tmp_path / "gains.yaml"),
                ]
            )
            cert = yaml.safe_load((tmp_path / "gains.yaml").read_text())["certificate"]
            # 1 only when no pole region covers the loop (skipped below), never a failed
            # verification of gains that would then fly
            assert rc_syn == 0 or cert["loop_delay"]["bound_s"] < configured, rc_syn
            print(
                f"gains: gamma {cert.get('gamma')}, achieved {cert.get('gamma_achieved')}, "
                f"loop delay certified {cert['loop_delay']}"
            )
            if cert["loop_delay"]["bound_s"] < configured:
                pytest.skip(
                    f"this flight's plant certifies {1e3 * cert['loop_delay']['bound_s']:.1f} ms "
                    f"of loop delay, below the configured {1e3 * configured:.1f} ms: the "
                    "controller refuses these gains (as it must)"
                )
            # ---- phase 2 through the ROS graph, the vehicle in the air in HOLD
            p2 = launch(
                "phase2.launch.py",
                {
                    "design": "rate_plant",
                    "gains_file": tmp_path / "gains.yaml",
                    "signals_file": tmp_path / "sig2" / "signals.npz",
                    "log_dir": tmp_path / "phase2_log",
                    "link_url": link,
                    "auto_start": "true",
                    "config_dir": cfg_dir,
                },
                "phase2",
            )
            for line, timeout in (
                ("sequence complete: every node started in order", 240.0),
                ("signal complete: hand-back and stop sent", 300.0),
            ):
                if p2.wait_for(line, timeout, unless="sequence aborted"):
                    continue
                if "safety abort: loop_delay" in p2.log():
                    # the law's commands came from states older than the certified delay (184 ms
                    # against 77 ms at load 17): the host, not the chain; handed back
                    assert p2.wait_for("hand-back", 60.0), p2.log()[-4000:]
                    why = re.findall(
                        r"safety abort: loop_delay: (.*?above the certified \S+ ms)", p2.log()
                    )
                    pytest.skip(f"host overloaded: {why[0] if why else 'loop delay > bound'}")
                raise AssertionError(p2.log()[-6000:])
            assert p2.wait_for("hand-back confirmed", 60.0), p2.log()[-4000:]
            text = p2.log()
            mode = re.findall(r"hand-back confirmed: vehicle in ([A-Z]+)", text)
            assert mode and mode[-1] in ("HOLD", "LAND"), text[-4000:]
            # no safety abort of its own: at the signal's end the sequencer stops the
            # controller through its abort service ("safety abort: external: abort service",
            # logged by the controller before the sequencer's "signal complete" line)
            own = re.findall(r"safety abort: (?!external: abort service).*", text)
            assert not own, (own, text[-6000:])
            stop(p2, 5)
    finally:
        for p in logs.values():
            p.kill()
        dom.release()
    rates = _bag_rates(tmp_path / "phase2_log")
    print(f"phase-2 bag (messages, Hz): {rates}")
    print(f"controller loop delay max {_loop_delay_max_ms(tmp_path / 'phase2_log'):.1f} ms")
    for topic, hz in (
        ("state", 100.0),
        ("imu", 100.0),
        ("rotor_speeds", 50.0),
        ("velocity_reference", 50.0),
        ("excitation", 50.0),
        ("actuator_command", 100.0),
        ("rate_setpoint", 50.0),
        ("status", 2.0),
    ):
        assert rates.get(topic, (0, 0.0))[1] >= 0.6 * hz, (topic, rates)
    # replay: the controller runtime (what fly phase2 runs) on the bag's inputs, with the
    # node's parameters, gives the commands the node sent
    from lpv_sysid.flight.controller import replay_controller

    # the parameters the node ran with: the launch's config_dir copy (its staleness limits
    # at 0.5 s); the shipped 0.2 s made the replay abort stale at its start, no command
    doc = yaml.safe_load((cfg_dir / "lpv_controller_px4.yaml").read_text())
    params = doc["/**/lpv_controller"]["ros__parameters"]
    params = dict(params, gains_file=str(tmp_path / "gains.yaml"))
    bag = tmp_path / "phase2_log"
    rep = replay_controller(str(bag), params, str(tmp_path / "replay"))
    names = ("thrust", "p_sp", "q_sp", "r_sp")

    def commands(b):
        from lpv_sysid.flight.controller.replay import bag_directories

        out: dict = {}
        for part in bag_directories(str(b)):
            for _, m in iobag.read_bag(str(part), topics=["/lpv_sysid/actuator_command"]).get(
                "/lpv_sysid/actuator_command", []
            ):
                out[messages.stamp_ns_of(m)] = messages.channels_from_joint_state(m, names)[1]
        return out

    flown, replayed = commands(bag), commands(tmp_path / "replay")
    common = sorted(set(flown) & set(replayed))
    diffs = np.array([float(np.abs(flown[k] - replayed[k]).max()) for k in common])
    same = int((diffs < 1e-9).sum())
    print(
        f"replay: {len(flown)} commands flown, {len(common)} stamps in both, {same} identical "
        f"(max |diff| {diffs.max():.3g}); replay event {rep['event']}"
    )
    # the law sees each input by its stamp: a command differs only where an input sample
    # arrived after its state at the node and not in the bag's order, or the reverse. Measured:
    # quiet 96 of 5948 differed (119 late in the bag); beside other tests 184 of 6530 (246 late
    # in the bag, 151 at the node); newest-delivered instead: 6-9 % differed
    late_node = max(_status_values(bag, "late_input_count"), default=-1.0)
    print(f"late input samples: replay {rep['late_inputs']}, node {late_node:.0f}")
    assert late_node >= 0, "the controller status carries no late_input_count"
    assert len(common) >= 0.95 * len(flown) > 1000
    assert len(common) - same <= 2 * (late_node + rep["late_inputs"])
    assert same >= 0.9 * len(common)
