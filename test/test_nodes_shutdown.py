"""Orderly shutdown of the node shells (nodes/shell.run) under SIGINT, as real rclpy does it.

Real rclpy shuts its context down inside its SIGINT handler, before ``destroy_node``, so
publishing there raises ``RCLError: Failed to publish: publisher's context is invalid``
(issue 11: the bridge died with exit 1 and its hand-back went out unconfirmed). The
stand-in now raises the same error; these tests fail on the old ``run()``.
"""

import logging
import signal

import pytest
import rclpy
import rclpy._standin as standin
from diagnostic_msgs.msg import DiagnosticArray
from rclpy._params_file import RCLError

from lpv_sysid.nodes import shell


@pytest.fixture(autouse=True)
def fresh():
    standin.reset()
    yield
    rclpy.try_shutdown()


def test_standin_publish_after_context_shutdown_raises_like_rclpy():
    rclpy.init()
    node = rclpy.create_node("p")
    pub = node.create_publisher(DiagnosticArray, "status", 10)
    pub.publish(DiagnosticArray())
    rclpy.shutdown()
    with pytest.raises(RCLError, match="context is invalid"):
        pub.publish(DiagnosticArray())


def test_standin_default_sigint_handler_shuts_context_down():
    rclpy.init()
    ctx = rclpy.get_default_context()
    assert ctx.ok()
    with pytest.raises(KeyboardInterrupt):
        signal.raise_signal(signal.SIGINT)
    assert not ctx.ok()  # rclpy's handler ran first


class _HandBack(shell.ShellNode):
    """Sends SIGINT to its own process (twice, like a terminal Ctrl-C plus launch's
    forwarded SIGINT) and needs three more spins after begin_shutdown to 'confirm'."""

    instances = []

    def __init__(self):
        super().__init__("handback_probe", [])
        self.pub = self.create_publisher(DiagnosticArray, "status", 10)
        self.ticks = 0
        self.began = 0
        self.after = 0
        self.published_in_shutdown = 0
        self.destroyed_with_context_ok = None
        self.create_timer(0.01, self.tick)
        _HandBack.instances.append(self)

    def tick(self):
        self.ticks += 1
        if self.ticks == 5:
            signal.raise_signal(signal.SIGINT)
            signal.raise_signal(signal.SIGINT)
        if self.began:
            self.after += 1

    def begin_shutdown(self):
        self.began += 1
        self.pub.publish(DiagnosticArray())  # would raise under rclpy's handler
        self.published_in_shutdown += 1

    def shutdown_complete(self):
        return self.after >= 3

    def destroy_node(self):
        self.destroyed_with_context_ok = self.context.ok()
        super().destroy_node()


def test_run_sigint_twice_hands_back_before_context_goes():
    _HandBack.instances.clear()
    previous = signal.getsignal(signal.SIGINT)
    assert shell.run(_HandBack) == 0
    node = _HandBack.instances[0]
    assert node.began == 1 and node.published_in_shutdown == 1
    assert node.after >= 3  # kept spinning until confirmed
    assert node.destroyed_with_context_ok is True  # destroyed before try_shutdown
    assert not rclpy.ok()
    assert signal.getsignal(signal.SIGINT) is previous  # handlers restored


class _NeverDone(_HandBack):
    SHUTDOWN_TIMEOUT_S = 0.2

    def shutdown_complete(self):
        return False


def test_run_bounded_when_shutdown_never_completes(caplog):
    _HandBack.instances.clear()
    with caplog.at_level(logging.ERROR):
        assert shell.run(_NeverDone) == 0
    node = _HandBack.instances[0]
    assert node.began == 1 and node.after > 0
    assert any("shutdown not complete after 0.2 s" in r.getMessage() for r in caplog.records)
