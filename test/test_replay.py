"""`lpv-sysid replay` on the sample bags: exact reproduction of the recorded flight, an
independent re-computation of the law, safety aborts and bad input."""

import os

import numpy as np
import pytest
import yaml
from lpv_test_gains import design_for, gains_dict, write_gains

from lpv_sysid.cli.main import main
from lpv_sysid.io import messages
from lpv_sysid.io.bag import read_bag
from lpv_sysid.io.formats import GainSchedule
from lpv_sysid.models.quadrotor import mixer

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLES = os.path.join(ROOT, "msg_samples")
P2 = os.path.join(SAMPLES, "phase2_sim")
P1 = os.path.join(SAMPLES, "phase1_sim")
GAINS = os.path.join(SAMPLES, "gains.yaml")
PARAMS = os.path.join(ROOT, "config", "lpv_controller.yaml")
NS = "/lpv_sysid"


def replay(tmp_path, *extra, bag=P2, gains=GAINS, out="out"):
    argv = (
        [
            "replay",
            "--bag",
            bag,
            "--node",
            "lpv_controller",
            "--params",
            PARAMS,
            "--out",
            str(tmp_path / out),
        ]
        + (["--gains", gains] if gains else [])
        + list(extra)
    )
    return main(argv), tmp_path / out


def commands(bag):
    data = read_bag(str(bag), topics=[f"{NS}/actuator_command"])
    return [(t, np.array(m.position)) for t, m in data[f"{NS}/actuator_command"]]


def test_replay_reproduces_recorded_commands(tmp_path, capsys):
    code, out = replay(tmp_path)
    assert code == 0
    text = capsys.readouterr().out
    assert "recorded ticks" in text and f"wrote {out}" in text
    got, rec = commands(out), commands(os.path.join(P2, "bag_0000"))
    assert len(got) == len(rec) > 1000
    assert [t for t, _ in got] == [t for t, _ in rec]
    # equal to rounding (the replay parses in batch with vectorised frame conversions)
    assert max(np.abs(a - b).max() for (_, a), (_, b) in zip(got, rec)) < 1e-12


def test_replay_matches_independent_law(tmp_path):
    """Other gains (K x 1.25): every unsaturated command equals u0 + K (x - x0) + R u_e
    computed here from the last inputs before the tick, multilinear weights by hand."""

    def scale_k(d):
        for v in d["vertices"]:
            v["K"] = (1.25 * np.array(v["K"])).tolist()

    g = tmp_path / "gains2.yaml"
    write_gains(g, box=5.0, edit=scale_k)  # the test certifies the law it flies
    code, out = replay(tmp_path, gains=str(g))
    assert code == 0
    got = commands(out)
    gs = GainSchedule.load(str(g))
    inputs = read_bag(os.path.join(P2, "bag_0000"))
    mix = mixer(0.225)

    def last_before(topic, t):
        msgs = inputs[f"{NS}/{topic}"]
        i = np.searchsorted([s for s, _ in msgs], t, side="left") - 1
        return msgs[i][1]

    checked = 0
    for t, u in got[50::37]:
        st = messages.state_from_odometry(last_before("state", t))
        _, om = messages.rotor_speeds_from_joint_state(last_before("rotor_speeds", t))
        _, vd, _ = messages.reference_from_twist(last_before("velocity_reference", t))
        _, ue = messages.excitation_from_joint_state(last_before("excitation", t))
        x = np.concatenate([st.euler[:2], st.v_body, st.omega, mix @ om])
        s = (vd - gs.scheduling.min) / (gs.scheduling.max - gs.scheduling.min)
        w = np.array(
            [
                np.prod([s[k] if c[k] == gs.scheduling.max[k] else 1 - s[k] for k in range(3)])
                for c in gs.scheduling.corners
            ]
        )
        assert w.sum() == pytest.approx(1.0)
        K = np.einsum("i,ijk->jk", w, gs.K)
        u_ref = w @ gs.u0 + K @ (x - w @ gs.x0) + gs.R @ ue
        esc = np.linalg.solve(mix, u_ref)
        if esc.min() < 0.0 or esc.max() > 1.0:
            np.testing.assert_allclose(u, mix @ np.clip(esc, 0.0, 1.0), rtol=1e-9, atol=1e-12)
            continue  # saturated (seed 0 Eq. 7 mixer limits)
        np.testing.assert_allclose(u, u_ref, rtol=1e-9, atol=1e-12)
        checked += 1
    assert checked >= 10
    assert not np.allclose(got[300][1], commands(os.path.join(P2, "bag_0000"))[300][1])


def test_replay_reports_abort_outside_box(tmp_path, capsys):
    """Gains for a +-0.3 m/s box against a flight whose v_d leaves it: exit 1, reason
    printed, ERROR status in the output and no command after the abort."""
    g = tmp_path / "small.yaml"
    write_gains(g, box=0.3, design=design_for(5.0))  # the flight's signal, a smaller box
    code, out = replay(tmp_path, gains=str(g))
    assert code == 1
    text = capsys.readouterr().out
    assert "SAFETY ABORT" in text and "out_of_box" in text
    data = read_bag(str(out))
    errs = [
        (t, s)
        for t, m in data[f"{NS}/status"]
        for s in messages.status_from_diagnostic_array(m)[1]
        if s.level == 2
    ]
    t_abort = errs[0][0]
    assert errs[0][1].values["reason"] == "out_of_box"
    assert all(t <= t_abort for t, _ in data.get(f"{NS}/actuator_command", []))


