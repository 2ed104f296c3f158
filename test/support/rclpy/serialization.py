"""Stand-in for ``rclpy.serialization``: CDR via the rosbags typestore."""

import _rosmsg_standin as _msgs


def serialize_message(message):
    if not hasattr(message, "_lpv_typename"):
        raise TypeError(f"Expected a ROS message, got {type(message)}")
    return _msgs.serialize(message)


def deserialize_message(serialized_message, message_type):
    return _msgs.deserialize(serialized_message, message_type)
