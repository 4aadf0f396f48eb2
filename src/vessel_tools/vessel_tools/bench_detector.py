"""Benchmark of the detector (``./vessel bench detector``): default against baseline, modes, node against core.

0. The shipped default (``--params``: ``config/aitas.yaml`` with the calibration) and the baseline
   (``--baseline-params``: the same with ``config/detector_coco.yaml`` on top, the COCO YOLOX-Nano tiled over the
   band) timed on the same frames in interleaved rounds: ``default_fps``, ``baseline_fps`` and their ratio.
1. The core alone on challenge frames: milliseconds per frame (median, p95) of ``detect`` for the ``full``,
   ``band`` and ``tiled`` modes (the other parameters as the node's defaults or ``--params``), and of the JPEG
   decode.
2. Once the workspace is built: frames per second through the detector node, between two processes. The node
   runs as its installed executable; this process publishes CompressedImage frames as fast as the node
   consumes them (the next frame goes out when the detections of the previous one arrive) and counts the
   Detection2DArray messages. The core alone (decode + detect, same frames, same parameters) is timed in the
   same run, in rounds interleaved with the node's so that load changes hit both, and the ratio node/core
   printed: what the node costs beyond the network.

Figures depend on the machine's load: the load average is printed and saved with them.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from vessel_common.command_line import command_line_tool
from vessel_common.errors import DataError
from vessel_common.paths import default_data_dir, repo_file, repo_root
from vessel_detect.detector_params import build_detector, load_params_files, open_model
from vessel_tools.calib.dataset import Dataset

MODES = ("full", "band", "tiled")


def _percentiles(values_ms: list[float]) -> dict[str, float]:
    array = np.asarray(values_ms, dtype=float)
    return {
        "median_ms": float(np.median(array)),
        "p95_ms": float(np.percentile(array, 95)),
        "mean_ms": float(array.mean()),
        "frames": int(array.size),
    }


def pick_frames(dataset, count: int) -> list[Path]:
    """``count`` frames spread over every video (labelled ones first: they show the vessel)."""
    frames = dataset.frames()
    labelled = [f for f in frames if f.has_label] or frames
    if not labelled:
        raise DataError(f"no frames in {dataset.path}")
    step = max(1, len(labelled) // max(1, count))
    return [f.path for f in labelled[::step][:count]]


def time_core(detector, jpegs: list[bytes], repeats: int = 1) -> tuple[list[float], list[float]]:
    """(decode ms, detect ms) per frame; one warm-up frame first."""
    detector.detect(cv2.imdecode(np.frombuffer(jpegs[0], np.uint8), cv2.IMREAD_COLOR))
    decode_ms, detect_ms = [], []
    for _ in range(repeats):
        for data in jpegs:
            t0 = time.perf_counter()
            image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
            t1 = time.perf_counter()
            detector.detect(image)
            t2 = time.perf_counter()
            decode_ms.append((t1 - t0) * 1000.0)
            detect_ms.append((t2 - t1) * 1000.0)
    return decode_ms, detect_ms


def _ros_available() -> str | None:
    try:
        import rclpy  # noqa: F401

        import vessel_msgs.msg  # noqa: F401
    except ImportError as error:
        return f"ROS workspace not sourced ({error}); run through ./vessel bench detector"
    return None


def detector_executable() -> Path:
    """The installed console script of the detector node."""
    return repo_root() / "ros2_ws" / "install" / "vessel_detect" / "lib" / "vessel_detect" / "detector"


class NodeDriver:
    """The detector node in its own process, fed CompressedImage frames paced by its output.

    ``send_frames`` publishes a frame, waits for its Detection2DArray (matched by stamp), then publishes the
    next: the node is never given a frame it would have to drop, and never waits for one longer than the
    round trip.
    """

    def __init__(self, jpegs: list[bytes], params_files: list[str], timeout_s: float):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import CompressedImage

        from vessel_msgs.msg import Detection2DArray

        self._message_class = CompressedImage
        self.jpegs = jpegs
        self.timeout_s = timeout_s
        exe = detector_executable()
        if not exe.exists():
            raise DataError(f"{exe} is not installed: run ./vessel setup")
        domain = random.randint(1, 100)
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        args = [str(exe), "--ros-args"] + [arg for path in params_files for arg in ("--params-file", path)]
        self.log_path = Path(os.environ.get("TMPDIR", "/tmp")) / f"bench_detector_node_{os.getpid()}.log"
        with open(self.log_path, "w") as log:
            self.process = subprocess.Popen(args, env=env, stdout=log, stderr=subprocess.STDOUT,
                                            start_new_session=True)
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node("bench_detector_driver", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.publisher = self.node.create_publisher(CompressedImage, "/camera/image_raw/compressed", reliable)
        self.answered: dict[int, float] = {}
        self.node.create_subscription(
            Detection2DArray, "/vessel/detections",
            lambda m: self.answered.setdefault(m.header.stamp.sec, time.perf_counter()), reliable,
        )
        self.sent = 0
        if not self._wait(lambda: self.publisher.get_subscription_count() > 0
                          and self.node.count_publishers("/vessel/detections") > 0, timeout_s):
            self.close()
            raise DataError(f"the detector node did not come up (log: {self.log_path})")
        # Warm-up frame, resent until answered (discovery may lag the match count).
        self._send()
        while not self._wait(lambda: bool(self.answered), 5.0):
            if self.process.poll() is not None:
                self.close()
                raise DataError(f"the detector node exited with status {self.process.returncode} "
                                f"(log: {self.log_path})")
            self._send()

    def _wait(self, predicate, seconds: float) -> bool:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            if predicate():
                return True
            if self.process.poll() is not None:
                return False
            self.executor.spin_once(timeout_sec=0.01)
        return predicate()

    def _send(self) -> int:
        from builtin_interfaces.msg import Time

        self.sent += 1
        message = self._message_class()
        message.header.stamp = Time(sec=1_000_000 + self.sent)
        message.header.frame_id = "camera"
        message.format = "jpeg"
        message.data = self.jpegs[self.sent % len(self.jpegs)]
        self.publisher.publish(message)
        return 1_000_000 + self.sent

    def send_frames(self, count: int) -> tuple[int, float]:
        """Send ``count`` frames one after the other; return (frames answered, seconds)."""
        answered = 0
        started = time.perf_counter()
        for _ in range(count):
            stamp = self._send()
            answered += int(self._wait(lambda stamp=stamp: stamp in self.answered, self.timeout_s))
        return answered, time.perf_counter() - started

    def close(self) -> None:
        """Stop the node (SIGINT, as Ctrl-C) and this process's ROS context."""
        import rclpy

        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout=15)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()


