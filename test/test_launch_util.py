"""nodes/launch_util and the launch files that use it, run against recording fakes of the
ROS 2 ``launch`` / ``launch_ros`` / ``ament_index_python`` API (not installed here).

The fakes keep the real signatures' keyword-only arguments, so a call the real classes
would refuse fails here too. They are injected into ``sys.modules`` for one test only
(never put on the path: a real ROS 2 install must not be shadowed).
"""

import importlib
import importlib.util
import os
import sys
import types

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARE = "/opt/ros/jazzy/share/lpv_sysid"


class _Recorded:
    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs

    def __eq__(self, other):
        return type(self) is type(other) and (self.args, self.kwargs) == (other.args, other.kwargs)

    def __repr__(self):
        return f"{type(self).__name__}{self.args}{self.kwargs}"


class LaunchDescription(_Recorded):
    def __init__(self, initial_entities=None):
        super().__init__(initial_entities)
        self.entities = list(initial_entities or [])


class DeclareLaunchArgument(_Recorded):
    def __init__(self, name, *, default_value=None, description=None, choices=None):
        super().__init__(
            name, default_value=default_value, description=description, choices=choices
        )
        self.name, self.default_value, self.description = name, default_value, description


class LaunchConfiguration(_Recorded):
    def __init__(self, variable_name, *, default=None):
        super().__init__(variable_name, default=default)


class PathJoinSubstitution(_Recorded):
    def __init__(self, substitutions):
        super().__init__(list(substitutions))


class PythonExpression(_Recorded):
    def __init__(self, expression):
        super().__init__(list(expression))


class IfCondition(_Recorded):
    def __init__(self, predicate_expression):
        super().__init__(predicate_expression)


class Node(_Recorded):
    def __init__(
        self,
        *,
        executable,
        package=None,
        name=None,
        namespace=None,
        output="log",
        parameters=None,
        condition=None,
        **kwargs,
    ):
        super().__init__(
            executable=executable,
            package=package,
            name=name,
            namespace=namespace,
            output=output,
            parameters=parameters,
            condition=condition,
            **kwargs,
        )
        self.executable, self.parameters, self.condition = executable, parameters, condition


def _share(package):
    assert package == "lpv_sysid"
    return SHARE


@pytest.fixture
def fake_launch(monkeypatch):
    mods = {
        "launch": dict(LaunchDescription=LaunchDescription),
        "launch.actions": dict(DeclareLaunchArgument=DeclareLaunchArgument),
        "launch.substitutions": dict(
            LaunchConfiguration=LaunchConfiguration,
            PathJoinSubstitution=PathJoinSubstitution,
            PythonExpression=PythonExpression,
        ),
        "launch.conditions": dict(IfCondition=IfCondition),
        "launch_ros": {},
        "launch_ros.actions": dict(Node=Node),
        "ament_index_python": {},
        "ament_index_python.packages": dict(get_package_share_directory=_share),
    }
    for name, attrs in mods.items():
        mod = types.ModuleType(name)
        mod.__dict__.update(attrs)
        monkeypatch.setitem(sys.modules, name, mod)
    # a fresh import against the fakes; the original state is restored afterwards
    monkeypatch.delitem(sys.modules, "lpv_sysid.nodes.launch_util", raising=False)
    return importlib.import_module("lpv_sysid.nodes.launch_util")


