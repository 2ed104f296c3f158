"""One declaration per node parameter (issue 14 item 1): each node's shipped YAML agrees
exactly with its settings dataclass, and the rclpy declarations are generated from it.

Before, config/lpv_controller.yaml set monitor_window_s, feedforward, ff_filter_tau and
ff_jerk_tau, which the node's hand-written PARAMETERS table did not declare: the node ran
the defaults while ``lpv-sysid replay`` applied the file."""

import math
import os

import pytest
import yaml

from lpv_sysid.errors import ConfigError
from lpv_sysid.nodes import _common as C
from lpv_sysid.nodes import parameters as P
from lpv_sysid.nodes.controller_runtime import ControllerSettings
from lpv_sysid.nodes.excitation_node import ExcitationSettings

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFIG = os.path.join(ROOT, "config")
NODES = [("lpv_controller.yaml", "lpv_controller", ControllerSettings),
         ("excitation_node.yaml", "excitation", ExcitationSettings)]

#: YAML value -> the ROS parameter type rclpy gives it (a params file is typed by its values)
def ros_type(v):
    if isinstance(v, bool):
        return P.BOOL
    if isinstance(v, int):
        return P.INTEGER
    if isinstance(v, float):
        return P.DOUBLE
    if isinstance(v, str):
        return P.STRING
    if isinstance(v, list) and v and all(isinstance(x, float) for x in v):
        return P.DOUBLE_ARRAY
    if isinstance(v, list) and v and all(isinstance(x, str) for x in v):
        return P.STRING_ARRAY
    return f"unsupported {type(v).__name__}"


@pytest.mark.parametrize("yaml_file, node, cls", NODES)
def test_yaml_and_declarations_agree(yaml_file, node, cls):
    with open(os.path.join(CONFIG, yaml_file)) as fh:
        doc = yaml.safe_load(fh)
    (key, body), = doc.items()
    assert key == f"/**/{node}"
    values = body["ros__parameters"]
    declared = P.specs(cls)
    assert sorted(set(values) - set(declared)) == []              # every YAML key declared
    # every declaration in the YAML, except lists whose default is empty (a params file
    # cannot give an empty list a type; they are documented there as a comment)
    optional = {n for n, (d, _) in declared.items() if d == ()}
    assert sorted(set(declared) - set(values) - optional) == []
    for name, v in values.items():
        assert ros_type(v) == declared[name][1].kind, name           # same types
    cls.from_dict(values)                                           # and valid together
    text = open(os.path.join(CONFIG, yaml_file)).read()
    for name in optional:
        assert f"# {name}:" in text


@pytest.mark.parametrize("yaml_file, node, cls", NODES)
def test_rclpy_declarations_are_generated_from_the_settings(yaml_file, node, cls):
    table = {name: (default, d) for name, default, d in C.settings_table(cls)}
    assert list(table) == list(P.specs(cls))
    for name, (default, spec) in P.specs(cls).items():
        got_default, d = table[name]
        assert d.type == C.Parameter.Type[spec.kind].value and d.description == spec.description
        if spec.kind == P.DOUBLE:
            assert (d.floating_point_range[0].from_value, d.floating_point_range[0].to_value) == \
                (spec.lo, spec.hi)
            assert got_default == default
        assert d.additional_constraints == spec.constraints()


def test_the_node_tables_are_the_generated_ones():
    from lpv_sysid.nodes import lpv_controller_node
    got = [(n, d.floating_point_range[0].to_value if d.floating_point_range else None)
           for n, _, d in lpv_controller_node.PARAMETERS]
    want = [(n, s.hi if s.kind == P.DOUBLE else None)
            for n, (_, s) in P.specs(ControllerSettings).items()]
    assert got == want
    names = {n for n, _ in got}
    assert {"monitor_window_s", "feedforward", "ff_filter_tau", "ff_jerk_tau"} <= names


def test_array_constraints_are_described_and_enforced():
    rl = dict((n, d) for n, _, d in C.settings_table(ControllerSettings))["rate_limit"]
    assert rl.additional_constraints == "each entry in (0, 1000]; length 0 or 4"
    with pytest.raises(ConfigError, match=r"parameter 'vertex_frd' needs 3 entries"):
        ExcitationSettings(signals_file="s.npz", vertex_frd=(1.0, 2.0))
    with pytest.raises(ConfigError, match=r"'mode' must be one of \['phase1', 'phase2'\]"):
        ExcitationSettings(signals_file="s.npz", mode="phase3")
    with pytest.raises(ConfigError, match="gains_file is a phase-2 check"):
        ExcitationSettings(signals_file="s.npz", gains_file="g.yaml")


def test_coerce_rules():
    spec = P.ParamSpec(P.DOUBLE, "x", 0.0, 1.0, lo_open=True)
    assert P.coerce("x", 1, spec, "w") == 1.0 and isinstance(P.coerce("x", 1, spec, "w"), float)
    for bad, msg in ((0.0, "must be > 0"), (1.5, "must be <= 1"), (math.nan, "must be finite"),
                     (True, "must be a number"), ("0.5", "must be a number")):
        with pytest.raises(ConfigError, match=msg):
            P.coerce("x", bad, spec, "w")
    arr = P.ParamSpec(P.DOUBLE_ARRAY, "a", -1.0, 1.0)
    assert P.coerce("a", [0, 0.5], arr, "w") == (0.0, 0.5)
    with pytest.raises(ConfigError, match="must be a list"):
        P.coerce("a", "0.5", arr, "w")


def test_yaml_parameters_reads_the_node_section(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text("/**/other:\n  ros__parameters: {a: 1}\n/**/lpv_controller:\n"
                 "  ros__parameters: {rate_hz: 100.0}\n")
    assert P.yaml_parameters(str(f), "lpv_controller") == {"rate_hz": 100.0}
    with pytest.raises(ConfigError, match="no parameters for node 'excitation'"):
        P.yaml_parameters(str(f), "excitation")
