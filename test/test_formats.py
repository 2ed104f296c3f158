"""io/formats/: vertex_models.yaml / gains.yaml round trips and one broken file per case,
each checked for the field path in the error message."""

import copy
import itertools

import numpy as np
import pytest
import yaml

from lpv_sysid.errors import ConfigError
from lpv_sysid.io import formats as fm
from lpv_sysid.io.files import sha256_file
from lpv_sysid.models import quadrotor as qr

RNG = np.random.default_rng(5)
LO, HI = [-5.0, -4.0, -2.0], [5.0, 4.0, 2.0]
CORNERS = [list(c) for c in itertools.product(*zip(LO, HI))]


def models_dict():
    vertices = []
    for c in CORNERS:
        A = RNG.normal(size=(12, 12))
        vertices.append(
            {
                "scheduling": list(c),
                "x0": RNG.normal(size=12).tolist(),
                "u0": RNG.normal(size=4).tolist(),
                "A": A.tolist(),
                "B": RNG.normal(size=(12, 4)).tolist(),
                "uncertain": [
                    {
                        "matrix": "A",
                        "row": 2,
                        "col": 0,
                        "nominal": float(A[2, 0]),
                        "std": 0.03,
                        "lower": float(A[2, 0]) - 0.09,
                        "upper": float(A[2, 0]) + 0.09,
                    },
                    {
                        "matrix": "B",
                        "row": 11,
                        "col": 3,
                        "nominal": 1.0,
                        "std": 0.0,
                        "lower": 1.0,
                        "upper": 1.0,
                    },
                ],
                "fit": {"r2": {"u": 0.97, "v": 0.95}, "tic": {"u": 0.1}},
            }
        )
    return {
        "format": "lpv_sysid/vertex_models@1",
        "time": "continuous",
        "states": [{"name": n, "unit": u} for n, u in zip(qr.STATE_NAMES, qr.STATE_UNITS)],
        "inputs": [{"name": n, "unit": u} for n, u in zip(qr.INPUT_NAMES, qr.INPUT_UNITS)],
        "scheduling": {"names": ["u_d", "v_d", "w_d"], "min": list(LO), "max": list(HI)},
        "vertices": vertices,
    }


def gains_dict(models, sha="0" * 64):
    return {
        "format": "lpv_sysid/gains@1",
        "states": copy.deepcopy(models["states"]),
        "inputs": copy.deepcopy(models["inputs"]),
        "scheduling": copy.deepcopy(models["scheduling"]),
        "vertices": [
            {
                "scheduling": list(v["scheduling"]),
                "K": RNG.normal(size=(4, 12)).tolist(),
                "x0": list(v["x0"]),
                "u0": list(v["u0"]),
            }
            for v in models["vertices"]
        ],
        "R": np.diag([0.1, 0.02, 0.02, 0.05]).tolist(),
        "Q": np.diag([1.0, 1.0, 0.5]).tolist(),
        "gamma": 1.0,
        "certificate": {
            "lmi": "seed 0 Lemma 1",
            "solver": "CLARABEL",
            "gamma_achieved": 0.93,
            "min_margin": 1.0e-6,
            "models_sha256": sha,
        },
    }


@pytest.fixture(scope="module")
def good_models():
    return models_dict()


@pytest.fixture(scope="module")
def good_gains(good_models):
    return gains_dict(good_models)


# ------------------------------------------------------------------ round trips
def test_models_round_trip(tmp_path, good_models):
    vm = fm.VertexModels.from_dict(copy.deepcopy(good_models))
    p = tmp_path / "vertex_models.yaml"
    sha = vm.save(p)
    assert sha == sha256_file(p) and len(sha) == 64
    back = fm.VertexModels.load(p)
    assert back.to_dict() == vm.to_dict()
    np.testing.assert_array_equal(back.A, np.array([v["A"] for v in good_models["vertices"]]))
    np.testing.assert_array_equal(back.B[3], np.array(good_models["vertices"][3]["B"]))
    assert back.vertices[0].uncertain[0].std == 0.03
    assert back.vertices[5].fit["r2"]["v"] == 0.95
    assert back.state_names == qr.STATE_NAMES and back.input_units == qr.INPUT_UNITS
    assert back.ts is None
    # the file itself is the documented layout
    raw = yaml.safe_load(p.read_text())
    assert raw["format"] == "lpv_sysid/vertex_models@1" and raw["time"] == "continuous"
    assert raw["states"][0] == {"name": "phi", "unit": "rad"}


