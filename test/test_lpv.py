"""models/lpv/polytope.py: box order, multilinear weights (seed 0 Eq. 21), Eq. (23) corners, Eq.
(34)."""

import itertools

import numpy as np
import pytest

from lpv_sysid.errors import ConfigError
from lpv_sysid.models.lpv import (
    PolytopicModel,
    ScheduledLpv,
    UncertainElement,
    box_vertices,
    interpolate_gain,
    multilinear_weight_gradient,
    multilinear_weights,
    uncertainty_vertices,
)

LO = np.array([-5.0, -2.0, -1.0])
HI = np.array([5.0, 4.0, 3.0])


def test_box_vertices_order_first_axis_slowest():
    v = box_vertices(LO, HI)
    assert v.shape == (8, 3)
    np.testing.assert_array_equal(v[0], LO)
    np.testing.assert_array_equal(v[1], [-5, -2, 3])  # last axis fastest
    np.testing.assert_array_equal(v[4], [5, -2, -1])  # first axis slowest
    np.testing.assert_array_equal(v[7], HI)
    assert [tuple(r) for r in v] == list(itertools.product(*zip(LO, HI)))


def test_weights_at_vertices_are_unit_vectors():
    for i, vd in enumerate(box_vertices(LO, HI)):
        a, clamped = multilinear_weights(vd, LO, HI)
        np.testing.assert_allclose(a, np.eye(8)[i], atol=1e-15)
        assert not clamped


def test_weights_hand_computed_point():
    # t = (0.25, 0.5, 0.75): alpha_i = prod of (1-t, t) chosen by the corner bits
    vd = LO + np.array([0.25, 0.5, 0.75]) * (HI - LO)
    a, _ = multilinear_weights(vd, LO, HI)
    expect = [
        0.75 * 0.5 * 0.25,
        0.75 * 0.5 * 0.75,
        0.75 * 0.5 * 0.25,
        0.75 * 0.5 * 0.75,
        0.25 * 0.5 * 0.25,
        0.25 * 0.5 * 0.75,
        0.25 * 0.5 * 0.25,
        0.25 * 0.5 * 0.75,
    ]
    np.testing.assert_allclose(a, expect, rtol=1e-15)


def test_weights_nonnegative_sum_one_and_reproduce_affine_functions():
    rng = np.random.default_rng(3)
    M = rng.normal(size=(5, 3))
    c = rng.normal(size=5)
    f_vert = box_vertices(LO, HI) @ M.T + c  # affine function at the vertices
    for _ in range(50):
        vd = LO + rng.random(3) * (HI - LO)
        a, clamped = multilinear_weights(vd, LO, HI)
        assert np.all(a >= 0) and abs(a.sum() - 1) < 1e-14 and not clamped
        np.testing.assert_allclose(a @ f_vert, M @ vd + c, rtol=1e-12, atol=1e-12)


def test_weights_clamp_outside_box_and_reject_nan():
    a, clamped = multilinear_weights([7.0, 0.0, 1.0], LO, HI)
    b, _ = multilinear_weights([5.0, 0.0, 1.0], LO, HI)
    assert clamped
    np.testing.assert_allclose(a, b)
    with pytest.raises(ConfigError, match="NaN"):
        multilinear_weights([np.nan, 0, 0], LO, HI)
    with pytest.raises(ConfigError):
        box_vertices([0, 0], [1, 0])


def test_weight_gradient_matches_finite_difference():
    vd = np.array([1.0, 0.5, 2.0])
    g = multilinear_weight_gradient(vd, LO, HI)
    h = 1e-6
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        fd = (multilinear_weights(vd + e, LO, HI)[0] - multilinear_weights(vd - e, LO, HI)[0]) / (
            2 * h
        )
        np.testing.assert_allclose(g[:, k], fd, atol=1e-8)


def _model(x0_affine=None):
    rng = np.random.default_rng(0)
    A = rng.normal(size=(8, 3, 3))
    B = rng.normal(size=(8, 3, 2))
    V = box_vertices(LO, HI)
    L = np.array([[0.1, 0.0, 0.0], [0.0, -0.2, 0.0], [1.0, 0.0, 0.5]])
    x0 = V @ L.T + np.array([0.0, 0.1, 2.0])
    return PolytopicModel(vmin=LO, vmax=HI, A=A, B=B, x0=x0, u0=rng.normal(size=(8, 2))), L


