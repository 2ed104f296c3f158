"""One flight path for phase 2 (issue 21 item 1, issue 25 item 1): ``lpv-sysid fly phase2`` and
the chain's phase 2 (:func:`lpv_sysid.flight.phase2.fly_phase2`) fly through the controller
node's runtime (:class:`lpv_sysid.flight.controller.ControllerRuntime`) and the excitation
node's, so every gains/signals tamper the node refuses is refused by the CLI path too, with the
same words, before anything is sent to the vehicle.

Per tamper case: the node's runtime (built from the shipped ``config/lpv_controller_px4.yaml``
as ``phase2.launch.py design:=rate_plant`` builds it) refuses with a ConfigError; ``fly_phase2``
against the PX4-faithful simulated vehicle (airborne in HOLD, lock-step) raises the same
ConfigError text, and the vehicle received no setpoint and no mode change; ``lpv-sysid fly
phase2`` exits 2 printing that text. The untampered files are accepted by the same runtime
(the control case: the checks are not refusing everything).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from test_chain_px4 import _lockstep, _vehicle, design  # noqa: F401  (module fixture)

from lpv_sysid.cli.main import main as cli_main
from lpv_sysid.configuration.defaults import config_file
from lpv_sysid.configuration.parameters import yaml_parameters
from lpv_sysid.errors import ConfigError
from lpv_sysid.flight.controller import ControllerRuntime, ControllerSettings
from lpv_sysid.flight.phase2 import Phase2Options, fly_phase2
from lpv_sysid.io.messages import MsgFactory
from lpv_sysid.mavlink.link import free_udp_port
from lpv_sysid.signals.store import load_npz, save_npz

CASES = (
    "K_negated",
    "K_x1.1",
    "gamma_x100",
    "sidecar_missing",
    "gains_sha256_removed",
    "u_e_x20",
    "v_d_x3",
    "kappa_10",
)


def _tampered(src: Path, tmp: Path, case: str) -> tuple[Path, Path, float]:
    """(gains, signals dir, kappa) of ``case``, written under ``tmp`` (sidecar copied along)."""
    g, s = tmp / "g", tmp / "s"
    g.mkdir()
    shutil.copytree(src / "signals", s)
    shutil.copy(src / "gains.cert.npz", g / "gains.cert.npz")
    doc = yaml.safe_load((src / "gains.yaml").read_text())
    kappa = 1.0
    if case == "K_negated":
        for v in doc["vertices"]:
            v["K"] = (-np.asarray(v["K"])).tolist()
    elif case == "K_x1.1":
        for v in doc["vertices"]:
            v["K"] = (1.1 * np.asarray(v["K"])).tolist()
    elif case == "gamma_x100":
        doc["gamma"] = 100.0 * doc["gamma"]
    elif case == "sidecar_missing":
        (g / "gains.cert.npz").unlink()
    elif case == "gains_sha256_removed":
        del doc["certificate"]["gains_sha256"]
    elif case in ("u_e_x20", "v_d_x3"):
        t, u, names = load_npz(str(s / "signals.npz"))
        u = np.array(u, dtype=float)
        for k, n in enumerate(names):
            if case == "u_e_x20" and str(n).startswith("ue_"):
                u[:, k] *= 20.0
            if case == "v_d_x3" and str(n) in ("u_d", "v_d", "w_d"):
                u[:, k] *= 3.0
        (s / "signals.npz").unlink()
        save_npz(str(s / "signals.npz"), t, u, [str(n) for n in names])
    elif case == "kappa_10":
        kappa = 10.0
    (g / "gains.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    return g / "gains.yaml", s, kappa


def _node_runtime(gains: Path, signals: Path, kappa: float) -> ControllerRuntime:
    """lpv_controller_node's runtime as phase2.launch.py (design rate_plant) parameterises it."""
    p = yaml_parameters(str(config_file("lpv_controller_px4.yaml")), "lpv_controller")
    p.update(
        gains_file=str(gains), signals_file=str(signals / "signals.npz"), excitation_gain=kappa
    )
    return ControllerRuntime(ControllerSettings.from_dict(p), MsgFactory.rosbags())


def test_untampered_files_are_accepted_by_the_node_runtime(design, tmp_path):  # noqa: F811
    gains, signals, kappa = _tampered(design, tmp_path, "none")
    rt = _node_runtime(gains, signals, kappa)
    assert (
        rt.design == "rate_plant"
        and rt.law.n_x == 8
        and rt.inputs
        == (
            "state",
            "velocity_reference",
            "excitation",
        )
    )
    info = " ".join(line for _, line in rt.take_log())
    assert "law sha256" in info and "kappa 1 x u_e within the designed excitation peak" in info


@pytest.mark.parametrize("case", CASES)
def test_every_tamper_is_refused_by_the_node_and_by_fly_phase2_alike(
    design,  # noqa: F811
    tmp_path,
    capsys,
    case,
):
    gains, signals, kappa = _tampered(design, tmp_path, case)
    with pytest.raises(ConfigError) as node:
        _node_runtime(gains, signals, kappa)
    text = str(node.value)
    expected = {
        "K_negated": "does not match the gains in the file",
        "K_x1.1": "does not match the gains in the file",
        "gamma_x100": "does not match the gains in the file",
        "sidecar_missing": "gains.cert.npz",
        "gains_sha256_removed": "certificate.gains_sha256: missing",
        "u_e_x20": "exceeds the design excitation peak",
        "v_d_x3": "outside the scheduling box",
        "kappa_10": "kappa 10 x ue_t peak",
    }[case]
    assert expected in text, text
    # the CLI core on the simulated PX4 in the air: same refusal, nothing sent
    veh, bcfg = _vehicle(tmp_path, airborne=True)
    try:
        ls, _ = _lockstep(veh)
        with pytest.raises(ConfigError) as cli:
            fly_phase2(
                gains,
                signals,
                tmp_path / "p2",
                bridge_config=bcfg,
                opts=Phase2Options(kappa=kappa, duration=20.0, ramp_s=2.0, lead_in_s=1.0),
                clock=ls.clock,
                sleep=ls.sleep,
                echo=lambda _: None,
                handle_signals=False,
            )
        for _ in range(50):  # whatever was sent would have arrived by now
            ls.sleep(0.004)
    finally:
        veh.close()
    assert str(cli.value) == text
    assert veh.setpoints_received == 0 and veh.mode_log == []
    assert not (tmp_path / "p2").exists() or not any((tmp_path / "p2").iterdir())
    # `lpv-sysid fly phase2`: exit 2 with the same words
    status = cli_main(
        [
            "fly",
            "phase2",
            "--connect",
            f"udpin:127.0.0.1:{free_udp_port()}",
            "--gains",
            str(gains),
            "--signals",
            str(signals),
            "--out",
            str(tmp_path / "p2cli"),
            "--kappa",
            f"{kappa:g}",
        ]
    )
    err = capsys.readouterr().err
    assert status == 2 and text in err, err
