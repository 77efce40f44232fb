"""Every topic of ours, and the QoS of the latched ones: the nodes, bench-live and the tests read them here.

The skin and joint topics (``/skin/<part>/taxels``, ``/skin/<part>/contacts``,
``/joint_states``) are the messages' format: :mod:`nao_skin.formats.pointcloud`.
"""
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

REQUEST_TOPIC = "/nao_skin/calibrate"                  # std_msgs/String: bags to calibrate (empty: the node's)
STATUS_TOPIC = "/nao_skin/calibration/status"          # std_msgs/String JSON, latched
GUIDANCE_TOPIC = "/nao_skin/guidance"                  # std_msgs/String JSON, latched
GUIDANCE_MARKERS_TOPIC = "/nao_skin/guidance/markers"  # visualization_msgs/MarkerArray, latched
HEATMAP_TOPIC = "/nao_skin/heatmap"                    # visualization_msgs/MarkerArray
PROGRESS_TOPIC = "/nao_skin/recorder/progress"         # std_msgs/String JSON
SIM_STATUS_TOPIC = "/sim_robot/status"                 # std_msgs/String JSON
BRIDGE_STATUS_TOPIC = "/skin/bridge_status"            # std_msgs/String JSON
TF_STATIC_TOPIC = "/tf_static"                         # tf2_msgs/TFMessage, latched
# a node says the first of the malformed messages it skips on a topic, not every one of a stream of them
MAX_SKIPPED_SAID = 5

#: a latched topic (as tf2_ros' StaticTransformBroadcaster publishes /tf_static): a subscriber with the
#: same QoS, joining at any time, gets the last message
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
DIAGNOSTICS_TOPIC = "/diagnostics"                     # diagnostic_msgs/DiagnosticArray, one status per node, 1 Hz
