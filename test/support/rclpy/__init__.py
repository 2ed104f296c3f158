"""In-repo stand-in for ROS 2 Jazzy ``rclpy`` used by CI (rclpy cannot be installed here).

Faithful to the Jazzy signatures of the subset the lpv_sysid node shells use; messages
are delivered in-process (publish -> serialized CDR -> subscription queue -> callback on
``spin_once``) on a simulated clock (see ``rclpy.executors``). Test helpers that have no
rclpy equivalent live in ``rclpy._standin``.
"""

from rclpy.utilities import (  # noqa: F401
    get_default_context,
    ok,
    remove_ros_args,
    shutdown,
    try_shutdown,  # noqa: F401
)

__all__ = [
    "init",
    "ok",
    "shutdown",
    "try_shutdown",
    "spin",
    "spin_once",
    "spin_until_future_complete",
    "create_node",
    "get_global_executor",
    "get_default_context",
]

_global_executor = None


from rclpy.signals import SignalHandlerOptions  # noqa: E402


def init(args=None, *, context=None, domain_id=None, signal_handler_options=None):
    context = get_default_context() if context is None else context
    context.init(args, domain_id=domain_id)
    if signal_handler_options is None:
        signal_handler_options = SignalHandlerOptions.ALL
    _install_signal_handlers(context, signal_handler_options)


_previous_handlers = {}


def _install_signal_handlers(context, options):
    """As rclpy: SIGINT/SIGTERM shut the context down (a spinning executor then raises
    ExternalShutdownException); SIGINT then chains to the previous handler, which by
    default raises KeyboardInterrupt. Restored by shutdown()/try_shutdown()."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return
    wanted = []
    if options in (SignalHandlerOptions.SIGINT, SignalHandlerOptions.ALL):
        wanted.append(signal.SIGINT)
    if options in (SignalHandlerOptions.SIGTERM, SignalHandlerOptions.ALL):
        wanted.append(signal.SIGTERM)
    for signo in wanted:
        prev = signal.getsignal(signo)

        def handler(s, frame, prev=prev):
            context.try_shutdown()
            if s == signal.SIGINT and callable(prev):
                prev(s, frame)

        _previous_handlers.setdefault(signo, prev)
        signal.signal(signo, handler)
    context.on_shutdown(uninstall_signal_handlers)


def uninstall_signal_handlers():
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return
    for signo, prev in list(_previous_handlers.items()):
        signal.signal(signo, prev if prev is not None else signal.SIG_DFL)
    _previous_handlers.clear()


def get_global_executor():
    global _global_executor
    from rclpy.executors import SingleThreadedExecutor

    if _global_executor is None or _global_executor.context is not get_default_context():
        _global_executor = SingleThreadedExecutor()
    return _global_executor


def create_node(
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
    from rclpy.node import Node

    return Node(
        node_name,
        context=context,
        cli_args=cli_args,
        namespace=namespace,
        use_global_arguments=use_global_arguments,
        enable_rosout=enable_rosout,
        start_parameter_services=start_parameter_services,
        parameter_overrides=parameter_overrides,
        allow_undeclared_parameters=allow_undeclared_parameters,
        automatically_declare_parameters_from_overrides=(
            automatically_declare_parameters_from_overrides
        ),
        enable_logger_service=enable_logger_service,
    )


def spin(node, executor=None):
    executor = get_global_executor() if executor is None else executor
    try:
        executor.add_node(node)
        while executor.context.ok():
            executor.spin_once()
    finally:
        executor.remove_node(node)


def spin_once(node, *, executor=None, timeout_sec=None):
    executor = get_global_executor() if executor is None else executor
    try:
        executor.add_node(node)
        executor.spin_once(timeout_sec=timeout_sec)
    finally:
        executor.remove_node(node)


def spin_until_future_complete(node, future, executor=None, timeout_sec=None):
    executor = get_global_executor() if executor is None else executor
    try:
        executor.add_node(node)
        executor.spin_until_future_complete(future, timeout_sec)
    finally:
        executor.remove_node(node)
