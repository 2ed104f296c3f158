"""The PX4 chain's phase-2 path (rate plant) against the package's simulated PX4 in lock-step,
and the chain's phase-1 recording of PX4's rate setpoints on a real PX4 SITL (skips without
PX4_SITL_DIR).

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
    cfg_doc["campaign"].update({"vertices": [8], "hover_validation": False, "finish": "LAND"})
    (tmp_path / "campaign.yaml").write_text(yaml.safe_dump(cfg_doc))
    with Px4Sitl(d, instance=9) as px4:
        res = fly(
            FlyConfig.load(tmp_path / "campaign.yaml"),
            px4.url,
            tmp_path / "out",
            params={"COM_OBL_RC_ACT": 5.0, "COM_OF_LOSS_T": 2.0},
            echo=lambda s: None,
            handle_signals=False,
            record_rate_setpoints=True,
        )
    if not res.summary.get("bags") and "stale input" in res.reason:
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
