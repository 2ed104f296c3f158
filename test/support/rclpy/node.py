"""Stand-in for ``rclpy.node.Node`` (ROS 2 Jazzy signatures and parameter semantics)."""

import math
import re
import warnings

import _rosmsg_standin as _msgs
from rcl_interfaces.msg import ParameterDescriptor, ParameterType, SetParametersResult

from rclpy._params_file import load_overrides, parse_ros_args, read
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.client import Client
from rclpy.clock import ROSClock
from rclpy.exceptions import (
    InvalidNamespaceException,
    InvalidNodeNameException,
    InvalidParameterException,
    InvalidParameterTypeException,
    InvalidParameterValueException,
    InvalidServiceNameException,
    InvalidTopicNameException,
    NoTypeSupportImportedException,
    ParameterAlreadyDeclaredException,
    ParameterImmutableException,
    ParameterNotDeclaredException,
    ParameterUninitializedException,
)
from rclpy.impl.rcutils_logger import RcutilsLogger
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import (
    DurabilityPolicy,
    QoSCompatibility,
    QoSProfile,
    qos_check_compatible,
    qos_profile_services_default,
)
from rclpy.service import Service
from rclpy.subscription import Subscription
from rclpy.timer import Timer
from rclpy.utilities import get_default_context

_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
_NODE_RX = re.compile(_TOKEN + r"\Z")
_NS_RX = re.compile(r"/(" + _TOKEN + r"(/" + _TOKEN + r")*)?\Z")
_NAME_RX = re.compile(r"(/" + _TOKEN + r")+\Z")
_PARAM_RX = re.compile(r"[A-Za-z_][A-Za-z0-9_./]*\Z")


def _first_bad(name, allowed=r"[A-Za-z0-9_/~{}]"):
    for i, c in enumerate(name):
        if not re.match(allowed, c):
            return i
    return 0


def validate_parameter_name(name):
    if not name or not _PARAM_RX.match(name) or ".." in name or name.endswith("."):
        raise InvalidParameterException(name)


