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


def test_fly_phase2_without_a_terminal_is_refused_after_the_checks_before_the_link(
    design,  # noqa: F811
    tmp_path,
):
    """Untampered files, stdin not a terminal, no --yes: the checks pass, then the question
    cannot be asked -> exit 2 'pass --yes', before any link is opened (nothing written)."""
    import subprocess
    import sys

    gains, signals, _ = _tampered(design, tmp_path, "none")
    argv = [sys.executable, "-m", "lpv_sysid.cli", "fly", "phase2", "--connect"]
    argv += [f"udpin:127.0.0.1:{free_udp_port()}", "--gains", str(gains)]
    argv += ["--signals", str(signals), "--out", str(tmp_path / "p2")]
    r = subprocess.run(argv, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=300)
    assert r.returncode == 2, r.stderr
    assert "refusing to fly without confirmation: stdin is not a terminal; pass --yes" in r.stderr
    assert not (tmp_path / "p2").exists() or not any((tmp_path / "p2").iterdir())


# ============================================ issue 21 items 4 and 5: the bag and the latency
FLIGHT_OPTS = Phase2Options(duration=20.0, ramp_s=2.0, lead_in_s=1.0)


@pytest.fixture(scope="module")
def flown(design, tmp_path_factory):  # noqa: F811
    """A 20 s phase-2 flight of ``fly_phase2`` on the simulated PX4 (lock-step, airborne in
    HOLD, no ESC telemetry): (summary, output directory, bridge config)."""
    tmp = tmp_path_factory.mktemp("flown")
    veh, bcfg = _vehicle(tmp, airborne=True)
    try:
        ls, _ = _lockstep(veh)
        s = fly_phase2(
            design / "gains.yaml",
            design / "signals",
            tmp / "p2",
            models=design / "vertex_models.yaml",
            bridge_config=bcfg,
            opts=FLIGHT_OPTS,
            clock=ls.clock,
            sleep=ls.sleep,
            echo=lambda _: None,
            handle_signals=False,
        )
    finally:
        veh.close()
    return s, tmp / "p2", bcfg


