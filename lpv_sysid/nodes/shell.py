"""Shared glue of the rclpy shells: topic table, QoS, parameter descriptors, base node, main().

Imported only by ``lpv_sysid/nodes/*`` (rclpy is imported here, never in the cores).
"""

from __future__ import annotations

import math
import signal
import threading
import time
from typing import Any

import rclpy
import rclpy.logging
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (
    QoSDurabilityPolicy,
    QoSHistoryPolicy,
    QoSProfile,
    QoSReliabilityPolicy,
)
from rclpy.signals import SignalHandlerOptions

from lpv_sysid.configuration.parameters import refuse_unknown
from lpv_sysid.errors import ConfigError, LpvSysidError
from lpv_sysid.io.messages import (
    NAMESPACE,
    TF_TOPIC,
    TYPES,
    VEHICLE_RECORD_TOPIC,
    MsgFactory,
    qos_of,
    tf_from_odometry,
)

# topic (relative to the namespace) -> type: the topic table of docs/DESIGN.md (io/messages/)
TOPIC_TYPES = dict(TYPES)


def qos_profile(spec: dict) -> QoSProfile:
    """An rclpy QoSProfile from the package's declaration (io/messages/topics.py)."""
    return QoSProfile(
        history=QoSHistoryPolicy[spec["history"].upper()],
        depth=spec["depth"],
        reliability=QoSReliabilityPolicy[spec["reliability"].upper()],
        durability=QoSDurabilityPolicy[spec["durability"].upper()],
    )


#: high-rate measurement streams: best effort (a late sample is worthless); references,
#: excitation, commands: reliable; status: reliable + transient local (a late joiner sees
#: each node's last status). Declared once in io/messages/topics.py (also what a bag
#: records as the offered QoS).
QOS_SENSOR = qos_profile(qos_of("state"))
QOS_RELIABLE = qos_profile(qos_of("velocity_reference"))
QOS_STATUS = qos_profile(qos_of("status"))
#: the bridge's ``vehicle_record``: reliable, transient local, keep last 1 -- publisher and
#: subscriber alike (the logger must receive the record published before it joined)
QOS_VEHICLE_RECORD = qos_profile(qos_of(VEHICLE_RECORD_TOPIC))
#: tf2_ros's TransformBroadcaster profile (reliable, volatile, keep last 100)
QOS_TF = QoSProfile(
    history=QoSHistoryPolicy.KEEP_LAST,
    depth=100,
    reliability=QoSReliabilityPolicy.RELIABLE,
    durability=QoSDurabilityPolicy.VOLATILE,
)


def qos_for(topic: str) -> QoSProfile:
    """The QoS of the package's publishers of ``topic`` -- and of its subscriptions, but
    always volatile: a transient-local reader matches only transient-local writers (a
    status published by ``ros2 topic pub`` or another tool would never arrive)."""
    return qos_profile({**qos_of(topic), "durability": "volatile"})


#: the ROS convention for diagnostics (diagnostic_aggregator, rqt_robot_monitor read it);
#: each node's ``status`` array is published there too
DIAGNOSTICS_TOPIC = "/diagnostics"


class StatusPublisher:
    """``status`` (in the node's namespace, what the package's nodes read and record) and
    :data:`DIAGNOSTICS_TOPIC`, one DiagnosticArray to both (reliable, transient local: a
    late ``ros2 topic echo status`` still sees the node's last status)."""

    def __init__(self, node) -> None:
        self.status = node.create_publisher(DiagnosticArray, "status", QOS_STATUS)
        self.diagnostics = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, QOS_STATUS)

    def publish(self, msg) -> None:
        self.status.publish(msg)
        self.diagnostics.publish(msg)