def test_gains_round_trip_and_models_check(tmp_path, good_models):
    mp = tmp_path / "vertex_models.yaml"
    sha = fm.VertexModels.from_dict(copy.deepcopy(good_models)).save(mp)
    g = fm.GainSchedule.from_dict(fm.certify_law(gains_dict(good_models, sha)))
    gp = tmp_path / "gains.yaml"
    g.save(gp)
    back = fm.GainSchedule.load(gp, models_path=mp)
    assert back.to_dict() == g.to_dict()
    assert back.K.shape == (8, 4, 12)
    assert back.certificate.models_sha256 == sha
    np.testing.assert_array_equal(back.R, np.diag([0.1, 0.02, 0.02, 0.05]))


def test_discrete_time_and_meta_round_trip(tmp_path, good_models):
    d = copy.deepcopy(good_models)
    d["time"] = {"discrete": 0.004}
    d["meta"] = {"source": "phase1 bags", "n": 3}
    vm = fm.VertexModels.from_dict(d)
    assert vm.ts == 0.004
    vm.save(tmp_path / "m.yaml")
    back = fm.VertexModels.load(tmp_path / "m.yaml")
    assert back.ts == 0.004 and back.meta == {"source": "phase1 bags", "n": 3}


def test_vertices_reordered_into_box_order(good_models):
    d = copy.deepcopy(good_models)
    d["vertices"] = d["vertices"][::-1]
    vm = fm.VertexModels.from_dict(d)
    np.testing.assert_array_equal([v.scheduling for v in vm.vertices], CORNERS)
    np.testing.assert_array_equal(vm.A[0], np.array(good_models["vertices"][0]["A"]))
    # same order as the LPV module uses for interpolation
    from lpv_sysid.models.lpv import box_vertices

    np.testing.assert_array_equal(vm.scheduling.corners, box_vertices(LO, HI))


def test_to_polytopic(good_models):
    pm = fm.VertexModels.from_dict(copy.deepcopy(good_models)).to_polytopic()
    assert pm.n_vertices == 8 and pm.n_x == 12 and pm.n_u == 4
    assert len(pm.systems[0]) == 2  # one free interval -> 2 corners (Eq. 23)
    a20 = good_models["vertices"][0]["A"][2][0]
    vals = sorted(Aj[2, 0] for Aj, _ in pm.systems[0])
    np.testing.assert_allclose(vals, [a20 - 0.09, a20 + 0.09], rtol=1e-15)


def test_generic_layout(tmp_path):
    d = {
        "format": "lpv_sysid/vertex_models@1",
        "time": "continuous",
        "states": [{"name": "x1", "unit": "m"}, {"name": "x2", "unit": "m/s"}],
        "inputs": [{"name": "f", "unit": "N"}],
        "scheduling": {"names": ["s"], "min": [0.0], "max": [1.0]},
        "vertices": [
            {"scheduling": [s], "x0": [0, 0], "u0": [0], "A": [[0, 1], [-1, -s]], "B": [[0], [1]]}
            for s in (1.0, 0.0)
        ],
    }
    with pytest.raises(ConfigError, match=r"states: expected 12 entries"):
        fm.VertexModels.from_dict(d)
    vm = fm.VertexModels.from_dict(d, layout=None)
    assert vm.A.shape == (2, 2, 2) and vm.vertices[1].A[1, 1] == -1.0


# ------------------------------------------------------------ broken models files
def _set(d, path, value):
    *head, last = path
    for k in head:
        d = d[k]
    if value is _DEL:
        del d[last]
    else:
        d[last] = value


