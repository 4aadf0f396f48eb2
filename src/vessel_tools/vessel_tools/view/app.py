"""``./vessel view`` (``ros2 run vessel_tools view``): serve the live page, optionally Foxglove, optionally the graph.

Without ``--source`` it watches whatever graph runs in its ROS domain. With ``--source BAG --rate R`` it starts
the graph first, exactly as ``./vessel graph`` does (``vessel_bringup.graph``: the same runner, the consumers first,
the camera once every link is matched), with the detector publishing its annotated image for the page. The view's
node spins in a thread of its own, so the page stays live while the graph is being started and watched.
"""

from __future__ import annotations

import argparse
import math
import shutil
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from vessel_common.command_line import command_line_tool
from vessel_common.errors import DataError, VesselError
from vessel_common.paths import repo_root
from vessel_tools.view.geometry import CameraGeometry, Chart, chart_from_corners, load_chart, load_geometry
from vessel_tools.view.node import ViewOptions, camera_namespaces
from vessel_tools.view.server import MAX_CLIENTS, ViewServer
from vessel_tools.view.state import ViewState


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """Command line of ``./vessel view``."""
    parser = argparse.ArgumentParser(
        prog="./vessel view",
        description="A live web page of the water (plan view, camera image, status) on http://HOST:PORT/, and the "
        "same data for Foxglove with --foxglove-port. Ctrl-C stops it (and the graph it started).")
    parser.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1: this "
                        "machine only; 0.0.0.0 opens it to the network)")
    parser.add_argument("--port", type=int, default=8080, help="HTTP/WebSocket port (0: any free one; printed)")
    parser.add_argument("--calib", type=Path, default=None, help="calibration file for the camera's position and "
                        "field of view (default config/aitas_camera.yaml)")
    parser.add_argument("--namespace", action="append", default=None, metavar="NS",
                        help="a camera's namespace (repeat for several cameras side by side; default: none)")
    parser.add_argument("--chart", type=Path, default=None, help='offline chart under the plan: a JSON file '
                        '{"image": "chart.png", "top_left": [lat, lon], "bottom_right": [lat, lon]}')
    parser.add_argument("--chart-image", type=Path, default=None, help="chart image (PNG/JPEG, north up), with "
                        "--chart-corners")
    parser.add_argument("--chart-corners", default=None, metavar="LAT,LON,LAT,LON",
                        help="latitude/longitude of the chart image's top-left and bottom-right corners")
    parser.add_argument("--source", default=None, help="start the graph on this source first (bag folder, .mcap, "
                        "video, image folder, device:N), as ./vessel graph --source does")
    parser.add_argument("--rate", type=float, default=None, help="with --source: replay rate (1 real time, 0 as "
                        "fast as the graph consumes)")
    parser.add_argument("--params", type=Path, default=None, help="with --source: the graph's parameter file "
                        "(default config/aitas.yaml)")
    parser.add_argument("--log-dir", type=Path, default=None, help="with --source: each node's output to "
                        "DIR/<node>.log instead of the terminal")
    parser.add_argument("--foxglove-port", type=int, default=None, help="also serve Foxglove's WebSocket protocol "
                        "on this port (8765 is Foxglove's default; needs requirements-view.txt)")
    parser.add_argument("--foxglove-layout", type=Path, default=None, metavar="FILE",
                        help="write the Foxglove layout (map, image, plan) to FILE and exit")
    parser.add_argument("--update-hz", type=float, default=10.0, help="most updates per second sent to a page")
    parser.add_argument("--image-hz", type=float, default=4.0, help="most camera images per second sent to a page")
    parser.add_argument("--max-clients", type=int, default=MAX_CLIENTS, help="WebSocket clients served at once")
    return parser.parse_args(argv)


