"""ROS 2 over Zenoh without a ROS install: the rmw_zenoh (Jazzy >= 0.2.4) wire format.

A ``RosContext`` turns an open Zenoh session into what ``rmw_zenoh_cpp`` would be: nodes,
publishers, subscriptions, services and clients that ``ros2 node list``, ``ros2 topic echo`` and
``ros2 service call`` see and talk to, with CDR payloads serialized by rosbags::

    from bridge.net.ros2 import RosContext, interfaces

    with RosContext(session, domain_id=0) as ros:
        node = ros.create_node("cartpole")
        pub = node.create_publisher("joint_states", "sensor_msgs/msg/JointState")
        pub.publish(cdr_bytes)
        node.create_service("~/reset", "std_srvs/srv/Trigger",
                            lambda request: interfaces.trigger_response(True, "reset"))

See docs/ros2.md for the mapping and the commands to run on a ROS 2 machine.
"""

from bridge.net.ros2.attachment import Attachment
from bridge.net.ros2.context import RosContext, session_id
from bridge.net.ros2.endpoints import MessageCallback, Publisher, RosEndpoint, Subscription
from bridge.net.ros2.node import RosNode
from bridge.net.ros2.qos import (
    DEFAULT,
    LATCHED,
    SENSOR_DATA,
    SERVICES_DEFAULT,
    Durability,
    History,
    QoS,
    Reliability,
)
from bridge.net.ros2.services import Client, Service, ServiceHandler
from bridge.net.ros2.tokens import EntityKind, Token
from bridge.net.ros2.typehash import type_hash

__all__ = [
    "DEFAULT",
    "LATCHED",
    "SENSOR_DATA",
    "SERVICES_DEFAULT",
    "Attachment",
    "Client",
    "Durability",
    "EntityKind",
    "History",
    "MessageCallback",
    "Publisher",
    "QoS",
    "Reliability",
    "RosContext",
    "RosEndpoint",
    "RosNode",
    "Service",
    "ServiceHandler",
    "Subscription",
    "Token",
    "session_id",
    "type_hash",
]
