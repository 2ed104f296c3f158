"""The whole gains file is sealed (issue 25 item 2).

Before: ``certificate.design`` (excitation peak, reference rate/accel) was outside the law
hash, so x 20 in an editor widened the runtime abort limits 20 x while the node started and
``verify`` passed; ``verify`` did not check ``certificate.gains_sha256`` at all; and with
``certify_law`` public and unkeyed, a re-hashed K x 3 was accepted. Now ``seal.sha256``
covers every entry but the seal (any field, also ones added later), every load checks it
(node, verify, replay, simulations), and an operator key adds ``seal.hmac_sha256`` that only
a key holder can write. Oracles: hashlib/hmac recomputed here on the canonical bytes.
"""

from __future__ import annotations

import hashlib
import hmac
import json
from pathlib import Path

import pytest
import yaml
from lpv_test_gains import write_gains

from lpv_sysid.cli.main import main
from lpv_sysid.errors import ConfigError
from lpv_sysid.flight.controller import ControllerRuntime, ControllerSettings
from lpv_sysid.io import messages
from lpv_sysid.io.formats import GainSchedule, certify_law, check_seal, seal_document

KEY = bytes(range(32))
OTHER = bytes(range(1, 33))


def _edit(path, fn):
    d = yaml.safe_load(path.read_text())
    fn(d)
    path.write_text(yaml.safe_dump(d, sort_keys=False))
    return d


def _runtime(gains, **kw):
    return ControllerRuntime(
        ControllerSettings(gains_file=str(gains), **kw), messages.MsgFactory.rosbags()
    )


def _models(path):
    """x' = x + u (scalar, unstable) on a 1-axis box (as test_verify.py)."""
    verts = [
        {"scheduling": [s], "x0": [0.0], "u0": [0.0], "A": [[1.0]], "B": [[1.0]], "uncertain": []}
        for s in (-1.0, 1.0)
    ]
    doc = {
        "format": "lpv_sysid/vertex_models@1",
        "time": "continuous",
        "states": [{"name": "x", "unit": "m/s"}],
        "inputs": [{"name": "u", "unit": "1"}],
        "scheduling": {"names": ["s"], "min": [-1.0], "max": [1.0]},
        "vertices": verts,
    }
    path.write_text(yaml.safe_dump(doc))
    return path


def _config(path, region=True):
    cfg = {
        "hinf": {"gamma": 0.5, "solver": "CLARABEL", "fallback": "SCS"},
        "weights": {"T": 2.0, "input_magnitudes": [1.0], "output_magnitudes": [2**-0.5]},
        "velocity_states": ["x"],
        "verify": {"n_random": 5, "seed": 1},
    }
    path.write_text(yaml.safe_dump(cfg))
    return path


@pytest.fixture()
def gains(tmp_path):
    return Path(write_gains(tmp_path / "gains.yaml", box=2.0))


def test_seal_is_sha256_of_the_canonical_document_without_the_seal(gains):
    d = yaml.safe_load(open(gains).read())
    body = {k: v for k, v in d.items() if k != "seal"}
    canon = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    want = hashlib.sha256(b"lpv_sysid/gains-seal@1\n" + canon.encode()).hexdigest()
    assert d["seal"] == {"sha256": want}
    assert list(d)[-1] == "seal"
    # layout does not matter: another key order and flow style keep the seal
    relaid = dict(reversed(list(d.items())))
    with open(gains, "w") as f:
        yaml.safe_dump(relaid, f, default_flow_style=True, sort_keys=True)
    GainSchedule.load(gains)


@pytest.mark.parametrize(
    "edit",
    [
        lambda d: d["certificate"]["design"].update(
            excitation_peak=[20 * x for x in d["certificate"]["design"]["excitation_peak"]]
        ),
        lambda d: d["certificate"]["design"].update(
            reference_rate=[20 * x for x in d["certificate"]["design"]["reference_rate"]]
        ),
        lambda d: d["certificate"].update(gamma_achieved=d["certificate"]["gamma_achieved"] / 2),
        lambda d: d["certificate"]["sidecar"].update(file="other.cert.npz"),
        lambda d: d["certificate"].update(loop_delay={"bound_s": 1.0}),  # a field added later
        lambda d: d.update(time="continuous"),
    ],
)
def test_any_edit_outside_the_law_is_refused_by_the_node_and_verify(gains, edit, capsys):
    _edit(gains, edit)
    with pytest.raises(ConfigError, match=r"gains.yaml: seal.sha256: \w+ does not match"):
        _runtime(gains)
    with pytest.raises(ConfigError, match="seal.sha256"):
        GainSchedule.load(gains)


def test_a_field_added_later_is_sealed_without_a_list(gains):
    d = yaml.safe_load(gains.read_text())
    d["certificate"]["loop_delay"] = {"bound_s": 0.02}
    gains.write_text(yaml.safe_dump(seal_document(d), sort_keys=False))
    GainSchedule.load(gains)  # sealed with it: loads
    _edit(gains, lambda d: d["certificate"]["loop_delay"].update(bound_s=0.2))
    with pytest.raises(ConfigError, match="seal.sha256"):
        GainSchedule.load(gains)


