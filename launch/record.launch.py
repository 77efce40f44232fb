"""Record self-touch: ``ros2 launch nao_skin record.launch.py [robot:=sim|nao] [nao_ip:=...] [rviz:=true]``.

Starts (the same set as ``nao-skin record``, from nao_skin.session.record):

* robot:=sim (default): sim_robot, the simulated robot on the live topics;
  robot:=nao: naoqi_bridge (unless naoqi:=false, e.g. naoqi_driver2 already
  publishes /joint_states) and yarp_skin_bridge (events_port:=...);
  guided:=true: the simulated robot follows the guidance;
* pairing_recorder writing the touch bag ``bag:=DIR`` (default
  ./nao_skin_touches_<date>_<time>), skin_heatmap, and the calibrate node;
* robot_state_publisher with the xacro URDF *without* skin frames, and
  rviz2 with config/nao_skin.rviz when rviz:=true;
* continue_from:="BAG ...": the session continues earlier sittings' bags (the
  calibrate node and the heat-map count their touches too);
* namespace:=/nao2: every node in that namespace, TF frames prefixed with it
  (a second robot on the same ROS domain);
* seed:=N (robot:=sim): the simulated robot's seed; continuing earlier sittings it
  plays one none of them played unless given one (the same seed plays the same touches);
* scene:=r_finger-torso,r_hand-torso: the scenes recorded (the simulated robot plays them;
  the recorder takes the fingertip scenes' touches, the heat-map shows their fingertips);
* capture:=true (robot:=nao): fingertip_capture presses the robot's fingertip on the torso
  through NAOqi, the recorder takes those touches; capture:=dry only plans (RViz markers);
* params_file:=FILE: a ROS 2 parameters file for the nodes, after config/record.yaml
  and config/bridges.yaml (checked before any node starts, as they are).

A launch ended by SIGTERM or SIGHUP stops its nodes as Ctrl-C does, and the nodes stop by
themselves when the launch is gone (a SIGKILL): the bag is closed, the calibration written.

A nao_skin node that ends ends the session (exit code 1 when it failed, after its own line saying why);
robot_state_publisher and rviz2 are left out, with a line, where they are not installed (as
``nao-skin record`` does).

Skin frames have exactly one publisher: the calibrate node publishes the
current calibration (``calibration:=FILE``, nominal by default) on
/tf_static and replaces it after each calibration
(``ros2 service call /calibrate/calibrate std_srvs/srv/Trigger`` calibrates on this
session's bag and answers with the result). robot_state_publisher gets
``skin_frames:=false``, so the two never disagree about a frame.
Parameters: config/record.yaml and config/bridges.yaml, then params_file:=.
"""
import sys

from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration

ARGUMENTS = {
    "robot": ("sim", "sim: simulated robot; nao: the real Nao through NAOqi and YARP"),
    "nao_ip": ("", "robot address for naoqi_bridge (default: config/bridges.yaml)"),
    "naoqi": ("true", "start naoqi_bridge (false when another driver publishes /joint_states)"),
    "events_port": ("", "skinManager's skin events port (default: config/bridges.yaml)"),
    "bag": ("", "touch bag directory to write (default: ./nao_skin_touches_<date>_<time>)"),
    "calibration": ("", "calibration to start from (default: the nominal skin)"),
    "continue_from": ("", "bags of earlier sittings of this capture, separated by spaces (shell quoting for a path"
                          " with a space): the live calibration and guidance cover their touches too"),
    "rviz": ("false", "start rviz2 with config/nao_skin.rviz"),
    "taxels": ("", "the robot's own taxel files, PART=FILE separated by spaces, shell quoting for a path with a"
                   " space (default: config/nao_skin.yaml's)"),
    "guided": ("false", "robot:=sim: the simulated robot's next touches follow /nao_skin/guidance"),
    "capture": ("false", "fingertip capture: true: the robot presses its fingertip on the torso by itself"
                         " (robot:=nao, through NAOqi); dry: only the planned approaches in RViz; false: none"),
    "namespace": ("", "every node in this ROS namespace (e.g. /nao2): topics under it, TF frames prefixed with it, so"
                      " a second robot records on the same ROS domain"),
    "seed": ("", "robot:=sim: the simulated robot's seed, the same seed plays the same touches (default:"
                 " config/record.yaml's; continuing earlier sittings, one none of them played)"),
    "scene": ("", "the scenes recorded, HAND-PART separated by commas: self-touch pairs (r_hand-torso) and fingertip"
                  " scenes (r_finger-torso); the simulated robot plays them, the recorder takes the fingertip"
                  " scenes' touches (default: the simulated robot's preset, self-touches only)"),
    "params_file": ("", "a ROS 2 parameters file for the nodes, applied after config/record.yaml and"
                        " config/bridges.yaml (e.g. calibrate: {ros__parameters: {gate_mm: 20.0}})"),
}


def _nodes(context):
    from nao_skin.nodes.launch_actions import ending_the_launch, installed, watching_the_launch
    from nao_skin.session.claim import claim_domain
    from nao_skin.session.record import check_needs, launch_flag, launch_words, record_session, robot_description

    arg = {name: LaunchConfiguration(name).perform(context) for name in ARGUMENTS}
    flag = {name: launch_flag(name, arg[name]) for name in ("naoqi", "rviz", "guided")}
    specs = record_session(arg["robot"], nao_ip=arg["nao_ip"], naoqi=flag["naoqi"],
                           events_port=arg["events_port"], bag_path=arg["bag"], calibration=arg["calibration"],
                           rviz=flag["rviz"], taxels=launch_words("taxels", arg["taxels"]),
                           guided=flag["guided"], continue_from=launch_words("continue_from", arg["continue_from"]),
                           namespace=arg["namespace"], params_file=arg["params_file"], seed=arg["seed"],
                           scene=arg["scene"], capture=arg["capture"],
                           say=lambda line: print(f"record.launch.py: {line}", file=sys.stderr))
    check_needs(specs)    # e.g. robot:=nao without YARP's Python bindings: one line before any node starts
    # one session per ROS domain and namespace on this machine (two would record each other's touches): held as long as the
    # launch context (the launch process) lives
    claim = claim_domain(namespace=specs[0].namespace, spelling="launch")
    if claim.problem:
        print(f"record.launch.py: {claim.problem}", file=sys.stderr)
    context.extend_globals({"nao_skin_domain_claim": claim})
    actions = []
    for spec in specs:
        if spec.optional and not installed(spec.package):
            print(f"record.launch.py: {spec.package} is not installed: the session runs without it", file=sys.stderr)
            continue
        overrides = {}
        for key, value in spec.overrides.items():
            if isinstance(value, tuple) and value and value[0] == "__urdf__":
                value = ParameterValue(robot_description(value[1], skin_frames=False), value_type=str)
            overrides[key] = value
        parameters = [str(f) for f in spec.params_files] + ([overrides] if overrides else [])
        node = Node(package=spec.package, executable=spec.executable, name=spec.name, namespace=spec.namespace,
                    parameters=parameters, arguments=list(spec.arguments), output="screen",
                    additional_env=watching_the_launch() if spec.ours else None)
        actions += ending_the_launch(node) if spec.ours else [node]
    return actions


def generate_launch_description():
    from nao_skin.nodes.launch_actions import stopping_as_on_ctrl_c

    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=text)
         for name, (default, text) in ARGUMENTS.items()]
        + [stopping_as_on_ctrl_c(), OpaqueFunction(function=_nodes)])
