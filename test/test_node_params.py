"""One declaration per node parameter (issue 14 item 1): each node's shipped YAML agrees
exactly with its declarations, and the rclpy declarations are generated from them -- a
settings dataclass of the node (controller, excitation, data logger, the sim vehicle's
shell) or the core's configuration dataclass (the bridge: BridgeConfig and MavrosConfig;
the sim vehicle's sensors: SensorConfig), nothing restated.

Before, config/lpv_controller.yaml set monitor_window_s, feedforward, ff_filter_tau and
ff_jerk_tau, which the node's hand-written PARAMETERS table did not declare: the node ran
the defaults while ``lpv-sysid replay`` applied the file; the bridge's table declared
``offboard.handback_mode`` but none of the ``handback_chain``, ``envelope.*`` or
``rotor_estimate.*`` sections its BridgeConfig reads. Under real rclpy, a parameter
declared without value (``rate_limit``, ``config_files``) emptied the node's whole
``get_parameters`` answer (``ros2 param dump``: ``ros__parameters: {}``)."""

import math
import os
import socket

import numpy as np
import pytest
import yaml

from lpv_sysid.configuration import parameters
from lpv_sysid.errors import ConfigError
from lpv_sysid.flight.bridge import handback_bound_s
from lpv_sysid.flight.bridge import settings as bridge_settings
from lpv_sysid.flight.controller import ControllerSettings
from lpv_sysid.flight.excitation import ExcitationSettings
from lpv_sysid.nodes import data_logger_node, mavlink_bridge_node, shell, sim_vehicle_node
from lpv_sysid.sim.vehicle_node import SimVehicleSettings

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFIG = os.path.join(ROOT, "config")
#: (params file, node name, {parameter: (default, ParamSpec)}, settings class or None)
NODES = [
    (
        "lpv_controller.yaml",
        "lpv_controller",
        parameters.specs(ControllerSettings),
        ControllerSettings,
    ),
    (
        "excitation_node.yaml",
        "excitation",
        parameters.specs(ExcitationSettings),
        ExcitationSettings,
    ),
    (
        "data_logger.yaml",
        "data_logger",
        parameters.specs(data_logger_node.DataLoggerSettings),
        data_logger_node.DataLoggerSettings,
    ),
    ("mavlink_bridge_node.yaml", "mavlink_bridge", mavlink_bridge_node.SPECS, None),
    ("sim_vehicle.yaml", "sim_vehicle", sim_vehicle_node.SPECS, None),
]
IDS = [n[1] for n in NODES]


def ros_type(v):
    """YAML value -> the ROS parameter type rclpy gives it (a params file is typed by its
    values)."""
    if isinstance(v, bool):
        return parameters.BOOL
    if isinstance(v, int):
        return parameters.INTEGER
    if isinstance(v, float):
        return parameters.DOUBLE
    if isinstance(v, str):
        return parameters.STRING
    for kind, t in (
        (parameters.DOUBLE_ARRAY, float),
        (parameters.STRING_ARRAY, str),
        (parameters.INTEGER_ARRAY, int),
    ):
        if (
            isinstance(v, list)
            and v
            and all(isinstance(x, t) and not isinstance(x, bool) for x in v)
        ):
            return kind
    return f"unsupported {type(v).__name__}"


def flatten(d, prefix=""):
    """Nested ros__parameters -> dotted names, as rcl reads a params file."""
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def yaml_values(yaml_file, node):
    with open(os.path.join(CONFIG, yaml_file)) as fh:
        doc = yaml.safe_load(fh)
    ((key, body),) = doc.items()
    assert key == f"/**/{node}"
    return flatten(body["ros__parameters"])


@pytest.mark.parametrize("yaml_file, node, declared, cls", NODES, ids=IDS)
def test_yaml_and_declarations_agree(yaml_file, node, declared, cls):
    values = yaml_values(yaml_file, node)
    assert sorted(set(values) - set(declared)) == []  # every YAML key declared
    # every declaration in the YAML, except lists whose default is empty (a params file
    # cannot write one: rcl reads [] as no value; they are documented there as a comment)
    optional = {n for n, (d, _) in declared.items() if d == ()}
    assert sorted(set(declared) - set(values) - optional) == []
    for name, v in values.items():
        assert ros_type(v) == declared[name][1].kind, name  # same types
    text = open(os.path.join(CONFIG, yaml_file)).read()
    for name in optional:
        assert f"# {name.rsplit('.', 1)[-1]}:" in text
    if cls is not None:
        cls.from_dict(values)  # and valid together