_DEL = object()

MODEL_CASES = [
    # (id, path to edit, new value, expected message fragment)
    (
        "format",
        ["format"],
        "lpv_sysid/vertex_models@3",
        r"format: expected 'lpv_sysid/vertex_models@2' \(or 'lpv_sysid/vertex_models@1'\)",
    ),
    ("missing-vertices", ["vertices"], _DEL, r"missing key\(s\) \['vertices'\]"),
    ("unknown-key", ["colour"], "red", r"unknown key\(s\) \['colour'\]"),
    ("time", ["time"], "discrete", r"time: expected 'continuous' or \{discrete: Ts\}"),
    ("time-ts", ["time"], {"discrete": -0.01}, r"time.discrete: sample time must be > 0"),
    ("state-name", ["states", 3, "name"], "vv", r"states\[3\].name: expected 'v', got 'vv'"),
    (
        "state-unit",
        ["states", 9, "unit"],
        "rad/s",
        r"states\[9\].unit: expected 'm\*rad/s' for 'da'",
    ),
    ("state-count", ["states"], [{"name": "phi", "unit": "rad"}], r"states: expected 12 entries"),
    (
        "input-unit",
        ["inputs", 0, "unit"],
        "rad/s",
        r"inputs\[0\].unit: expected '1' for 'ut', got 'rad/s'",
    ),
    (
        "input-missing-unit",
        ["inputs", 1],
        {"name": "ua"},
        r"inputs\[1\]: missing key\(s\) \['unit'\]",
    ),
    (
        "sched-names",
        ["scheduling", "names"],
        ["u_d", "w_d", "v_d"],
        r"scheduling.names: expected \['u_d', 'v_d', 'w_d'\]",
    ),
    ("box-order", ["scheduling", "min", 1], 4.0, r"scheduling: need min < max on axis 'v_d'"),
    ("box-nan", ["scheduling", "max", 2], float("nan"), r"scheduling.max\[2\]: must be finite"),
    ("box-len", ["scheduling", "min"], [-5.0, -4.0], r"scheduling.min: expected 3 values, got 2"),
    (
        "A-shape",
        ["vertices", 3, "A", 5],
        [0.0] * 11,
        r"vertices\[3\].A: expected shape 12x12, got 12 rows of lengths \[11, 12\]",
    ),
    (
        "A-rows",
        ["vertices", 3, "A"],
        [[0.0] * 12] * 11,
        r"vertices\[3\].A: expected shape 12x12, got 11x12",
    ),
    (
        "B-shape",
        ["vertices", 0, "B"],
        [[0.0] * 3] * 12,
        r"vertices\[0\].B: expected shape 12x4, got 12x3",
    ),
    (
        "A-nan",
        ["vertices", 2, "A", 4, 7],
        float("nan"),
        r"vertices\[2\].A\[4\]\[7\]: must be finite, got nan",
    ),
    (
        "B-inf",
        ["vertices", 6, "B", 0, 1],
        float("inf"),
        r"vertices\[6\].B\[0\]\[1\]: must be finite, got inf",
    ),
    (
        "A-string",
        ["vertices", 1, "A", 0, 0],
        "1.0",
        r"vertices\[1\].A\[0\]\[0\]: expected a number, got string",
    ),
    (
        "A-bool",
        ["vertices", 1, "A", 0, 0],
        True,
        r"vertices\[1\].A\[0\]\[0\]: expected a number, got boolean",
    ),
    ("x0-len", ["vertices", 4, "x0"], [0.0] * 11, r"vertices\[4\].x0: expected 12 values, got 11"),
    ("u0-nan", ["vertices", 4, "u0", 2], float("nan"), r"vertices\[4\].u0\[2\]: must be finite"),
    (
        "not-corner",
        ["vertices", 5, "scheduling"],
        [0.0, 0.0, 0.0],
        r"vertices\[5\].scheduling: \[0.0, 0.0, 0.0\] is not a corner",
    ),
    (
        "twice",
        ["vertices", 5, "scheduling"],
        list(CORNERS[0]),
        r"vertices\[5\].scheduling: corner \[-5.0, -4.0, -2.0\] already given by vertices\[0\]",
    ),
    ("seven", ["vertices", 7], _DEL, r"vertices: expected 8 vertices .* got 7"),
    (
        "unc-matrix",
        ["vertices", 1, "uncertain", 0, "matrix"],
        "C",
        r"vertices\[1\].uncertain\[0\].matrix: expected 'A' or 'B'",
    ),
    (
        "unc-row",
        ["vertices", 1, "uncertain", 0, "row"],
        12,
        r"vertices\[1\].uncertain\[0\].row: 12 outside 0..11 of A",
    ),
    (
        "unc-col-B",
        ["vertices", 1, "uncertain", 1, "col"],
        4,
        r"vertices\[1\].uncertain\[1\].col: 4 outside 0..3 of B \(12x4\)",
    ),
    (
        "unc-col-neg",
        ["vertices", 1, "uncertain", 0, "col"],
        -1,
        r"vertices\[1\].uncertain\[0\].col: -1 outside",
    ),
    (
        "unc-row-float",
        ["vertices", 1, "uncertain", 0, "row"],
        2.0,
        r"vertices\[1\].uncertain\[0\].row: expected an integer",
    ),
    (
        "unc-order",
        ["vertices", 2, "uncertain", 1, "lower"],
        1.5,
        r"vertices\[2\].uncertain\[1\]: need lower <= nominal <= upper, got 1.5 <= 1.0 <= 1.0",
    ),
    (
        "unc-std",
        ["vertices", 2, "uncertain", 0, "std"],
        -0.1,
        r"vertices\[2\].uncertain\[0\].std: must be >= 0",
    ),
    (
        "unc-missing",
        ["vertices", 2, "uncertain", 0, "std"],
        _DEL,
        r"vertices\[2\].uncertain\[0\]: missing key\(s\) \['std'\]",
    ),
    (
        "unc-dup",
        ["vertices", 2, "uncertain", 1],
        {
            "matrix": "A",
            "row": 2,
            "col": 0,
            "nominal": 0.0,
            "std": 0.0,
            "lower": -1.0,
            "upper": 1.0,
        },
        r"vertices\[2\].uncertain\[1\]: A\[2\]\[0\] already given by uncertain\[0\]",
    ),
    (
        "fit-nan",
        ["vertices", 0, "fit", "r2", "u"],
        float("nan"),
        r"vertices\[0\].fit.r2.u: must be finite",
    ),
    ("vertex-unknown", ["vertices", 0, "K"], [[0.0]], r"vertices\[0\]: unknown key\(s\) \['K'\]"),
    ("vertices-not-list", ["vertices"], {"a": 1}, r"vertices: expected a list, got mapping"),
]


