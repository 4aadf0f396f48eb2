"""``vessel``: the project's one command line, behind ``./vessel TOOL`` and ``ros2 run vessel_tools TOOL``.

Each tool is a module with a ``main(argv)`` (also runnable as ``python -m MODULE``); this module only finds it,
imports it when asked for (so ``--help`` is instant and needs nothing installed) and passes the arguments on.
Every tool ends the same way (``vessel_common.command_line``): one ``error:`` line and exit 2 on bad input, exit
130 on Ctrl-C. ``./vessel`` itself keeps only what has to happen before Python can run: setup, env and test.
"""

from __future__ import annotations

import importlib
import sys
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Tool:
    """One tool: the module whose ``main`` runs it, arguments put before the user's, and what it does."""

    module: str
    summary: str
    usage: str = ""
    prefix: tuple[str, ...] = ()


@dataclass(frozen=True)
class Group:
    """A tool with sub-tools (``bag build``, ``bench live``); ``default``: the one run with no sub-tool named."""

    tools: dict[str, Tool] = field(default_factory=dict)
    default: str | None = None


TOOLS: dict[str, Tool | Group] = {
    "demo": Tool("vessel_tools.demo", "the whole graph on the challenge videos, recorded, scored, plotted",
                 "[--data DIR] [--videos LIST] [--out DIR] [--calib FILE] [--detections labels|FILE.csv]"),
    "results": Tool("vessel_tools.results_page", "the results page (docs/results.md) written from a demo's "
                    "summary.json", "out/demo/summary.json --out docs/results.md"),
    "graph": Tool("vessel_bringup.graph", "start the node graph as processes, what vessel_graph.launch.py does",
                  "[--source BAG|VIDEO|DIR|device:N] [--rate R] [--nodes LIST] [--respawn] [--record BAG] "
                  "[--namespace NAME | --cameras cam0=SRC,cam1=SRC [--processes per-node|per-role]]"),
    "view": Tool("vessel_tools.view.app", "a live web page of the water (plan, camera image, status) and the same "
                 "data for Foxglove; starts the graph on --source first", "[--port 8080] [--source BAG --rate R] "
                 "[--foxglove-port 8765] [--chart FILE.json]"),
    "eval": Tool("vessel_tools.track.evaluation",
                 "score predictions like the paper (m per 100 m, median, p80, coverage)",
                 "PREDICTIONS.csv --data DIR [--videos LIST] [--out DIR]"),
    "calibrate": Tool("vessel_tools.calibrate", "GPS-only camera calibration into a ROS parameter file "
                      "(without hand labels: the vessel is found among detected boats)",
                      "--data DIR --videos 7-12 --out FILE.yaml [--water-level CSV] [--from labels|detections]"),
    "horizon": Tool("vessel_tools.calib.far_edge", "the sea's far edge measured in a dataset's frames: the reference "
                    "line a moving camera's horizon is compared with (camera.far_edge_ideal_abc)",
                    "--data DIR --videos LIST --calib FILE"),
    "bag": Group({
        "build": Tool("vessel_tools.detect.bag_build", "rosbag2 MCAP folders (one per video) from a dataset folder or "
                      "a video file", "--data DIR [--videos LIST] --out BAGDIR"),
        "info": Tool("vessel_tools.detect.bag_build",
                     "topics, counts and time span of bags (what `ros2 bag info` shows)",
                     "BAG...", ("--info",)),
        "recover": Tool("vessel_tools.detect.bag_build", "make a bag whose recorder died (or that was cut short) "
                        "readable", "BAG [--out NEW]", ("--recover",)),
    }),
    "detect": Tool("vessel_tools.detect.detect_cli", "the detector over a dataset folder or any camera's images; its "
                   "recall or scores against YOLO labels; training labels generated from the GPS; fine-tune the "
                   "detector; rank against the GPS", "run|recall|rank|export-labels|train|images|score-images ..."),
    "bench": Group({
        "graph": Tool("vessel_tools.bench", "the whole graph's frames/s and latency against the detector core",
                      "[--out FILE.json]"),
        "detector": Tool("vessel_tools.bench_detector", "the detector core and node: ms per frame, frames/s, "
                         "against the COCO tiled set-up", "[--out FILE.json]"),
        "cameras": Tool("vessel_tools.bench_cameras", "N cameras at F frames/s each on this computer: frames "
                        "offered and processed, latency, memory and CPU per camera and in all; --kill one camera",
                        "--cameras N|1,2,4,8 [--fps 2] [--minutes 1] [--processes per-node] [--out F.json]"),
        "live": Tool("vessel_tools.bench_live", "the graph on a stream at the camera's frame rate: frames offered, "
                     "processed, dropped; latency; memory of every node", "[--minutes 10] [--fps 25] [--out F]"),
        "restart": Tool("vessel_tools.bench_restart", "kill -9 one node of `graph --respawn`: time to the next "
                        "fix, fixes lost, fixes against an uninterrupted run", "[--nodes LIST] [--compare-cold]"),
        "soak": Tool("vessel_tools.bench_soak", "the tracker and fuser cores without ROS on a looped stream for "
                     "minutes: CPU per frame, memory and every structure's size, minute by minute",
                     "[--minutes 10] [--fps 25] [--scene looped|harbour] [--recording DIR] [--out F]"),
        "messages": Tool("vessel_tools.bench_messages", "a track array through rclpy's message conversion against "
                         "the nodes' wire codec: ms per array each way, in one process", "[--tracks 10,40,80]"),
        "view": Tool("vessel_tools.view.bench", "the graph's frames/s with 20 WebSocket clients of ./vessel view "
                     "(one never reading) against none, in one run", "[--clients 20] [--frames 36] [--rounds 2]"),
    }, default="graph"),
    "pipeline": Tool("vessel_tools.track.pipeline", "tracker, fuser and target choice without ROS over a detections "
                     "CSV (online or smoothed offline); where the defaults were chosen",
                     "--videos 7-12 --detections FILE.csv|labels --out DIR [--leave-one-out 7-12] [--mode offline]"),
    "fit": Group({
        "distance-model": Tool("vessel_tools.track.distance_model_fit", "refit the box-size distance model and the cue "
                               "noise into a parameter file (only those values change, and the detector's "
                               "size_prior.model with them; comments stay)",
                               "--videos 7-12 --out FILE.yaml"),
        "error-model": Tool("vessel_tools.track.error_model_fit", "refit the error model (expected error against "
                            "distance) from scores.csv files into a parameter file", "SCORES.csv --out FILE.yaml"),
    }),
    "appearance": Tool("vessel_tools.track.appearance", "the vessel-of-interest appearance cue: fit, score, rank",
                       "fit|score|rank ..."),
    "params": Group({
        "render": Tool("vessel_tools.parameter_docs", "write config/parts/NODE.yaml and the table of "
                       "docs/parameters.md from the nodes' parameter tables", "[--check]", ("render",)),
    }),
    "simulate": Tool("vessel_tools.track.simulation", "the tracker on simulated harbour traffic: id switches, extra "
                     "tracks, RMSE", "[--interval 4 1 0.1] [--seeds 6]"),
    "replay-check": Tool("vessel_tools.replay_check", "replay bags through camera and detector at a rate: frames "
                         "sent, received, dropped", "BAG... [--rate R]"),
}