def test_phase2_bag_has_every_topic_at_its_configured_rate_and_the_latency(flown):
    """The bag of a phase-2 flight has
    state, imu, rotor_speeds (estimated from ACTUATOR_OUTPUT_STATUS), status,
    velocity_reference, excitation, actuator_command (the setpoints sent) and rate_setpoint
    (PX4's ATTITUDE_TARGET echo), each at the rate its configuration sets; the summary's
    state-stamp -> setpoint-sent latency is the one of the bag's stamps. Before: rotor_speeds,
    imu and status 0 messages, the excitation a stream of zeros, no echo, no latency."""
    from lpv_sysid.flight.phase2 import loop_latency
    from lpv_sysid.io import bag as iobag
    from lpv_sysid.io import messages
    from lpv_sysid.io.files import read_yaml

    s, out, bcfg = flown
    opts = FLIGHT_OPTS
    assert s["ok"] and s["handback"]["state"] == "DONE", s["reason"]
    bag = out / s["bag"]
    info = {k.rsplit("/", 1)[-1]: v for k, v in iobag.topic_info(str(bag)).items()}
    streams = read_yaml(str(bcfg))["link"]["streams"]
    ctrl = yaml_parameters(str(config_file("lpv_controller_px4.yaml")), "lpv_controller")
    expected = {
        # one state sample per attitude and per position message (telemetry decoder)
        "state": streams["ATTITUDE_QUATERNION"] + streams["LOCAL_POSITION_NED"],
        "imu": streams["HIGHRES_IMU"],
        "rotor_speeds": streams["ACTUATOR_OUTPUT_STATUS"],  # no ESC_STATUS: the estimate
        "velocity_reference": opts.control_rate_hz,  # the excitation runtime's rate_hz
        "excitation": opts.control_rate_hz,
        "rate_setpoint": streams["ATTITUDE_TARGET"],
    }
    print({k: round(v.rate_hz, 2) for k, v in info.items()}, s["latency_state_to_setpoint_ms"])
    for topic, hz in expected.items():
        assert info[topic].rate_hz == pytest.approx(hz, rel=0.05), (topic, info[topic])
    # the setpoints sent: one per state sample of a new stamp, at least the attitude rate
    assert info["actuator_command"].count == s["controller"]["commands"] > 0
    assert info["actuator_command"].rate_hz >= 0.95 * streams["ATTITUDE_QUATERNION"]
    assert info["status"].count >= ctrl["status_rate_hz"] * info["status"].duration_s * 0.9
    got = iobag.read_bag(str(bag))
    rotor = [m for _, m in got["/lpv_sysid/rotor_speeds"]]
    assert {messages.rotor_source_of(m) for m in rotor} == {"estimated"}
    ue = np.array(
        [messages.excitation_from_joint_state(m)[1] for _, m in got["/lpv_sysid/excitation"]]
    )
    assert np.abs(ue).max() > 0.05  # the signal, not zeros
    # PX4's echo equals what was sent (float32 on the wire)
    sent = np.array(
        [
            messages.channels_from_joint_state(m, ("thrust", "p_sp", "q_sp", "r_sp"))[1]
            for _, m in got["/lpv_sysid/actuator_command"]
        ]
    )
    echo = np.array(
        [
            messages.channels_from_joint_state(m, ("thrust", "p_sp", "q_sp", "r_sp"))[1]
            for _, m in got["/lpv_sysid/rate_setpoint"]
        ]
    )
    clipped = np.column_stack([np.clip(sent[:, 0], 0.05, 0.95), np.clip(sent[:, 1:], -2, 2)])
    for row in echo[5::50]:
        assert np.min(np.abs(clipped - row).max(axis=1)) < 1e-5
    # latency: the summary's numbers are the bag's (log time - header stamp per command)
    rows = got["/lpv_sysid/actuator_command"]
    lat = loop_latency(
        [messages.stamp_ns_of(m) * 1e-9 for _, m in rows], [t * 1e-9 for t, _ in rows]
    )
    summ = s["latency_state_to_setpoint_ms"]
    assert summ["commands"] == lat["commands"] == len(rows)
    for k in ("p50", "p99", "max"):
        assert summ[k] == pytest.approx(lat[k], abs=1e-9)
    assert yaml.safe_load((out / "phase2_summary.yaml").read_text())[
        "latency_state_to_setpoint_ms"
    ]["commands"] == len(rows)


def test_phase2_recording_carries_epoch_stamps_and_the_vehicle_record(flown):
    """Issue 23 item 2 for phase 2: the bag is stamped in wall-clock (epoch) ns and
    ``experiment.yaml`` holds the clock offset and the vehicle record -- kind SIMULATED (the
    package's own PX4 stand-in), firmware, parameters, battery, site (its HOME_POSITION) and
    PX4's boot on the bag clock. Oracle: the lock-step vehicle's clock is the flight clock
    (it boots at flight time 0 and sends time_boot_ms = its time), so its boot on the bag
    clock is ``clock.offset_ns``; the estimate may only be late, by the link latency (one
    lock-step step, 4 ms) + the ms truncation: within the 10 ms of the issue."""
    import time as _time

    from lpv_sysid.io import bag as iobag
    from lpv_sysid.sim.px4_vehicle.telemetry import HOME_ALT, HOME_LAT, HOME_LON

    s, out, _ = flown
    meta = yaml.safe_load((out / "experiment.yaml").read_text())
    off = meta["clock"]["offset_ns"]
    assert meta["clock"]["kind"] == "utc"
    assert abs(off - _time.time_ns()) < 3600 * 10**9  # wall clock of this run, not 1970
    v = meta["vehicle"]
    assert v["kind"] == "SIMULATED"
    assert v["firmware"]["flight_sw_version"].startswith("v1.")
    assert len(v["px4_parameters"]) > 10
    assert v["battery"]["start"]["voltage_v"] > 10.0
    site = v["site"]
    assert site["latitude_deg"] == pytest.approx(HOME_LAT, abs=2e-7)
    assert site["longitude_deg"] == pytest.approx(HOME_LON, abs=2e-7)
    assert site["altitude_amsl_m"] == pytest.approx(HOME_ALT, abs=1e-3)
    boot = v["px4_clock"]["boot_ns"]
    assert 0 <= boot - off < 10_000_000, boot - off
    info = iobag.topic_info(str(out / s["bag"]))
    st = info["/lpv_sysid/state"]
    # bag clock - offset = the flight (lock-step) clock: the phase-2 run started after take-off
    assert 0.0 < (st.start_ns - off) * 1e-9 < st.duration_s + (st.start_ns - off) * 1e-9 < 200.0