@pytest.mark.parametrize("case", MODEL_CASES, ids=[c[0] for c in MODEL_CASES])
def test_broken_models(good_models, case):
    _, path, value, msg = case
    d = copy.deepcopy(good_models)
    _set(d, path, value)
    with pytest.raises(ConfigError, match=r"^vertex_models.yaml: " + msg):
        fm.VertexModels.from_dict(d)


# ------------------------------------------------------------- broken gains files
GAIN_CASES = [
    ("format", ["format"], "lpv_sysid/vertex_models@1", r"format: expected 'lpv_sysid/gains@1'"),
    (
        "K-shape",
        ["vertices", 3, "K", 0],
        [0.0] * 11,
        r"vertices\[3\].K: expected shape 4x12, got 4 rows of lengths \[11, 12\]",
    ),
    (
        "K-shape-all",
        ["vertices", 3, "K"],
        [[0.0] * 11] * 4,
        r"vertices\[3\].K: expected shape 4x12, got 4x11",
    ),
    (
        "K-nan",
        ["vertices", 0, "K", 1, 1],
        float("nan"),
        r"vertices\[0\].K\[1\]\[1\]: must be finite",
    ),
    ("R-shape", ["R"], np.eye(3).tolist(), r"R: expected shape 4x4, got 3x3"),
    ("Q-shape", ["Q"], np.eye(4).tolist(), r"Q: expected shape 3x3, got 4x4"),
    ("Q-singular", ["Q"], np.diag([1.0, 0.0, 1.0]).tolist(), r"Q: must be invertible"),
    ("gamma", ["gamma"], 0.0, r"gamma: must be > 0"),
    ("gamma-str", ["gamma"], "1.0", r"gamma: expected a number, got string"),
    (
        "cert-missing",
        ["certificate", "models_sha256"],
        _DEL,
        r"certificate: missing key\(s\) \['models_sha256'\]",
    ),
    (
        "cert-sha",
        ["certificate", "models_sha256"],
        "abc",
        r"certificate.models_sha256: expected 64 lowercase hex digits",
    ),
    (
        "cert-gamma",
        ["certificate", "gamma_achieved"],
        1.2,
        r"certificate.gamma_achieved: 1.2 exceeds gamma = 1.0",
    ),
    (
        "cert-solver",
        ["certificate", "solver"],
        "",
        r"certificate.solver: expected a non-empty string",
    ),
    ("state-name", ["states", 0, "name"], "roll", r"states\[0\].name: expected 'phi', got 'roll'"),
    ("x0-len", ["vertices", 2, "x0"], [0.0] * 13, r"vertices\[2\].x0: expected 12 values, got 13"),
    (
        "not-corner",
        ["vertices", 2, "scheduling"],
        [5.0, 4.0, 0.0],
        r"vertices\[2\].scheduling: \[5.0, 4.0, 0.0\] is not a corner",
    ),
    ("unknown", ["vertices", 2, "A"], [[0.0]], r"vertices\[2\]: unknown key\(s\) \['A'\]"),
]


