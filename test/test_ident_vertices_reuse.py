"""identify_vertices solves each maneuver's rows once and finishes the maneuvers that cannot
identify the motor constants with the pooled estimate from the same row solution.

Oracle: the pipeline as it was defined before (and as its docstring states it): every
maneuver through the whole per-vertex fit (``identify_vertex``), then the maneuvers without
their own ``a_Omega, b_Omega`` through the whole fit again with ``motor: known`` and the
pooled prior.  The results must agree to 1e-12 (they are computed by the same arithmetic).
The smoothers the motor rows call on four columns at once are checked against one call per
column, and the smoothing-only path against the smoothing half of the differentiator.
"""

import dataclasses
import math

import numpy as np
import pytest

from lpv_sysid.control.baseline import BaselineGains
from lpv_sysid.control.campaign import run_name
from lpv_sysid.ident import dataprep as dp
from lpv_sysid.ident import derivatives as deriv
from lpv_sysid.ident import vertex as vx
from lpv_sysid.models.quadrotor import Quadrotor
from lpv_sysid.sim import phase1 as p1
from lpv_sysid.sim.vehicle import SensorConfig

POOLED = "; pooled estimate of the maneuvers that identified them"


@pytest.fixture(scope="module")
def datas():
    """A descending corner (a rotor at its lower speed limit 0.7 % of the fit segment) and the
    hover (no rotor at a limit), as in test_ident_phase1.py."""
    q = Quadrotor()
    cfg = p1.Phase1Config(trim_s=8.0, excite_s=24.0)
    out = []
    for s, v in ((3, (5.0, -5.0, 5.0)), (4, (0.0, 0.0, 0.0))):
        rec = p1.simulate_run(q, BaselineGains(), SensorConfig(), cfg, v, run_name(v), seed=s)
        out.append(dp.align(dp.streams_from_record(rec), vx.IdentificationConfig()).vertex)
    return out


def _two_passes(datas, cfg, first_cfg=None):
    """The reference: whole per-vertex fits, then whole fits again with the pooled prior."""
    first = [vx.identify_vertex(d, cfg) for d in datas]
    prior = vx.pooled_motor(
        [vx.identify_vertex(d, first_cfg) for d in datas] if first_cfg else first
    )
    if prior is None:
        return first, None
    out = []
    for d, r in zip(datas, first):
        if r.motor["mode"] == "identified" and first_cfg is None:
            out.append(r)
            continue
        again = vx.identify_vertex(d, dataclasses.replace(cfg, motor="known"), motor_prior=prior)
        again.motor["reason"] = f"{r.motor.get('reason', '')}{POOLED}"
        out.append(again)
    return out, prior


def _numbers(obj, path=""):
    """(path, value) of every number in a nested dict/list document."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _numbers(v, f"{path}.{k}")
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            yield from _numbers(v, f"{path}[{i}]")
    else:
        yield path, obj


def _assert_same(got, want):
    assert len(got) == len(want)
    for g, w in zip(got, want):
        assert g.motor.keys() == w.motor.keys() and g.motor["mode"] == w.motor["mode"]
        assert g.motor.get("reason") == w.motor.get("reason")
        a = list(_numbers({"entry": g.to_dict(), "motor": g.motor, "x_flown": list(g.x_flown)}))
        b = list(_numbers({"entry": w.to_dict(), "motor": w.motor, "x_flown": list(w.x_flown)}))
        assert [p for p, _ in a] == [p for p, _ in b]
        for (p, x), (_, y) in zip(a, b):
            if isinstance(x, float):
                assert math.isclose(x, y, rel_tol=1e-12, abs_tol=1e-300) or (
                    math.isnan(x) and math.isnan(y)
                ), (p, x, y)
            else:
                assert x == y, (p, x, y)
        for m in ("A", "B", "std_A", "std_B"):
            np.testing.assert_allclose(getattr(g.fit, m), getattr(w.fit, m), rtol=1e-12, atol=0)
        np.testing.assert_allclose(g.fit.cov_joint, w.fit.cov_joint, rtol=1e-12, atol=0)


#: no pinned time allowed: the corner cannot identify a_Omega, b_Omega, the hover can
STRICT = vx.IdentificationConfig(motor_max_pinned=0.0)


def test_pooled_prior_from_the_same_row_solution(datas):
    cfg = STRICT
    got = vx.identify_vertices(datas, cfg)
    want, prior = _two_passes(datas, cfg)
    assert [r.motor["mode"] for r in got] == ["prior", "identified"]
    assert prior is not None and got[0].motor["reason"].endswith(POOLED)
    # the prior is the hover's a_Omega, b_Omega; it enters the corner's motor rows
    assert got[0].fit.A[8, 8] == pytest.approx(-prior[0][0], rel=1e-12)
    assert got[0].fit.B[8, 0] == pytest.approx(prior[1][0], rel=1e-12)
    _assert_same(got, want)


def test_relaxed_pinning_when_no_maneuver_identifies_the_motor(datas):
    """Only the corner: nothing identifies a_Omega, b_Omega under ``motor_max_pinned``, so the
    prior is pooled over fits without the limit and the corner is finished with it."""
    cfg = STRICT
    assert vx.identify_vertex(datas[0], cfg).motor["mode"] == "known"
    got = vx.identify_vertices(datas[:1], cfg)
    relaxed = dataclasses.replace(cfg, motor_max_pinned=1.0)
    want, prior = _two_passes(datas[:1], cfg, first_cfg=relaxed)
    assert prior is not None and got[0].motor["mode"] == "prior"
    _assert_same(got, want)


def test_no_prior_anywhere_keeps_the_known_motor(datas):
    cfg = vx.IdentificationConfig()
    blind = [dataclasses.replace(d, motor_identifiable=False) for d in datas]
    got = vx.identify_vertices(blind, cfg)
    want, prior = _two_passes(blind, cfg)
    assert prior is None and [r.motor["mode"] for r in got] == ["known", "known"]
    _assert_same(got, want)


@pytest.mark.parametrize("method", ["fourier", "savgol"])
def test_smooth_columns_equals_one_call_per_column(method):
    """What the motor rows rely on: ``smooth_columns`` gives every column exactly what a call
    on that column alone gives (the Fourier smoother in one call: independent FFTs; the
    Savitzky-Golay edge fit solves all columns together and differs in the last bits, so it
    goes column by column), and ``smooth`` is exactly the smoothing half."""
    rng = np.random.default_rng(5)
    x = np.cumsum(rng.normal(size=(1001, 4)), axis=0)
    cfg = deriv.DerivativeConfig(method=method)
    s4 = deriv.smooth_columns(x, 0.01, cfg)
    d4 = deriv.smooth_columns(x, 0.01, cfg, derivative=True)
    for i in range(4):
        s1, d1 = deriv.smooth_and_differentiate(x[:, i], 0.01, cfg)
        np.testing.assert_array_equal(s4[:, i], s1)
        np.testing.assert_array_equal(d4[:, i], d1)
        np.testing.assert_array_equal(deriv.smooth(x[:, i], 0.01, cfg), s1)
    np.testing.assert_array_equal(
        deriv.smooth(x, 0.01, cfg), deriv.smooth_and_differentiate(x, 0.01, cfg)[0]
    )
