"""synthesis/regions.py: LMI regions (seed 2 Eqs. 113-127), observer (Sec. 5.5), integral action
(Eqs. 128-129), combined with Lemma 1 -- all verified by eigenvalues / independent H-inf norms."""

import numpy as np
import pytest

from lpv_sysid.errors import ConfigError, SolverError
from lpv_sysid.synthesis.example_models import first_order_plant
from lpv_sysid.synthesis.hinf import HinfOptions, hinf_norm, solve_lemma1
from lpv_sysid.synthesis.regions import (
    Region,
    closed_loop_eigs,
    integral_augmentation,
    place_observer,
    place_poles,
)


def _polytope():
    """3-state unstable polytope, 2 scheduling vertices x 2 uncertainty vertices."""
    base = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, -2.0, 0.5]])
    B = np.array([[0.0], [0.0], [1.0]])
    out = []
    for s in (0.0, 1.0):
        lst = []
        for d in (-0.2, 0.2):
            A = base.copy()
            A[2, 0] += s + d
            lst.append((A, B))
        out.append(lst)
    return out


def test_region_characteristic_matches_definition():
    reg = Region(disk_q=2.0, disk_r=3.0, s_min=-4.0, s_max=-0.5)
    alpha, beta = reg.characteristic()
    rng = np.random.default_rng(0)
    for z in rng.normal(size=40) * 3 + 1j * rng.normal(size=40) * 3:
        f = alpha + z * beta + np.conj(z) * beta.T  # Eq. (114)
        inside = np.max(np.linalg.eigvalsh(f)) < 0
        assert inside == bool(reg.contains(np.array([z]))[0])
    assert reg.stable_for(None)
    with pytest.raises(ConfigError):
        Region.from_dict({"disk": {"centre": -1}})
    r2 = Region.from_dict({"disk": {"centre": -2.0, "radius": 3.0}, "half_plane": {"alpha": 0.5}})
    assert r2.disk_q == 2.0 and r2.s_max == -0.5


def test_state_feedback_places_poles_in_disk_and_strip_continuous():
    systems = _polytope()
    reg = Region(disk_q=3.0, disk_r=2.5, s_min=-5.0, s_max=-1.0)  # seed 2 Eq. (127) shape
    res = place_poles(systems, reg)
    eigs = np.concatenate(closed_loop_eigs(systems, res.K))
    assert np.all(reg.contains(eigs)), eigs
    # interior scheduling point with the interpolated gain (quadratic D-stability, common X)
    A = 0.3 * systems[0][1][0] + 0.7 * systems[1][0][0]
    K = 0.3 * res.K[0] + 0.7 * res.K[1]
    assert np.all(reg.contains(np.linalg.eigvals(A + systems[0][0][1] @ K)))


def test_discrete_time_disk_inside_unit_circle():
    Ts = 0.05
    systems = [[(np.eye(3) + Ts * A, Ts * B) for A, B in lst] for lst in _polytope()]
    reg = Region(disk_q=-0.5, disk_r=0.4)  # centre 0.5, radius 0.4
    assert reg.stable_for(Ts)
    res = place_poles(systems, reg)
    eigs = np.concatenate(closed_loop_eigs(systems, res.K))
    assert np.all(np.abs(eigs - 0.5) < 0.4) and np.all(np.abs(eigs) < 1)


def test_observer_error_dynamics_in_region():
    systems = _polytope()
    C = np.array([[1.0, 0.0, 0.0]])
    reg = Region(disk_q=4.0, disk_r=3.0, s_max=-1.5)
    L, _ = place_observer(systems, C, reg)
    assert L.shape == (2, 3, 1)
    for i, lst in enumerate(systems):
        for A, _B in lst:
            e = np.linalg.eigvals(A + L[i] @ C)  # e = x_hat - x, Eq. (130)
            assert np.all(reg.contains(e)), e


def test_integral_augmentation_zero_steady_state_error():
    A, B = _polytope()[0][0]
    C = np.array([[1.0, 0.0, 0.0]])
    Aa, Ba = integral_augmentation(A, B, C)
    np.testing.assert_array_equal(Aa[3:, :3], C)
    Ad, _ = integral_augmentation(A, B, C, ts=0.1)
    np.testing.assert_array_equal(Ad[3:, 3:], np.eye(1))  # Eq. (129)
    reg = Region(s_max=-0.5, disk_q=2.0, disk_r=1.8)
    res = place_poles([[(Aa, Ba)]], reg)
    Acl = Aa + Ba @ res.K[0]
    assert np.all(reg.contains(np.linalg.eigvals(Acl)))
    # constant reference r enters as -[0; I] r (Eq. 129); steady state: C x = r
    r = 0.7
    xs = np.linalg.solve(Acl, np.array([0, 0, 0, 1.0]) * r)
    assert abs(C @ xs[:3] - r) < 1e-9


def test_infeasible_region_raises():
    systems = [[(np.array([[1.0]]), np.array([[0.0]]))]]  # uncontrollable unstable mode
    with pytest.raises(SolverError):
        place_poles(systems, Region(s_max=-1.0))


def test_hinf_combined_with_region_common_H():
    # first-order plant: the region confines the pole, H-inf bound holds at the same time
    a, b, r = 1.0, 1.0, 1.0
    model = first_order_plant(a, b, r * b)
    reg = Region(s_min=-2.5, s_max=-1.0)
    res = solve_lemma1(
        model, np.array([[r]]), np.array([[1.0]]), HinfOptions(gamma=0.5, region=reg)
    )
    k = res.K[0, 0, 0]
    pole = a + b * k
    assert -2.5 < pole <= -2.0 + 1e-6  # H-inf needs pole <= -2 (gamma 0.5), region > -2.5
    assert hinf_norm(np.array([[pole]]), np.array([[r * b]]), np.eye(1)).value <= 0.5 * (1 + 1e-6)
    np.testing.assert_allclose(res.H, res.H.T, atol=1e-9)


def test_region_dict_round_trip():
    for d in (
        {"disk": {"centre": -2.0, "radius": 1.5}, "strip": {"min": -4.0, "max": -0.5}},
        {"strip": {"min": -4.0, "max": None}},
        {"half_plane": {"alpha": 0.3}},
    ):
        r = Region.from_dict(d)
        assert Region.from_dict(r.to_dict()) == r