@pytest.mark.parametrize("case", GAIN_CASES, ids=[c[0] for c in GAIN_CASES])
def test_broken_gains(good_gains, case):
    _, path, value, msg = case
    d = copy.deepcopy(good_gains)
    _set(d, path, value)
    with pytest.raises(ConfigError, match=r"^gains.yaml: " + msg):
        fm.GainSchedule.from_dict(d)


# --------------------------------------------------- gains vs models consistency
@pytest.fixture()
def pair(tmp_path, good_models):
    mp = tmp_path / "vertex_models.yaml"
    sha = fm.VertexModels.from_dict(copy.deepcopy(good_models)).save(mp)
    return mp, sha, gains_dict(good_models, sha)


def _write(tmp_path, d, name="gains.yaml"):
    """``d`` as the certifying tool writes it (law hash, seal): these tests are about the
    models check, which a load runs after the file's own checks."""
    p = tmp_path / name
    p.write_text(yaml.safe_dump(fm.certify_law(d)))
    return p


def test_gains_sha_mismatch(tmp_path, pair):
    mp, sha, g = pair
    g["certificate"]["models_sha256"] = "f" * 64
    with pytest.raises(
        ConfigError,
        match=r"^gains.yaml: certificate.models_sha256: f{64} does not match "
        r"vertex_models.yaml \(sha256 " + sha,
    ):
        fm.GainSchedule.load(_write(tmp_path, g), models_path=mp)


def test_models_file_changed_after_synthesis(tmp_path, pair):
    mp, sha, g = pair
    gp = _write(tmp_path, g)
    fm.GainSchedule.load(gp, models_path=mp)
    mp.write_bytes(mp.read_bytes() + b"# edited\n")
    with pytest.raises(ConfigError, match="certificate.models_sha256"):
        fm.GainSchedule.load(gp, models_path=mp)