def usage(program: str = "./vessel", header: bool = True) -> str:
    """Every tool, with its sub-tools, what it takes and what it does."""
    lines = [f"usage: {program} TOOL [ARGS]", ""] if header else []
    lines.append(f"Tools ({program} TOOL --help: a tool's options)")
    for name in TOOLS:
        lines += _tool_lines(name)
    return "\n".join(lines)


def _tool_lines(name: str) -> list[str]:
    """A tool's usage lines (each sub-tool's, for a group; the one run with none named is marked)."""
    entry = TOOLS[name]
    tools = {f"{name} {sub}": tool for sub, tool in entry.tools.items()} if isinstance(entry, Group) \
        else {name: entry}
    lines = []
    for label, tool in tools.items():
        if isinstance(entry, Group) and label == f"{name} {entry.default}":
            label = f"{name} [{entry.default}]"
        lines.append(f"  {label} {tool.usage}".rstrip())
        lines += textwrap.wrap(tool.summary, width=116, initial_indent=" " * 6, subsequent_indent=" " * 6)
    return lines


def group_usage(name: str, program: str = "./vessel") -> str:
    """A group's sub-tools: what ``./vessel GROUP --help`` prints."""
    return "\n".join([f"usage: {program} {name} SUBTOOL [ARGS] ({program} {name} SUBTOOL --help: its options)", "",
                      *_tool_lines(name)])


def resolve(argv: Sequence[str]) -> tuple[Tool, list[str]]:
    """The tool ``argv`` names and the arguments for its ``main``; ValueError naming the choices otherwise."""
    if not argv:
        raise ValueError("no tool given")
    name, rest = argv[0], list(argv[1:])
    entry = TOOLS.get(name)
    if entry is None:
        raise ValueError(f"unknown tool '{name}': choose from {', '.join(TOOLS)}")
    if isinstance(entry, Group):
        if rest and rest[0] in entry.tools:
            return entry.tools[rest[0]], rest[1:]
        if entry.default is not None and (not rest or rest[0].startswith("-")):
            return entry.tools[entry.default], rest
        named = f"{name} {rest[0]}" if rest else name
        raise ValueError(f"'{named}': choose {name} " + " | ".join(entry.tools))
    return entry, rest


def main(argv: Sequence[str] | None = None, program: str = "./vessel") -> int:
    """Run the tool ``argv`` names; its exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(usage(program))
        return 0
    if argv[0] == "--list":  # for ./vessel help, after its own commands
        print(usage(program, header=False))
        return 0
    if isinstance(TOOLS.get(argv[0]), Group) and argv[1:2] in (["-h"], ["--help"]):
        print(group_usage(argv[0], program))
        return 0
    try:
        tool, rest = resolve(argv)
    except ValueError as error:
        print(f"error: {error}\n\n{usage(program)}", file=sys.stderr)
        return 2
    module = importlib.import_module(tool.module)
    prefix = list(tool.prefix)
    if prefix and prefix[0].startswith("-") and ("-h" in rest or "--help" in rest):
        prefix = []  # an option standing for the sub-tool (bag recover: --recover BAG) would want its argument
    return int(module.main([*prefix, *rest]) or 0)


def _entry(name: str):
    def run() -> None:
        sys.exit(main([name, *sys.argv[1:]], program="ros2 run vessel_tools"))

    run.__doc__ = f"Console script ``{name}``: ``vessel {name}``."
    return run


demo = _entry("demo")
bench = _entry("bench")
evaluate = _entry("eval")
pipeline = _entry("pipeline")
fit = _entry("fit")
view = _entry("view")


def console() -> None:
    """Console script ``vessel``: ``ros2 run vessel_tools vessel TOOL ARGS``."""
    sys.exit(main(program="ros2 run vessel_tools vessel"))


if __name__ == "__main__":
    sys.exit(main())