def log_lines(logger, lines) -> None:
    """Log a runtime core's queued ``(level, text)`` lines (level ``info`` | ``warn`` |
    ``error``) with the node's ``logger`` (timestamped, on /rosout). One call site per
    severity: real rclpy keys its log context on the calling line and raises "Logger
    severity cannot be changed between calls" when one line logs two severities."""
    for level, text in lines:
        if level == "error":
            logger.error(text)
        elif level == "warn":
            logger.warning(text)
        else:
            logger.info(text)


def trigger(node, call, emit):
    """A std_srvs/Trigger callback of ``node``: ``call(now) -> (success, message, output)``
    answers the request; ``output`` goes to ``emit`` (the runtime cores' services)."""

    def cb(request, response):
        response.success, response.message, out = call(node.now())
        emit(out)
        return response

    return cb


def double(description: str, lo: float, hi: float, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(
        type=Parameter.Type.DOUBLE.value,
        description=description,
        read_only=read_only,
        floating_point_range=[
            FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)
        ],
    )


def integer(description: str, lo: int, hi: int, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(
        type=Parameter.Type.INTEGER.value,
        description=description,
        read_only=read_only,
        integer_range=[IntegerRange(from_value=int(lo), to_value=int(hi), step=1)],
    )


def typed(kind: Parameter.Type, description: str, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(type=kind.value, description=description, read_only=read_only)


def clock_source(node) -> str:
    """Which time the node clock reads (header stamps are judged against it): simulation
    time under ``use_sim_time`` (``/clock``), else the system (wall) time."""
    clock = node.get_clock()
    sim = bool(getattr(clock, "ros_time_is_active", False))
    return (
        f"node clock {clock.clock_type.name}: "
        f"{'simulation time (/clock, use_sim_time)' if sim else 'system time'}; "
        "input stamps are judged against it"
    )


def clock_kind(node) -> str:
    """``ros_sim_time`` under ``use_sim_time`` (``/clock``), else ``utc`` (the system wall
    clock, epoch ns): the kind of the node clock's stamps (io/messages ``CLOCK_KINDS``)."""
    try:
        sim = bool(node.get_parameter("use_sim_time").value)
    except Exception:  # noqa: BLE001 - a stand-in or older rclpy without the parameter
        sim = False
    return "ros_sim_time" if sim else "utc"


#: the parameters every node applies while it runs (``ros2 param set`` takes effect: the
#: status timer's period changes, :meth:`ShellNode.apply_parameters`); every other parameter
#: is declared ``read_only`` (read once at start: ``ros2 param set`` is refused, so an
#: operator never believes a setting changed when it did not)
RUNTIME_PARAMETERS = frozenset({"status_rate_hz"})
#: why a read-only parameter cannot be set
READ_ONLY_NOTE = "read-only: applied at start (restart the node to change it)"


def settings_table(settings_cls, runtime: frozenset = RUNTIME_PARAMETERS) -> list:
    """The ``[(name, default, descriptor)]`` table of :func:`declare` generated from a
    settings dataclass (:mod:`lpv_sysid.configuration.parameters`); see :func:`spec_table`."""
    from lpv_sysid.configuration.parameters import specs

    return spec_table(specs(settings_cls), runtime)


def spec_table(specs: dict, runtime: frozenset = RUNTIME_PARAMETERS) -> list:
    """``[(name, default, descriptor)]`` from ``{name: (default, ParamSpec)}``
    (:func:`lpv_sysid.configuration.parameters.specs` / ``config_specs``): type, description, the
    range (``floating_point_range`` / ``integer_range``, enforced by rclpy) and the
    remaining constraints as ``additional_constraints`` (checked by the settings or
    configuration class). A parameter not in ``runtime`` is ``read_only``. An empty array
    default is declared as an empty list of its type (see :func:`declare`)."""
    table = []
    for name, (default, spec) in specs.items():
        kind = Parameter.Type[spec.kind]
        ro = name not in runtime
        if spec.kind == "DOUBLE" and spec.lo is not None:
            d = double(spec.description, spec.lo, spec.hi, read_only=ro)
        elif spec.kind == "INTEGER" and spec.lo is not None:
            d = integer(spec.description, spec.lo, spec.hi, read_only=ro)
        else:
            d = typed(kind, spec.description, read_only=ro)
        d.additional_constraints = spec.constraints()
        if isinstance(default, tuple):
            default = list(default) if default else kind
        table.append((name, default, d))
    return table


def declare(node, table) -> dict:
    """Declare ``[(name, default, descriptor)]``; return ``{name: value}``.

    A ``Parameter.Type`` default (an array type) declares a list parameter whose default is
    empty: typed, then set to an empty list of that type unless a parameter file or ``-p``
    gave it a value (a plain ``[]`` would be typed BYTE_ARRAY by rclpy, and a params file
    cannot write one). Nothing is left uninitialized: under real rclpy one uninitialized
    parameter makes the node's ``get_parameters`` service answer with no values at all
    (``ros2 param dump`` prints ``ros__parameters: {}``).

    A read-only parameter that needs that empty list is declared writable, given the
    list, then made read-only with ``set_descriptor`` (rclpy refuses ``set_parameters`` on a
    read-only parameter, and ``set_descriptor`` runs no parameter callback).
    """
    values = {}
    for name, default, descriptor in table:
        writable = descriptor
        if descriptor.read_only and isinstance(default, Parameter.Type):
            writable = _descriptor_copy(descriptor, read_only=False)
        try:
            p = node.declare_parameter(name, default, writable)
        except (InvalidParameterValueException, InvalidParameterTypeException) as exc:
            # a -p or parameter-file value outside the declared range or of another type:
            # one named error (run(): FATAL line, exit 2), not a traceback
            raise ConfigError(f"parameter '{name}': {exc}") from None
        if p.type_ == Parameter.Type.NOT_SET:
            # no default, or a params file wrote ``name: []`` (rcl reads it as no value)
            kind = Parameter.Type(descriptor.type)
            if kind not in _ARRAY_TYPES:
                raise ConfigError(
                    f"parameter '{name}' has no value (a params file wrote [] "
                    f"for a {kind.name} parameter)"
                )
            p = Parameter(name, kind, [])
            (result,) = node.set_parameters([p])
            if not result.successful:
                raise ConfigError(f"parameter '{name}': {result.reason}")
        if writable is not descriptor:
            try:
                node.set_descriptor(name, _descriptor_copy(descriptor, read_only=True))
            except Exception as exc:  # noqa: BLE001 - rclpy versions differ here
                # still refused at run time: ShellNode's on-set callback rejects it
                node.get_logger().debug(f"parameter '{name}' left writable: {exc!r}")
        values[name] = _plain(p.value) if isinstance(default, (list, Parameter.Type)) else p.value
    # the node's parameter-file / -p values (rclpy keeps them in _parameter_overrides, no
    # public accessor): one that no declaration took, and that is none of rclpy's own
    # (use_sim_time, qos_overrides.*, ...: has_parameter), is refused by name
    given = [
        k
        for k in node._parameter_overrides
        if not node.has_parameter(k) and not k.startswith("qos_overrides.")
    ]
    refuse_unknown(given, values, node.get_fully_qualified_name())
    return values


def _plain(value):
    """A parameter value as the settings classes take it (rclpy gives arrays as
    ``array.array`` or lists)."""
    if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
        return value
    return list(value)


def _descriptor_copy(d: ParameterDescriptor, read_only: bool) -> ParameterDescriptor:
    return ParameterDescriptor(
        name=d.name,
        type=d.type,
        description=d.description,
        additional_constraints=d.additional_constraints,
        read_only=read_only,
        dynamic_typing=d.dynamic_typing,
        floating_point_range=list(d.floating_point_range),
        integer_range=list(d.integer_range),
    )


_ARRAY_TYPES = (
    Parameter.Type.DOUBLE_ARRAY,
    Parameter.Type.STRING_ARRAY,
    Parameter.Type.INTEGER_ARRAY,
    Parameter.Type.BOOL_ARRAY,
)


class ShellNode(Node):
    """Base of the node shells: ``node_name`` in ``/lpv_sysid`` unless a namespace is given
    (a ``__ns`` remap still wins), the module's parameter table declared into
    ``self.params`` (see :func:`declare`), and the node clock in seconds / nanoseconds.

    Parameters at run time: the table's writable parameters (:data:`RUNTIME_PARAMETERS`)
    are applied when set (``ros2 param set``): the new values go through the node's
    :meth:`settings_from` (the same declaration and checks as at start) and then
    :meth:`apply_parameters`; a value those refuse is rejected with their reason (an
    ``on_set_parameters`` callback), the node keeps the old one. Every other parameter is
    read-only (rclpy refuses the set: "Trying to set a read-only parameter")."""

    #: at most one "rejected" warning per input topic in this period [s]
    REJECT_LOG_PERIOD_S = 1.0
    #: the executor :func:`run` spins the node with (a class with ``add_node`` and
    #: ``spin_once(timeout_sec)``); the high-rate controller sets ``lean_executor.LeanExecutor``
    EXECUTOR: Any = SingleThreadedExecutor

    def __init__(self, node_name: str, parameters, **kwargs):
        kwargs.setdefault("namespace", NAMESPACE)
        super().__init__(node_name, **kwargs)
        self._rejected_logged_at: dict[str, float] = {}
        self.params = declare(self, parameters)
        #: the parameters applied while the node runs (the writable ones of the table)
        self.runtime_parameters = frozenset(n for n, _, d in parameters if not d.read_only)
        self._status_timer = None
        self._tf: Any = None
        self.add_on_set_parameters_callback(self._on_set_parameters)

    def enable_tf(self) -> None:
        """Publish the REP-105 transform odom -> base_link of every ``state`` message on
        ``/tf`` (``publish_tf``; see :meth:`publish_tf_of`). tf2_msgs is imported only here:
        a node without TF runs on a ROS install that lacks it."""
        from tf2_msgs.msg import TFMessage

        self._tf = (self.create_publisher(TFMessage, TF_TOPIC, QOS_TF), MsgFactory.rclpy())

    def publish_tf_of(self, topic: str, msg) -> None:
        """After publishing ``msg`` on ``topic``: its transform, when it is the state and
        TF is enabled."""
        if self._tf is not None and topic == "state":
            pub, f = self._tf
            pub.publish(tf_from_odometry(f, msg))

    def settings_from(self, values: dict):
        """The node's settings from ``{parameter: value}`` (raises a ConfigError naming the
        parameter when a value or a combination is refused); the shells whose parameters
        are one settings class set :attr:`SETTINGS` to it."""
        return self.SETTINGS.from_dict(values)

    #: the settings class of :meth:`settings_from` (a node overrides one or the other)
    SETTINGS: Any = None

    def status_timer(self, rate_hz: float, callback):
        """The node's status timer (``status_rate_hz``; its period follows the parameter),
        and the first status published now: a timer fires one period after it is created
        (10 s at 0.1 Hz), and ``status`` is transient local so that a late ``ros2 topic
        echo`` sees the node's last status -- which must exist from the start (issue 24:
        under real Jazzy a late echo otherwise waited for the first timer period)."""
        self._status_timer = self.create_timer(1.0 / rate_hz, callback)
        callback()
        return self._status_timer

    def apply_parameters(self, settings, changes: dict) -> None:
        """Make ``changes`` (validated: ``settings`` holds every value) take effect."""
        if "status_rate_hz" in changes and self._status_timer is not None:
            self._status_timer.timer_period_ns = int(round(1e9 / changes["status_rate_hz"]))

    def _on_set_parameters(self, params) -> SetParametersResult:
        # only the package's own parameters: rclpy's (use_sim_time, ...) are rclpy's business
        changes = {p.name: _plain(p.value) for p in params if p.name in self.params}
        if not changes:
            return SetParametersResult(successful=True)
        fixed = sorted(set(changes) - self.runtime_parameters)
        if fixed:  # read-only ones never get here under rclpy; undeclared ones neither
            return SetParametersResult(
                successful=False, reason=f"{', '.join(fixed)}: {READ_ONLY_NOTE}"
            )
        values = {**self.params, **changes}
        try:
            settings = self.settings_from(values)
            self.apply_parameters(settings, changes)
        except LpvSysidError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        self.params = values
        self.get_logger().info(
            "parameters applied: " + ", ".join(f"{k}={v!r}" for k, v in changes.items())
        )
        return SetParametersResult(successful=True)

    #: wall-time bound of the orderly shutdown of :func:`run` [s]
    SHUTDOWN_TIMEOUT_S = 3.0

    def begin_shutdown(self) -> None:
        """Start the node's orderly shutdown (context still valid: may publish)."""

    def shutdown_complete(self) -> bool:
        """True once the orderly shutdown needs no more spinning."""
        return True

    def shutdown_state(self) -> str:
        """What the orderly shutdown is still waiting for (logged on timeout)."""
        return "complete" if self.shutdown_complete() else "waiting"

    def context_ok(self) -> bool:
        """Whether this node may still publish (false once the context is shut down)."""
        return self.context.ok()

    def now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def now(self) -> float:
        return self.now_ns() * 1e-9

    def parse_input(self, topic: str, parse, msg):
        """``parse(msg)``; a bad message (LpvSysidError) is dropped with a warning naming
        ``topic`` (at most one per topic per :attr:`REJECT_LOG_PERIOD_S` of node time) and
        gives ``None``: one bad input never stops the node."""
        try:
            return parse(msg)
        except LpvSysidError as exc:
            # throttled per topic by hand: rclpy's throttle_duration_sec keys on the call
            # site, which is this one line for every topic of every shell
            now = self.now()
            if now - self._rejected_logged_at.get(topic, -math.inf) >= self.REJECT_LOG_PERIOD_S:
                self._rejected_logged_at[topic] = now
                self.get_logger().warning(f"{topic} rejected: {exc}")
            return None


def core_log(node):
    """``log(level, text)`` for a pure-Python core that logs as it goes (level ``info``,
    ``warn`` or ``error``): each line through :func:`log_lines` with ``node``'s logger."""
    logger = node.get_logger()
    return lambda level, text: log_lines(logger, [(level, text)])


class RuntimeShell(ShellNode):
    """A shell around a pure-Python ``self.runtime`` whose calls return ``(topic, message)``
    pairs: :meth:`publish_outputs` publishes them, in order, on ``self.pub[topic]``; the
    runtime's state is read as ``node.runtime.<name>``."""

    pub: dict

    def publish_outputs(self, outputs) -> None:
        for topic, msg in outputs:
            self.pub[topic].publish(msg)
            self.publish_tf_of(topic, msg)


class StopRequest:
    """SIGINT/SIGTERM handler that only records the request (see :func:`run`).

    Real rclpy shuts the context down inside its own SIGINT handler, before any
    ``destroy_node`` runs, so a node can no longer publish its hand-back or close its
    bag on Ctrl-C (issue 11: ``Failed to publish: publisher's context is invalid``), and a
    terminal's Ctrl-C plus launch's forwarded SIGINT raised ``KeyboardInterrupt`` inside
    rosbags' ``writer.close()``. Here a signal only sets ``requested``; repeated signals
    are counted, never raised, and the orderly shutdown of :func:`run` is bounded by
    :attr:`ShellNode.SHUTDOWN_TIMEOUT_S` (the bridge: its whole hand-back chain), below
    :data:`LAUNCH_SIGTERM_TIMEOUT_S` (launch's SIGTERM; a SIGTERM during the orderly shutdown
    is counted too, never fatal).
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.requested = False
        self.signals = 0
        self._previous: dict = {}

    def install(self) -> "StopRequest":
        if threading.current_thread() is threading.main_thread():
            for signo in self.SIGNALS:
                self._previous[signo] = signal.signal(signo, self._handler)
        return self

    def uninstall(self) -> None:
        for signo, prev in self._previous.items():
            signal.signal(signo, prev if prev is not None else signal.SIG_DFL)
        self._previous.clear()

    def _handler(self, signo, _frame) -> None:
        self.requested = True
        self.signals += 1


def run(node_factory, args=None, name: str = NAMESPACE) -> int:
    """ros2/examples minimal-node main, with an orderly shutdown that real rclpy allows.

    rclpy's own signal handlers are disabled (``SignalHandlerOptions.NO``) and
    :class:`StopRequest` records SIGINT/SIGTERM instead. On a request the node's
    :meth:`ShellNode.begin_shutdown` runs while the context is still valid (hand-back
    command, final status, bag closed), the executor keeps spinning until
    :meth:`ShellNode.shutdown_complete` (e.g. PX4's HEARTBEAT confirmed the hand-back
    mode) or :attr:`ShellNode.SHUTDOWN_TIMEOUT_S` of wall time, then the node is destroyed
    and the context shut down. An external shutdown of the context (``ros2 lifecycle``,
    another thread) skips straight to destruction. Exit status 0. Once the node is built
    it logs :data:`READY`; the launch files leave the orderly shutdown and the teardown
    :data:`LAUNCH_SIGTERM_TIMEOUT_S` before launch escalates to SIGTERM.

    Bad configuration (LpvSysidError, e.g. an invalid gains file) ends the node with one
    FATAL log line naming the problem and exit status 2.
    """
    stop = StopRequest().install()
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        node = node_factory()
        # the node class chooses its executor (the controller: lean_executor)
        executor = getattr(node, "EXECUTOR", SingleThreadedExecutor)()
        executor.add_node(node)
        node.get_logger().info(READY)
        while rclpy.ok() and not stop.requested:
            executor.spin_once(timeout_sec=SPIN_PERIOD_S)
        if rclpy.ok():
            _orderly_shutdown(node, executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except LpvSysidError as exc:
        rclpy.logging.get_logger(name).fatal(f"{name}: {exc}")
        return 2
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        stop.uninstall()
    return 0


#: executor wait per spin: how soon a recorded signal is acted upon [s]
SPIN_PERIOD_S = 0.05
#: logged by :func:`run` once the node is constructed (parameters, topics, services up)
READY = "ready (SIGINT/SIGTERM: orderly shutdown)"
#: what the launch files give every node between launch's SIGINT and its SIGTERM
#: (``sigterm_timeout``, launch's default 5 s; ``ros2 launch ... sigterm_timeout:=S``
#: overrides it): the orderly shutdown (the bridge's whole hand-back chain, 8 s worst case
#: with the shipped offboard settings; the excitation's fade) plus the process teardown,
#: which took up to 3 s on 2 cores under load 14 -- after 5 s launch's SIGTERM killed nodes
#: whose shutdown was complete (exit -15, "process has died")
LAUNCH_SIGTERM_TIMEOUT_S = 15.0
#: process teardown after the orderly shutdown, kept free of the launch budget [s]
TEARDOWN_MARGIN_S = 3.0


def _orderly_shutdown(node, executor) -> None:
    node.begin_shutdown()
    deadline = time.monotonic() + node.SHUTDOWN_TIMEOUT_S
    while rclpy.ok() and not node.shutdown_complete() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=SPIN_PERIOD_S)
    if not node.shutdown_complete():
        node.get_logger().error(
            f"shutdown not complete after {node.SHUTDOWN_TIMEOUT_S} s: {node.shutdown_state()}"
        )
