"""lpv_sysid.nodes.lean_executor under a real rclpy (issue 27): the controller's and the
bridge's executor delivers what rclpy's SingleThreadedExecutor delivers.

One process in a sourced ROS (ROS's python3, this tree on PYTHONPATH), two nodes on one
LeanExecutor: a talker publishes Int64 0..N-1 (reliable, depth N: none may be lost) and a
best-effort Int64 on a second topic; a listener takes the first topic as messages and as raw
CDR bytes, offers a Trigger service that the talker calls, runs a 100 Hz timer, and asks
the second topic reliably, so rclpy's QoS-event handler (a waitable) reports the incompatible
QoS. Skips with one line without a usable ROS 2."""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent / "support"))
from ros_real import DomainId, find_ros  # noqa: E402

SETUP, SKIP_REASON = find_ros()
pytestmark = pytest.mark.skipif(SETUP is None, reason=SKIP_REASON)
ROOT = Path(__file__).resolve().parents[1]
N = 200

SCRIPT = r"""
import json, sys, time
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rclpy.event_handler import SubscriptionEventCallbacks
from std_msgs.msg import Int64
from std_srvs.srv import Trigger
from lpv_sysid.nodes.lean_executor import LeanExecutor, HIGH_RATE_EXECUTOR

N = int(sys.argv[1])
rclpy.init()
talker = rclpy.create_node("lean_talker")
listener = rclpy.create_node("lean_listener")
got, raw, ticks, incompatible, answers = [], [], [0], [], []
rel = QoSProfile(depth=N, reliability=ReliabilityPolicy.RELIABLE)
listener.create_subscription(Int64, "numbers", lambda m: got.append(m.data), rel)
listener.create_subscription(
    Int64, "numbers", lambda b: raw.append(deserialize_message(b, Int64).data), rel, raw=True
)
listener.create_subscription(
    Int64, "best_effort", lambda m: None, rel,
    event_callbacks=SubscriptionEventCallbacks(
        incompatible_qos=lambda e: incompatible.append(e.total_count)
    ),
)
def on_trigger(req, resp):
    resp.success, resp.message = True, f"after {len(got)} numbers"
    return resp
listener.create_service(Trigger, "trigger", on_trigger)
listener.create_timer(0.01, lambda: ticks.__setitem__(0, ticks[0] + 1))
pub = talker.create_publisher(Int64, "numbers", rel)
best_effort = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
talker.create_publisher(Int64, "best_effort", best_effort)
client = talker.create_client(Trigger, "trigger")
ex = LeanExecutor()
ex.add_node(talker)
ex.add_node(listener)
end = time.monotonic() + 60.0
while time.monotonic() < end and pub.get_subscription_count() < 2:
    ex.spin_once(timeout_sec=0.05)
while time.monotonic() < end and not client.service_is_ready():
    ex.spin_once(timeout_sec=0.05)
future = client.call_async(Trigger.Request())
future.add_done_callback(lambda f: answers.append([f.result().success, f.result().message]))
for k in range(N):
    pub.publish(Int64(data=k))
    ex.spin_once(timeout_sec=0.0)
def waiting():
    return len(got) < N or len(raw) < N or not answers or not incompatible
while time.monotonic() < end and waiting():
    ex.spin_once(timeout_sec=0.05)
print(json.dumps({
    "got": got, "raw": raw, "ticks": ticks[0], "incompatible": incompatible,
    "answers": answers, "high_rate": HIGH_RATE_EXECUTOR.__name__,
}))
ex.shutdown()
talker.destroy_node()
listener.destroy_node()
rclpy.shutdown()
"""


def test_lean_executor_delivers_messages_raw_bytes_services_timers_and_qos_events(tmp_path):
    script = tmp_path / "lean.py"
    script.write_text(SCRIPT)
    dom = DomainId(os.getpid() % 50 + 13)
    try:
        cmd = (
            f"source {shlex.quote(str(SETUP))} >/dev/null && "
            f"export ROS_DOMAIN_ID={dom.value} ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST "
            f"PYTHONPATH={shlex.quote(str(ROOT))}:$PYTHONPATH && "
            f"python3 {shlex.quote(str(script))} {N}"
        )
        r = subprocess.run(["bash", "-c", cmd], capture_output=True, text=True, timeout=180)
    finally:
        dom.release()
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["got"] == list(range(N))  # every message, in order (reliable, depth N)
    assert out["raw"] == list(range(N))  # the raw subscription: the same numbers from CDR
    # the service answered once, the client's done callback ran
    assert len(out["answers"]) == 1 and out["answers"][0][0] is True
    assert out["answers"][0][1].startswith("after ")
    assert out["incompatible"] and out["incompatible"][0] >= 1  # a QoS event (waitable)
    assert out["ticks"] >= 1  # the timer ran
    assert out["high_rate"] == "LeanExecutor"  # a real rclpy: the nodes' choice is the lean one
