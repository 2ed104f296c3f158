"""Test helpers of the stand-in (no rclpy equivalent): reset, simulated clock, shutdown."""

from rclpy.utilities import _reset_default_context, get_default_context


def reset():
    """Fresh default context (call before each test)."""
    import rclpy

    rclpy._global_executor = None
    rclpy.uninstall_signal_handlers()
    return _reset_default_context()


def now_ns(context=None):
    return (context or get_default_context())._standin_now_ns


def shutdown_at(seconds_from_now, context=None):
    """Shut the context down once the simulated clock has advanced this far."""
    ctx = context or get_default_context()
    ctx._standin_shutdown_at_ns = ctx._standin_now_ns + int(seconds_from_now * 1e9)


def spin_for(executor, seconds):
    """Spin an executor until the simulated clock has advanced ``seconds``."""
    ctx = executor.context
    end = ctx._standin_now_ns + int(seconds * 1e9)
    while ctx._standin_now_ns < end:
        executor.spin_once(timeout_sec=(end - ctx._standin_now_ns) / 1e9)
    # drain work that became ready exactly at the end
    while executor._ready_work() is not None:
        executor.spin_once(timeout_sec=0.0)


def find_publisher(node, topic):
    name = node.resolve_topic_name(topic)
    return next((p for p in node.publishers if p.topic_name == name), None)


def find_subscription(node, topic):
    name = node.resolve_topic_name(topic)
    return next((s for s in node.subscriptions if s.topic_name == name), None)


def spin_nodes(nodes, seconds):
    """Spin ``nodes`` together on one SingleThreadedExecutor for ``seconds`` of simulated
    time; returns the executor."""
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor()
    for n in nodes:
        ex.add_node(n)
    spin_for(ex, seconds)
    return ex


def call_trigger(client_node, server_nodes, srv_name, timeout_sec=1.0):
    """Call a std_srvs/Trigger service served by one of ``server_nodes``; the response."""
    from std_srvs.srv import Trigger

    from rclpy.executors import SingleThreadedExecutor

    cli = client_node.create_client(Trigger, srv_name)
    assert cli.wait_for_service(timeout_sec=timeout_sec)
    fut = cli.call_async(Trigger.Request())
    ex = SingleThreadedExecutor()
    for n in [client_node, *server_nodes]:
        ex.add_node(n)
    ex.spin_until_future_complete(fut, timeout_sec=timeout_sec)
    return fut.result()
