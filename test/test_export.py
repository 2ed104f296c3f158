"""Export of the identified models (issue 23 item 4): the ``.mat`` file read back with
scipy.io.loadmat and the python-control systems checked against the YAML's numbers
(poles = eig(A), frequency response = (jwI - A)^-1 B computed here with numpy)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from scipy.io import loadmat
from test_formats import models_dict

from lpv_sysid.io import formats as fm


@pytest.fixture(scope="module")
def models():
    return fm.VertexModels.from_dict(copy.deepcopy(models_dict()))


def test_mat_file_holds_the_yaml_numbers(models, tmp_path):
    path = fm.save_models_mat(models, tmp_path / "vertex_models.mat")
    m = loadmat(str(path))
    assert str(m["format"][0]) == fm.MAT_FORMAT
    assert m["A"].shape == (12, 12, 8) and m["B"].shape == (12, 4, 8)
    for k, v in enumerate(models.vertices):
        np.testing.assert_array_equal(m["A"][:, :, k], v.A)
        np.testing.assert_array_equal(m["B"][:, :, k], v.B)
        np.testing.assert_array_equal(m["x0"][:, k], v.x0)
        np.testing.assert_array_equal(m["scheduling"][:, k], v.scheduling)
    assert [str(c[0][0]) for c in m["state_names"]] == list(models.state_names)
    assert float(m["Ts"][0, 0]) == 0.0
    unc = m["uncertain"]
    assert unc.shape == (16, 8)  # 2 entries per vertex
    first = models.vertices[0].uncertain[0]
    # MATLAB 1-based: vertex 1, matrix A (1), row 3, col 1
    np.testing.assert_allclose(
        unc[0], [1, 1, first.row + 1, first.col + 1, first.nominal, 0.03, first.lower, first.upper]
    )
    np.testing.assert_array_equal(m["box_min"].ravel(), models.scheduling.min)


def test_control_systems_match_the_models(models):
    pytest.importorskip("control", reason="python-control not installed (requirements.txt)")
    systems = fm.control_systems(models)
    assert len(systems) == 8
    w = 2.3
    for sys, v in zip(systems, models.vertices):
        np.testing.assert_allclose(
            np.sort_complex(sys.poles()), np.sort_complex(np.linalg.eigvals(v.A)), rtol=1e-9
        )
        H = np.linalg.solve(1j * w * np.eye(12) - v.A, v.B)
        np.testing.assert_allclose(sys(1j * w), H, rtol=1e-9, atol=1e-12)
        assert sys.input_labels == list(models.input_names)
        assert sys.isctime()