def _describe(fname):
    spec = importlib.util.spec_from_file_location(
        "lf_" + fname.split(".")[0], os.path.join(ROOT, "launch", fname)
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    ld = mod.generate_launch_description()
    args = {
        e.name: (e.default_value, e.description)
        for e in ld.entities
        if isinstance(e, DeclareLaunchArgument)
    }
    order = [e.name for e in ld.entities if isinstance(e, DeclareLaunchArgument)]
    nodes = {e.executable: e for e in ld.entities if isinstance(e, Node)}
    return order, args, nodes


def test_declare_arguments_and_params(fake_launch):
    L = fake_launch
    out = L.declare_arguments(gains_file=L.REQUIRED, log_dir="x_log", notes={"log_dir": "test"})
    assert [a.name for a in out] == ["config_dir", "namespace", "gains_file", "log_dir"]
    assert out[0].default_value == os.path.join(SHARE, "config")
    assert out[0].description == "directory holding the node parameter files"
    assert out[1].default_value == "lpv_sysid"  # one namespace per vehicle
    assert out[2].default_value is None  # required: no default_value given at all
    assert out[2].kwargs["default_value"] is None
    assert out[3].default_value == "x_log"
    assert out[3].description == "experiment directory of the data logger (test)"
    assert L.params("a.yaml") == PathJoinSubstitution(
        [LaunchConfiguration("config_dir"), "a.yaml"]
    )
    with pytest.raises(KeyError, match=r"\['colour'\]"):
        L.declare_arguments(colour="red")
    with pytest.raises(KeyError, match=r"\['speed'\]"):
        L.declare_arguments(notes={"speed": "fast"})


CONFIG_DIR = os.path.join(SHARE, "config")
MAVROS_ARGS = ["mavros_ns", "fcu_url", "tgt_system"]
SIGNALS = ("signals.npz", "signals.npz written by `lpv-sysid signals`")


@pytest.mark.parametrize(
    "fname, order, expected",
    [
        (
            "phase1.launch.py",
            [
                "config_dir",
                "namespace",
                "signals_file",
                "vertex",
                "log_dir",
                "transport",
                "link_url",
                "auto_start",
                *MAVROS_ARGS,
            ],
            {
                "signals_file": SIGNALS,
                "vertex": (
                    "[0.0, 0.0, 0.0]",
                    "vertex body velocity (u, v, w) FRD, m/s, for this run",
                ),
                "log_dir": ("phase1_log", "experiment directory of the data logger"),
            },
        ),
        (
            "phase2.launch.py",
            [
                "config_dir",
                "namespace",
                "gains_file",
                "signals_file",
                "log_dir",
                "design",
                "transport",
                "link_url",
                "auto_start",
                *MAVROS_ARGS,
            ],
            {
                "gains_file": (None, "gains.yaml from `lpv-sysid synthesize`"),
                "signals_file": SIGNALS,
                "log_dir": ("phase2_log", "experiment directory of the data logger"),
            },
        ),
        (
            "sim.launch.py",
            [
                "phase",
                "config_dir",
                "namespace",
                "signals_file",
                "gains_file",
                "vertex",
                "log_dir",
                "auto_start",
            ],
            {
                "phase": ("1", "1: baseline + excitation, 2: LPV controller"),
                "gains_file": (
                    "gains.yaml",
                    "gains.yaml from `lpv-sysid synthesize` (phase 2 only)",
                ),
                "vertex": (
                    "[0.0, 0.0, 0.0]",
                    "vertex body velocity (u, v, w) FRD, m/s, for this run (phase 1 only)",
                ),
                "log_dir": ("sim_log", "experiment directory of the data logger"),
            },
        ),
    ],
)
def test_launch_files_declare_and_wire(fake_launch, fname, order, expected):
    got_order, args, nodes = _describe(fname)
    assert got_order == order
    assert args["config_dir"][0] == CONFIG_DIR
    for name, value in expected.items():
        assert args[name] == value, name
    for executable, node in nodes.items():
        if node.kwargs["package"] == "mavros":
            continue  # test_phase_launches_take_the_mavros_transport
        assert node.kwargs["namespace"] == LaunchConfiguration("namespace")
        assert node.kwargs["package"] == "lpv_sysid"
        # first parameter entry: the node's file in config_dir (the sequencer has none);
        # every LaunchConfiguration in the overrides names a declared argument
        if executable != "sequencer_node":
            first = node.parameters[0]
            assert first.args[0][0] == LaunchConfiguration("config_dir")
        for v in node.parameters[-1].values():
            if isinstance(v, LaunchConfiguration):
                assert v.args[0] in args, (executable, v)
    if fname == "phase2.launch.py":
        # the controller checks the signal the excitation node plays (box, envelope, kappa)
        assert nodes["lpv_controller_node"].parameters[1] == {
            "gains_file": LaunchConfiguration("gains_file"),
            "signals_file": LaunchConfiguration("signals_file"),
        }
        assert nodes["excitation_node"].parameters[1]["gains_file"] == LaunchConfiguration(
            "gains_file"
        )
        # design:=rate_plant -> the PX4 controller file and the rate_setpoint bridge command
        ctrl_file = nodes["lpv_controller_node"].parameters[0].args[0][1]
        command = nodes["mavlink_bridge_node"].parameters[1]["command"]
        for expr, rate, virtual in (
            (ctrl_file, "lpv_controller_px4.yaml", "lpv_controller.yaml"),
            (command, "rate_setpoint", "attitude_rate"),
        ):
            parts = expr.args[0]
            for design, want in (("rate_plant", rate), ("virtual_actuator", virtual)):
                text = "".join(design if isinstance(p, LaunchConfiguration) else p for p in parts)
                assert eval(text, {}) == want  # noqa: S307 - PythonExpression's own evaluation
        assert args["design"][0] == "virtual_actuator"
    if fname == "sim.launch.py":
        assert nodes["lpv_controller_node"].condition is not None
        assert all(n.condition is None for e, n in nodes.items() if e != "lpv_controller_node")
    else:  # the operator's per-flight choices reach the bridge
        bridge = nodes["mavlink_bridge_node"].parameters[1]
        assert bridge["transport"] == LaunchConfiguration("transport")
        # link_url reaches the bridge's link_url_override, never link.url: its default (empty)
        # leaves config_dir's link.url in force (test_link_url_precedence)
        assert bridge["link_url_override"] == LaunchConfiguration("link_url")
        assert "link.url" not in bridge
        assert args["transport"][0] == "mavlink" and args["link_url"][0] == ""
    seq = nodes["sequencer_node"].parameters[-1]
    assert (
        seq["auto_start"] == LaunchConfiguration("auto_start") and args["auto_start"][0] == "false"
    )
    steps = {
        "phase1.launch.py": ["mavlink_bridge", "excitation"],
        "phase2.launch.py": [
            "mavlink_bridge:ready",
            "lpv_controller",
            "mavlink_bridge",
            "excitation",
        ],
    }
    if fname in steps:
        assert seq["steps"] == steps[fname]
        from lpv_sysid.flight.sequencer import SequencerSettings

        SequencerSettings(steps=tuple(seq["steps"]))  # valid steps


def test_campaign_launch_reads_the_share_copy_of_the_configs(fake_launch):
    """campaign.launch.py's campaign file and node parameter files come from the one ROS share
    lookup (default_configs.share_config_dir), the same directory as every launch file's
    ``config_dir``."""
    order, args, nodes = _describe("campaign.launch.py")
    assert order[0] == "config_dir" and args["config_dir"][0] == CONFIG_DIR
    assert args["campaign_file"][0] == os.path.join(CONFIG_DIR, "campaign.yaml")
    for executable in ("mavlink_bridge_node", "data_logger_node"):
        assert nodes[executable].parameters[0].args[0][0] == LaunchConfiguration("config_dir")
    assert os.path.isfile(os.path.join(ROOT, "lpv_sysid", "config", "campaign.yaml"))


def test_node_builds_the_package_node_with_its_parameter_file(fake_launch):
    """launch_util.node: executable ``<name>_node`` of the package in /lpv_sysid, screen
    output, the shutdown budget of nodes/shell (not launch's 5 s), the parameter file in
    ``config_dir`` first and the overrides after it; no file, no overrides: no entry."""
    from lpv_sysid.nodes import shell

    L = fake_launch
    n = L.node("excitation", "excitation_node.yaml", {"mode": "phase1", "x.y": L.arg("vertex")})
    assert n.kwargs == {
        "executable": "excitation_node",
        "package": "lpv_sysid",
        "name": "excitation",
        "namespace": LaunchConfiguration("namespace"),
        "output": "screen",
        "remappings": None,
        "parameters": [
            PathJoinSubstitution([LaunchConfiguration("config_dir"), "excitation_node.yaml"]),
            {"mode": "phase1", "x.y": LaunchConfiguration("vertex")},
        ],
        "condition": None,
        "sigterm_timeout": LaunchConfiguration(
            "sigterm_timeout", default=str(shell.LAUNCH_SIGTERM_TIMEOUT_S)
        ),
    }
    assert shell.LAUNCH_SIGTERM_TIMEOUT_S > 5.0  # more than launch's own default
    assert L.node("campaign", overrides={"out_dir": "d"}).parameters == [{"out_dir": "d"}]
    assert L.node("data_logger").parameters == []
    cond = IfCondition("true")
    assert L.node("lpv_controller", "lpv_controller.yaml", condition=cond).condition is cond


@pytest.mark.parametrize(
    "fname", ["phase1.launch.py", "phase2.launch.py", "sim.launch.py", "campaign.launch.py"]
)
def test_every_launched_node_gets_the_shutdown_budget(fake_launch, fname):
    """Every node of every launch file is built by launch_util.node: the package, the
    /lpv_sysid namespace, screen output and the ``sigterm_timeout`` launch configuration."""
    from lpv_sysid.nodes import shell

    _, _, nodes = _describe(fname)
    budget = LaunchConfiguration("sigterm_timeout", default=str(shell.LAUNCH_SIGTERM_TIMEOUT_S))
    assert nodes
    nodes.pop("mavros_node", None)  # MAVROS itself: not the package's node
    for executable, n in nodes.items():
        assert n.kwargs["name"] + "_node" == executable
        assert n.kwargs["output"] == "screen" and n.kwargs["sigterm_timeout"] == budget


@pytest.mark.parametrize("fname", ["phase1.launch.py", "phase2.launch.py"])
def test_phase_launches_take_the_mavros_transport(fake_launch, fname):
    """``transport:=mavros mavros_ns:=... fcu_url:=...``: the bridge's transport and MAVROS
    namespace come from the arguments (defaults: the MAVLink transport, /mavros); MAVROS
    itself starts only with a non-empty fcu_url, in mavros_ns, with the shipped
    mavros_px4.yaml (setpoint_raw thrust_scaling 1) before the URL and target system."""
    import yaml

    order, args, nodes = _describe(fname)
    assert {a: args[a][0] for a in ["transport", *MAVROS_ARGS]} == {
        "transport": "mavlink",
        "mavros_ns": "/mavros",
        "fcu_url": "",
        "tgt_system": "1",
    }
    bridge = nodes["mavlink_bridge_node"].parameters[1]
    assert bridge["transport"] == LaunchConfiguration("transport")
    assert bridge["mavros.namespace"] == LaunchConfiguration("mavros_ns")
    m = nodes["mavros_node"]
    assert m.kwargs["package"] == "mavros" and m.kwargs["namespace"] == LaunchConfiguration(
        "mavros_ns"
    )
    assert m.parameters == [
        PathJoinSubstitution([LaunchConfiguration("config_dir"), "mavros_px4.yaml"]),
        {
            "fcu_url": LaunchConfiguration("fcu_url"),
            "tgt_system": LaunchConfiguration("tgt_system"),
        },
    ]
    assert m.condition == IfCondition(
        PythonExpression(["'", LaunchConfiguration("fcu_url"), "' != ''"])
    )
    with open(os.path.join(ROOT, "lpv_sysid", "config", "mavros_px4.yaml")) as f:
        px4 = yaml.safe_load(f)
    assert px4["/**/setpoint_raw"]["ros__parameters"]["thrust_scaling"] == 1.0
    deny = set(px4["/**"]["ros__parameters"]["plugin_denylist"])
    used = {"sys_status", "command", "setpoint_raw", "local_position", "imu", "rc_io", "param"}
    used |= {"home_position", "global_position", "gps_status", "esc_status"}  # evidence
    assert deny and not deny & used


@pytest.mark.parametrize("fname", ["phase1.launch.py", "phase2.launch.py", "campaign.launch.py"])
def test_link_url_precedence(fake_launch, fname):
    """Issue 24: ``link_url`` silently replaced ``link.url`` of ``config_dir`` (its default was
    the shipped URL). Now: the argument's default is empty and it reaches the bridge as
    ``link_url_override`` after the parameter file (launch_ros: later entries win); the
    bridge uses the file's ``link.url`` unless the argument is non-empty, and its start log
    names the source. Oracle: the shipped file's URL and a URL given here."""
    import yaml

    from lpv_sysid.flight.bridge import SPECS, BridgeRuntime
    from lpv_sysid.io import messages

    _, args, nodes = _describe(fname)
    assert args["link_url"][0] == ""
    assert "empty (default): link.url of config_dir" in args["link_url"][1]
    bridge = nodes["mavlink_bridge_node"].parameters
    assert bridge[0] == PathJoinSubstitution(
        [LaunchConfiguration("config_dir"), "mavlink_bridge_node.yaml"]
    )
    assert bridge[1]["link_url_override"] == LaunchConfiguration("link_url")
    assert "link.url" not in bridge[1]

    path = os.path.join(ROOT, "lpv_sysid", "config", "mavlink_bridge_node.yaml")
    with open(path) as f:
        body = yaml.safe_load(f)["/**/mavlink_bridge"]["ros__parameters"]

    def flat(d, prefix=""):
        out = {}
        for k, v in d.items():
            out.update(flat(v, f"{prefix}{k}.") if isinstance(v, dict) else {prefix + k: v})
        return out

    file_values = {**{n: d for n, (d, _) in SPECS.items()}, **flat(body)}
    assert file_values["link_url_override"] == ""  # the shipped file sets no override
    file_url = body["link"]["url"]
    given = "udpin:127.0.0.1:14999"
    assert given != file_url
    f = messages.MsgFactory.rosbags()
    for launch_value, want, source in (
        ("", file_url, "link.url of the parameter file"),
        (given, given, "link_url launch argument"),
    ):
        rt = BridgeRuntime(
            {**file_values, "link_url_override": launch_value}, f, "/lpv_sysid/b", 15.0, 3.0
        )
        assert rt.link is not None and rt.link.config.link.url == want
        (line,) = [t for lv, t in rt.take_log() if t.startswith("MAVLink ")]
        assert line.startswith(f"MAVLink {want} (from the {source}"), line
