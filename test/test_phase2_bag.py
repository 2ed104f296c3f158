"""Phase-2 bag (sim/phase2/bag.py): written in blocks by encode_block + BagWriter.write_many, the
same messages as the io.messages builders one at a time (read back with rosbags' AnyReader)."""

from __future__ import annotations

import numpy as np
import pytest

from lpv_sysid.io import messages
from lpv_sysid.io.bag import BagWriter, jazzy_typestore
from lpv_sysid.io.bag.cdr import records_close
from lpv_sysid.sim.phase2 import BAG_TOPICS, SAMPLE_TOPICS, Phase2Bag

KAPPA = 2.5
NS = "/lpv_sysid"


def _flight(n: int, seed: int = 0):
    """n control samples at 100 Hz of random (finite) measured data; statuses every 40 samples
    and one abort-like status in the middle, as simulate_nonlinear emits them."""
    rng = np.random.default_rng(seed)
    t = np.round(np.arange(n) * 0.01 + 1e-3 * rng.uniform(0, 1), 9)
    x16 = rng.normal(size=(n, 16))
    x16[:, 3:6] *= 0.5  # Euler angles
    return {
        "t": t,
        "x16": x16,
        "accel": rng.normal(size=(n, 3)),
        "gyro": rng.normal(size=(n, 3)),
        "omega": 700 + 50 * rng.normal(size=(n, 4)),
        "v_d": rng.uniform(-2, 2, size=(n, 3)),
        "ue": KAPPA * rng.normal(size=(n, 4)),
        "u": rng.normal(size=(n, 4)),
    }


def _fly_into(bag, d, status_every: int = 40):
    """Feed ``bag`` like simulate_nonlinear; returns the expected (topic, stamp, message)
    sequence built by the io.messages builders one message at a time (the former writer)."""
    f = messages.MsgFactory.rosbags()
    want = []
    for k, t in enumerate(d["t"]):
        ns = int(round(float(t) * 1e9))
        x = d["x16"][k]
        bag.sample(
            t, x, (d["accel"][k], d["gyro"][k]), d["omega"][k], d["v_d"][k], d["ue"][k], d["u"][k]
        )
        want += [
            ("state", ns, messages.odometry_from_state(f, ns, x[0:3], x[3:6], x[6:9], x[9:12])),
            ("rotor_speeds", ns, messages.rotor_speeds_msg(f, ns, d["omega"][k])),
            ("imu", ns, messages.imu_msg(f, ns, d["accel"][k], d["gyro"][k], x[3:6])),
            ("velocity_reference", ns, messages.twist_reference_msg(f, ns, d["v_d"][k], 0.0)),
            ("excitation", ns, messages.excitation_msg(f, ns, d["ue"][k] / KAPPA)),
            ("actuator_command", ns, messages.actuator_command_msg(f, ns, d["u"][k])),
        ]
        if k % status_every == 0:
            bag.status(t, "OK", "phase 2 excitation running", {"kappa": KAPPA})
            vals = {"phase": "phase2", "kappa": KAPPA}
            st = messages.diagnostic_status(
                f, "OK", "sim_phase2", "phase 2 excitation running", vals
            )
            want.append(("status", ns, messages.diagnostic_array(f, ns, [st])))
    return want


def _read_raw(path):
    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as reader:
        rows = [(c.topic, ts, bytes(raw)) for c, ts, raw in reader.messages()]
        msgs = {}
        for c, _, raw in reader.messages():
            msgs.setdefault(c.topic, []).append(reader.deserialize(raw, c.msgtype))
    return rows, msgs


