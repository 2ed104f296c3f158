"""PRBS (seed 1 Sec. 3.4), maximal-length sequences and validation manoeuvres."""

import numpy as np
import pytest

from lpv_sysid.errors import ConfigError
from lpv_sysid.signals.maneuvers import doublet, maneuver_3211, sweep
from lpv_sysid.signals.prbs import mls, periodic_autocorrelation, prbs, switching_intervals


def test_prbs_levels_intervals_and_mean():
    fs, amp = 100.0, 0.15
    t, x = prbs(200.0, fs, amp, min_interval=0.05, max_interval=0.3, seed=7)
    assert t.size == 20000 and t[1] - t[0] == pytest.approx(0.01)
    assert set(np.unique(x)) == {-amp, amp}
    iv = switching_intervals(x, 1 / fs)
    assert iv.min() >= 0.05 - 1e-12 and iv.max() <= 0.3 + 1e-12
    # hold times uniform on {5..30} samples: mean 17.5 samples = 0.175 s
    assert iv.mean() == pytest.approx(0.175, abs=0.01)
    # alternating levels with i.i.d. holds: |mean| ~ amp * std(hold)/mean(hold)/sqrt(#switches)
    assert abs(x.mean()) < 0.05 * amp


def test_prbs_reproducible_with_seed():
    a = prbs(10.0, 50.0, 1.0, 0.1, 0.5, seed=3)[1]
    b = prbs(10.0, 50.0, 1.0, 0.1, 0.5, seed=3)[1]
    c = prbs(10.0, 50.0, 1.0, 0.1, 0.5, seed=4)[1]
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_prbs_bad_input():
    with pytest.raises(ConfigError, match="max_interval"):
        prbs(10.0, 50.0, 1.0, 0.5, 0.1)
    with pytest.raises(ConfigError, match="whole number of samples"):
        prbs(10.0, 10.0, 1.0, 0.01, 0.05)
    with pytest.raises(ConfigError, match="amplitude"):
        prbs(10.0, 10.0, float("nan"), 0.1, 0.5)


@pytest.mark.parametrize("nbits", [5, 8, 10])
def test_mls_autocorrelation_and_balance(nbits):
    n = 2**nbits - 1
    x = mls(nbits, amplitude=2.0)
    assert x.size == n
    # balance: 2^(n-1) ones and 2^(n-1) - 1 zeros -> sum = amplitude
    assert x.sum() == pytest.approx(2.0)
    r = periodic_autocorrelation(x)
    # independent check by explicit circular shifts
    r_direct = np.array([np.dot(x, np.roll(x, -k)) for k in range(n)]) / np.dot(x, x)
    assert np.allclose(r, r_direct, atol=1e-12)
    assert r[0] == pytest.approx(1.0)
    assert np.allclose(r[1:], -1.0 / n, atol=1e-12)


def test_mls_hold_and_state():
    x = mls(4, samples_per_bit=3)
    assert x.size == 45 and np.all(x.reshape(15, 3) == x.reshape(15, 3)[:, :1])
    y = mls(4, state=[0, 1, 0, 1])
    z = mls(4)
    # another start state is a cyclic shift of the same m-sequence
    assert any(np.array_equal(np.roll(z, k), y) for k in range(15))
    with pytest.raises(ConfigError):
        mls(4, state=[0, 0, 0, 0])
    with pytest.raises(ConfigError):
        mls(1)


def test_doublet_and_3211_shapes():
    fs = 100.0
    t, x = maneuver_3211(0.5, 2.0, fs, start=1.0)
    # 3-2-1-1 with dt_p = 0.5 s: +2 on [1, 2.5), -2 on [2.5, 3.5), +2 on [3.5, 4), -2 on [4, 4.5)
    assert x[int(1.0 * fs) - 1] == 0 and x[int(1.0 * fs)] == 2.0
    assert np.sum(x == 2.0) == int(2.0 * fs) and np.sum(x == -2.0) == int(1.5 * fs)
    assert x[int(2.5 * fs)] == -2.0 and x[int(3.5 * fs)] == 2.0 and x[int(4.4 * fs)] == -2.0
    assert np.all(x[int(4.5 * fs) :] == 0)
    # integral: 2 * 0.5 * (3 - 2 + 1 - 1) = 1
    assert np.sum(x) / fs == pytest.approx(1.0)
    t, d = doublet(0.2, 1.0, fs, start=0.5, duration=2.0)
    assert t.size == 200 and np.sum(d) == pytest.approx(0.0) and np.sum(d == 1.0) == 20
    with pytest.raises(ConfigError):
        doublet(1.0, 1.0, fs, start=0.0, duration=1.0)


def test_sweep_frequency_content():
    fs, T = 200.0, 20.0
    t, x = sweep(T, fs, 0.5, 5.0, amplitude=0.3, method="linear")
    assert abs(x[0]) < 1e-12 and np.max(np.abs(x)) <= 0.3 + 1e-12
    # zero crossings of a linear chirp: 2 * integral f dt = 2 * T * (f0 + f1)/2 = 110
    crossings = np.sum(np.diff(np.signbit(x)) != 0)
    assert abs(crossings - 110) <= 2
    with pytest.raises(ConfigError):
        sweep(T, fs, 0.5, 150.0)