def test_unsealed_file_is_refused_with_the_remedy(gains):
    _edit(gains, lambda d: d.pop("seal"))
    with pytest.raises(ConfigError, match=r"seal: missing.*re-run `lpv-sysid synthesize`"):
        _runtime(gains)


def test_verify_checks_the_law_hash(tmp_path, capsys):
    """A K changed by 1e-9 (relative) keeps every numerical check passing: verify used to
    print PASS; now the law no longer hashes to certificate.gains_sha256 (exit 2)."""
    models = _models(tmp_path / "vertex_models.yaml")
    cfg = _config(tmp_path / "synthesis.yaml", region=True)
    out = tmp_path / "out" / "gains.yaml"
    rc = main(["synthesize", "--models", str(models), "--config", str(cfg), "--out", str(out)])
    assert rc == 0 and out.is_file()
    capsys.readouterr()

    def nudge(d):
        d["vertices"][0]["K"][0][0] *= 1 + 1e-9

    d = yaml.safe_load(out.read_text())
    nudge(d)
    d = seal_document(d)  # even re-sealed: the law hash still tells
    out.write_text(yaml.safe_dump(d, sort_keys=False))
    rc = main(["verify", "--gains", str(out), "--models", str(models), "--full-box", "0"])
    err = capsys.readouterr().err
    assert rc == 2 and "certificate.gains_sha256" in err and "does not match" in err


def test_keyed_seal_synthesize_verify_and_node(tmp_path, capsys):
    key_file = tmp_path / "seal.key"
    key_file.write_text(KEY.hex() + "\n")
    other_file = tmp_path / "other.key"
    other_file.write_bytes(OTHER)
    models = _models(tmp_path / "vertex_models.yaml")
    cfg = _config(tmp_path / "synthesis.yaml", region=True)
    out = tmp_path / "out" / "gains.yaml"
    args = ["synthesize", "--models", str(models), "--config", str(cfg), "--out", str(out)]
    rc = main(args + ["--key", str(key_file)])
    assert rc == 0, capsys.readouterr()
    d = yaml.safe_load(out.read_text())
    body = {k: v for k, v in d.items() if k != "seal"}
    data = b"lpv_sysid/gains-seal@1\n" + json.dumps(
        body, sort_keys=True, separators=(",", ":")
    ).encode("ascii")
    assert d["seal"]["hmac_sha256"] == hmac.new(KEY, data, hashlib.sha256).hexdigest()
    verify = ["verify", "--gains", str(out), "--models", str(models), "--full-box", "0"]
    capsys.readouterr()
    assert main(verify + ["--key", str(key_file)]) == 0
    assert "keyed seal (seal.hmac_sha256) checked" in capsys.readouterr().out
    assert main(verify + ["--key", str(other_file)]) == 2
    assert "seal.hmac_sha256: does not match with the given key" in capsys.readouterr().err
    # re-certified without the key (certify_law is public): the unkeyed checks pass, the
    # keyed one refuses
    d["vertices"][0]["K"][0][0] *= 3.0
    out.write_text(yaml.safe_dump(certify_law(d, layout=None), sort_keys=False))
    GainSchedule.load(out, auto_layout=True)
    assert main(verify + ["--key", str(key_file)]) == 2
    assert "seal.hmac_sha256: missing, but a seal key was given" in capsys.readouterr().err


def test_controller_node_requires_the_keyed_seal_when_given_a_key(tmp_path, gains):
    key_file = tmp_path / "seal.key"
    key_file.write_bytes(KEY)
    with pytest.raises(ConfigError, match="seal.hmac_sha256: missing"):
        _runtime(gains, seal_key_file=str(key_file))
    d = yaml.safe_load(gains.read_text())
    gains.write_text(yaml.safe_dump(seal_document(d, KEY), sort_keys=False))
    rt = _runtime(gains, seal_key_file=str(key_file))
    assert any("its seal (keyed)" in line for _, line in rt.take_log())
    # negated K re-hashed and re-sealed by someone without the key
    d["vertices"][0]["K"] = [[-x for x in row] for row in d["vertices"][0]["K"]]
    gains.write_text(yaml.safe_dump(certify_law(d), sort_keys=False))
    with pytest.raises(ConfigError, match="seal.hmac_sha256: missing"):
        _runtime(gains, seal_key_file=str(key_file))
    bad_key = tmp_path / "bad.key"
    bad_key.write_text("not a key")
    with pytest.raises(ConfigError, match="seal key file .* expected 32 raw bytes"):
        _runtime(gains, seal_key_file=str(bad_key))


def test_check_seal_rejects_malformed_seals():
    doc = seal_document({"format": "x", "a": [1, 2.5, {"b": True}]})
    assert check_seal(doc, "f") == "sealed (sha256)"
    for seal, needle in (
        ("abc", "expected a mapping"),
        ({"sha256": "ABC"}, "expected 64 lowercase hex"),
        ({"sha256": doc["seal"]["sha256"], "note": 1}, "unknown key"),
        ({}, "seal.sha256: missing"),
    ):
        with pytest.raises(ConfigError, match=needle):
            check_seal({**doc, "seal": seal}, "f")