@pytest.mark.parametrize(
    "edit,msg",
    [
        (
            lambda g: g["scheduling"]["max"].__setitem__(0, 6.0),
            r"scheduling.max\[0\]|vertices\[\d\].scheduling",
        ),
        (
            lambda g: g["vertices"][4]["x0"].__setitem__(3, 99.0),
            r"vertices\[4\].x0: differs from vertex_models.yaml vertices\[4\].x0",
        ),
        (
            lambda g: g.__setitem__("time", {"discrete": 0.01}),
            r"time: \{'discrete': 0.01\} differs from vertex_models.yaml 'continuous'",
        ),
    ],
)
def test_gains_inconsistent_with_models(tmp_path, pair, edit, msg):
    mp, _, g = pair
    edit(g)
    with pytest.raises(ConfigError, match=r"^gains.yaml: " + msg):
        fm.GainSchedule.load(_write(tmp_path, g), models_path=mp)


def test_gains_box_differs_from_models(tmp_path, pair):
    mp, _, g = pair
    # shift the whole box consistently: the gains file alone is valid, the pair is not
    g["scheduling"]["max"][0] = 6.0
    for v in g["vertices"]:
        if v["scheduling"][0] == 5.0:
            v["scheduling"][0] = 6.0
    fm.GainSchedule.from_dict(copy.deepcopy(g))
    with pytest.raises(
        ConfigError, match=r"^gains.yaml: scheduling: box .* differs from vertex_models.yaml"
    ):
        fm.GainSchedule.load(_write(tmp_path, g), models_path=mp)


# ------------------------------------------------------------------ YAML level
def test_malformed_yaml_names_line(tmp_path):
    p = tmp_path / "gains.yaml"
    p.write_text("format: lpv_sysid/gains@1\ngamma: [1.0\nR: 2\n")
    with pytest.raises(ConfigError, match=r"^gains.yaml: malformed YAML at line 3, column 2"):
        fm.GainSchedule.load(p)


def test_duplicate_key_names_line(tmp_path):
    p = tmp_path / "vertex_models.yaml"
    p.write_text("format: lpv_sysid/vertex_models@1\ntime: continuous\ntime: continuous\n")
    with pytest.raises(
        ConfigError,
        match=r"malformed YAML at line 3, column 1: duplicate key 'time' \(first at line 2\)",
    ):
        fm.VertexModels.load(p)


def test_empty_missing_and_non_mapping_files(tmp_path):
    p = tmp_path / "vertex_models.yaml"
    p.write_text("")
    with pytest.raises(ConfigError, match=r"^vertex_models.yaml: expected a mapping, got null"):
        fm.VertexModels.load(p)
    p.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match=r"expected a mapping, got list"):
        fm.VertexModels.load(p)
    with pytest.raises(ConfigError, match=r"^nothing.yaml: cannot read"):
        fm.VertexModels.load(tmp_path / "nothing.yaml")
    p.write_bytes(b"format: \xff\xfe\n")
    with pytest.raises(ConfigError, match="not UTF-8"):
        fm.VertexModels.load(p)


def test_nan_written_as_yaml_nan_is_rejected(tmp_path, good_models):
    d = copy.deepcopy(good_models)
    p = tmp_path / "vertex_models.yaml"
    text = yaml.safe_dump(d).replace(repr(d["vertices"][7]["B"][5][2]), ".nan", 1)
    p.write_text(text)
    with pytest.raises(ConfigError, match=r"vertices\[7\].B\[5\]\[2\]: must be finite, got nan"):
        fm.VertexModels.load(p)


def test_save_refuses_invalid_object(tmp_path, good_models):
    vm = fm.VertexModels.from_dict(copy.deepcopy(good_models))
    bad_vx = fm.VertexModel(**{**vm.vertices[0].__dict__, "A": np.full((12, 12), np.nan)})
    bad = fm.VertexModels(**{**vm.__dict__, "vertices": (bad_vx,) + vm.vertices[1:]})
    with pytest.raises(ConfigError, match=r"m.yaml: vertices\[0\].A\[0\]\[0\]: must be finite"):
        bad.save(tmp_path / "m.yaml")
    assert not (tmp_path / "m.yaml").exists()