class Node:
    PARAM_REL_TOL = 1e-6

    def __init__(
        self,
        node_name,
        *,
        context=None,
        cli_args=None,
        namespace=None,
        use_global_arguments=True,
        enable_rosout=True,
        start_parameter_services=True,
        parameter_overrides=None,
        allow_undeclared_parameters=False,
        automatically_declare_parameters_from_overrides=False,
        enable_logger_service=False,
    ):
        self._context = get_default_context() if context is None else context
        self._context._check_ok()
        remaps, files, params = [], [], []
        if use_global_arguments:
            r, f, p = self._context._global_ros_args
            remaps += r
            files += f
            params += p
        r, f, p = parse_ros_args(cli_args)
        remaps += r
        files += f
        params += p
        for src, dst in remaps:
            if src == "__node":
                node_name = dst
            elif src == "__ns":
                namespace = dst
        if not node_name or not _NODE_RX.match(node_name):
            raise InvalidNodeNameException(
                node_name,
                "node name must not be empty and contain only alphanumerics and "
                "underscores, not starting with a number",
                _first_bad(node_name, r"[A-Za-z0-9_]"),
            )
        namespace = namespace or "/"
        if not namespace.startswith("/"):
            namespace = "/" + namespace
        if not _NS_RX.match(namespace):
            raise InvalidNamespaceException(namespace, "namespace is invalid", 0)
        self._name = node_name
        self._namespace = namespace
        self._remaps = [(s, d) for s, d in remaps if not s.startswith("__")]
        self._logger = RcutilsLogger(
            ".".join([t for t in namespace.split("/") if t] + [node_name])
        )
        self._clock = ROSClock(_context=self._context)
        self._allow_undeclared_parameters = allow_undeclared_parameters
        self._parameters = {}
        self._descriptors = {}
        self._pre_set_parameters_callbacks = []
        self._on_set_parameters_callbacks = []
        self._post_set_parameters_callbacks = []
        self.publishers, self.subscriptions, self.timers = [], [], []
        self.services, self.clients, self.guards, self.waitables = [], [], [], []
        self._default_callback_group = MutuallyExclusiveCallbackGroup()
        self._parameter_overrides = {}
        fqn = self.get_fully_qualified_name().lstrip("/")
        for path in files:
            for prm in load_overrides(read(path), fqn):
                self._parameter_overrides[prm.name] = prm
        for prm in params:
            self._parameter_overrides[prm.name] = prm
        if parameter_overrides is not None:
            self._parameter_overrides.update({p.name: p for p in parameter_overrides})
        self._destroyed = False
        self._context._standin_nodes.append(self)
        self.declare_parameter("use_sim_time", False)
        if automatically_declare_parameters_from_overrides:
            self._parameters.update(
                {k: v for k, v in self._parameter_overrides.items() if k not in self._parameters}
            )
            for k in self._parameter_overrides:
                self._descriptors.setdefault(k, ParameterDescriptor(name=k, dynamic_typing=True))

    # -- identity ---------------------------------------------------------------------
    @property
    def context(self):
        return self._context

    @property
    def default_callback_group(self):
        return self._default_callback_group

    @property
    def executor(self):
        return getattr(self, "_executor", None)

    def get_name(self):
        return self._name

    def get_namespace(self):
        return self._namespace

    def get_fully_qualified_name(self):
        return self._namespace.rstrip("/") + "/" + self._name

    def get_logger(self):
        return self._logger

    def get_clock(self):
        return self._clock

    def resolve_topic_name(self, topic, *, only_expand=False):
        return self._expand(topic, InvalidTopicNameException, only_expand)

    def resolve_service_name(self, service, *, only_expand=False):
        return self._expand(service, InvalidServiceNameException, only_expand)

    def _expand(self, name, exc, only_expand=False):
        if not isinstance(name, str) or not name:
            raise exc(name, "topic name must not be empty", 0)
        fqn = self.get_fully_qualified_name()
        if name == "~":
            full = fqn
        elif name.startswith("~/"):
            full = fqn + name[1:]
        elif name.startswith("/"):
            full = name
        else:
            full = self._namespace.rstrip("/") + "/" + name
        if not only_expand:
            for src, dst in self._remaps:
                if self._expand(src, exc, True) == full:
                    full = self._expand(dst, exc, True)
                    break
        if not _NAME_RX.match(full):
            raise exc(
                name,
                "must not contain characters other than alphanumerics, '_', '~', "
                "'{', or '}', must not end with '/', tokens must not start with a number",
                _first_bad(name),
            )
        return full

    # -- parameters -------------------------------------------------------------------
    def declare_parameter(self, name, value=None, descriptor=None, ignore_override=False):
        if value is None and descriptor is None:
            args = (name,)
        else:
            descriptor = ParameterDescriptor() if descriptor is None else descriptor
            args = (name, value, descriptor)
        return self.declare_parameters("", [args], ignore_override)[0]

    def declare_parameters(self, namespace, parameters, ignore_override=False):
        parameter_list = []
        descriptors = {}
        for index, parameter_tuple in enumerate(parameters):
            if len(parameter_tuple) < 1 or len(parameter_tuple) > 3:
                raise TypeError(
                    f"Invalid parameter tuple length at index {index} in parameters list: "
                    f"{parameter_tuple}; expecting length between 1 and 3"
                )
            value = None
            name = parameter_tuple[0]
            if not isinstance(name, str):
                raise TypeError(
                    f"First element {name} at index {index} in parameters list is not a str."
                )
            if namespace:
                name = f"{namespace}.{name}"
            validate_parameter_name(name)
            second_arg = parameter_tuple[1] if 1 < len(parameter_tuple) else None
            descriptor = parameter_tuple[2] if 2 < len(parameter_tuple) else ParameterDescriptor()
            if not isinstance(descriptor, ParameterDescriptor):
                raise TypeError(
                    f"Third element {descriptor} at index {index} in parameters "
                    "list is not a ParameterDescriptor."
                )
            if len(parameter_tuple) == 1:
                warnings.warn(
                    f"when declaring parameter named '{name}', declaring a parameter "
                    "only providing its name is deprecated."
                )
                descriptor.dynamic_typing = True
            if isinstance(second_arg, Parameter.Type):
                if second_arg == Parameter.Type.NOT_SET:
                    raise ValueError(
                        f"Cannot declare parameter {{{name}}} as statically typed of type NOT_SET"
                    )
                if descriptor.dynamic_typing is True:
                    raise ValueError(
                        f"When declaring parameter {{{name}}} passing a descriptor with"
                        "`dynamic_typing=True` is not allowed when the parameter type is provided"
                    )
                descriptor.type = second_arg.value
            else:
                value = second_arg
                if not descriptor.dynamic_typing:
                    descriptor.type = Parameter.Type.from_parameter_value(value).value
                    if descriptor.type == ParameterType.PARAMETER_NOT_SET:
                        raise ValueError(
                            "Cannot declare a statically typed parameter with "
                            "default value of type PARAMETER_NOT_SET"
                        )
            if not ignore_override and name in self._parameter_overrides:
                value = self._parameter_overrides[name].value
            parameter_list.append(Parameter(name, value=value))
            descriptors[name] = descriptor
        already = [p.name for p in parameter_list if p.name in self._parameters]
        if any(already):
            raise ParameterAlreadyDeclaredException(already)
        for param in parameter_list:
            result = self._set_one(param, descriptors, allow_not_set_type=True, declaring=True)
            if not result.successful:
                if result.reason.startswith("Wrong parameter type"):
                    raise InvalidParameterTypeException(
                        param, Parameter.Type(descriptors[param.name].type).name
                    )
                raise InvalidParameterValueException(param.name, param.value, result.reason)
        return [self._parameters[p.name] for p in parameter_list]

    def undeclare_parameter(self, name):
        if not self.has_parameter(name):
            raise ParameterNotDeclaredException(name)
        if self._descriptors[name].read_only:
            raise ParameterImmutableException(name)
        del self._parameters[name]
        del self._descriptors[name]

    def has_parameter(self, name):
        return name in self._parameters

    def get_parameter(self, name):
        if self.has_parameter(name):
            p = self._parameters[name]
            if p.type_ != Parameter.Type.NOT_SET or self._descriptors[name].dynamic_typing:
                return p
            raise ParameterUninitializedException(name)
        if self._allow_undeclared_parameters:
            return Parameter(name, Parameter.Type.NOT_SET, None)
        raise ParameterNotDeclaredException(name)

    def get_parameters(self, names):
        if not all(isinstance(n, str) for n in names):
            raise TypeError("All names must be instances of type str")
        return [self.get_parameter(n) for n in names]

    def get_parameter_or(self, name, alternative_value=None):
        if alternative_value is None:
            alternative_value = Parameter(name, Parameter.Type.NOT_SET)
        if not self.has_parameter(name) or self._parameters[name].type_ == Parameter.Type.NOT_SET:
            return alternative_value
        return self._parameters[name]

    def get_parameters_by_prefix(self, prefix):
        prefix = prefix + "." if prefix else ""
        return {k[len(prefix) :]: v for k, v in self._parameters.items() if k.startswith(prefix)}

    def describe_parameter(self, name):
        try:
            return self._descriptors[name]
        except KeyError:
            if self._allow_undeclared_parameters:
                return ParameterDescriptor()
            raise ParameterNotDeclaredException(name) from None

    def describe_parameters(self, names):
        return [self.describe_parameter(n) for n in names]

    def set_descriptor(self, name, descriptor, alternative_value=None):
        if not self.has_parameter(name):
            raise ParameterNotDeclaredException(name)
        if self._descriptors[name].read_only:
            raise ParameterImmutableException(name)
        # rclpy: the current value must satisfy the new descriptor (no callbacks run)
        if not self._check(self._parameters[name], descriptor, False).successful:
            raise InvalidParameterValueException(name, self._parameters[name].value, "descriptor")
        descriptor.name = name
        self._descriptors[name] = descriptor
        return self.get_parameter(name).get_parameter_value()

    def set_parameters(self, parameter_list):
        results = []
        for param in parameter_list:
            if not isinstance(param, Parameter):
                raise TypeError("parameter must be instance of type '{}'".format(repr(Parameter)))
            if param.name not in self._parameters and not self._allow_undeclared_parameters:
                raise ParameterNotDeclaredException(param.name)
            results.append(self._set_one(param, None))
        return results

    def set_parameters_atomically(self, parameter_list):
        for p in parameter_list:
            if p.name not in self._parameters and not self._allow_undeclared_parameters:
                raise ParameterNotDeclaredException(p.name)
        for p in parameter_list:
            r = self._check(p, self._descriptors.get(p.name), False)
            if not r.successful:
                return r
        for cb in self._on_set_parameters_callbacks:
            r = cb(list(parameter_list))
            if not r.successful:
                return r
        for p in parameter_list:
            self._parameters[p.name] = p
        for cb in self._post_set_parameters_callbacks:
            cb(list(parameter_list))
        return SetParametersResult(successful=True)

    def _check(self, param, descriptor, allow_not_set_type):
        if descriptor is None:
            return SetParametersResult(successful=True)
        if descriptor.dynamic_typing:
            descriptor.type = param.type_.value
        elif descriptor.type != param.type_.value and not (
            allow_not_set_type and param.type_ == Parameter.Type.NOT_SET
        ):
            return SetParametersResult(
                successful=False,
                reason=f"Wrong parameter type, expected '{Parameter.Type(descriptor.type)}' "
                f"got '{param.type_}'",
            )
        if param.type_ == Parameter.Type.INTEGER and descriptor.integer_range:
            rng = descriptor.integer_range[0]
            if not rng.from_value <= param.value <= rng.to_value:
                return SetParametersResult(
                    successful=False,
                    reason=f"Parameter {param.name} out of range. Min: {rng.from_value}, "
                    f"Max: {rng.to_value}, value: {param.value}",
                )
            if (
                rng.step != 0
                and (param.value - rng.from_value) % rng.step != 0
                and param.value != rng.to_value
            ):
                return SetParametersResult(
                    successful=False,
                    reason=f"The parameter value ({param.value}) is not close enough to a "
                    f"valid step. Min: {rng.from_value}, Max: {rng.to_value}, "
                    f"step: {rng.step}",
                )
        if param.type_ == Parameter.Type.DOUBLE and descriptor.floating_point_range:
            rng = descriptor.floating_point_range[0]
            v = param.value
            tol = self.PARAM_REL_TOL
            edge = math.isclose(v, rng.from_value, rel_tol=tol) or math.isclose(
                v, rng.to_value, rel_tol=tol
            )
            if not edge and not rng.from_value <= v <= rng.to_value:
                return SetParametersResult(
                    successful=False,
                    reason=f"Parameter {param.name} out of range. Min: {rng.from_value}, "
                    f"Max: {rng.to_value}, value: {v}",
                )
            if not edge and rng.step != 0.0:
                k = round((v - rng.from_value) / rng.step)
                if not math.isclose(rng.from_value + k * rng.step, v, rel_tol=tol):
                    return SetParametersResult(
                        successful=False,
                        reason=f"The parameter value ({v}) is not close enough to a valid "
                        f"step. Min: {rng.from_value}, Max: {rng.to_value}, "
                        f"step: {rng.step}",
                    )
        return SetParametersResult(successful=True)

    def _set_one(self, param, descriptors, allow_not_set_type=False, declaring=False):
        if not declaring:
            for cb in self._pre_set_parameters_callbacks:
                modified = cb([param])
                if not modified:
                    return SetParametersResult(
                        successful=False,
                        reason="parameter list cannot be empty, this might be due to "
                        "pre_set_parameters_callback modifying the original parameters "
                        "list.",
                    )
                param = modified[0]
        if descriptors is not None:
            descriptor = descriptors[param.name]
        else:
            descriptor = self._descriptors.get(param.name)
            if descriptor is not None and descriptor.read_only:
                return SetParametersResult(
                    successful=False, reason=f"Trying to set a read-only parameter: {param.name}."
                )
        result = self._check(param, descriptor, allow_not_set_type)
        if not result.successful:
            return result
        for cb in self._on_set_parameters_callbacks:
            result = cb([param])
            if not result.successful:
                return result
        if descriptor is not None:
            descriptor.name = param.name
            self._descriptors[param.name] = descriptor
        elif param.name not in self._descriptors:
            self._descriptors[param.name] = ParameterDescriptor(
                name=param.name, type=param.type_.value, dynamic_typing=True
            )
        if param.type_ == Parameter.Type.NOT_SET and not declaring:
            self._parameters.pop(param.name, None)
        else:
            self._parameters[param.name] = param
        for cb in self._post_set_parameters_callbacks:
            cb([param])
        return SetParametersResult(successful=True)

    def add_pre_set_parameters_callback(self, callback):
        self._pre_set_parameters_callbacks.insert(0, callback)

    def add_on_set_parameters_callback(self, callback):
        self._on_set_parameters_callbacks.insert(0, callback)
        return callback

    def add_post_set_parameters_callback(self, callback):
        self._post_set_parameters_callbacks.insert(0, callback)

    def remove_pre_set_parameters_callback(self, callback):
        self._pre_set_parameters_callbacks.remove(callback)

    def remove_on_set_parameters_callback(self, callback):
        self._on_set_parameters_callbacks.remove(callback)

    def remove_post_set_parameters_callback(self, callback):
        self._post_set_parameters_callbacks.remove(callback)

    # -- entities ---------------------------------------------------------------------
    def _qos(self, qos_profile):
        if isinstance(qos_profile, QoSProfile):
            return qos_profile
        if isinstance(qos_profile, int):
            return QoSProfile(depth=qos_profile)
        raise TypeError("Expected QoSProfile or int, but received {!r}".format(type(qos_profile)))

    def create_publisher(
        self,
        msg_type,
        topic,
        qos_profile,
        *,
        callback_group=None,
        event_callbacks=None,
        qos_overriding_options=None,
        publisher_class=Publisher,
    ):
        qos = self._qos(qos_profile)
        if not _msgs.is_message_class(msg_type):
            raise NoTypeSupportImportedException()
        name = self.resolve_topic_name(topic)
        pub = publisher_class(self, msg_type, name, qos, event_callbacks=event_callbacks)
        self.publishers.append(pub)
        for sub in self._context._standin_entities("subscriptions"):
            self._standin_match(pub, sub)
        return pub

    def create_subscription(
        self,
        msg_type,
        topic,
        callback,
        qos_profile,
        *,
        callback_group=None,
        event_callbacks=None,
        qos_overriding_options=None,
        raw=False,
    ):
        qos = self._qos(qos_profile)
        if not _msgs.is_message_class(msg_type):
            raise NoTypeSupportImportedException()
        name = self.resolve_topic_name(topic)
        sub = Subscription(
            self,
            msg_type,
            name,
            callback,
            callback_group or self._default_callback_group,
            qos,
            raw=raw,
            event_callbacks=event_callbacks,
        )
        self.subscriptions.append(sub)
        for pub in self._context._standin_entities("publishers"):
            # DDS: only a transient-local reader receives a transient-local writer's history
            late_joiner = sub.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
            if late_joiner and self._standin_match(pub, sub) and pub._latched:
                for data in pub._latched:
                    sub._standin_enqueue(data)
        return sub

    def _standin_match(self, pub, sub):
        if pub.topic_name != sub.topic_name:
            return False
        if pub.msg_type._lpv_typename != sub.msg_type._lpv_typename:
            self._logger.warning(
                f"stand-in: topic '{pub.topic_name}' has publisher type "
                f"{pub.msg_type._lpv_typename} and subscription type "
                f"{sub.msg_type._lpv_typename}; they do not communicate"
            )
            return False
        comp, reason = qos_check_compatible(pub.qos_profile, sub.qos_profile)
        if comp == QoSCompatibility.ERROR:
            self._logger.warning(
                f"New publisher discovered on topic '{pub.topic_name}', offering incompatible "
                f"QoS. No messages will be received from it. {reason}"
            )
            return False
        return True

    def create_timer(
        self, timer_period_sec, callback, callback_group=None, clock=None, autostart=True
    ):
        period_ns = int(float(timer_period_sec) * 1e9)
        timer = Timer(
            callback,
            callback_group or self._default_callback_group,
            period_ns,
            clock or self._clock,
            context=self._context,
            autostart=autostart,
        )
        self.timers.append(timer)
        return timer

    def create_service(
        self,
        srv_type,
        srv_name,
        callback,
        *,
        qos_profile=qos_profile_services_default,
        callback_group=None,
    ):
        if not _msgs.is_service_class(srv_type):
            raise NoTypeSupportImportedException()
        name = self.resolve_service_name(srv_name)
        if any(s.service_name == name for s in self._context._standin_entities("services")):
            self._logger.warning(
                f"stand-in: a second server for service '{name}': with real "
                "DDS every server answers and the client takes the first"
            )
        srv = Service(
            self,
            srv_type,
            name,
            callback,
            callback_group or self._default_callback_group,
            qos_profile,
        )
        self.services.append(srv)
        return srv

    def create_client(
        self, srv_type, srv_name, *, qos_profile=qos_profile_services_default, callback_group=None
    ):
        if not _msgs.is_service_class(srv_type):
            raise NoTypeSupportImportedException()
        name = self.resolve_service_name(srv_name)
        cli = Client(
            self, srv_type, name, qos_profile, callback_group or self._default_callback_group
        )
        self.clients.append(cli)
        return cli

    @staticmethod
    def _standin_remove(entities, entity):
        """Drop ``entity`` from this node's list; whether it was there (rclpy's bool)."""
        if entity in entities:
            entities.remove(entity)
            return True
        return False

    def destroy_publisher(self, publisher):
        if self._standin_remove(self.publishers, publisher):
            publisher._destroyed = True
            return True
        return False

    def destroy_subscription(self, subscription):
        return self._standin_remove(self.subscriptions, subscription)

    def destroy_timer(self, timer):
        if self._standin_remove(self.timers, timer):
            timer.destroy()
            return True
        return False

    def destroy_service(self, service):
        return self._standin_remove(self.services, service)

    def destroy_client(self, client):
        return self._standin_remove(self.clients, client)

    def destroy_node(self):
        for pub in list(self.publishers):
            self.destroy_publisher(pub)
        self.subscriptions.clear()
        for t in list(self.timers):
            self.destroy_timer(t)
        self.services.clear()
        self.clients.clear()
        if self in self._context._standin_nodes:
            self._context._standin_nodes.remove(self)
        self._destroyed = True

    # -- graph ------------------------------------------------------------------------
    def get_topic_names_and_types(self, no_demangle=False):
        topics = {}
        for e in list(self._context._standin_entities("publishers")) + list(
            self._context._standin_entities("subscriptions")
        ):
            topics.setdefault(e.topic_name, set()).add(e.msg_type._lpv_typename)
        return sorted((k, sorted(v)) for k, v in topics.items())

    def get_service_names_and_types(self):
        return sorted(
            (s.service_name, [s.srv_type._lpv_typename])
            for s in self._context._standin_entities("services")
        )

    def get_node_names(self):
        return [n.get_name() for n in self._context._standin_nodes]

    def count_publishers(self, topic_name):
        name = self.resolve_topic_name(topic_name)
        return sum(
            1 for p in self._context._standin_entities("publishers") if p.topic_name == name
        )

    def count_subscribers(self, topic_name):
        name = self.resolve_topic_name(topic_name)
        return sum(
            1 for s in self._context._standin_entities("subscriptions") if s.topic_name == name
        )
