"""sequencer_node (issue 24 item 4) against stand-in Trigger servers that publish the
status the real nodes publish: it starts them in the safe order."""

from lpv_sysid.flight.sequencer import RUNNING
from lpv_sysid.io import messages


def test_sequencer_node_starts_fake_nodes_in_order():
    import rclpy
    import rclpy._standin as standin
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.node import Node
    from std_srvs.srv import Trigger

    from lpv_sysid.nodes import shell
    from lpv_sysid.nodes.sequencer_node import SequencerNode

    standin.reset()
    rclpy.init(args=["n", "--ros-args", "-p", "auto_start:=true"])
    try:
        order = []
        fake = Node("fakes", namespace="lpv_sysid")
        pub = fake.create_publisher(DiagnosticArray, "status", shell.QOS_STATUS)
        fr = messages.MsgFactory.rclpy()
        values = {
            "mavlink_bridge": {"link_up": "True", "state": "IDLE"},
            "lpv_controller": {"armed": "false"},
            "excitation": {"phase": "waiting_for_start"},
        }
        started = {
            "mavlink_bridge": {"state": "OFFBOARD_ACTIVE"},
            "lpv_controller": {"armed": "true"},
            "excitation": {"phase": "playing"},
        }

        def server(node):
            def cb(req, resp):
                order.append(node)
                values[node].update(started[node])
                resp.success, resp.message = True, "ok"
                return resp

            return cb

        for node in values:
            fake.create_service(Trigger, f"{node}/start", server(node))
            fake.create_service(Trigger, f"{node}/abort", server(node))

        def publish():
            sts = [
                messages.diagnostic_status(fr, "OK", f"/lpv_sysid/{n}", "", v)
                for n, v in values.items()
            ]
            pub.publish(messages.diagnostic_array(fr, standin.now_ns(), sts))

        fake.create_timer(0.1, publish)
        seq = SequencerNode()
        standin.spin_nodes([fake, seq], 3.0)
        assert order == ["lpv_controller", "mavlink_bridge", "excitation"]
        assert seq.runtime.state == RUNNING
    finally:
        rclpy.try_shutdown()