def test_report_of_the_flown_phase2_run(flown, tmp_path):
    """Issue 23 item 4: ``report --run`` on a ``fly phase2`` directory opens with the go/no-go,
    labels the phase-2 flight with the kind its recorder recorded (SIMULATED: the package's
    PX4 stand-in; the site on the first page) and draws the flown time histories with the
    box, the limits and, for an aborted run, the abort. Oracles: the numbers of
    phase2_log.npz and phase2_summary.yaml themselves."""
    import shutil

    from lpv_sysid.report import write_report

    s, out, _ = flown
    run = tmp_path / "run"
    shutil.copytree(out, run)
    text = write_report(run).read_text()
    head = text.split("\n## ")[1]
    assert head.startswith("Go / no-go: **")
    row = next(x for x in text.splitlines() if x.startswith("| phase-2 flight |"))
    assert "| SIMULATED |" in row and "site 47.39774" in row
    assert "## Phase 2: flown under the LPV law (SIMULATED)" in text
    assert (run / "report" / "phase2_flight.png").is_file()
    log = np.load(run / "phase2_log.npz")
    err = np.abs(log["x"][:, 2:5] - log["v_d"]).max()
    assert f"max |v - v_d| {err:.3f} m/s (limit {FLIGHT_OPTS.max_tracking_error:g} m/s)" in text
    assert "signal complete." in text and "ABORT" not in text.split("## Phase 2: flown")[1]
    lim = s["limits"]
    assert lim["max_rate_rad_s"] == FLIGHT_OPTS.max_rate and lim["thrust"] == [0.05, 0.95]
    assert len(lim["box_min"]) == 3 and all(a < b for a, b in zip(lim["box_min"], lim["box_max"]))
    # the same flight recorded as aborted: the outcome, the go/no-go and the figure say so
    doc = yaml.safe_load((run / "phase2_summary.yaml").read_text())
    doc.update(ok=False, reason="tracking error 1.20 m/s > 1 m/s (axis u) -> hand back")
    (run / "phase2_summary.yaml").write_text(yaml.safe_dump(doc))
    text = write_report(run).read_text()
    assert "| outcome | ABORTED: tracking error 1.20 m/s" in text
    assert "Go / no-go: **NO-GO**" in text
    assert "ABORTED at the red line" in text and "and the abort (red line)" in text


def test_loop_latency_percentiles():
    from lpv_sysid.flight.phase2 import loop_latency

    t_state = np.arange(100) * 0.01
    delay = np.r_[np.full(98, 0.002), 0.010, 0.030]  # 2 ms, one 10 ms, one 30 ms
    lat = loop_latency(t_state, t_state + delay)
    assert lat["commands"] == 100
    assert lat["p50"] == pytest.approx(2.0) and lat["max"] == pytest.approx(30.0)
    # numpy's linear percentile: rank 98.01 between 10 ms and 30 ms
    assert lat["p99"] == pytest.approx(10.0 + 0.01 * 20.0)


def test_the_node_runtime_replays_the_cli_flight_command_for_command(flown, design, tmp_path):  # noqa: F811
    """``lpv-sysid replay`` (lpv_controller_node's runtime over the recorded inputs, with the
    parameters of config/lpv_controller_px4.yaml, the file phase2.launch.py design:=rate_plant
    gives the node) computes the commands ``fly phase2`` sent, to float64 round-off: one
    controller, not two."""
    from lpv_sysid.flight.controller import replay_controller
    from lpv_sysid.io import bag as iobag
    from lpv_sysid.io import messages

    s, out, _ = flown
    p = yaml_parameters(str(config_file("lpv_controller_px4.yaml")), "lpv_controller")
    p.update(gains_file=str(design / "gains.yaml"))
    r = replay_controller(str(out / s["bag"]), p, str(tmp_path / "replay"))
    assert r["event"] is None or r["event"].reason == "stale"  # the recording ends
    names = ("thrust", "p_sp", "q_sp", "r_sp")

    def commands(bag):
        rows = iobag.read_bag(str(bag))["/lpv_sysid/actuator_command"]
        return {
            messages.stamp_ns_of(m): messages.channels_from_joint_state(m, names)[1]
            for _, m in rows
        }

    flown_cmds, replayed = commands(out / s["bag"]), commands(tmp_path / "replay")
    common = sorted(set(flown_cmds) & set(replayed))
    assert len(common) >= 0.99 * len(flown_cmds) > 1000
    diff = max(float(np.abs(flown_cmds[k] - replayed[k]).max()) for k in common)
    print(f"replay: {len(common)} of {len(flown_cmds)} commands compared, max |diff| {diff:.3g}")
    assert diff < 1e-9, diff


