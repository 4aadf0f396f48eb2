"""Replay a bag through the camera node (its own process) and count what a subscriber here receives.

Prints the frames in the bag, the frames received with their original stamps, whether /clock followed the
stamps, and the wall time against the bag's duration / rate. Needs the built workspace.

    ./vessel replay-check bags/video_13 --rate 10
"""

from __future__ import annotations

import argparse
import os
import random
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from vessel_common.command_line import command_line_tool
from vessel_common.errors import VesselError
from vessel_common.paths import repo_root
from vessel_common.qos import image_qos_profile
from vessel_detect import bag_messages, bag_reader, bag_topics


def check(bag: Path, rate: float, image_qos: str = "sensor_data", timeout_s: float | None = None) -> dict:
    """Run the replay and return the figures (see the module docstring)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    with bag_reader.BagReader(bag) as reader:
        expected = [bag_messages.sec_to_ns(t) for t, _ in reader.images()]
    if not expected:
        raise VesselError(f"{bag} has no images")
    domain_id = random.randint(1, 100)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = rclpy.create_node("replay_check", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    heard = _subscribe(node, image_qos)
    started = time.monotonic()
    process = _start_camera(bag, rate, image_qos, domain_id)
    span_s = (expected[-1] - expected[0]) / 1e9
    limit = timeout_s or (span_s / rate + 60.0 if rate > 0 else 600.0)
    try:
        while process.poll() is None and time.monotonic() - started < limit:
            executor.spin_once(timeout_sec=0.02)
        for _ in range(20):
            executor.spin_once(timeout_sec=0.01)
    finally:
        if process.poll() is None:
            process.kill()
        output = process.communicate()[0]
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
    received, arrival, clock = heard.received, heard.arrival, heard.clock
    return {
        "bag": str(bag),
        "rate": rate,
        "frames_in_bag": len(expected),
        "frames_received": len(received),
        "stamps_identical": received == expected,
        "clock_messages": len(clock),
        "clock_monotonic": clock == sorted(clock),
        "clock_hits_every_stamp": set(expected) <= set(clock),
        "bag_span_s": span_s,
        "replay_span_s": (arrival[-1] - arrival[0]) if len(arrival) > 1 else 0.0,
        "camera_exit_status": process.returncode,
        "camera_summary": next((ln for ln in output.splitlines() if "ended:" in ln), output.strip()[-300:]),
    }


@dataclass
class _Heard:
    """What the subscriber here received: image stamps (ns) with their arrival times, and /clock stamps (ns)."""

    received: list[int] = field(default_factory=list)
    arrival: list[float] = field(default_factory=list)
    clock: list[int] = field(default_factory=list)


def _subscribe(node, image_qos: str) -> _Heard:
    """Subscribe ``node`` to the camera's images and to /clock; what they bring in."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import CompressedImage

    heard = _Heard()

    def on_image(message) -> None:
        heard.received.append(message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec)
        heard.arrival.append(time.monotonic())

    node.create_subscription(CompressedImage, bag_topics.DEFAULT_IMAGE_TOPIC, on_image,
                             image_qos_profile(image_qos, reliable_depth=10))
    node.create_subscription(
        Clock, "/clock", lambda m: heard.clock.append(m.clock.sec * 1_000_000_000 + m.clock.nanosec),
        QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE),
    )
    return heard


def _start_camera(bag: Path, rate: float, image_qos: str, domain_id: int) -> subprocess.Popen:
    """The installed camera node replaying ``bag`` at ``rate`` on ``domain_id``, its output captured."""
    exe = repo_root() / "ros2_ws/install/vessel_detect/lib/vessel_detect/camera"
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    return subprocess.Popen(
        [str(exe), "--ros-args", "-p", f"source:={bag}", "-p", f"rate:={rate}", "-p", "wait_for_subscribers:=1",
         "-p", f"image_qos:={image_qos}", "-p", "end_linger_s:=0.5"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )


@command_line_tool
def main(argv: list[str] | None = None) -> int:
    """Command line: print the figures of one or more replays."""
    parser = argparse.ArgumentParser(prog="./vessel replay-check", description=__doc__.splitlines()[0])
    parser.add_argument("bags", type=Path, nargs="+")
    parser.add_argument("--rate", type=float, action="append", help="rate factor(s) (default 10)")
    parser.add_argument("--image-qos", default="sensor_data", choices=["sensor_data", "reliable"])
    args = parser.parse_args(argv)
    for bag in args.bags:
        for rate in args.rate or [10.0]:
            figures = check(bag, rate, args.image_qos)
            print(" ".join(f"{k}={v:.2f}" if isinstance(v, float) else f"{k}={v}" for k, v in figures.items()
                           if k != "camera_summary"))
            print(f"  camera: {figures['camera_summary']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
