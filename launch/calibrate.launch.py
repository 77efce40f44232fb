"""Calibrate recorded bags: ``ros2 launch nao_skin calibrate.launch.py inputs:="sitting1 sitting2" out_dir:=DIR``.

Runs the calibrate node once on the inputs at start (options: config/record.yaml,
section ``calibrate``, then ``params_file:=FILE``), writes DIR/calibration.yaml and the
report, and keeps publishing the calibrated skin frames on /tf_static; a calibration that
fails ends the launch with exit code 1 (the node's own line says why). ``taxels:=`` names
the robot's own taxel files, as record.launch.py's does (a bag recorded with them is
calibrated on them). Do not run it next to a record session: that session's calibrate
node already publishes the skin frames (calibrate there with
``ros2 service call /calibrate/calibrate std_srvs/srv/Trigger``).
"""
from launch_ros.actions import Node

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration

ARGUMENTS = {
    "inputs": (None, "bags (or legacy .txt), separated by spaces (quote a path with a space:"
                     " inputs:=\"'my sitting' sitting2\")"),
    "out_dir": ("nao_skin_calibration", "output directory"),
    "calibration": ("", "prior calibration (default: nominal)"),
    "taxels": ("", "the robot's own taxel files the bags were recorded with, PART=FILE separated by spaces, shell"
                   " quoting for a path with a space (default: config/nao_skin.yaml's)"),
    "fingertip": ("", "the fingertip that pressed the legacy .txt inputs' touches (the format does not say; a bag"
                      " does): NAME for every such input, or INPUT=NAME each, separated by spaces (e.g. r_finger)"),
    "namespace": ("", "the node's ROS namespace (e.g. /nao2): its topics under it, its frames prefixed"),
    "params_file": ("", "a ROS 2 parameters file for the node, applied after config/record.yaml (e.g. calibrate:"
                        " {ros__parameters: {gate_mm: 20.0}})"),
}


def _node(context):
    from nao_skin.nodes.launch_actions import ending_the_launch, watching_the_launch
    from nao_skin.session.record import calibrate_on_inputs, launch_words

    arg = {name: LaunchConfiguration(name).perform(context) for name in ARGUMENTS}
    # every argument checked before the node starts, one line for a mistake
    spec = calibrate_on_inputs(launch_words("inputs", arg["inputs"]), arg["out_dir"], calibration=arg["calibration"],
                               taxels=launch_words("taxels", arg["taxels"]), namespace=arg["namespace"],
                               params_file=arg["params_file"], fingertip=launch_words("fingertip", arg["fingertip"]))
    return ending_the_launch(Node(package=spec.package, executable=spec.executable, name=spec.name, output="screen",
                                  namespace=spec.namespace,
                                  parameters=[str(f) for f in spec.params_files] + [spec.overrides],
                                  additional_env=watching_the_launch()))


def generate_launch_description():
    from nao_skin.nodes.launch_actions import stopping_as_on_ctrl_c

    return LaunchDescription(
        [DeclareLaunchArgument(name, description=text) if default is None
         else DeclareLaunchArgument(name, default_value=default, description=text)
         for name, (default, text) in ARGUMENTS.items()]
        + [stopping_as_on_ctrl_c(), OpaqueFunction(function=_node)])