def check_args(args: argparse.Namespace) -> None:
    """Refuse values that cannot work, each with one line saying what to give instead."""
    for name in ("port", "foxglove_port"):
        value = getattr(args, name)
        if value is not None and not 0 <= value <= 65535:
            raise DataError(f"--{name.replace('_', '-')} {value}: give a TCP port, 0-65535")
    for name in ("update_hz", "image_hz"):
        value = getattr(args, name)
        if not (math.isfinite(value) and 0 < value <= 100):
            raise DataError(f"--{name.replace('_', '-')} {value}: give a rate above 0 and at most 100 per second")
    if args.max_clients < 1:
        raise DataError(f"--max-clients {args.max_clients}: give at least 1")
    if args.rate is not None and not (math.isfinite(args.rate) and args.rate >= 0):
        raise DataError(f"--rate {args.rate}: give 0 (as fast as the graph consumes) or a positive factor")
    if (args.rate is not None or args.params is not None) and not args.source:
        raise DataError("--rate and --params go with --source (the graph the view starts); add --source BAG")
    if bool(args.chart_image) != bool(args.chart_corners):
        raise DataError("--chart-image and --chart-corners go together: give both (or --chart FILE.json)")


def load_chart_option(args: argparse.Namespace, geometry: CameraGeometry) -> Chart | None:
    """The chart of ``--chart`` or ``--chart-image`` + ``--chart-corners``, placed about the camera."""
    if args.chart is not None:
        return load_chart(args.chart, geometry.lat, geometry.lon)
    if args.chart_image is None:
        return None
    try:
        lat1, lon1, lat2, lon2 = (float(v) for v in args.chart_corners.split(","))
    except ValueError:
        raise DataError(f"--chart-corners {args.chart_corners!r}: give LAT,LON,LAT,LON (top-left, then "
                        "bottom-right corner, degrees)") from None
    return chart_from_corners(args.chart_image, (lat1, lon1), (lat2, lon2), geometry.lat, geometry.lon)


@dataclass
class Running:
    """What the view started, to be stopped in reverse order."""

    server: ViewServer | None = None
    bridge: object = None
    context: object = None
    executor: object = None
    node: object = None
    spin_thread: threading.Thread | None = None
    runner: object = None
    temp_dirs: list[Path] = field(default_factory=list)

    def stop(self) -> None:
        """Stop the graph, the node, the Foxglove bridge and the server (whatever was started)."""
        if self.runner is not None:
            statuses = self.runner.stop()
            print("[view] graph stopped: " + ", ".join(f"{k}={v}" for k, v in statuses.items()), file=sys.stderr)
        if self.executor is not None:  # the spinning thread ends before the node goes
            self.executor.shutdown(timeout_sec=2.0)
        if self.spin_thread is not None:
            self.spin_thread.join(timeout=5.0)
        if self.node is not None:
            self.node.destroy_node()
        if self.context is not None:
            import rclpy

            rclpy.try_shutdown(context=self.context)
        if self.bridge is not None:
            self.bridge.close()
        if self.server is not None:
            self.server.stop()
        for path in self.temp_dirs:
            shutil.rmtree(path, ignore_errors=True)


def start_node(running: Running, state: ViewState, cameras: dict, options: ViewOptions) -> None:
    """The view's node in its own context, spun by a thread (the main thread starts and watches the graph)."""
    try:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        from vessel_tools.view.node import ViewNode
    except ImportError as error:
        raise VesselError(f"the ROS 2 workspace is not sourced ({error}): run ./vessel view, or eval "
                          '"$(./vessel env)" first') from None
    running.context = rclpy.Context()
    rclpy.init(context=running.context, signal_handler_options=SignalHandlerOptions.NO)
    server = running.server
    running.node = ViewNode(state, cameras, server, options, running.bridge, context=running.context)
    server.on_drop = running.node.dropped
    running.executor = SingleThreadedExecutor(context=running.context)
    running.executor.add_node(running.node)
    running.spin_thread = threading.Thread(target=_spin, args=(running.executor,), name="view-node", daemon=True)
    running.spin_thread.start()