def test_dx0_dvd_of_affine_equilibrium_is_its_matrix_eq34():
    model, L = _model()
    for vd in ([0.0, 0.0, 0.0], [4.0, -1.5, 2.9]):
        np.testing.assert_allclose(model.dx0_dvd(vd), L, atol=1e-12)
        np.testing.assert_allclose(model.x0_at(vd), L @ vd + [0.0, 0.1, 2.0], atol=1e-12)


def test_interpolated_gain_and_scheduled_model():
    model, _ = _model()
    K = np.arange(8 * 2 * 3, dtype=float).reshape(8, 2, 3)
    vd = np.array([0.0, 1.0, 1.0])  # centre of the box: all weights 1/8
    np.testing.assert_allclose(interpolate_gain(K, vd, LO, HI), K.mean(axis=0))
    s = ScheduledLpv(model, K)
    np.testing.assert_allclose(s.K(vd), K.mean(axis=0))
    np.testing.assert_allclose(s.A(vd), model.A.mean(axis=0))
    with pytest.raises(ConfigError):
        ScheduledLpv(model, K[:, :1])


def test_uncertainty_corners_eq23():
    A = np.diag([1.0, 2.0])
    B = np.array([[0.0], [1.0]])
    els = [
        UncertainElement("A", 0, 0, 0.5, 1.5),
        UncertainElement("B", 1, 0, 0.8, 1.2),
        UncertainElement("A", 1, 1, 2.0, 2.0),
    ]  # fixed: does not double the count
    sys = uncertainty_vertices(A, B, els)
    assert len(sys) == 4
    vals = sorted((a[0, 0], b[1, 0]) for a, b in sys)
    assert vals == [(0.5, 0.8), (0.5, 1.2), (1.5, 0.8), (1.5, 1.2)]
    assert all(a[1, 1] == 2.0 for a, _ in sys)
    with pytest.raises(ConfigError, match="corners"):
        uncertainty_vertices(A, B, els[:2], max_corners=2)
    with pytest.raises(ConfigError):
        uncertainty_vertices(A, B, [UncertainElement("A", 5, 0, 0, 1)])
    with pytest.raises(ConfigError):
        UncertainElement.from_dict({"matrix": "A", "row": 0, "col": 0, "lower": 2, "upper": 1})


def test_polytopic_model_validates_shapes():
    with pytest.raises(ConfigError, match="A must have shape"):
        PolytopicModel(
            vmin=LO, vmax=HI, A=np.zeros((4, 3, 3)), B=np.zeros((4, 3, 1)), x0=None, u0=None
        )
    m = PolytopicModel.from_uncertain_elements(
        LO,
        HI,
        np.zeros((8, 2, 2)),
        np.zeros((8, 2, 1)),
        None,
        None,
        [[UncertainElement("A", 0, 1, -1, 1)]] * 8,
    )
    assert [len(s) for s in m.systems] == [2] * 8


def test_from_vertex_systems_of_the_identification_helper():
    from lpv_sysid.ident.vertex import uncertainty as unc

    A = np.array([[-1.0, 0.5], [0.0, -2.0]])
    B = np.array([[0.0], [1.0]])
    uv = unc.build(
        A,
        B,
        [("A", 0, 1, 0.5, 0.1), ("B", 1, 0, 1.0, 0.05)],
        unc.UncertaintyConfig(k_sigma=2.0, output_states=(0, 1)),
    )
    m = PolytopicModel.from_vertex_systems([0.0], [1.0], [uv, uv], x0=None, u0=None)
    assert [len(s) for s in m.systems] == [4, 4]
    vals = sorted((round(a[0, 1], 12), round(b[1, 0], 12)) for a, b in m.systems[0])
    assert vals == [(0.3, 0.9), (0.3, 1.1), (0.7, 0.9), (0.7, 1.1)]
