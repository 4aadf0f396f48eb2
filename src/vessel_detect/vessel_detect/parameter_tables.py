"""The parameter tables of the camera, recorder and replay-detector nodes (ROS-free).

Each node declares its parameters from its table (``vessel_common.node_parameters.declare_table``); the part files
``config/parts/camera.yaml`` and ``recorder.yaml`` and the table of ``docs/parameters.md`` are written from them.
A ``live`` row may be changed with ``ros2 param set`` while the node runs (the node applies it, after the same
checks as at start); every other row is read-only: a restart with ``-p NAME:=VALUE`` changes it.
"""

from __future__ import annotations

from vessel_calib.calibration_parameters import DEFAULT_CAMERA_PARAMETERS
from vessel_common.parameter_table import Param, ParameterTable

# The topic and type names of vessel_detect.bag_topics, which this ROS-free module cannot import (a test compares them).
IMAGE_TOPIC = "/camera/image_raw/compressed"
CAMERA_FIX_TOPIC = "/camera/fix"
GPS_TRUTH_TOPIC = "/vessel/gps_truth"
OWN_SHIP_FIX_TOPIC = "/own_ship/fix"
OWN_SHIP_IMU_TOPIC = "/own_ship/imu"
DETECTION_2D_ARRAY = "vessel_msgs/msg/Detection2DArray"

IMAGE_QOS_CHOICES = ("sensor_data", "reliable")