# ====================================== issue 21 item 2: the rate plant through the bridge node
def test_bridge_node_runtime_sends_rate_plant_commands_as_set_attitude_target(tmp_path):
    """mavlink_bridge_node's runtime with ``command: rate_setpoint`` (phase2.launch.py
    design:=rate_plant) parses ``actuator_command`` by the rate plant's names and sends them
    as SET_ATTITUDE_TARGET thrust + body rates: the simulated PX4 (airborne in HOLD) tracks
    exactly those values in OFFBOARD; when the commands stop it hands back (HOLD confirmed).
    PX4's ATTITUDE_TARGET echo is republished on ``rate_setpoint`` (recorded by the data
    logger). Before: ``actuator command ignored: bridge command is 'rate_setpoint'``.
    A virtual-actuator command (ut, ua, ue, ur) is refused by the parser, not sent."""
    from lpv_sysid.flight.bridge import SPECS, BridgeRuntime
    from lpv_sysid.io import messages
    from lpv_sysid.io.messages import MessageError
    from lpv_sysid.mavlink.bridge import RATE_INPUT_NAMES

    f = MsgFactory.rosbags()
    veh, _ = _vehicle(tmp_path, airborne=True)
    port = veh.config.url.rsplit(":", 1)[-1]
    params = {n: d for n, (d, _) in SPECS.items()}
    params.update(
        {
            "link.url": f"udpin:127.0.0.1:{port}",
            "command": "rate_setpoint",
            "auto_start": True,
            "offboard.arm": False,
            "offboard.input_timeout": 0.5,
        }
    )
    rt = BridgeRuntime(params, f, "/lpv_sysid/mavlink_bridge", 15.0, 3.0)
    u = np.array([0.55, 0.1, -0.05, 0.02])
    bad = messages.actuator_command_msg(f, 1, [0.5, 0.0, 0.0, 0.0])
    with pytest.raises(MessageError):
        rt.parsers["actuator_command"](bad)
    t, dt = 0.0, 0.004
    rt.open(t)
    modes: list = []
    echo: list = []
    assert "rate_setpoint" in [e.key for e in rt.publishers]
    try:
        for k in range(int(12.0 / dt)):  # bounded: 12 s of simulated time
            t += dt
            veh.step(t)
            echo += [(t, m) for key, m in rt.on_timer(t) if key == "rate_setpoint"]
            if k % 5 == 0 and t < 6.0:  # 50 Hz commands for 6 s, then silence
                msg = messages.joint_state(f, round(t * 1e9), RATE_INPUT_NAMES, position=u)
                rt.on_sample("actuator_command", rt.parsers["actuator_command"](msg), t)
            if not modes or modes[-1] != veh.mode.name:
                modes.append(veh.mode.name)
            if t > 4.0 and veh.mode.name == "OFFBOARD":
                sp = veh.setpoint
                assert sp.kind == "rates" and sp.thrust == pytest.approx(u[0], abs=1e-6)
                assert np.allclose(sp.rates, u[1:], atol=1e-6)
        final = (rt.core.state.value, rt.core.status(t).get("reason"))
    finally:
        rt.close()
        veh.close()
    assert modes[:3] == ["HOLD", "OFFBOARD", "HOLD"], modes
    # commands stopped = a fault of the input stream: the run FAILED, PX4 confirmed in HOLD
    assert final[1].startswith("hand-back confirmed: vehicle in HOLD: stale input"), final
    # PX4's echo (ATTITUDE_TARGET, requested at 50 Hz for command rate_setpoint) republished on
    # rate_setpoint for the data logger: the values sent, at the requested rate
    vals = np.array([messages.channels_from_joint_state(m, RATE_INPUT_NAMES)[1] for _, m in echo])
    ts = np.array([t for t, _ in echo])
    assert len(vals) > 50 and np.allclose(vals, u, atol=1e-6)
    assert (len(ts) - 1) / (ts[-1] - ts[0]) == pytest.approx(50.0, rel=0.05)