def test_bridge_yaml_reaches_bridge_config_and_defaults_round_trip():
    """The generated bridge parameters carry BridgeConfig's defaults (nest(defaults) builds
    BridgeConfig()), and the node's YAML reaches every section, NaN / "" meaning unset."""
    from lpv_sysid.mavlink.bridge import BridgeConfig, MavrosConfig

    specs = mavlink_bridge_node.SPECS
    defaults = {n: d for n, (d, _) in specs.items()}
    _, bridge, mavros = bridge_settings.split_parameters(defaults)
    assert BridgeConfig.from_dict(bridge) == BridgeConfig()
    assert MavrosConfig.from_dict(mavros) == MavrosConfig()
    _, bridge, mavros = bridge_settings.split_parameters(
        {**defaults, **yaml_values("mavlink_bridge_node.yaml", "mavlink_bridge")}
    )
    cfg = BridgeConfig.from_dict(bridge)
    assert cfg.offboard.handback_chain == ("HOLD", "LAND") and cfg.offboard.handback_mode is None
    assert cfg.offboard.setpoint_rate_hz == 50.0 and cfg.offboard.input_timeout == 0.5
    assert dict(cfg.link.streams) == {
        "LOCAL_POSITION_NED": 50.0,
        "ATTITUDE_QUATERNION": 100.0,
        "HIGHRES_IMU": 100.0,
        "ESC_STATUS": 50.0,
    }
    assert cfg.link.signing_key_file is None and cfg.rotor_estimate.a_omega is None
    assert cfg.rotor_estimate.motor_outputs == (1, 2, 3, 4)
    assert cfg.envelope.floor == 5.0 and cfg.envelope.max_tilt_deg == 50.0
    assert MavrosConfig.from_dict(mavros).setpoint_rate_hz == 50.0  # shared with offboard.*
    # a value set through the generated parameter is what BridgeConfig gets
    _, bridge, _ = bridge_settings.split_parameters(
        {
            **defaults,
            "rotor_estimate.a_omega": 15.0,
            "offboard.handback_chain": ["LAND"],
            "envelope.radius": 50.0,
        }
    )
    cfg = BridgeConfig.from_dict(bridge)
    assert (cfg.rotor_estimate.a_omega, cfg.offboard.handback_chain, cfg.envelope.radius) == (
        15.0,
        ("LAND",),
        50.0,
    )
    with pytest.raises(ConfigError, match="handback_chain"):
        BridgeConfig.from_dict(
            bridge_settings.split_parameters({**defaults, "offboard.handback_chain": ["ACRO"]})[1]
        )


def test_sim_vehicle_sensor_parameters_are_sensor_config():
    from lpv_sysid.sim.vehicle import SensorConfig

    values = yaml_values("sim_vehicle.yaml", "sim_vehicle")
    sensors = {k: v for k, v in values.items() if k in SensorConfig.__dataclass_fields__}
    assert SensorConfig.from_dict(sensors) == SensorConfig()  # the YAML restates its defaults
    assert set(sim_vehicle_node.SPECS) == set(parameters.specs(SimVehicleSettings)) | set(
        SensorConfig.__dataclass_fields__
    )


