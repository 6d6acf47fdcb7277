"""ROS 2 launch file: an FMU node (real time, ROS view) and a deployed agent node.

On a ROS 2 Jazzy machine with fmu-bridge installed in the same Python environment:

    ros2 launch launch_scripts/fmu_agent.launch.py run:=runs/cartpole-ppo \\
        experiment:=examples/cartpole_balance.yaml backend:=rclpy rate:=1.0 runtime:=onnx

``backend:=rclpy`` (the default) runs both as rclpy nodes on the machine's RMW and needs no Zenoh
router: the agent opens no Zenoh session, the FMU node's own one is a peer. ``backend:=zenoh``
speaks the rmw_zenoh wire format directly: start ``ros2 run rmw_zenoh_cpp rmw_zenohd`` first, pass
``router:=tcp/127.0.0.1:7447`` and export RMW_IMPLEMENTATION=rmw_zenoh_cpp for the ros2 CLI.
``runtime`` is the agent's: torch (default), onnx or fmu (the exported policy FMU). See docs/ros2.md.

Where launch_ros is installed both are launch_ros ``Node`` actions, so a namespace pushed by an
enclosing launch file (``PushRosNamespace``), remappings and parameters reach them: ``fmu-bridge``
reads the ``--ros-args`` that ``Node`` appends. Without launch_ros they are plain processes.
"""

from typing import Any


def commands(
    run: str,
    experiment: str,
    *,
    name: str = "plant",
    backend: str = "rclpy",
    rate: str = "1.0",
    router: str = "",
    runtime: str = "torch",
) -> dict[str, list[str]]:
    """The two ``fmu-bridge`` command lines (without the program name) the launch file starts."""
    connect = ["--connect", router] if router else []
    transport = "rclpy" if backend == "rclpy" else "ros2"
    node = ["node", experiment, "--name", name, "--mode", "realtime", "--rate", rate, "--ros"]
    node += ["--ros-backend", backend, *connect]
    agent = ["agent", "run", run, "--config", experiment, "--node", name, "--transport", transport]
    agent += ["--runtime", runtime, *connect]
    return {"fmu_node": node, "fmu_agent": agent}


def _process(name: str, arguments: list[str]) -> Any:
    """A ROS node action where launch_ros exists (namespace, remaps, parameters honoured)."""
    from launch.actions import ExecuteProcess

    try:
        from launch_ros.actions import Node
    except ImportError:
        return ExecuteProcess(cmd=["fmu-bridge", *arguments], output="screen")
    return Node(executable="fmu-bridge", name=name, arguments=arguments, output="screen")


def generate_launch_description() -> Any:
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument, OpaqueFunction
    from launch.substitutions import LaunchConfiguration

    def start(context: Any) -> list[Any]:
        values = {
            key: LaunchConfiguration(key).perform(context)
            for key in ("run", "experiment", "name", "backend", "rate", "router", "runtime")
        }
        return [_process(name, arguments) for name, arguments in commands(**values).items()]

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
                "router",
                default_value="",
                description="Zenoh router (backend:=zenoh, e.g. tcp/127.0.0.1:7447); none by default",
            ),
            DeclareLaunchArgument(
                "runtime", default_value="torch", description="the agent's runtime: torch, onnx or fmu"
            ),
            OpaqueFunction(function=start),
        ]
    )