@pytest.mark.parametrize("flush_every", [500, 7])
def test_bulk_bag_equals_the_builders_message_by_message(tmp_path, monkeypatch, flush_every):
    """Every record byte-identical to the builder message serialised alone, stamps and counts
    equal, decoded values equal to the arrays; BagWriter.write (per message) is never called."""

    def no_per_message_write(self, topic, stamp_ns, msg):
        raise AssertionError("phase-2 bag wrote a message one at a time")

    monkeypatch.setattr(BagWriter, "write", no_per_message_write)
    d = _flight(123)
    with Phase2Bag(tmp_path / "bag", kappa=KAPPA, flush_every=flush_every) as bag:
        want = _fly_into(bag, d)
    ts = jazzy_typestore()
    rows, msgs = _read_raw(tmp_path / "bag")
    n = d["t"].size
    assert bag.counts == {**{k: n for k in SAMPLE_TOPICS}, "status": 4}
    for name in BAG_TOPICS:
        got = [(s, raw) for topic, s, raw in rows if topic == f"{NS}/{name}"]
        exp = [
            (s, bytes(ts.serialize_cdr(m, messages.TYPES[name])))
            for nm, s, m in want
            if nm == name
        ]
        assert [s for s, _ in got] == [s for s, _ in exp]  # stamps, in order
        if name in ("state", "imu"):
            # the orientation quaternion comes from whole-array arithmetic (frames: q @ M.T):
            # equal to the one-message value within 2 ulp; every other field byte-identical
            assert all(
                records_close(messages.TYPES[name], g, e, rtol=0, atol=4.5e-16, typestore=ts)
                for (_, g), (_, e) in zip(got, exp)
            )
            assert all(len(g) == len(e) for (_, g), (_, e) in zip(got, exp))
        else:
            assert [r for _, r in got] == [r for _, r in exp]  # byte-identical records
    # decoded values against the arrays (independent of the builders' encoding)
    x = d["x16"]
    for k in (0, 61, n - 1):
        st = messages.state_from_odometry(msgs[f"{NS}/state"][k])
        assert st.stamp_ns == int(round(d["t"][k] * 1e9))
        np.testing.assert_allclose(st.pos_ned, x[k, 0:3], rtol=0, atol=1e-12)
        np.testing.assert_allclose(st.euler, x[k, 3:6], rtol=0, atol=1e-12)
        np.testing.assert_allclose(st.v_body, x[k, 6:9], rtol=0, atol=1e-12)
        _, om = messages.rotor_speeds_from_joint_state(msgs[f"{NS}/rotor_speeds"][k])
        np.testing.assert_array_equal(om, d["omega"][k])
        imu = messages.imu_from_msg(msgs[f"{NS}/imu"][k])
        np.testing.assert_allclose(imu.specific_force, d["accel"][k], rtol=0, atol=1e-15)
        np.testing.assert_allclose(imu.euler, x[k, 3:6], rtol=0, atol=1e-12)
        _, vd, r = messages.reference_from_twist(msgs[f"{NS}/velocity_reference"][k])
        np.testing.assert_array_equal(vd, d["v_d"][k])
        assert r == 0.0
        _, ue = messages.excitation_from_joint_state(msgs[f"{NS}/excitation"][k])
        np.testing.assert_allclose(ue, d["ue"][k] / KAPPA, rtol=1e-15)
        _, u = messages.actuator_command_from_joint_state(msgs[f"{NS}/actuator_command"][k])
        np.testing.assert_array_equal(u, d["u"][k])
    _, statuses = messages.status_from_diagnostic_array(msgs[f"{NS}/status"][1])
    assert statuses[0].values["kappa"] == str(KAPPA) and statuses[0].values["phase"] == "phase2"


def test_non_finite_sample_is_named_by_the_builders(tmp_path):
    """A NaN sends the block through the builders, whose error names the field; the samples of
    earlier blocks stay in the (readable) bag."""
    d = _flight(30)
    d["accel"][25, 1] = np.nan
    with pytest.raises(messages.MessageError, match="imu.specific_force: non-finite"):
        with Phase2Bag(tmp_path / "bag", kappa=KAPPA, flush_every=20) as bag:
            _fly_into(bag, d)
    rows, _ = _read_raw(tmp_path / "bag")
    assert sum(1 for topic, _, _ in rows if topic == f"{NS}/state") == 20


def test_error_in_flight_still_writes_the_pending_samples(tmp_path):
    """An exception inside the with block (a crash mid-flight): the samples flown so far are
    written and the bag is closed readable; the original exception propagates."""
    d = _flight(15)
    with pytest.raises(RuntimeError, match="boom"):
        with Phase2Bag(tmp_path / "bag", kappa=KAPPA) as bag:
            _fly_into(bag, d)
            raise RuntimeError("boom")
    rows, _ = _read_raw(tmp_path / "bag")
    assert sum(1 for topic, _, _ in rows if topic == f"{NS}/excitation") == 15