def test_config_specs_rules():
    from dataclasses import dataclass, field

    @dataclass(frozen=True)
    class Inner:
        x: float = 1.0
        table: tuple[tuple[str, float], ...] = (("A", 1.0), ("B", 2.0))

    @dataclass(frozen=True)
    class Outer:
        name: str | None = None
        gain: float | None = None
        ids: tuple[int, ...] = (1, 2)
        inner: Inner = field(default_factory=Inner)

    d = {"name": "n", "gain": "g", "ids": "i", "inner.x": "x", "inner.table": "t"}
    specs = parameters.config_specs(Outer, d)
    assert {k: (v[0], v[1].kind) for k, v in specs.items() if k != "gain"} == {
        "name": ("", parameters.STRING),
        "ids": ((1, 2), parameters.INTEGER_ARRAY),
        "inner.x": (1.0, parameters.DOUBLE),
        "inner.table.A": (1.0, parameters.DOUBLE),
        "inner.table.B": (2.0, parameters.DOUBLE),
    }
    assert math.isnan(specs["gain"][0]) and specs["gain"][1].optional
    assert parameters.nest({"name": "", "gain": math.nan, "inner.table.A": 3.0}, specs) == {
        "inner": {"table": {"A": 3.0}}
    }
    with pytest.raises(TypeError, match="'inner.x' has no description"):
        parameters.config_specs(Outer, {k: v for k, v in d.items() if k != "inner.x"})
    with pytest.raises(TypeError, match=r"descriptions of no generated parameter: \['extra'\]"):
        parameters.config_specs(Outer, {**d, "extra": "e"})

    @dataclass(frozen=True)
    class Bad:
        m: dict = field(default_factory=dict)

    with pytest.raises(TypeError, match="no ROS parameter form"):
        parameters.config_specs(Bad, {"m": "m"})


def _free_udp_port():
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


@pytest.fixture(scope="module")
def node_inputs(tmp_path_factory):
    from lpv_test_gains import write_gains

    from lpv_sysid.signals.store import save_npz

    d = tmp_path_factory.mktemp("inputs")
    t = np.arange(0.0, 4.0, 0.02)
    save_npz(str(d / "s.npz"), t, np.zeros((t.size, 4)), ["u_ref", "v_ref", "w_ref", "r_ref"])
    return {
        "lpv_controller": {"gains_file": write_gains(d / "gains.yaml")},
        "excitation": {"signals_file": str(d / "s.npz")},
        "data_logger": {"out_dir": str(d / "log")},
        "mavlink_bridge": {"link.url": f"udpin:127.0.0.1:{_free_udp_port()}"},
        "sim_vehicle": {},
    }


@pytest.mark.parametrize("yaml_file, node, declared, cls", NODES, ids=IDS)
def test_every_parameter_of_a_running_node_has_a_value(
    yaml_file, node, declared, cls, node_inputs
):
    """Started from its YAML, a node has no uninitialized parameter: each reads back with
    its declared type (real rclpy answers no value at all to a get_parameters request
    naming one uninitialized parameter, so ``ros2 param dump`` printed nothing)."""
    import importlib

    import rclpy
    from rclpy.parameter import Parameter

    exe = {
        "mavlink_bridge": "mavlink_bridge_node",
        "lpv_controller": "lpv_controller_node",
        "data_logger": "data_logger_node",
        "sim_vehicle": "sim_vehicle_node",
        "excitation": "excitation_node",
    }[node]
    mod = importlib.import_module(f"lpv_sysid.nodes.{exe}")
    cls_node = next(
        v
        for k, v in vars(mod).items()
        if k.endswith("Node")
        and isinstance(v, type)
        and issubclass(v, shell.ShellNode)
        and v is not shell.ShellNode
    )
    args = ["n", "--ros-args", "--params-file", os.path.join(CONFIG, yaml_file)]
    for k, v in node_inputs[node].items():
        args += ["-p", f"{k}:={v}"]
    rclpy.init(args=args)
    try:
        n = cls_node()
        try:
            for name, (_, spec) in declared.items():
                p = n.get_parameter(name)  # never uninitialized
                assert p.type_ == Parameter.Type[spec.kind], (name, p.type_)
        finally:
            n.destroy_node()
    finally:
        rclpy.try_shutdown()


@pytest.mark.parametrize("yaml_file, node, declared, cls", NODES, ids=IDS)
def test_rclpy_declarations_are_generated_from_the_settings(yaml_file, node, declared, cls):
    table = {name: (default, d) for name, default, d in shell.spec_table(declared)}
    assert list(table) == list(declared)
    for name, (default, spec) in declared.items():
        got_default, d = table[name]
        assert (
            d.type == shell.Parameter.Type[spec.kind].value and d.description == spec.description
        )
        if spec.kind == parameters.DOUBLE and spec.lo is not None:
            assert (d.floating_point_range[0].from_value, d.floating_point_range[0].to_value) == (
                spec.lo,
                spec.hi,
            )
        elif spec.kind == parameters.DOUBLE:
            assert list(d.floating_point_range) == []  # checked by the config class
            assert spec.checked_by and "checked at start by" in d.additional_constraints
        if spec.kind == parameters.DOUBLE:
            assert got_default == default or math.isnan(got_default) and math.isnan(default)
        assert d.additional_constraints == spec.constraints()
        assert d.description  # every parameter is described