CAMERA_TITLE = "Camera ingest node (vessel_detect camera): what to publish and how fast."
CAMERA_PARAMETERS = ParameterTable("camera", CAMERA_TITLE, (
    Param("source", "", "What to publish: rosbag2 folder, .mcap file, video file, image folder, or device:N "
          "(OpenCV camera index), /dev/videoN, rtsp://... stream."),
    Param("rate", 1.0, "Replay speed factor for recorded sources: 1.0 real time, 10.0 ten times faster, 0 = as fast "
          "as the graph consumes (next frame when the detections of the previous one arrive, or after "
          "ack_timeout_s).", value_range=(0.0, 1000.0), live=True),
    Param("loop", False, "Replay the source again and again (recorded sources)."),
    Param("loop_restamp", True, "On loops, shift stamps by the source's length so time keeps increasing; false "
          "repeats the original stamps (time jumps back: the pacing, /clock and the wait for detections start "
          "over)."),
    Param("start_offset_s", 0.0, "Start this many seconds after the source's first frame.", value_range=(0.0, 1.0e6)),
    Param("publish_compressed", True, "Publish sensor_msgs/CompressedImage (JPEG as stored; others encoded)."),
    Param("publish_raw", False, "Publish sensor_msgs/Image (bgr8); decoding costs CPU, use for in-process use."),
    Param("image_topic", IMAGE_TOPIC, "Image topic read from a bag (CompressedImage). The topics read from a bag "
          "are its names as recorded: a relative topic parameter (camera/fix) reads /camera/fix."),
    Param("compressed_topic", IMAGE_TOPIC.lstrip("/"), "Topic of the published CompressedImage."),
    Param("raw_topic", "camera/image_raw", "Topic of the published raw Image."),
    Param("image_qos", "sensor_data", "QoS of the image topics: sensor_data (best effort, keep last 5) or reliable "
          "(keep last 10; a reliable subscriber needs it).", choices=IMAGE_QOS_CHOICES),
    Param("frame_id", "camera", "frame_id of images from sources that carry none (video, folder, device)."),
    Param("jpeg_quality", 95, "JPEG quality when frames must be encoded (video, device).", value_range=(1, 100),
          live=True),
    Param("publish_clock", True, "Publish /clock from the stamps when replaying a recorded source (never for live "
          "cameras), so the graph can run with use_sim_time."),
    Param("clock_rate_hz", 50.0, "How often /clock advances between frames (wall clock), at rate > 0.",
          value_range=(1.0, 1000.0), live=True),
    Param("republish", True, "Republish the camera fix, GPS truth and own-ship topics recorded in a bag."),
    Param("camera_fix_topic", CAMERA_FIX_TOPIC.lstrip("/"), "Camera position topic (NavSatFix, latched)."),
    Param("gps_truth_topic", GPS_TRUTH_TOPIC.lstrip("/"), "Vessel GPS ground truth topic (NavSatFix)."),
    Param("own_ship_fix_topic", OWN_SHIP_FIX_TOPIC, "Position of the ship the camera is on (NavSatFix), republished "
          "from a bag that has it."),
    Param("own_ship_imu_topic", OWN_SHIP_IMU_TOPIC, "Attitude of the ship the camera is on (Imu, REP-103, frame "
          "base_link), republished from a bag that has it."),
    Param("camera_fix_from_parameters", True, "When the source has no camera fix (video, folder, device, a bag "
          "without one), publish camera.camera_lat/camera_lon once, latched."),
    Param("camera.camera_lat", DEFAULT_CAMERA_PARAMETERS["camera_lat"], "Camera latitude, WGS-84 degrees.",
          value_range=(-90.0, 90.0)),
    Param("camera.camera_lon", DEFAULT_CAMERA_PARAMETERS["camera_lon"], "Camera longitude, WGS-84 degrees.",
          value_range=(-180.0, 180.0)),
    Param("start_utc", "", "UTC of the first frame of a video or image folder without stamps in its file names "
          "(ISO-8601 or epoch seconds); empty = now."),
    Param("fps", 0.0, "Frame rate: of an image folder without stamps (default 1), forced on a video (default: its "
          "own frame times), requested from a device (0 = its default).", value_range=(0.0, 1000.0)),
    Param("device_width", 0, "Requested device image width (0 = the device's default).", value_range=(0, 10000)),
    Param("device_height", 0, "Requested device image height (0 = the device's default).", value_range=(0, 10000)),
    Param("ack_topic", "vessel/detections", "At rate 0: the detector output whose arrival releases the next frame "
          "(vessel_msgs/Detection2DArray with the image's stamp)."),
    Param("ack_type", DETECTION_2D_ARRAY, "At rate 0: message type of ack_topic, any with a header (e.g. "
          "vessel_msgs/msg/VesselTrackArray to pace on the fuser's /vessel/tracks)."),
    Param("ack_timeout_s", 2.0, "At rate 0: publish the next frame after this long without detections.",
          value_range=(0.01, 600.0), live=True),
    Param("frames_in_flight", 1, "At rate 0: frames published whose detections have not arrived yet. 1 = lock step; "
          "2 keeps the next frame waiting at the detector while it works on one, so neither the transport nor this "
          "node's turn-around idles it (give the detector images_waiting 2, else one of two images arriving before "
          "its worker takes the first is dropped).", value_range=(1, 2), live=True),
    Param("wait_for_subscribers", -1, "Before the first frame, wait until this many subscribers are matched on the "
          "image topic, so no frame is lost while the graph starts. 0 = start at once; -1 = automatic: at rate 0 "
          "wait for one image subscriber and a publisher on ack_topic (the detector), else start at once.",
          value_range=(-1, 100)),
    Param("wait_timeout_s", 30.0, "Longest wait for those subscribers; then start anyway (logged).",
          value_range=(0.0, 3600.0)),
    Param("drop_late", False, "At rate > 0, drop frames that are late by more than max_lag_s (keeps real time on a "
          "slow machine) instead of sending every frame late.", live=True),
    Param("max_lag_s", 0.5, "Lateness beyond which a frame counts as late (and is dropped with drop_late).",
          value_range=(0.0, 60.0), live=True),
    Param("max_frames", 0, "Stop after publishing this many frames (0 = the whole source), e.g. for a short demo or "
          "test.", value_range=(0, 1_000_000_000), live=True),
    Param("exit_at_end", True, "Exit (status 0) when a recorded source ends without loop; false keeps the node "
          "alive, e.g. to keep the latched camera fix available."),
    Param("end_linger_s", 1.0, "Seconds to stay up after the last frame so subscribers receive it.",
          value_range=(0.0, 60.0), live=True),
    Param("resume_file", "", "Where a recorded source's replay is, written (JSON, atomically) after every frame or "
          "message sent, so that a camera restarted after a crash (respawn) carries on after the last one it sent "
          "instead of replaying from the first frame; the latest camera fix is sent again. Used only for the same "
          "source and start time; a live camera just continues. '': none (./vessel graph --respawn and the launch "
          "file's respawn:=true give one)."),
), notes=("`source` is usually given on the command line (-p source:=bags/video_13) or by the launch file / "
          "./vessel demo.",))
"""The camera node's parameters. Live: ``rate`` (the replay paces from the next frame at the new rate; a live
camera refuses it), and what the replay reads per frame or at its end: ``jpeg_quality``, ``clock_rate_hz``,
``ack_timeout_s``, ``frames_in_flight``, ``drop_late``, ``max_lag_s``, ``max_frames``, ``end_linger_s``."""