def test_bag_latency_cli_reads_a_data_logger_bag(tmp_path, capsys):
    """``lpv-sysid bag latency``: the node path's numbers from the data logger's bag (log time =
    receipt, header stamp = the state stamp the controller computed the command on)."""
    from lpv_sysid.io import bag as iobag
    from lpv_sysid.io import messages

    f = MsgFactory.rosbags()
    t0 = 1_700_000_000_000_000_000
    delays_ms = [1.0] * 98 + [5.0, 20.0]
    with iobag.BagWriter(tmp_path / "b") as w:
        w.add_topic("/lpv_sysid/actuator_command", messages.TYPES["actuator_command"])
        for i, d in enumerate(delays_ms):
            stamp = t0 + i * 4_000_000
            msg = messages.joint_state(
                f, stamp, ("thrust", "p_sp", "q_sp", "r_sp"), position=[0.5, 0, 0, 0]
            )
            w.write("/lpv_sysid/actuator_command", stamp + round(d * 1e6), msg)
    assert cli_main(["bag", "latency", str(tmp_path / "b")]) == 0
    out = capsys.readouterr().out
    # numpy's linear percentile: p99 at rank 98.01 between 5 ms and 20 ms
    assert "100 commands" in out and "p50 1.000 ms" in out and "max 20.000 ms" in out
    assert "p99 5.150 ms" in out, out


def _phase1_bags(tmp_path: Path, plant) -> Path:
    """An earlier phase-1 directory (campaign_summary.yaml + two bags with state and PX4's
    rate setpoints) of the known rate plant ``plant`` (test_rate_plant._simulate)."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from test_rate_plant import _simulate

    from lpv_sysid.io import bag as iobag
    from lpv_sysid.io import messages
    from lpv_sysid.models import rate_plant as rp

    f = MsgFactory.rosbags()
    p1 = tmp_path / "old" / "phase1"
    bags = {}
    for k, seed in enumerate((0, 1)):
        t, x, u = _simulate(plant, T=25.0, seed=seed)
        t0 = 1_000_000_000 * (100 + 50 * k)
        name = f"bag_{k:04d}"
        bags[f"run{k}"] = name
        with iobag.BagWriter(p1 / name) as b:
            b.add_topic("/lpv_sysid/state", messages.TYPES["state"])
            b.add_topic("/lpv_sysid/rate_setpoint", messages.TYPES["actuator_command"])
            for i in range(0, len(t), 2):
                ns = t0 + round(t[i] * 1e9)
                msg = messages.odometry_from_state(
                    f, ns, [0.0, 0.0, -10.0], [x[i, 0], x[i, 1], 0.0], x[i, 2:5], x[i, 5:8]
                )
                b.write("/lpv_sysid/state", ns, msg)
            for i in range(0, len(t), 4):
                ns = t0 + round(t[i] * 1e9)
                msg = messages.joint_state(f, ns, rp.INPUT_NAMES, position=u[i])
                b.write("/lpv_sysid/rate_setpoint", ns, msg)
    (p1 / "campaign_summary.yaml").write_text(
        yaml.safe_dump({"ok": True, "result": "complete", "bags": bags})
    )
    return p1


def test_chain_phase2_refuses_what_the_node_refuses(tmp_path):
    """``lpv-sysid chain --phase1 OLD --kappa 10``: the chain identifies, synthesizes and
    verifies (steps 2-4), then its phase 2 is refused before the link is opened with the
    controller node's words for the same gains, signals and kappa."""
    from test_rate_plant import P0

    from lpv_sysid.flight.chain import chain

    p1 = _phase1_bags(tmp_path, P0)
    lines: list = []
    status = chain(
        f"udpin:127.0.0.1:{free_udp_port()}",
        tmp_path / "chain",
        kappa=10.0,
        phase1_dir=p1,
        echo=lines.append,
        preflight=False,
    )
    out = tmp_path / "chain"
    summary = yaml.safe_load((out / "chain_summary.yaml").read_text())
    assert status == 1 and (out / "gains.yaml").exists(), lines[-10:]
    with pytest.raises(ConfigError) as node:
        _node_runtime(out / "gains.yaml", out / "signals", 10.0)
    assert "kappa 10 x ue_t peak" in str(node.value)
    assert summary["phase2"]["reason"] == str(node.value)
    assert not (out / "phase2").exists() or not any((out / "phase2").iterdir())


