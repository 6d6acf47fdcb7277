"""Networked FMU nodes over Zenoh: the wire protocol, sessions, the node, the remote plant and
the vector env over many nodes, and (``bridge.net.ros2``) the rmw_zenoh ROS 2 view.

A node serves a plant (a :class:`bridge.plant.spec.PlantSpec`) and the names it serves (a
:class:`bridge.net.served.Served`); building them from an experiment or a system file is
composition above the network (``bridge.serving``). May import plants and the experiment; never
the task (``bridge.task``), ``bridge.serving``, the env (``bridge.env``) or recording.
"""
