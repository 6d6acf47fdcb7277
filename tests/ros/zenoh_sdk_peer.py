"""A ROS 2 participant over rmw_zenoh's wire built on zenoh-ros2-sdk (PyPI), not on fmu-bridge: it lists
the graph, subscribes to an FMU node's outputs and pushes actions, and prints what it saw as JSON.

Offline: the message definitions come from the installed ROS packages (``<prefix>/share/<pkg>/msg``),
so the SDK never clones its message repositories (the test forbids git's network protocols).

    python zenoh_sdk_peer.py PORT DOMAIN NODE COUNT FORCE
"""

from __future__ import annotations

import json
import sys
import threading
import time
from pathlib import Path
from typing import Any


def main() -> None:
    port, domain, node, count, force = (
        int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], int(sys.argv[4]), float(sys.argv[5])
    )  # fmt: skip
    from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber, get_message_class
    from zenoh_ros2_sdk.discovery import get_topic_names_and_types
    from zenoh_ros2_sdk.message_registry import get_registry

    get_registry(str(Path(sys.prefix) / "share"))  # the message cache: the installed ROS packages
    where = {"domain_id": domain, "router_ip": "127.0.0.1", "router_port": port}
    topics: list[Any] = []
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and not any(t == f"/{node}/outputs" for t, _ in topics):
        topics = get_topic_names_and_types(timeout=1.0, **where)
    received: list[dict[str, Any]] = []
    lock = threading.Lock()

    def on_message(msg: Any) -> None:
        stamp = int(msg.header.stamp.sec) * 10**9 + int(msg.header.stamp.nanosec)
        with lock:
            received.append({"stamp_ns": stamp, "name": list(msg.name), "position": msg.position.tolist()})

    def wait_for(n: int) -> None:
        end = time.monotonic() + 60
        while time.monotonic() < end:
            with lock:
                if len(received) >= n:
                    return
            time.sleep(0.02)

    sub = ROS2Subscriber(f"/{node}/outputs", "sensor_msgs/msg/JointState", on_message, **where)
    wait_for(count)
    with lock:
        before = len(received)
    pub = ROS2Publisher(f"/{node}/actions", "sensor_msgs/msg/JointState", **where)
    header_type = get_message_class("std_msgs/msg/Header")
    time_type = get_message_class("builtin_interfaces/msg/Time")
    import numpy as np

    def moved() -> int | None:  # the index of the first sample with the cart moving (x_dot != 0)
        with lock:
            return next((i for i in range(before, len(received)) if received[i]["position"][1] != 0.0), None)

    # The node holds the latest action, so the same push may go again: sent until the cart moves
    # (the first ones may meet no route yet, for longer on a loaded machine), then `count` more
    end = time.monotonic() + 60
    while moved() is None and time.monotonic() < end:
        pub.publish(
            header=header_type(stamp=time_type(sec=0, nanosec=0), frame_id=""),
            name=["force"],
            position=np.array([force]),
            velocity=np.array([], dtype=np.float64),
            effort=np.array([], dtype=np.float64),
        )
        time.sleep(0.05)
    first = moved()
    wait_for((before if first is None else first) + count)
    sub.close()
    pub.close()
    with lock:
        seen = list(received)
    print(json.dumps({"topics": topics, "before": seen[:before], "after": seen[before:]}), flush=True)


if __name__ == "__main__":
    main()
