"""Networked FMU nodes over Zenoh: the wire protocol, sessions, the node, the remote plant and
the vector env over many nodes, and (``bridge.net.ros2``) the rmw_zenoh ROS 2 view.

May import the plant seam, the task and the experiment; never the env (``bridge.env``) or
recording.
"""