def run(args: argparse.Namespace) -> dict:
    """Measure and print; return the figures."""
    data = Path(args.data) if args.data else default_data_dir()
    if data is None:
        raise DataError("no dataset folder: pass --data DIR or set VESSEL_DATA (default ../shared/aitas)")
    dataset = Dataset(data)
    params_files = [p for p in (args.params, args.calib, args.detector_params) if p]
    values, params_camera = load_params_files(params_files)
    camera = params_camera or dataset.camera_model()
    paths = pick_frames(dataset, args.frames)
    jpegs = [p.read_bytes() for p in paths]
    load = os.getloadavg()
    cores = os.cpu_count()
    print(f"detector benchmark: {len(jpegs)} challenge frames of {data}, {cores} cores, load average "
          f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f} (other work on the machine makes these figures noisy)")
    model = open_model(values)
    result: dict = {"frames": len(jpegs), "cpu_count": cores, "load_average": list(load),
                    "intra_op_threads": int(values["intra_op_threads"]), "params": params_files, "modes": {}}
    if args.baseline_params:
        baseline_files = [p for p in (args.params, args.calib) if p] + [args.baseline_params]
        result.update(compare_with_baseline(values, camera, model, baseline_files, jpegs, args.rounds))
    _time_modes(args.modes, values, camera, model, jpegs, result)
    if args.no_node:
        return result
    reason = _ros_available()
    if reason:
        print(f"  node: skipped: {reason}")
        result["node"] = {"skipped": reason}
        return result
    detector = build_detector(values, camera, model)
    result.update(_node_against_core(detector, jpegs, params_files, args, values["mode"]))
    return result


def _time_modes(modes, values, camera, model, jpegs: list[bytes], result: dict) -> None:
    """The core's ms per frame in each of ``modes``, and of the JPEG decode, into ``result``; printed."""
    decode_all: list[float] = []
    for mode in modes:
        detector = build_detector(values_in_mode(values, mode), camera, model)
        decode_ms, detect_ms = time_core(detector, jpegs)
        decode_all += decode_ms
        figures = _percentiles(detect_ms)
        figures["network_runs_per_frame"] = len(detector.windows(detector.reference_wh))
        result["modes"][mode] = figures
        print(f"  core {mode:5s}: {figures['median_ms']:7.1f} ms median, {figures['p95_ms']:7.1f} ms p95 per frame "
              f"({figures['network_runs_per_frame']} network runs per frame)")
    result["jpeg_decode"] = _percentiles(decode_all)
    print(f"  JPEG decode: {result['jpeg_decode']['median_ms']:.1f} ms median")


