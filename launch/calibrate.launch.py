"""Calibrate recorded bags: ``ros2 launch nao_skin calibrate.launch.py inputs:="sitting1 sitting2" out_dir:=DIR``.

Runs the calibrate node once on the inputs at start (options: config/record.yaml,
section ``calibrate``), writes DIR/calibration.yaml and the report, and keeps
publishing the calibrated skin frames on /tf_static; a calibration that fails ends the launch with exit
code 1 (the node's own line says why). Do not run it next to a
record session: that session's calibrate node already publishes the skin
frames (calibrate there with ``ros2 topic pub --once /nao_skin/calibrate ...``).
"""
from launch_ros.actions import Node

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration


def _node(context):
    from nao_skin.nodes.launch_actions import ending_the_launch, watching_the_launch
    from nao_skin.paths import config_dir
    from nao_skin.session.record import launch_namespace, launch_words

    inputs = launch_words("inputs", LaunchConfiguration("inputs").perform(context))
    # record.yaml's calibrate section is a record session's: here no live updates (no recorder runs)
    overrides = {"inputs": inputs or [""], "calibrate_on_start": True, "live": False,
                 "out_dir": LaunchConfiguration("out_dir").perform(context)}
    calibration = LaunchConfiguration("calibration").perform(context)
    if calibration:
        overrides["calibration"] = calibration
    namespace = launch_namespace(LaunchConfiguration("namespace").perform(context))    # one line for a bad one
    return ending_the_launch(Node(package="nao_skin", executable="calibrate", name="calibrate", output="screen",
                                  namespace=namespace, parameters=[str(config_dir() / "record.yaml"), overrides],
                                  additional_env=watching_the_launch()))


def generate_launch_description():
    from nao_skin.nodes.launch_actions import stopping_as_on_ctrl_c

    return LaunchDescription([
        stopping_as_on_ctrl_c(),
        DeclareLaunchArgument("inputs", description="bags (or legacy .txt), separated by spaces (quote a path"
                                                    " with a space: inputs:=\"'my sitting' sitting2\")"),
        DeclareLaunchArgument("out_dir", default_value="nao_skin_calibration", description="output directory"),
        DeclareLaunchArgument("calibration", default_value="", description="prior calibration (default: nominal)"),
        DeclareLaunchArgument("namespace", default_value="", description="the node's ROS namespace (e.g. /nao2):"
                                                                         " its topics under it, its frames prefixed"),
        OpaqueFunction(function=_node),
    ])