RECORDER_DEFAULT_TOPICS = (
    "vessel/detections:vessel_msgs/msg/Detection2DArray",
    "vessel/tracks/screen:vessel_msgs/msg/VesselTrackArray",
    "vessel/tracks:vessel_msgs/msg/VesselTrackArray",
    "vessel/fix:sensor_msgs/msg/NavSatFix",
    "vessel/fixes",
    "vessel/gps_truth:sensor_msgs/msg/NavSatFix",
    "camera/fix:sensor_msgs/msg/NavSatFix",
    "/diagnostics:diagnostic_msgs/msg/DiagnosticArray",
)
"""The graph's outputs; `vessel/fixes` takes its type from the graph (it depends on the GPS publisher's mode)."""

RECORDER_PARAMETERS = ParameterTable("recorder", "Recorder node (vessel_detect recorder): writes the graph's outputs "
                                     "to a rosbag2 MCAP folder; SIGINT closes it.", (
    Param("output", "", "Bag folder to create (default: rosbag2_<UTC date-time> in the working directory)."),
    Param("topics", RECORDER_DEFAULT_TOPICS, "Topics to record, each 'name' (type from the graph) or "
          "'name:pkg/msg/Type'; a relative name is the graph's own under its namespace and is written into the "
          "bag without it (/a/vessel/fix as /vessel/fix), so a camera in any namespace can replay it."),
    Param("overwrite", False, "Replace an existing bag at 'output'."),
    Param("discovery_period_s", 0.5, "How often to look for publishers of topics not yet subscribed.",
          value_range=(0.05, 60.0)),
    Param("queue_depth", 100, "Subscription queue depth per topic.", value_range=(1, 100000)),
    Param("flush_period_s", 1.0, "Write what was received to disk this often (a recorder killed with -9 loses at "
          "most this much; `./vessel bag recover` makes its bag readable); 0: only at the end, s.",
          value_range=(0.0, 3600.0)),
    Param("resume_file", "", "Where the recorder notes the bags of its recording (JSON), so that a recorder restarted "
          "after a crash (respawn) records into the next part beside them, OUTPUT.1, OUTPUT.2, ..., instead of "
          "refusing the existing OUTPUT, which stays as it is (./vessel bag recover OUTPUT makes it readable). '': "
          "none (./vessel graph --respawn and the launch file's respawn:=true give one)."),
))
"""The recorder's parameters, all read-only: the bag, its topics and its writer are set up at start."""

REPLAY_CSV_COLUMNS = ("stamp", "x1", "y1", "x2", "y2", "score", "class_name")
"""Columns of the CSV the replay detector publishes: ``stamp`` (UNIX seconds), the box in full-resolution
pixels, ``score``, ``class_name``."""

PACE_CHOICES = ("images", "self")

REPLAY_DETECTOR_PARAMETERS = ParameterTable("detector", "Replay detector (vessel_detect replay_detector): stands in "
                                            "for the detector, publishing boxes recorded in a CSV.", (
    Param("detections_csv", "", "CSV of detections to replay (columns: " + ", ".join(REPLAY_CSV_COLUMNS) + ")"),
    Param("stamp_tolerance_s", 0.005, "largest stamp difference between an image and its CSV rows, seconds",
          value_range=(0.0, 10.0), live=True),
    Param("pace", "images", "'images': one array per received image; 'self': one array per CSV stamp, paced by "
          "ack_topic, no camera needed", choices=PACE_CHOICES),
    Param("compressed_topic", IMAGE_TOPIC.lstrip("/"), "CompressedImage topic to follow ('' to not subscribe; pace "
          "images)"),
    Param("image_topic", "", "Image topic to follow ('' to not subscribe)"),
    Param("image_qos", "sensor_data", "QoS of the image subscriptions: sensor_data (best effort) or reliable (with a "
          "camera publishing reliably, no image is lost when the replay answers faster than a detector would)",
          choices=IMAGE_QOS_CHOICES),
    Param("detections_topic", "vessel/detections", "Detection2DArray output"),
    Param("ack_topic", "vessel/tracks/screen", "pace self: the next array goes when a VesselTrackArray with the "
          "previous stamp arrives here"),
    Param("ack_timeout_s", 5.0, "pace self: or after this long, s", value_range=(0.01, 600.0), live=True),
    Param("frame_id", "camera", "pace self: header frame_id"),
    Param("wait_for_subscribers", 1, "pace self: start once this many subscribers of the detections are matched "
          "(e.g. tracker + recorder)", value_range=(0, 100), live=True),
))
"""The replay detector's parameters. It runs as ``detector`` and reads the detector's block of a shared parameter
file (its ``foreign_parameters``); this table is its own rows only, not a part file. Live: ``stamp_tolerance_s``,
``ack_timeout_s``, ``wait_for_subscribers`` (read at each image or pacing tick)."""

TABLES = (CAMERA_PARAMETERS, RECORDER_PARAMETERS, REPLAY_DETECTOR_PARAMETERS)
