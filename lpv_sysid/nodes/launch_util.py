"""Launch-file helpers shared by ``launch/*.launch.py``.

The launch files are installed on their own under ``share/lpv_sysid/launch``, so what they
share lives in the package and they import it from here: the launch arguments every
experiment uses (one description each), the parameter-file lookup in ``config_dir``, whose
default is the ROS share copy of the shipped configs
(:func:`lpv_sysid.configuration.defaults.share_config_dir`), and the construction of the package's
nodes (:func:`node`: namespace, output, shutdown budget, parameter file + overrides). Needs
ROS 2 ``launch``, ``launch_ros`` and ``ament_index_python`` (imported only by the launch
files).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Optional

from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node

from lpv_sysid.configuration.defaults import PACKAGE, share_config_dir
from lpv_sysid.io.messages import NAMESPACE
from lpv_sysid.nodes.shell import LAUNCH_SIGTERM_TIMEOUT_S

#: launch argument -> description (shared by every launch file that declares it)
DESCRIPTIONS = {
    "config_dir": "directory holding the node parameter files",
    "signals_file": "signals.npz written by `lpv-sysid signals`",
    "gains_file": "gains.yaml from `lpv-sysid synthesize`",
    "vertex": "vertex body velocity (u, v, w) FRD, m/s, for this run",
    "log_dir": "experiment directory of the data logger",
    "design": "the plant the gains were designed for: virtual_actuator (ut, ua, ue, ur; bridge "
    "command attitude_rate, config lpv_controller.yaml) or rate_plant (thrust + body-rate "
    "setpoints sent as SET_ATTITUDE_TARGET, bridge command rate_setpoint, config "
    "lpv_controller_px4.yaml: PX4 >= 1.14, gains of `lpv-sysid chain` / `identify --plant "
    "px4-rate`)",
    "namespace": "ROS namespace of every node and topic (no leading slash); one per vehicle",
    "transport": "mavlink (the bridge's own MAVLink link to PX4) | mavros (MAVROS topics)",
    "link_url": "MAVLink link of the bridge: udpin:HOST:PORT, tcp:HOST:PORT, /dev/ttyAMA0; "
    "empty (default): link.url of config_dir's mavlink_bridge_node.yaml; a value wins over it "
    "(the bridge logs which one it used)",
    "auto_start": "true: the sequencer starts the nodes in order at once; false: on its "
    "start service",
    # the MAVROS transport (issue 26): MAVROS_ARGUMENTS, mavros_overrides, mavros_node
    "mavros_ns": "namespace of the MAVROS node (transport mavros)",
    "fcu_url": "non-empty: start MAVROS here with this fcu_url (PX4 SITL instance 0: "
    "udp://:14540@127.0.0.1:14580); empty: MAVROS runs elsewhere",
    "tgt_system": "MAVROS tgt_system: PX4's MAV_SYS_ID (SITL: 1 + instance)",
}
#: ``design`` launch argument values (the controller reads the design from the gains file and
#: refuses a file of neither; the argument picks the bridge command and parameter file)
DESIGNS = ("virtual_actuator", "rate_plant")

#: the MAVROS transport's launch arguments and defaults (``declare_arguments(**...)``;
#: ``transport`` is one of the per-flight arguments below)
MAVROS_ARGUMENTS = {"mavros_ns": "/mavros", "fcu_url": "", "tgt_system": "1"}

#: the defaults of the per-flight arguments: the transport of the shipped
#: config/mavlink_bridge_node.yaml; no link URL (empty: config_dir's ``link.url`` applies)
TRANSPORT_DEFAULT = "mavlink"
LINK_URL_DEFAULT = ""


def bridge_overrides(**more) -> dict:
    """The bridge's parameters chosen per flight by launch arguments (``transport``,
    ``link_url``), plus ``more``. ``link_url`` goes to the bridge's ``link_url_override``,
    not to ``link.url``: a launch file cannot leave a parameter out when an argument is
    empty, so the bridge resolves it (non-empty wins over ``link.url`` of the parameter
    file; it logs which one it used, lpv_sysid.flight.bridge.settings.link_url_source)."""
    return {"transport": arg("transport"), "link_url_override": arg("link_url"), **more}


def sequencer(steps: Any, remappings: Optional[list] = None, **more) -> Node:
    """The sequencer node (nodes/sequencer_node.py) running ``steps`` (a list, or a
    substitution giving one), on its ``start`` service or at once with ``auto_start``;
    ``more``: further parameters (``use_sim_time``)."""
    overrides = {"steps": steps, "auto_start": arg("auto_start"), **more}
    return node("sequencer", overrides=overrides, remappings=remappings)


#: marks an argument without default (``ros2 launch`` refuses to start without it)
REQUIRED = None


def declare_arguments(notes: Optional[dict[str, str]] = None, **defaults) -> list:
    """``DeclareLaunchArgument`` for ``config_dir``, ``namespace`` and then for each keyword,
    in order.

    ``config_dir`` defaults to the installed ``share/lpv_sysid/config``, ``namespace`` to
    ``lpv_sysid`` (every node of :func:`node` runs in it, so every topic is under it). A
    keyword's value is the argument's default (:data:`REQUIRED`: none); its description is
    the shared one of :data:`DESCRIPTIONS`, followed by ``" (<note>)"`` for the names in
    ``notes``.
    """
    unknown = sorted((set(defaults) | set(notes or {})) - set(DESCRIPTIONS))
    if unknown:
        raise KeyError(f"launch arguments without a description: {unknown}")
    notes = notes or {}
    out = []
    first = {"config_dir": share_config_dir(), "namespace": NAMESPACE}
    for name, default in {**first, **defaults}.items():
        description = DESCRIPTIONS[name] + (f" ({notes[name]})" if name in notes else "")
        if default is REQUIRED:
            out.append(DeclareLaunchArgument(name, description=description))
        else:
            out.append(DeclareLaunchArgument(name, default_value=default, description=description))
    return out


def arg(name: str) -> LaunchConfiguration:
    """The value of the launch argument ``name`` (a substitution, resolved at launch)."""
    return LaunchConfiguration(name)


def params(name: Any) -> PathJoinSubstitution:
    """The node parameter file ``name`` in the directory of the ``config_dir`` argument."""
    return PathJoinSubstitution([arg("config_dir"), name])


def by_design(rate_plant: str, virtual_actuator: str) -> Any:
    """``rate_plant`` when the ``design`` launch argument is ``rate_plant``, else
    ``virtual_actuator`` (a substitution, resolved at launch)."""
    from launch.substitutions import PythonExpression

    return PythonExpression(
        [f"{rate_plant!r} if '", arg("design"), f"' == 'rate_plant' else {virtual_actuator!r}"]
    )


def sigterm_timeout() -> LaunchConfiguration:
    """launch's SIGINT -> SIGTERM escalation (5 s by default) after the nodes' orderly
    shutdown: :data:`lpv_sysid.nodes.shell.LAUNCH_SIGTERM_TIMEOUT_S`; ``sigterm_timeout:=S``
    overrides it."""
    return LaunchConfiguration("sigterm_timeout", default=str(LAUNCH_SIGTERM_TIMEOUT_S))


def node(
    name: str,
    params_file: Any = None,
    overrides: Optional[Mapping[str, Any]] = None,
    condition: Any = None,
    remappings: Optional[list] = None,
) -> Node:
    """The package's node ``name`` (executable ``<name>_node``, setup.py ``NODES``) in the
    namespace of the ``namespace`` launch argument (``lpv_sysid``), logging to the screen,
    with :func:`sigterm_timeout`; ``remappings``: launch_ros remapping pairs.

    Its parameters: the file ``params_file`` in ``config_dir`` (:func:`params`; ``None``:
    none), then ``overrides`` (launch arguments through :func:`arg`). ``condition``: a launch
    condition (``IfCondition``) or ``None`` (always started).
    """
    parameters: list = [params(params_file)] if params_file is not None else []
    if overrides:
        parameters.append(dict(overrides))
    return Node(
        package=PACKAGE,
        executable=f"{name}_node",
        name=name,
        namespace=arg("namespace"),
        output="screen",
        remappings=remappings,
        sigterm_timeout=sigterm_timeout(),
        parameters=parameters,
        condition=condition,
    )


def mavros_overrides() -> dict:
    """mavlink_bridge parameters of the MAVROS arguments (:data:`MAVROS_ARGUMENTS`)."""
    return {"mavros.namespace": arg("mavros_ns")}


def mavros_node() -> Node:
    """MAVROS (``mavros_node`` of the mavros package) in ``mavros_ns``, started only when
    ``fcu_url`` is given; its ``setpoint_raw`` plugin gets ``thrust_scaling`` 1 (MAVROS 2
    ignores every non-zero AttitudeTarget thrust while it is unset) through the shipped
    ``mavros_px4.yaml`` of ``config_dir`` (which also leaves out the plugins MAVROS's own
    px4_pluginlists.yaml leaves out).

    For SITL convenience: a Ctrl-C of the launch stops MAVROS together with the bridge,
    so a hand-back that still needs MAVROS cannot be confirmed (the bridge ends FAILED and
    PX4's offboard-loss failsafe acts). On a vehicle, run MAVROS on its own and call the
    bridge's ``abort`` (or stop the phase launch) before stopping MAVROS."""
    from launch.conditions import IfCondition
    from launch.substitutions import PythonExpression

    return Node(
        package="mavros",
        executable="mavros_node",
        namespace=arg("mavros_ns"),
        output="screen",
        sigterm_timeout=sigterm_timeout(),
        parameters=[
            params("mavros_px4.yaml"),
            {"fcu_url": arg("fcu_url"), "tgt_system": arg("tgt_system")},
        ],
        condition=IfCondition(PythonExpression(["'", arg("fcu_url"), "' != ''"])),
    )