def test_replay_rate_grid_on_phase1_sample(tmp_path):
    code, out = replay(tmp_path, "--ticks", "rate", bag=P1)
    assert code == 0
    meta = yaml.safe_load(open(os.path.join(P1, "experiment.yaml")))
    dur = (meta["bags"][0]["end_ns"] - meta["bags"][0]["start_ns"]) * 1e-9
    got = commands(out)
    assert 0 <= 250 * dur - len(got) <= 4  # ticks before every input has arrived: none
    assert np.all(np.diff([t for t, _ in got]) == 4_000_000)


@pytest.mark.parametrize(
    "kind, needle",
    [
        ("nobag", "no such file"),
        ("badgains", "gamma"),
        ("missing_topic", "not in bag"),
        ("exists", "already exists"),
    ],
)
def test_replay_bad_input(tmp_path, capsys, kind, needle):
    bag, gains = P2, GAINS
    if kind == "nobag":
        bag = str(tmp_path / "nope")
    elif kind == "badgains":
        d = gains_dict(box=5.0)
        d["gamma"] = 0.0
        gains = tmp_path / "bad.yaml"
        gains.write_text(yaml.safe_dump(d))
        gains = str(gains)
    elif kind == "missing_topic":
        bag = str(tmp_path / "logonly")
        from lpv_sysid.io.bag import BagWriter

        with BagWriter(bag) as w:
            w.add_topic(f"{NS}/state", "nav_msgs/msg/Odometry")
    elif kind == "exists":
        (tmp_path / "out").mkdir()
    code, _ = replay(tmp_path, bag=bag, gains=gains)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and needle in err[0]


def test_replay_bound_monitor_abort(tmp_path, capsys):
    """gamma = 0.05 (certificate alike) and a params file lowering monitor_min_energy: the
    bound monitor's L2 gain estimate exceeds gamma x margin -> bound_exceeded abort."""

    def tight(d):
        d["gamma"] = 0.05
        d["certificate"]["gamma_achieved"] = 0.05

    g = tmp_path / "tight.yaml"
    write_gains(g, box=5.0, edit=tight)
    params = tmp_path / "ctl.yaml"
    params.write_text(
        "/**/lpv_controller:\n  ros__parameters:\n    monitor_min_energy: 0.001\n"
        "    monitor_margin: 1.2\n"
    )
    out = tmp_path / "out"
    code = main(
        [
            "replay",
            "--bag",
            P2,
            "--node",
            "lpv_controller",
            "--params",
            str(params),
            "--gains",
            str(g),
            "--out",
            str(out),
        ]
    )
    text = capsys.readouterr().out
    assert code == 1 and "bound_exceeded: L2 gain estimate" in text
    got, rec = commands(out), commands(os.path.join(P2, "bag_0000"))
    assert 0 < len(got) < len(rec)  # commanded until the monitor tripped


# ------------------------------------------------- command count from the bag's own stamps
def _receipt_stamps(bag):
    data = read_bag(os.path.join(bag, "bag_0000"))
    return {t: [ns for ns, _ in data[f"{NS}/{t}"]] for t in INPUTS}, data


INPUTS = ("state", "rotor_speeds", "velocity_reference", "excitation")


def _params(tmp_path, **values):
    """config/lpv_controller.yaml with ``values`` replacing its entries."""
    import re

    text = open(PARAMS).read()
    for k, v in values.items():
        text, n = re.subn(rf"(?m)^(\s+{k}:)\s*\S+", rf"\g<1> {v}", text)
        assert n == 1, k
    p = tmp_path / "ctl.yaml"
    p.write_text(text)
    return str(p)


def test_replay_command_count_timer_grid(tmp_path):
    """tick_source timer, --ticks rate: one command per grid tick t0 + k / rate_hz (k >= 1) up
    to the last input, once every input stream has delivered a sample before the tick (the
    merge puts a tick before inputs of the same stamp) -- counted here from the bag's
    receipt stamps alone; at 250 Hz state and rate_hz 250 that is one per state sample."""
    stamps, _ = _receipt_stamps(P2)
    t0 = min(s[0] for s in stamps.values())
    t_last = max(s[-1] for s in stamps.values())
    ready = max(s[0] for s in stamps.values())
    period = 4_000_000
    expected = sum(1 for k in range(1, (t_last - t0) // period + 1) if t0 + k * period > ready)
    code, out = replay(tmp_path, "--ticks", "rate")
    assert code == 0
    got = commands(out)
    assert len(got) == expected
    assert abs(len(got) - len(stamps["state"])) <= 3  # ~ a command per state sample
    assert [t for t, _ in got] == [
        t0 + k * period for k in range(1, (t_last - t0) // period + 1) if t0 + k * period > ready
    ]


def test_replay_command_count_state_ticks(tmp_path):
    """tick_source state (as the node: on_input): one command per state sample whose header
    stamp is newer than the last one ticked and that arrives after every other stream's first
    sample, stamped with its header stamp -- counted from the bag, not from the runtime. The
    replay used to tick a rate grid whatever tick_source said (the node did not)."""
    stamps, data = _receipt_stamps(P2)
    first_other = max(stamps[t][0] for t in INPUTS if t != "state")
    expected, last = [], None
    for ns, msg in data[f"{NS}/state"]:
        h = messages.stamp_ns_from_time(msg.header.stamp)
        if ns > first_other and (last is None or h > last):
            expected.append(h)
        last = h if last is None or h > last else last
    code, out = main_replay(tmp_path, _params(tmp_path, tick_source="state"))
    assert code == 0
    got = commands(out)
    assert [t for t, _ in got] == expected and len(expected) > 1000


def main_replay(tmp_path, params):
    out = tmp_path / "out_state"
    code = main(
        [
            "replay",
            "--bag",
            P2,
            "--node",
            "lpv_controller",
            "--params",
            params,
            "--gains",
            GAINS,
            "--out",
            str(out),
        ]
    )
    return code, out
