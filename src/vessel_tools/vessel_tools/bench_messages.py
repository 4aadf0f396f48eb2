"""``./vessel bench messages``: a track array through rclpy's message conversion and through ``vessel_common.wire``.

The tracker, the fuser and the GPS publisher each take and give a ``VesselTrackArray`` per image; at a camera's
frame rate, with tens of tracks, turning those into Python objects and back costs them more than their own work.
This measures, in one process and in alternating rounds, what one array costs each way: rclpy's
``deserialize_message``/``serialize_message`` (what a plain subscription and ``publish`` of a message object do)
against the wire codec the nodes use. The arrays are filled as the fuser publishes them (every field set, NaN
where a value is unknown).

    ./vessel bench messages [--tracks 10,40,80] [--rounds 5] [--out FILE.json]
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from vessel_common.command_line import command_line_tool
from vessel_common.errors import DataError
from vessel_tools.bench_report import machine_info, print_and_save

ARRAY_TYPE = "vessel_msgs/msg/VesselTrackArray"


def track_array(count: int, seed: int = 0):
    """An rclpy ``VesselTrackArray`` of ``count`` tracks with every field set, as the fuser fills them."""
    from vessel_msgs.msg import VesselTrack, VesselTrackArray

    rng = np.random.default_rng(seed)
    array = VesselTrackArray()
    array.header.stamp.sec, array.header.frame_id = 1_700_000_000, "camera"
    for index in range(count):
        track = VesselTrack(id=f"T{index}", class_id="vessel", status=1, detection_count=12, has_world=True,
                            confidence=float(rng.random()), score=float(rng.random()), has_cpa=bool(index % 2))
        track.header = array.header
        track.bbox.center.position.x, track.bbox.center.position.y = (float(v) for v in rng.uniform(0, 1920, 2))
        track.bbox.size_x, track.bbox.size_y = (float(v) for v in rng.uniform(5, 200, 2))
        track.detection_bbox = track.bbox
        track.screen_covariance = np.array([4.0, 0.1, 0.1, 3.0])
        track.position.x, track.position.y = (float(v) for v in rng.uniform(-2000, 2000, 2))
        track.position_covariance = np.array([25.0, 1.0, 1.0, 16.0])
        track.velocity_covariance = np.full(4, math.nan) if index % 3 == 0 else np.array([1.0, 0.0, 0.0, 1.0])
        track.latitude, track.longitude = 59.0 + float(rng.random()), 10.0 + float(rng.random())
        track.distance_m, track.bearing_deg, track.expected_error_m = float(rng.uniform(50, 3000)), 80.0, 12.0
        track.cpa_m = track.tcpa_s = math.nan if index % 2 == 0 else 120.0
        array.tracks.append(track)
    return array


def _per_call_ms(call, repeats: int) -> float:
    start = time.perf_counter()
    for _ in range(repeats):
        call()
    return (time.perf_counter() - start) / repeats * 1000.0


def measure(count: int, rounds: int, repeats: int) -> dict:
    """Median ms per array over ``rounds`` alternating rounds: decode and encode, rclpy against the wire codec."""
    from rclpy.serialization import deserialize_message, serialize_message

    from vessel_common.wire import WireType
    from vessel_msgs.msg import VesselTrackArray

    wire = WireType(ARRAY_TYPE)
    message = track_array(count)
    cdr = serialize_message(message)
    decoded = wire.decode(cdr)
    if repr(deserialize_message(wire.encode(decoded), VesselTrackArray)) != repr(message):
        raise DataError("bench messages: the wire codec did not give back the array rclpy serialised")
    figures: dict[str, list[float]] = {"rclpy_decode": [], "wire_decode": [], "rclpy_encode": [], "wire_encode": []}
    for _ in range(rounds):
        figures["rclpy_decode"].append(_per_call_ms(lambda: deserialize_message(cdr, VesselTrackArray), repeats))
        figures["wire_decode"].append(_per_call_ms(lambda: wire.decode(cdr), repeats))
        figures["rclpy_encode"].append(_per_call_ms(lambda: serialize_message(message), repeats))
        figures["wire_encode"].append(_per_call_ms(lambda: wire.encode(decoded), repeats))
    result = {name: float(np.median(values)) for name, values in figures.items()}
    result.update(tracks=count, bytes=len(cdr),
                  decode_ratio=result["rclpy_decode"] / result["wire_decode"],
                  encode_ratio=result["rclpy_encode"] / result["wire_encode"])
    return result


def format_table(rows: list[dict], machine: dict) -> str:
    """The figures as a plain-text table."""
    lines = [f"VesselTrackArray per call, ms (median of rounds); {machine.get('cores')} cores, "
             f"load average {' '.join(f'{v:.2f}' for v in machine.get('load_average_before', []))}",
             f"{'tracks':>6} {'bytes':>7} {'decode rclpy':>12} {'wire':>6} {'ratio':>6} "
             f"{'encode rclpy':>12} {'wire':>6} {'ratio':>6}"]
    for row in rows:
        lines.append(f"{row['tracks']:6d} {row['bytes']:7d} {row['rclpy_decode']:12.3f} {row['wire_decode']:6.3f} "
                     f"{row['decode_ratio']:6.2f} {row['rclpy_encode']:12.3f} {row['wire_encode']:6.3f} "
                     f"{row['encode_ratio']:6.2f}")
    return "\n".join(lines)


def parse_args(argv) -> argparse.Namespace:
    """The command line; a bad value exits with argparse's usage message."""
    parser = argparse.ArgumentParser(prog="vessel bench messages", description=__doc__.split("\n\n")[0])
    parser.add_argument("--tracks", default="10,40,80", help="tracks per array, comma-separated (default 10,40,80)")
    parser.add_argument("--rounds", type=int, default=5, help="alternating rounds (default 5)")
    parser.add_argument("--repeats", type=int, default=200, help="calls per round and codec (default 200)")
    parser.add_argument("--out", type=Path, help="write the figures as JSON")
    args = parser.parse_args(argv)
    try:
        args.track_counts = [int(v) for v in args.tracks.split(",") if v.strip()]
    except ValueError:
        parser.error(f"--tracks {args.tracks}: give whole numbers, e.g. 10,40,80")
    if not args.track_counts or min(args.track_counts) < 0 or args.rounds < 1 or args.repeats < 1:
        parser.error("--tracks needs numbers >= 0, --rounds and --repeats at least 1")
    return args


@command_line_tool
def main(argv=None) -> int:
    """Console entry point (``./vessel bench messages``)."""
    args = parse_args(argv)
    rows = [measure(count, args.rounds, args.repeats) for count in args.track_counts]
    machine = machine_info()
    return print_and_save(format_table(rows, machine), {"machine": machine, "arrays": rows}, args.out)


if __name__ == "__main__":
    raise SystemExit(main())