def _node_against_core(detector, jpegs: list[bytes], params_files: list, args, mode: str) -> dict:
    """Frames/s of the detector node between processes against the core alone, in interleaved rounds; printed.

    Interleaved so that a change of the machine's load hits both sides alike.
    """
    driver = NodeDriver(jpegs, params_files, args.timeout_s)
    per_round = max(1, args.node_frames // args.rounds)
    core_frames = core_seconds = node_frames = node_seconds = 0.0
    rounds = []
    try:
        for index in range(args.rounds):
            chunk = [jpegs[(index * per_round + k) % len(jpegs)] for k in range(per_round)]
            decode_ms, detect_ms = time_core(detector, chunk)
            seconds = (sum(decode_ms) + sum(detect_ms)) / 1000.0
            answered, elapsed = driver.send_frames(per_round)
            rounds.append({"core_fps": per_round / seconds, "node_fps": answered / elapsed})
            core_frames += per_round
            core_seconds += seconds
            node_frames += answered
            node_seconds += elapsed
    finally:
        driver.close()
    core_fps = core_frames / core_seconds
    node_fps = node_frames / node_seconds
    ratio = node_fps / core_fps
    print(f"  {mode} mode, {args.rounds} interleaved rounds of {per_round} frames:")
    print(f"  core alone (decode + detect): {core_fps:.2f} frames/s")
    print(f"  node between processes:       {node_fps:.2f} frames/s ({int(node_frames)}/{int(args.rounds * per_round)}"
          " frames answered)")
    print(f"  node / core: {ratio:.2f} (per round: "
          + ", ".join(f"{r['node_fps'] / r['core_fps']:.2f}" for r in rounds) + ")")
    return {"core_fps": core_fps, "node": {"fps": node_fps, "frames": int(node_frames), "rounds": rounds},
            "node_over_core": ratio}


def values_in_mode(values: Mapping[str, Any], mode: str) -> dict[str, Any]:
    """The detector parameters with ``mode`` set."""
    return dict(values, mode=mode)


def compare_with_baseline(values, camera, model, baseline_files: list[str], jpegs: list[bytes],
                          rounds: int) -> dict:
    """frames/s (decode + detect) of the default and the baseline detector, interleaved in ``rounds``."""
    baseline_values, baseline_camera = load_params_files(baseline_files)
    default = build_detector(values, camera, model)
    baseline = build_detector(baseline_values, baseline_camera or camera)
    seconds = {"default": 0.0, "baseline": 0.0}
    frames = 0
    for _ in range(max(1, rounds)):
        for name, detector in (("default", default), ("baseline", baseline)):
            decode_ms, detect_ms = time_core(detector, jpegs)
            seconds[name] += (sum(decode_ms) + sum(detect_ms)) / 1000.0
        frames += len(jpegs)
    default_fps, baseline_fps = frames / seconds["default"], frames / seconds["baseline"]
    runs = {name: len(d.windows(d.reference_wh)) for name, d in (("default", default), ("baseline", baseline))}
    print(f"  shipped default: {default_fps:6.2f} frames/s ({runs['default']} network run(s) per frame, "
          f"{default.model.path.name})")
    print(f"  COCO baseline:   {baseline_fps:6.2f} frames/s ({runs['baseline']} network run(s) per frame, "
          f"{baseline.model.path.name})")
    print(f"  default / baseline: {default_fps / baseline_fps:.2f} ({max(1, rounds)} interleaved rounds of "
          f"{len(jpegs)} frames, decode included)")
    return {"default_fps": default_fps, "baseline_fps": baseline_fps,
            "default_over_baseline": default_fps / baseline_fps,
            "default_model": str(default.model.path), "baseline_model": str(baseline.model.path),
            "default_runs_per_frame": runs["default"], "baseline_runs_per_frame": runs["baseline"]}


def build_parser() -> argparse.ArgumentParser:
    """Command-line interface."""
    parser = argparse.ArgumentParser(prog="./vessel bench detector", description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", help="dataset folder (default: $VESSEL_DATA or ../shared/aitas)")
    parser.add_argument("--params", default=repo_file("config/aitas.yaml"),
                        help="parameter YAML of the default (detector: block; default config/aitas.yaml)")
    parser.add_argument("--calib", default=repo_file("config/aitas_camera.yaml"),
                        help="calibration YAML (default config/aitas_camera.yaml)")
    parser.add_argument("--detector-params", default=None,
                        help="loaded on top of --params and --calib for the default, e.g. config/detector_coco.yaml")
    parser.add_argument("--baseline-params", default=repo_file("config/detector_coco.yaml"),
                        help="loaded on top of --params for the baseline (default config/detector_coco.yaml; '' "
                             "for none)")
    parser.add_argument("--frames", type=int, default=30, help="frames for the per-mode timings")
    parser.add_argument("--modes", type=lambda s: [m for m in s.split(",") if m], default=list(MODES))
    parser.add_argument("--node-frames", type=int, default=30, help="frames sent through the node")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved core/node rounds")
    parser.add_argument("--no-node", action="store_true", help="only the core timings")
    parser.add_argument("--timeout-s", type=float, default=60.0, help="longest wait for the node's answer")
    parser.add_argument("--out", help="also write the figures as JSON")
    return parser


@command_line_tool
def main(argv: list[str] | None = None) -> int:
    """Entry point: exit 0, or 2 with one ``error:`` line."""
    args = build_parser().parse_args(argv)
    result = run(args)
    if args.out:
        from vessel_calib.params import atomic_write_text

        atomic_write_text(Path(args.out), json.dumps(result, indent=2))
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
