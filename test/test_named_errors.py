"""Named errors where a generic one (or none) was due (issue 25 item 12).

Each case is a one-line error with exit 2 naming the input and the problem, raised before
any work is done: a bag whose ``/lpv_sysid/state`` is typed Imu (was ``KeyError
'child_frame_id'``; replay exited 1, a verdict on the gains), ``config ../../etc/passwd``
(printed that path, exit 0), ``fly --dry-run --set-param X=abc`` (accepted), ``demo --kappa
-1`` (failed at step 6 after 20-37 s), ``chain --kappa nan`` (failed after waiting for a
vehicle), ``simulate phase2`` kappa/box-margin beyond the controller's ranges (ran), the
excitation node's abort markers compared case-sensitively ("True" was no abort).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import pytest

from lpv_sysid.cli.main import main
from lpv_sysid.errors import BagError, ConfigError
from lpv_sysid.io import bag as bg
from lpv_sysid.io import messages as m

ROOT = Path(__file__).resolve().parents[1]
F = m.MsgFactory.rosbags()
T0 = 1_700_000_000_000_000_000


def _run(argv, capsys):
    rc = main(argv)
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def _imu_as_state(path):
    with bg.BagWriter(path, storage="mcap") as b:
        b.add_topic("/lpv_sysid/state", "sensor_msgs/msg/Imu")
        for i in range(5):
            ns = T0 + i * 10_000_000
            b.write("/lpv_sysid/state", ns, m.imu_msg(F, ns, [0.0, 0.0, -9.8], [0.0, 0.0, 0.0]))
    return path


def test_a_topic_of_the_wrong_type_is_a_named_bag_error(tmp_path):
    bag = _imu_as_state(tmp_path / "b")
    with pytest.raises(BagError, match=r"topic /lpv_sysid/state has type sensor_msgs/msg/Imu, "
                       r"expected nav_msgs/msg/Odometry"):  # fmt: skip
        bg.read_bag(bag, topics=["/lpv_sysid/state"])
    got = bg.read_bag(bag, strict=False)
    assert "/lpv_sysid/state" not in got and any("has type" in p for p in got.problems)


def test_replay_of_a_wrong_typed_bag_exits_2_not_1(tmp_path, capsys):
    bag = _imu_as_state(tmp_path / "b")
    gains = ROOT / "msg_samples" / "gains.yaml"
    rc, _, err = _run(
        ["replay", "--bag", str(bag), "--node", "lpv_controller", "--params",
         str(ROOT / "config" / "lpv_controller.yaml"), "--gains", str(gains),
         "--out", str(tmp_path / "out")],
        capsys,
    )  # fmt: skip
    assert rc == 2 and "has type sensor_msgs/msg/Imu" in err


@pytest.mark.parametrize("name", ["../../../../etc/passwd", "/etc/passwd", "nope.yaml", ""])
def test_config_names_only_shipped_files(name, capsys):
    rc, out, err = _run(["config", name], capsys)
    assert rc == 2 and "is not a shipped config file" in err and "passwd" not in out
    rc, out, _ = _run(["config", "synthesis.yaml"], capsys)
    assert rc == 0 and out.strip().endswith("synthesis.yaml")


def test_fly_dry_run_checks_set_param(capsys):
    rc, _, err = _run(
        ["fly", "phase1", "--connect", "udpin:127.0.0.1:1", "--out", "/nonexistent/x",
         "--config", str(ROOT / "config" / "campaign.yaml"), "--dry-run",
         "--set-param", "COM_OBL_RC_ACT=abc"],
        capsys,
    )  # fmt: skip
    assert rc == 2 and "--set-param 'COM_OBL_RC_ACT=abc': value is not a number" in err


@pytest.mark.parametrize("kappa", ["-1", "nan", "1e9"])
def test_demo_refuses_a_bad_kappa_before_step_1(kappa, tmp_path, capsys):
    t0 = time.monotonic()
    rc, _, err = _run(["demo", "--out", str(tmp_path / "d"), "--kappa", kappa], capsys)
    assert rc == 2 and "--kappa" in err and "excitation multiplier" in err
    assert not (tmp_path / "d").exists()  # nothing ran
    assert time.monotonic() - t0 < 60  # (generous: it used to take 20-37 s of steps)


def test_chain_refuses_a_nan_kappa_before_waiting_for_a_vehicle(tmp_path):
    from lpv_sysid.flight.chain import chain

    with pytest.raises(ConfigError, match="--kappa nan"):
        chain("udpin:127.0.0.1:1", tmp_path / "c", kappa=math.nan)
    assert not (tmp_path / "c").exists()


@pytest.mark.parametrize(
    "kw, needle", [({"kappa": 1e9}, "kappa"), ({"box_margin": 1e9}, "box_margin")]
)
def test_simulate_phase2_options_meet_the_controller_ranges(kw, needle):
    from lpv_sysid.sim.phase2 import Phase2Config

    with pytest.raises(ConfigError, match=needle):
        Phase2Config(**kw)


@pytest.mark.parametrize(
    "values",
    [{"aborted": "True"}, {"aborted": "TRUE"}, {"state": "handback"}, {"phase": " Aborted "},
     {"Phase": "failed"}],
)  # fmt: skip
def test_excitation_abort_markers_are_case_insensitive(values):
    from lpv_sysid.flight.excitation import reports_abort

    class S:
        pass

    s = S()
    s.values = values
    assert reports_abort(s)
    s.values = {"aborted": "false", "state": "OFFBOARD_ACTIVE", "phase": "excite"}
    assert not reports_abort(s)


def test_simulate_phase2_refuses_signals_beyond_the_design_envelope(tmp_path, capsys):
    """``simulate phase2`` with a table x 20 used to run; it now meets the check of the
    flight path (check_design against the gains' certificate.design)."""
    from lpv_sysid.io.formats import GainSchedule
    from lpv_sysid.signals.store import load_npz, save_npz
    from lpv_sysid.sim.phase2 import load_signals

    sig = tmp_path / "signals"
    cfg = str(ROOT / "config" / "signals_phase2.yaml")
    assert main(["signals", "--config", cfg, "--out", str(sig), "--no-plot"]) == 0
    design = GainSchedule.load(ROOT / "msg_samples" / "gains.yaml").certificate.design
    load_signals(sig, ramp=2.0, design=design)  # the designed signal: accepted
    t, u, names = load_npz(str(sig / "signals.npz"))
    big = tmp_path / "big"
    big.mkdir()
    save_npz(str(big / "signals.npz"), t, 20 * u, names)
    with pytest.raises(ConfigError, match="exceeds the design|beyond the design"):
        load_signals(big, ramp=2.0, design=design)