def _spin(executor) -> None:
    from rclpy.executors import ExternalShutdownException

    try:
        executor.spin()
    except ExternalShutdownException:
        pass


def start_graph(args: argparse.Namespace, running: Running, stop) -> None:
    """Start the graph on ``--source`` as ``./vessel graph`` does, the detector also publishing its annotated image.

    Uses ``vessel_bringup.graph``'s runner and ``start_graph_nodes`` (consumers first, the camera once every link is
    matched) so the view starts the very graph ``./vessel graph`` would; one more parameter file turns the image on.
    """
    from vessel_bringup import graph
    from vessel_bringup.graph_nodes import GRAPH_NODES, sim_time_for_source
    extra = Path(tempfile.mkdtemp(prefix="vessel_view_"))
    running.temp_dirs.append(extra)
    annotated = extra / "view.yaml"
    annotated.write_text(yaml.safe_dump({"detector": {"ros__parameters": {"publish_annotated": True}}}))
    params = [args.params or graph.default_params_file(), args.calib or graph.default_calibration_file(), annotated]
    graph_args = graph.parse_args(["--source", str(args.source)]
                                  + (["--rate", repr(float(args.rate))] if args.rate is not None else []))
    running.runner = runner = graph.GraphRunner(params, log_dir=args.log_dir, echo=args.log_dir is None)
    wanted = [node.name for node in GRAPH_NODES]
    sim_time = sim_time_for_source(str(args.source))
    graph.start_graph_nodes(graph_args, runner, wanted, sim_time, stop)


def watch_graph(running: Running, stop) -> None:
    """Until a stop is asked for: a failed node stops the view with its log; the end of a replay is said once."""
    said_end = False
    while not stop.is_set():
        time.sleep(0.2)
        runner = running.runner
        if runner is None:
            continue
        failed = runner.failed()
        if failed:
            raise VesselError(f"node {failed[0]} of the graph stopped:\n{runner.log_tail(failed[0])}")
        camera = runner.running.get("camera")
        if not said_end and camera is not None and camera.process.poll() is not None:
            said_end = True
            print("[view] the camera's source has ended: the page keeps the last state (Ctrl-C stops)",
                  file=sys.stderr, flush=True)


@command_line_tool
def main(argv: Sequence[str] | None = None) -> int:
    """Serve the page (and Foxglove) until Ctrl-C."""
    args = parse_args(argv)
    check_args(args)
    if args.foxglove_layout is not None:
        from vessel_tools.view.foxglove_bridge import foxglove_layout

        args.foxglove_layout.write_text(foxglove_layout())
        print(f"[view] wrote the Foxglove layout to {args.foxglove_layout}")
        return 0
    if args.source:  # before anything starts: the graph would wait for a camera that cannot start
        from vessel_detect.source_spec import check_source

        check_source(args.source)
    geometry = load_geometry(args.calib or repo_root() / "config" / "aitas_camera.yaml")
    state = ViewState(chart=load_chart_option(args, geometry))
    cameras = {namespace: geometry for namespace in camera_namespaces(args.namespace)}
    from vessel_bringup.graph import StopRequest

    stop = StopRequest()
    running = Running()
    try:
        stop.install()
        running.server = ViewServer(state, args.host, args.port, max_clients=args.max_clients)
        running.server.start()
        if args.foxglove_port is not None:
            from vessel_tools.view.foxglove_bridge import FoxgloveBridge

            running.bridge = FoxgloveBridge(args.host, args.foxglove_port)
        start_node(running, state, cameras, ViewOptions(args.update_hz, args.image_hz))
        print(f"[view] serving {running.server.url}" + (f" and Foxglove on ws://{args.host}:{running.bridge.port}"
                                                        if running.bridge is not None else ""), flush=True)
        if args.source:
            start_graph(args, running, stop)
        watch_graph(running, stop)
        print("[view] stopping", file=sys.stderr, flush=True)
        return 0
    finally:
        running.stop()
        stop.restore()


if __name__ == "__main__":
    sys.exit(main())
