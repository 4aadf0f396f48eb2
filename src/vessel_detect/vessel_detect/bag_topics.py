"""The names this project's bags use: topics, message types, NavSatFix constants, and the hint for a bad bag.

Plain strings and numbers, importable without ROS or rosbags.
"""

from __future__ import annotations

DEFAULT_IMAGE_TOPIC = "/camera/image_raw/compressed"
DEFAULT_CAMERA_FIX_TOPIC = "/camera/fix"
DEFAULT_GPS_TRUTH_TOPIC = "/vessel/gps_truth"
DEFAULT_OWN_SHIP_FIX_TOPIC = "/own_ship/fix"
DEFAULT_OWN_SHIP_IMU_TOPIC = "/own_ship/imu"



def in_bag(topic: str) -> str:
    """The name a node's topic has in a bag: a relative one (``camera/fix``) as if recorded without a namespace.

    A graph under a namespace records its own topics without it and replays a bag's topics into it, so a bag of
    one camera plays in any camera's graph.
    """
    return topic if not topic or topic.startswith("/") else "/" + topic


COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
IMAGE = "sensor_msgs/msg/Image"
NAV_SAT_FIX = "sensor_msgs/msg/NavSatFix"
IMU = "sensor_msgs/msg/Imu"
CLOCK = "rosgraph_msgs/msg/Clock"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
DETECTION_2D_ARRAY = "vessel_msgs/msg/Detection2DArray"
VESSEL_TRACK_ARRAY = "vessel_msgs/msg/VesselTrackArray"

# sensor_msgs/NavSatStatus and NavSatFix constants (kept here so callers need no message classes).
STATUS_NO_FIX = -1
STATUS_FIX = 0
SERVICE_GPS = 1
COVARIANCE_TYPE_UNKNOWN = 0
COVARIANCE_TYPE_APPROXIMATED = 1
COVARIANCE_TYPE_DIAGONAL_KNOWN = 2

BUILD_HINT = "rebuild it with `./vessel bag build` (or `bag_build`)"