@pytest.mark.parametrize(
    "module",
    [
        "excitation_node",
        "lpv_controller_node",
        "data_logger_node",
        "mavlink_bridge_node",
        "sim_vehicle_node",
    ],
)
def test_each_node_declares_exactly_its_generated_table(module):
    import importlib

    mod = importlib.import_module(f"lpv_sysid.nodes.{module}")
    declared = dict(
        NODES[
            [n[1] for n in NODES].index(
                {
                    "excitation_node": "excitation",
                    "lpv_controller_node": "lpv_controller",
                    "data_logger_node": "data_logger",
                    "mavlink_bridge_node": "mavlink_bridge",
                    "sim_vehicle_node": "sim_vehicle",
                }[module]
            )
        ][2]
    )
    assert [n for n, _, _ in mod.PARAMETERS] == list(declared)


def test_the_node_tables_are_the_generated_ones():
    from lpv_sysid.nodes import lpv_controller_node

    got = [
        (n, d.floating_point_range[0].to_value if d.floating_point_range else None)
        for n, _, d in lpv_controller_node.PARAMETERS
    ]
    want = [
        (n, s.hi if s.kind == parameters.DOUBLE else None)
        for n, (_, s) in parameters.specs(ControllerSettings).items()
    ]
    assert got == want
    names = {n for n, _ in got}
    assert {"monitor_window_s", "feedforward", "ff_filter_tau", "ff_jerk_tau"} <= names


def test_array_constraints_are_described_and_enforced():
    rl = dict((n, d) for n, _, d in shell.settings_table(ControllerSettings))["rate_limit"]
    assert rl.additional_constraints == "each entry in [0.01, 1000]; length 0 or 4"
    with pytest.raises(ConfigError, match=r"parameter 'vertex_frd' needs 3 entries"):
        ExcitationSettings(signals_file="s.npz", vertex_frd=(1.0, 2.0))
    with pytest.raises(ConfigError, match=r"'mode' must be one of \['phase1', 'phase2'\]"):
        ExcitationSettings(signals_file="s.npz", mode="phase3")
    with pytest.raises(ConfigError, match="gains_file is a phase-2 check"):
        ExcitationSettings(signals_file="s.npz", gains_file="g.yaml")


def test_coerce_rules():
    spec = parameters.ParamSpec(parameters.DOUBLE, "x", 0.0, 1.0, lo_open=True)
    assert parameters.coerce("x", 1, spec, "w") == 1.0 and isinstance(
        parameters.coerce("x", 1, spec, "w"), float
    )
    for bad, msg in (
        (0.0, "must be > 0"),
        (1.5, "must be <= 1"),
        (math.nan, "must be finite"),
        (True, "must be a number"),
        ("0.5", "must be a number"),
    ):
        with pytest.raises(ConfigError, match=msg):
            parameters.coerce("x", bad, spec, "w")
    arr = parameters.ParamSpec(parameters.DOUBLE_ARRAY, "a", -1.0, 1.0)
    assert parameters.coerce("a", [0, 0.5], arr, "w") == (0.0, 0.5)
    with pytest.raises(ConfigError, match="must be a list"):
        parameters.coerce("a", "0.5", arr, "w")


