"""Every topic of ours, and the QoS of the latched ones: the nodes, bench-live and the tests read them here.

The skin and joint topics (``/skin/<part>/taxels``, ``/skin/<part>/contacts``,
``/joint_states``, as a bag names them) are the messages' format: :mod:`nao_skin.formats.pointcloud`;
the nodes use them in their namespace (:func:`relative`).

Names are relative, so a session started in a namespace (``namespace:=/nao2``) has its own topics and a
second robot can record on the same ROS domain; outside a namespace they are the absolute names
(``/nao_skin/calibrate``). /tf_static and /diagnostics stay global, as ROS has them: the frames a node
in a namespace publishes carry the namespace as a prefix instead (:func:`frame_prefix`, what
robot_state_publisher's ``frame_prefix`` does).
"""
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

REQUEST_TOPIC = "nao_skin/calibrate"                  # std_msgs/String: bags to calibrate (empty: the node's)
STATUS_TOPIC = "nao_skin/calibration/status"          # std_msgs/String JSON, latched
GUIDANCE_TOPIC = "nao_skin/guidance"                  # std_msgs/String JSON, latched
GUIDANCE_MARKERS_TOPIC = "nao_skin/guidance/markers"  # visualization_msgs/MarkerArray, latched
HEATMAP_TOPIC = "nao_skin/heatmap"                    # visualization_msgs/MarkerArray
UNCERTAINTY_TOPIC = "nao_skin/calibration/uncertainty"  # visualization_msgs/MarkerArray, latched
PROGRESS_TOPIC = "nao_skin/recorder/progress"         # std_msgs/String JSON
SIM_STATUS_TOPIC = "sim_robot/status"                 # std_msgs/String JSON
BRIDGE_STATUS_TOPIC = "skin/bridge_status"            # std_msgs/String JSON
TF_STATIC_TOPIC = "/tf_static"                         # tf2_msgs/TFMessage, latched
# a node says the first of the malformed messages it skips on a topic, not every one of a stream of them
MAX_SKIPPED_SAID = 5

#: how deep the sensor streams (joint states, skin taxels and contacts) are kept at both ends, publisher and
#: recorder: what a recorder held up for seconds (a busy machine, a slow disk, a stopped process) was sent
#: meanwhile waits there until it runs again, 10 s of joint states at 100 Hz (docs/decisions.md, "A recorder
#: held up for seconds")
STREAM_DEPTH = 1000

#: a latched topic (as tf2_ros' StaticTransformBroadcaster publishes /tf_static): a subscriber with the
#: same QoS, joining at any time, gets the last message
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
DIAGNOSTICS_TOPIC = "/diagnostics"                     # diagnostic_msgs/DiagnosticArray, one status per node, 1 Hz


def relative(topic: str) -> str:
    """A topic of the messages' format (``/joint_states``, ``/skin/<part>/taxels``: how a bag names them) as
    a node of ours subscribes or publishes it: in its namespace."""
    return topic.lstrip("/")


def frame_prefix(node) -> str:
    """What the node's TF frames and markers are prefixed with: its namespace (``/nao2`` -> ``nao2/``), none
    outside a namespace."""
    namespace = node.get_namespace().strip("/")
    return f"{namespace}/" if namespace else ""
