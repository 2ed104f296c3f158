"""io/yaml_file.read_yaml and the configuration readers built on it."""

from pathlib import Path

import pytest

from lpv_sysid.cli.design import load_config as load_identification
from lpv_sysid.cli.design import quadrotor_section
from lpv_sysid.cli.design.identify_nonlinear import _params as nonlinear_params
from lpv_sysid.errors import ConfigError
from lpv_sysid.io.files import read_yaml
from lpv_sysid.mavlink.bridge import BridgeConfig
from lpv_sysid.report import load_run
from lpv_sysid.signals.multisine import load_config as load_signals
from lpv_sysid.sim.phase1 import load_config as load_phase1

BAD = "a: [1, 2\nb: 3\n"  # unclosed flow sequence


def test_read_yaml_values_and_errors(tmp_path):
    f = tmp_path / "ok.yaml"
    f.write_text("mass: 1.5\nlist: [1, 2]\nname: ümlaut\n", encoding="utf-8")
    assert read_yaml(f) == {"mass": 1.5, "list": [1, 2], "name": "ümlaut"}
    assert read_yaml(str(f)) == read_yaml(f)
    (tmp_path / "empty.yaml").write_text("")
    assert read_yaml(tmp_path / "empty.yaml") is None
    (tmp_path / "bad.yaml").write_text(BAD)
    with pytest.raises(
        ConfigError, match=r"^.*bad\.yaml: malformed YAML \(while parsing a flow sequence\)$"
    ):
        read_yaml(tmp_path / "bad.yaml")
    with pytest.raises(
        ConfigError, match=r"^.*nope\.yaml: cannot read \(No such file or directory\)$"
    ):
        read_yaml(tmp_path / "nope.yaml")
    with pytest.raises(ConfigError, match=r"^vehicle_file x: cannot read \(Is a directory\)$"):
        read_yaml(tmp_path, "vehicle_file x")


@pytest.mark.parametrize(
    "reader",
    [
        load_identification,
        quadrotor_section,
        nonlinear_params,
        BridgeConfig.load,
        load_signals,
        load_phase1,
    ],
)
def test_readers_name_the_file_on_bad_yaml(tmp_path, reader):
    f = tmp_path / "cfg.yaml"
    f.write_text(BAD)
    with pytest.raises(ConfigError, match=r"cfg\.yaml: malformed YAML \(while parsing"):
        reader(f)


def test_quadrotor_section_readers(tmp_path):
    f = tmp_path / "q.yaml"
    f.write_text("quadrotor: {mass: 1.9}\ncontroller: {}\n")
    assert quadrotor_section(f) == {"mass": 1.9}
    assert nonlinear_params(f).mass == 1.9
    assert quadrotor_section(None) == {}
    f.write_text("quadrotor: [1, 2]\n")
    for reader in (quadrotor_section, nonlinear_params):
        with pytest.raises(ConfigError, match=r"q\.yaml: section 'quadrotor' must be a mapping"):
            reader(f)
    f.write_text("quadrotor: {colour: red}\n")
    with pytest.raises(ConfigError, match=r"q\.yaml: quadrotor: unknown key"):
        nonlinear_params(f)


def test_signals_config_keeps_missing_and_empty_wording(tmp_path):
    with pytest.raises(ConfigError, match=r"nope\.yaml: no such file$"):
        load_signals(str(tmp_path / "nope.yaml"))
    (tmp_path / "e.yaml").write_text("")
    with pytest.raises(ConfigError, match=r"e\.yaml: empty file$"):
        load_signals(str(tmp_path / "e.yaml"))


def test_report_names_malformed_input(tmp_path):
    (tmp_path / "gains.yaml").write_text(BAD)
    data = load_run(tmp_path, verify=False)
    assert data.problems["gains"].endswith(
        "gains.yaml: malformed YAML (while parsing a flow sequence)"
    )


def test_save_yaml_round_trips_atomically_and_read_located_names_the_line(tmp_path):
    from lpv_sysid.io.files import read_located, save_yaml

    doc = {"format": "x@1", "K": [[0.1, -2.5e-7], [3.0, 4.0]], "names": ["a", "b"]}
    p = tmp_path / "sub" / "f.yaml"
    save_yaml(doc, p)
    assert read_located(p) == doc
    assert "- [0.1, -2.5e-07]" in p.read_text()  # matrix rows in flow style
    assert [q.name for q in p.parent.iterdir()] == ["f.yaml"]  # no temporary file left
    p.write_text("a: 1\nb: [1\nc: 2\n")
    with pytest.raises(ConfigError, match=r"^f\.yaml: malformed YAML at line 3, column 2"):
        read_located(p)


def test_one_sha256_for_every_file_hash(tmp_path):
    import hashlib

    from lpv_sysid.io.files import sha256_file

    p = tmp_path / "b.bin"
    p.write_bytes(b"lpv" * 1000)
    want = hashlib.sha256(b"lpv" * 1000).hexdigest()
    assert sha256_file(p) == want
    # no other module hashes files its own way: hashlib appears only in io/files/hashing.py,
    # in the law hash of io/formats/gains.py (a hash of arrays, not of a file) and in the
    # seal of io/formats/seal.py (a hash of the parsed document, not of its bytes)
    pkg = Path(__file__).resolve().parent.parent / "lpv_sysid"
    users = sorted(
        str(f.relative_to(pkg)) for f in pkg.rglob("*.py") if "hashlib" in f.read_text()
    )
    assert users == ["io/files/hashing.py", "io/formats/gains.py", "io/formats/seal.py"]