def test_yaml_parameters_reads_the_node_section(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text(
        "/**/other:\n  ros__parameters: {a: 1}\n/**/lpv_controller:\n"
        "  ros__parameters: {rate_hz: 100.0}\n"
    )
    assert parameters.yaml_parameters(str(f), "lpv_controller") == {"rate_hz": 100.0}
    with pytest.raises(ConfigError, match="no parameters for node 'excitation'"):
        parameters.yaml_parameters(str(f), "excitation")


def test_launch_files_leave_the_bridge_its_whole_hand_back_chain():
    """launch's SIGINT -> SIGTERM escalation (5 s by default) cut orderly shutdowns short
    (exit -15 under load); every launch_ros Node gets sigterm_timeout, and the shipped
    bridge's worst-case hand-back chain plus the teardown margin fits in it."""
    import ast

    from lpv_sysid.mavlink.bridge import BridgeConfig

    defaults = {n: d for n, (d, _) in mavlink_bridge_node.SPECS.items()}
    _, bridge, _ = bridge_settings.split_parameters(
        {**defaults, **yaml_values("mavlink_bridge_node.yaml", "mavlink_bridge")}
    )
    off = BridgeConfig.from_dict(bridge).offboard
    # HOLD then LAND, each: 4 DO_SET_MODE attempts of 0.5 s + 2 s for the HEARTBEAT; + 1 s
    assert handback_bound_s(off) == 2 * (4 * 0.5 + 2.0) + 1.0
    assert handback_bound_s(off) + shell.TEARDOWN_MARGIN_S <= shell.LAUNCH_SIGTERM_TIMEOUT_S
    # every launch file builds its nodes through launch_util.node, whose one launch_ros
    # Node call passes sigterm_timeout (its value: test_launch_util)
    launch_files = [f for f in os.listdir(os.path.join(ROOT, "launch")) if f.endswith(".py")]
    assert len(launch_files) == 4
    for fname in sorted(launch_files):
        tree = ast.parse(open(os.path.join(ROOT, "launch", fname)).read())
        called = {getattr(c.func, "id", "") for c in ast.walk(tree) if isinstance(c, ast.Call)}
        assert "node" in called and "Node" not in called, fname
    util = ast.parse(open(os.path.join(ROOT, "lpv_sysid", "nodes", "launch_util.py")).read())
    calls = [
        c
        for c in ast.walk(util)
        if isinstance(c, ast.Call) and getattr(c.func, "id", "") == "Node"
    ]
    assert len(calls) == 2  # the package's nodes (node) and MAVROS (mavros_node)
    for call in calls:
        kw = {k.arg: k.value for k in call.keywords}
        assert getattr(kw["sigterm_timeout"].func, "id", None) == "sigterm_timeout"


#: issue 25 item 5: misspelled keys of a params file (the audit's), one per node
MISSPELLED = {
    "lpv_controller": ("envelope_margn", "envelope_margin"),
    "excitation": ("ramp_secs", "ramp_s"),
    "data_logger": ("flush_intervall_s", "flush_interval_s"),
    "mavlink_bridge": ("envelope.cieling", "envelope.ceiling"),
    "sim_vehicle": ("state_hzz", "state_hz"),
}


@pytest.mark.parametrize("yaml_file, node, declared, cls", NODES, ids=IDS)
def test_misspelled_key_in_a_params_file_refuses_the_node(
    yaml_file, node, declared, cls, node_inputs, tmp_path
):
    """A key no declaration takes is refused at node start, named with the closest declared
    name (before: rclpy kept it as an undeclared override and the node ran the default)."""
    import importlib

    import rclpy

    exe = {
        "mavlink_bridge": "mavlink_bridge_node",
        "lpv_controller": "lpv_controller_node",
        "data_logger": "data_logger_node",
        "sim_vehicle": "sim_vehicle_node",
        "excitation": "excitation_node",
    }[node]
    mod = importlib.import_module(f"lpv_sysid.nodes.{exe}")
    cls_node = next(
        v
        for k, v in vars(mod).items()
        if k.endswith("Node")
        and isinstance(v, type)
        and issubclass(v, shell.ShellNode)
        and v is not shell.ShellNode
    )
    with open(os.path.join(CONFIG, yaml_file)) as f:
        data = yaml.safe_load(f)
    (body,) = data.values()
    bad, meant = MISSPELLED[node]
    section = body["ros__parameters"]
    *path, leaf = bad.split(".")
    for p in path:
        section = section[p]
    section[leaf] = 1.0
    params = tmp_path / yaml_file
    params.write_text(yaml.safe_dump(data))
    inputs = dict(node_inputs[node])
    if node == "data_logger":
        inputs["out_dir"] = str(tmp_path / "log")  # a fresh one: the logger refuses a used one
    args = ["n", "--ros-args", "--params-file", str(params)]
    for k, v in inputs.items():
        args += ["-p", f"{k}:={v}"]
    rclpy.init(args=args)
    try:
        with pytest.raises(ConfigError, match=r"unknown parameter\(s\) \['" + bad) as e:
            cls_node()
        if meant:
            assert f"did you mean '{meant}'" in str(e.value)
    finally:
        rclpy.try_shutdown()
    # the shipped file itself starts (also: rclpy's own parameters are no unknown keys)
    rclpy.init(args=args[:3] + [os.path.join(CONFIG, yaml_file)] + args[4:])
    try:
        cls_node().destroy_node()
    finally:
        rclpy.try_shutdown()


def test_unknown_ros_parameter_given_with_p_is_refused_too(node_inputs):
    import rclpy

    from lpv_sysid.nodes.lpv_controller_node import LpvControllerNode

    gains = node_inputs["lpv_controller"]["gains_file"]
    rclpy.init(
        args=["n", "--ros-args", "-p", f"gains_file:={gains}", "-p", "box_margn:=0.5",
              "-p", "use_sim_time:=false"]
    )  # fmt: skip
    try:
        with pytest.raises(ConfigError, match=r"\['box_margn'\].*did you mean 'box_margin'"):
            LpvControllerNode()
    finally:
        rclpy.try_shutdown()


@pytest.mark.parametrize(
    "given, match",
    [
        ("status_rate_hz:=0.05", r"parameter 'status_rate_hz': .*(range|0\.05)"),
        ("status_rate_hz:=fast", r"parameter 'status_rate_hz': .*(type|STRING)"),
    ],
)
def test_out_of_range_or_mistyped_p_is_one_named_error(node_inputs, given, match):
    """A ``-p`` value outside the declared range (or of another type) ends the node with a
    ConfigError naming the parameter (``run``: one FATAL line, exit 2), not rclpy's
    traceback (issue 24: ``status_rate_hz:=0.05`` printed a Python traceback)."""
    import rclpy

    from lpv_sysid.nodes.lpv_controller_node import LpvControllerNode

    gains = node_inputs["lpv_controller"]["gains_file"]
    rclpy.init(args=["n", "--ros-args", "-p", f"gains_file:={gains}", "-p", given])
    try:
        with pytest.raises(ConfigError, match=match):
            LpvControllerNode()
    finally:
        rclpy.try_shutdown()


#: node name of a launch file's node(...) -> the module of its shell
_LAUNCH_NODES = {
    "mavlink_bridge": "mavlink_bridge_node",
    "lpv_controller": "lpv_controller_node",
    "data_logger": "data_logger_node",
    "sim_vehicle": "sim_vehicle_node",
    "excitation": "excitation_node",
    "campaign": "campaign_node",
}


def _declared_names(node: str) -> set:
    import importlib

    mod = importlib.import_module(f"lpv_sysid.nodes.{_LAUNCH_NODES[node]}")
    return {name for name, _, _ in mod.PARAMETERS}


def test_every_launch_override_is_a_declared_parameter():
    """Issue 25 item 5: a node refuses an undeclared parameter at start, so a launch file
    that passes one would not start; read from the launch files' syntax (no ROS needed):
    every literal key of a ``node(name, file, {...})`` override is declared by that node
    (or is rclpy's own use_sim_time)."""
    import ast
    import glob

    seen = 0
    for path in sorted(glob.glob(os.path.join(ROOT, "launch", "*.launch.py"))):
        tree = ast.parse(open(path).read())
        for call in ast.walk(tree):
            if not (isinstance(call, ast.Call) and getattr(call.func, "id", "") == "node"):
                continue
            name = call.args[0].value
            over = call.args[2] if len(call.args) > 2 else None
            for kw in call.keywords:
                if kw.arg == "overrides":
                    over = kw.value
            if not isinstance(over, ast.Dict):
                continue
            keys = {k.value for k in over.keys if isinstance(k, ast.Constant)}
            unknown = keys - _declared_names(name) - {"use_sim_time"}
            assert unknown == set(), (path, name, unknown)
            seen += 1
    assert seen >= 10