def test_chain_flies_phase2_on_the_simulated_px4_and_checks_the_model_by_output_error(tmp_path):
    """``lpv-sysid chain --phase1 OLD`` against the simulated PX4 in the air (lock-step): the
    chain's phase 2 (the node runtimes) flies the signal, hands back to LAND, and the chain
    summary carries the identified plant's output-error R^2 per row on the phase-2 flight (its
    window stated) and the loop latency. ``--set-param`` values hold through phase 2 (PX4's
    own parameter snapshot in the phase-2 recording shows them) and are restored when the
    chain ends (the simulated PX4 holds the old values again)."""
    from test_chain_px4 import P_SIM

    from lpv_sysid.flight.chain import chain

    p1 = _phase1_bags(tmp_path, P_SIM)
    veh, bcfg = _vehicle(tmp_path, airborne=True)
    url = yaml.safe_load(bcfg.read_text())["link"]["url"]
    lines: list = []
    before = {k: veh.param(k) for k in ("COM_OF_LOSS_T", "MPC_TILTMAX_AIR")}
    assert before == {"COM_OF_LOSS_T": 1.0, "MPC_TILTMAX_AIR": 45.0}  # the sim's defaults
    try:
        ls, _ = _lockstep(veh)
        status = chain(
            url,
            tmp_path / "chain",
            params={"COM_OF_LOSS_T": 2.0, "MPC_TILTMAX_AIR": 40.0},
            phase1_dir=p1,
            echo=lines.append,
            preflight=False,
            clock=ls.clock,
            sleep=ls.sleep,
            phase2=FLIGHT_OPTS,
        )
        after = {k: veh.param(k) for k in before}
    finally:
        veh.close()
    summary = yaml.safe_load((tmp_path / "chain" / "chain_summary.yaml").read_text())
    p2 = summary["phase2"]
    assert status == 0 and p2["ok"] and p2["handback"]["state"] == "DONE", lines[-12:]
    flown = yaml.safe_load((tmp_path / "chain" / "phase2" / "experiment.yaml").read_text())
    seen = flown["vehicle"]["px4_parameters"]
    assert (seen["COM_OF_LOSS_T"], seen["MPC_TILTMAX_AIR"]) == (2.0, 40.0)
    assert after == before
    assert [(d["name"], d["old"], d["new"]) for d in summary["params_set"]] == [
        ("COM_OF_LOSS_T", 1.0, 2.0),
        ("MPC_TILTMAX_AIR", 45.0, 40.0),
    ]
    assert summary["params_restored"] == [
        {"name": "COM_OF_LOSS_T", "value": 1.0, "restored": True},
        {"name": "MPC_TILTMAX_AIR", "value": 45.0, "restored": True},
    ]
    # the synthesis covers the loop phase 2 flies: its certificate's bound >= the configured
    # loop, or the pole region is shrunk until it does (chain.synthesize_for_loop)
    syn = next(st for st in summary["steps"] if st["step"].startswith("Lemma 1"))
    assert syn["attempts"][-1]["loop_delay_bound_s"] >= syn["loop_delay_s"] > 0
    oe = p2["model_check_output_error"]
    assert oe["window_s"] == 10.0 and set(oe) >= {"u", "v", "w", "p", "q", "r"}
    assert all(isinstance(oe[k], float) for k in ("u", "v", "w", "p", "q", "r"))
    assert p2["latency_state_to_setpoint_ms"]["commands"] > 1000
    print("output error R^2 on the phase-2 flight:", oe)


def chain_design_only(p1: Path, out: Path) -> int:
    """``lpv-sysid chain --phase1 P1 --kappa 10``: identification, signals and synthesis;
    phase 2 refused before any link traffic (kappa beyond the designed excitation)."""
    from lpv_sysid.flight.chain import chain

    return chain(
        f"udpin:127.0.0.1:{free_udp_port()}",
        out,
        kappa=10.0,
        phase1_dir=p1,
        echo=lambda _: None,
        preflight=False,
    )


