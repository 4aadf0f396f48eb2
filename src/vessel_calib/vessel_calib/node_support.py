"""What every node of the project shares: start-up and shutdown, parameters, QoS, health reporting.

This is the only module of ``vessel_calib`` that imports rclpy; the cores stay ROS-free. Nodes use it so that
they all behave the same way: parameters declared with descriptors, a clean exit (status 0, no traceback) on
SIGINT, problems logged once per kind, counted and published on ``/diagnostics``, and configuration errors
that stop the node at start with one clear line.
"""

from __future__ import annotations

import math
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

from vessel_calib.errors import VesselError

SENSOR_DATA_QOS = qos_profile_sensor_data
"""Best effort, keep last 5: images and other high-rate data where the newest sample matters most."""

LATCHED_QOS = QoSProfile(
    depth=1,
    history=HistoryPolicy.KEEP_LAST,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
"""Reliable and transient local: a late subscriber still gets the last sample (e.g. the camera's fix)."""


def image_qos_profile(name: str, reliable_depth: int = 5) -> QoSProfile:
    """The QoS of image topics named by an ``image_qos`` parameter: ``sensor_data`` or ``reliable``.

    ``reliable_depth``: the history kept when reliable (a publisher keeps more, so a slow reader can catch up).
    """
    if name == "sensor_data":
        return SENSOR_DATA_QOS
    if name == "reliable":
        return reliable_qos(reliable_depth)
    raise VesselError(f"image_qos '{name}' unknown: use sensor_data or reliable")


def reliable_qos(depth: int = 10) -> QoSProfile:
    """Reliable, volatile, keep last ``depth``: detections, tracks and fixes, where no message may be lost."""
    return QoSProfile(
        depth=depth,
        history=HistoryPolicy.KEEP_LAST,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )


def stamp_to_sec(stamp: Time) -> float:
    """Seconds since the epoch of a ``builtin_interfaces/Time``."""
    return stamp.sec + stamp.nanosec * 1e-9


def sec_to_stamp(seconds: float) -> Time:
    """A ``builtin_interfaces/Time`` for seconds since the epoch (rounded to the nanosecond)."""
    total_ns = round(seconds * 1e9)
    return Time(sec=total_ns // 1_000_000_000, nanosec=total_ns % 1_000_000_000)


def declare_parameter(
    node: Node,
    name: str,
    default: Any,
    description: str,
    *,
    read_only: bool = False,
    float_range: tuple[float, float] | None = None,
    int_range: tuple[int, int] | None = None,
    additional_constraints: str = "",
) -> Any:
    """Declare one parameter with a descriptor and return its value.

    Ranges are enforced by ROS when the parameter is set at start (``--params-file``, ``-p``) or later.
    """
    descriptor = ParameterDescriptor(
        description=description,
        read_only=read_only,
        additional_constraints=additional_constraints,
    )
    if float_range is not None:
        descriptor.floating_point_range = [
            FloatingPointRange(from_value=float(float_range[0]), to_value=float(float_range[1]), step=0.0)
        ]
    if int_range is not None:
        descriptor.integer_range = [
            IntegerRange(from_value=int(int_range[0]), to_value=int(int_range[1]), step=0)
        ]
    return node.declare_parameter(name, default, descriptor).value


CAMERA_PARAMETER_DESCRIPTIONS: dict[str, str] = {
    "camera_lat": "Camera latitude, WGS-84 degrees.",
    "camera_lon": "Camera longitude, WGS-84 degrees.",
    "image_width": "Image width in pixels the calibration was made for.",
    "image_height": "Image height in pixels the calibration was made for.",
    "H": "Homography, 9 numbers row-major: z_p (x_p, y_p, 1) = H (x_w, y_w, 1), world in metres east/north.",
    "K1": "Radial distortion term about the centre: x_s = x_c + (x_p - x_c)(1 + K1 r_p^2).",
    "center_x": "Distortion centre x, pixels.",
    "center_y": "Distortion centre y, pixels.",
    "heading_deg": "Camera heading implied by H, degrees from north (informational; checked against H).",
    "box_anchor": "Point of a vessel's box that H maps to its position: horizontal centre, this share of the way "
                  "down (0 top, 0.5 centre as in the paper, 1 bottom); written by calibrate.",
    "water_level_m": "Water level (in the datum of the fuser's water_level.file) that H belongs to; NaN: calibrated "
                     "without the tide (calibrate --water-level writes it).",
    "height_m": "Camera height above the water at water_level_m, m; NaN: derived from H (calibrate writes it).",
}


DEFAULT_CAMERA_PARAMETERS: dict[str, Any] = {
    "camera_lat": 32.70297,
    "camera_lon": -117.234631,
    "image_width": 1280,
    "image_height": 720,
    "H": [-441.0, 379.0, -1000.0, -217.0, -56.5, -548.0, -0.512, -0.144, 1.0],
    "K1": -4.053e-07,
    "center_x": 640.0,
    "center_y": 360.0,
    "heading_deg": 76.475,
    "box_anchor": 0.5,
    "water_level_m": math.nan,
    "height_m": math.nan,
}
"""The challenge camera, the paper's calibration with its sign typo corrected (see aitas/camera.json)."""


def declare_camera_model(node: Node, prefix: str = "camera"):
    """Declare the ``camera.*`` calibration parameters and build the camera model from them.

    Defaults are the paper's corrected calibration of the challenge camera, so nodes work on the challenge
    data without a calibration file. A calibration that cannot be used raises ``CalibrationError`` naming the
    key; nodes let it stop them at start (``run_node`` prints it as one line).
    """
    from vessel_calib.camera_model import CameraModel

    values = {}
    for key, default in DEFAULT_CAMERA_PARAMETERS.items():
        description = CAMERA_PARAMETER_DESCRIPTIONS.get(key, f"Camera calibration value '{key}'.")
        values[key] = declare_parameter(node, f"{prefix}.{key}", default, description, read_only=True)
    return CameraModel.from_params(values)


#: Diagnostics key prefix of ``NodeHealth.watch_subscribers``: ``matched_subscribers./vessel/tracks`` = "3".
MATCHED_SUBSCRIBERS = "matched_subscribers."


def matched_subscribers(array) -> dict[str, int]:
    """Subscriptions matched by each topic's publisher, from a ``DiagnosticArray`` of ``NodeHealth`` nodes."""
    found: dict[str, int] = {}
    for status in array.status:
        for item in status.values:
            if item.key.startswith(MATCHED_SUBSCRIBERS) and item.value.isdigit():
                found[item.key[len(MATCHED_SUBSCRIBERS):]] = int(item.value)
    return found


class NodeHealth:
    """Counts a node's problems, logs each kind once, and publishes them on ``/diagnostics``.

    A running node never dies on bad input: it calls ``problem(kind, message)``, which logs the first
    occurrence of that kind as a warning (later ones at debug level), counts every occurrence, and reports the
    counts with the node's own figures (``set_value``) once a second.
    """

    def __init__(self, node: Node, hardware_id: str = "camera", period_s: float = 1.0):
        self._node = node
        self._hardware_id = hardware_id
        self._counts: dict[str, int] = {}
        self._values: dict[str, str] = {}
        self._messages: dict[str, str] = {}
        self._status_level = DiagnosticStatus.OK
        self._status_message = "running"
        self._lock = threading.Lock()
        self._watched: list = []
        self._publisher = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._timer = node.create_timer(period_s, self.publish)

    def watch_subscribers(self, *publishers) -> None:
        """Report how many subscriptions each publisher has matched (``matched_subscribers.<topic>``).

        Seen from the publisher's own side: a subscriber that other nodes already see may not be matched to this
        publisher yet, and what is published before the match is lost (reliable QoS covers matched readers only).
        A supervisor (``./vessel demo``) waits on these before it starts the source.
        """
        self._watched.extend(p for p in publishers if p is not None)

    @property
    def counts(self) -> dict[str, int]:
        """A copy of the problem counters by kind."""
        with self._lock:
            return dict(self._counts)

    def problem(self, kind: str, message: str) -> None:
        """Record one problem of a kind: logged the first time, counted always."""
        with self._lock:
            count = self._counts.get(kind, 0) + 1
            self._counts[kind] = count
            self._messages[kind] = message
        if count == 1:
            self._node.get_logger().warning(f"{message} (counted as '{kind}' on /diagnostics; logged once)")
        else:
            self._node.get_logger().debug(f"{message} ({kind} #{count})")

    def count(self, kind: str, amount: int = 1) -> None:
        """Count an event that needs no log line (e.g. frames processed)."""
        with self._lock:
            self._counts[kind] = self._counts.get(kind, 0) + amount

    def set_value(self, key: str, value: Any) -> None:
        """Report a figure (latency, frames sent, progress) in the next diagnostics message."""
        if isinstance(value, float):
            value = f"{value:.6g}" if math.isfinite(value) else str(value)
        with self._lock:
            self._values[key] = str(value)

    def set_status(self, level: bytes, message: str) -> None:
        """Set the overall level (``DiagnosticStatus.OK/WARN/ERROR/STALE``) and its message."""
        with self._lock:
            self._status_level = level
            self._status_message = message

    def publish(self) -> None:
        """Publish the current status, figures and problem counts."""
        status = DiagnosticStatus()
        status.name = f"{self._node.get_name()}"
        status.hardware_id = self._hardware_id
        with self._lock:
            level = self._status_level
            message = self._status_message
            counts = sorted(self._counts.items())
            values = sorted(self._values.items())
            problem_kinds = set(self._messages)
        if problem_kinds and level == DiagnosticStatus.OK:
            level = DiagnosticStatus.WARN
            message = f"{message}; problems: " + ", ".join(f"{k}={v}" for k, v in counts if k in problem_kinds)
        status.level = level
        status.message = message
        values += [(f"{MATCHED_SUBSCRIBERS}{p.topic_name}", str(p.get_subscription_count())) for p in self._watched]
        status.values = [KeyValue(key=k, value=v) for k, v in values]
        status.values += [KeyValue(key=f"count.{k}", value=str(v)) for k, v in counts]
        array = DiagnosticArray()
        array.header.stamp = self._node.get_clock().now().to_msg()
        array.status = [status]
        self._publisher.publish(array)


def _ignore_late_sigint() -> None:
    """Ignore SIGINT once the exit status is decided.

    A supervisor stopping the graph while this node already leaves (e.g. the camera at the end of a bag) must not
    turn a clean exit into death by signal.
    """
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def run_node(
    node_factory: Callable[[], Node],
    args: Sequence[str] | None = None,
    *,
    threads: int = 1,
) -> int:
    """Run a node until SIGINT or shutdown, the same way for every executable of the project.

    Returns the process exit status: 0 after SIGINT or a node that finished its work, 2 when the node could
    not start because of a ``VesselError`` (printed as one ``error:`` line naming the problem and the fix).
    """
    try:
        rclpy.init(args=args)
    except RuntimeError as error:  # rclpy's RCLError: malformed --ros-args
        print(f"error: cannot start: {error}. Check the --ros-args part of the command line "
              "(e.g. -p name:=value, --params-file FILE).", file=sys.stderr)
        return 2
    node = None
    status = 0
    try:
        node = node_factory()
        executor = MultiThreadedExecutor(num_threads=threads) if threads > 1 else SingleThreadedExecutor()
        executor.add_node(node)
        while rclpy.ok() and not getattr(node, "finished", False):
            executor.spin_once(timeout_sec=0.1)
        status = int(getattr(node, "exit_status", 0))
    except VesselError as error:
        print(f"error: {error}", file=sys.stderr)
        status = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        status = 0
    finally:
        _ignore_late_sigint()
        if node is not None:
            try:
                close = getattr(node, "close", None)
                if close is not None:
                    close()
                node.destroy_node()
            except Exception as error:
                print(f"warning: while shutting down: {error}", file=sys.stderr)
        if rclpy.ok():
            rclpy.try_shutdown()
        _ignore_late_sigint()  # again: shutting rclpy down puts back the handler it replaced at init
    return status


def main_for(node_class: type[Node], threads: int = 1) -> Callable[[], None]:
    """Make the console-script entry point of a node class; a node module ends with one such line."""

    def main(args: Sequence[str] | None = None) -> None:
        sys.exit(run_node(node_class, args if args is not None else sys.argv, threads=threads))

    return main


def wait_for(predicate: Callable[[], bool], timeout_s: float, node: Node | None = None) -> bool:
    """Poll ``predicate`` (spinning ``node`` if given) until it is true or ``timeout_s`` passes."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        if node is not None:
            rclpy.spin_once(node, timeout_sec=0.05)
        else:
            time.sleep(0.05)
    return predicate()
