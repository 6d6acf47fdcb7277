"""ROS 2 launch file: an FMU node (real time, ROS view) and a deployed agent node.

On a ROS 2 Jazzy machine with fmu-bridge installed in the same Python environment:

    ros2 launch launch_scripts/fmu_agent.launch.py run:=runs/cartpole-ppo \\
        experiment:=examples/cartpole_balance.yaml backend:=rclpy rate:=1.0

``backend:=rclpy`` runs both as rclpy nodes on the machine's RMW; ``backend:=zenoh`` speaks the
rmw_zenoh wire format directly (then start ``ros2 run rmw_zenoh_cpp rmw_zenohd`` first and export
RMW_IMPLEMENTATION=rmw_zenoh_cpp for the ros2 CLI). See docs/ros2.md.

Where launch_ros is installed both are launch_ros ``Node`` actions, so a namespace pushed by an
enclosing launch file (``PushRosNamespace``), remappings and parameters reach them: ``fmu-bridge``
reads the ``--ros-args`` that ``Node`` appends. Without launch_ros they are plain processes.
"""

from typing import Any

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, ExecuteProcess
from launch.substitutions import LaunchConfiguration, PythonExpression


def _process(name: str, arguments: list[Any]) -> Any:
    """A ROS node action where launch_ros exists (namespace, remaps, parameters honoured)."""
    try:
        from launch_ros.actions import Node
    except ImportError:
        return ExecuteProcess(cmd=["fmu-bridge", *arguments], output="screen")
    return Node(executable="fmu-bridge", name=name, arguments=arguments, output="screen")


def generate_launch_description() -> LaunchDescription:
    run = LaunchConfiguration("run")
    experiment = LaunchConfiguration("experiment")
    name = LaunchConfiguration("name")
    backend = LaunchConfiguration("backend")
    rate = LaunchConfiguration("rate")
    router = LaunchConfiguration("router")
    transport = PythonExpression(["'rclpy' if '", backend, "' == 'rclpy' else 'ros2'"])
    return LaunchDescription(
        [
            DeclareLaunchArgument("run", description="run directory or model .zip from fmu-bridge train"),
            DeclareLaunchArgument("experiment", description="the experiment YAML the agent was trained on"),
            DeclareLaunchArgument("name", default_value="plant", description="FMU node name (ROS namespace)"),
            DeclareLaunchArgument("backend", default_value="rclpy", description="rclpy or zenoh"),
            DeclareLaunchArgument(
                "rate", default_value="1.0", description="real-time factor of the FMU node"
            ),
            DeclareLaunchArgument(
                "router", default_value="tcp/127.0.0.1:7447", description="Zenoh router endpoint"
            ),
            _process(
                "fmu_node",
                [
                    "node",
                    experiment,
                    "--name",
                    name,
                    "--mode",
                    "realtime",
                    "--rate",
                    rate,
                    "--ros",
                    "--ros-backend",
                    backend,
                    "--connect",
                    router,
                ],
            ),
            _process(
                "fmu_agent",
                [
                    "agent",
                    "run",
                    run,
                    "--config",
                    experiment,
                    "--node",
                    name,
                    "--transport",
                    transport,
                    "--connect",
                    router,
                ],
            ),
        ]
    )