def test_chain_synthesis_shrinks_the_pole_region_until_the_loop_is_covered(tmp_path, capsys):
    """``synthesize_for_loop``: asked for a loop 5 ms beyond what the shipped region proves,
    it synthesizes again with a smaller disk until the certificate's delay bound covers it;
    each attempt verified, the bounds growing; the gains left are the covering one."""
    from test_chain_px4 import P_SIM

    from lpv_sysid.configuration.defaults import config_file
    from lpv_sysid.flight.chain.steps import synthesize_for_loop
    from lpv_sysid.synthesis.gains import REGION_SCALES
    from lpv_sysid.io.formats import GainSchedule

    p1 = _phase1_bags(tmp_path, P_SIM)
    out = tmp_path / "chain"
    status = chain_design_only(p1, out)
    assert (out / "vertex_models.yaml").exists() and (out / "signals").exists(), status
    cfg, summ = config_file("synthesis_chain.yaml"), out / "signals" / "summary.yaml"
    first_ok, first = synthesize_for_loop(
        out / "vertex_models.yaml", cfg, summ, tmp_path / "a", 1e-3, lambda _: None
    )
    b0 = first[0]["loop_delay_bound_s"]
    assert first_ok and len(first) == 1 and b0 > 1e-3
    ok, att = synthesize_for_loop(
        out / "vertex_models.yaml", cfg, summ, tmp_path / "b", b0 + 0.005, lambda _: None
    )
    bounds = [a["loop_delay_bound_s"] for a in att]
    assert ok and len(att) >= 2 and all(a["verified"] for a in att), att
    assert bounds[0] == b0 and bounds[-1] >= b0 + 0.005 and bounds == sorted(bounds)
    assert [a["region_scale"] for a in att] == list(REGION_SCALES[: len(att)])
    gs = GainSchedule.load(str(tmp_path / "b" / "gains.yaml"), auto_layout=True)
    assert gs.certificate.loop_delay_bound_s == bounds[-1]
    # an attempt that finds no gains (Lemma 1 infeasible in the smaller region) ends the
    # search: the previous gains stay, and so does the config that made them
    from lpv_sysid.errors import SolverError
    from lpv_sysid.synthesis.gains import cover_loop

    calls: list = []

    def attempt(path):
        calls.append(yaml.safe_load(path.read_text()))
        if len(calls) > 1:
            raise SolverError("Lemma 1 infeasible at gamma=1: gamma_min=1.022. | remedies")
        return True, tmp_path / "a" / "gains.yaml"

    used = tmp_path / "d" / "used.yaml"
    ok_d, att_d = cover_loop(cfg, used, b0 + 0.005, attempt)
    assert ok_d and [a["region_scale"] for a in att_d] == [1.0, 0.8]
    assert att_d[1]["error"] == "Lemma 1 infeasible at gamma=1: gamma_min=1.022."
    assert yaml.safe_load(used.read_text()) == calls[0] != calls[1]
    # the ROS-graph path's command does the same (lpv-sysid synthesize --loop-delay)
    from lpv_sysid.cli.main import main as cli_main

    argv = ["synthesize", "--models", str(out / "vertex_models.yaml"), "--config", str(cfg)]
    argv += ["--summary", str(summ), "--out", str(tmp_path / "c" / "gains.yaml")]
    (tmp_path / "c").mkdir()
    assert cli_main([*argv, "--loop-delay", str(b0 + 0.005)]) == 0
    gc = GainSchedule.load(str(tmp_path / "c" / "gains.yaml"), auto_layout=True)
    assert gc.certificate.loop_delay_bound_s == pytest.approx(bounds[-1], rel=0.02)
    used = yaml.safe_load((tmp_path / "c" / "gains.synthesis.yaml").read_text())
    assert used["hinf"]["region"]["disk"]["radius"] == pytest.approx(7.0 * att[-1]["region_scale"])
    capsys.readouterr()
    assert cli_main([*argv, "--loop-delay", "nan"]) != 0
    assert "--loop-delay must be in (0, 1) s, got nan" in capsys.readouterr().err
