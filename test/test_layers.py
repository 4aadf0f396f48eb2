"""The source modules form layers that import only downward, with no import cycle and no ROS in the core.

Layers, lowest first (a module may import its own layer and those below):

- ``common``: errors, paths, serialized imports, state files, the command-line tail, parameter names (package
  ``vessel_common``),
  geodesy, the packages' ``__init__``;
- ``core``: ROS-free runtime code: camera model, parameter files, detector and its decoding, tracker, fusion,
  selection, smoothing, the runtime halves of the distance and error models;
- ``ros``: ROS plumbing shared by nodes and tools: node support, parameter declarations, bag I/O, image sources;
- ``nodes``: the rclpy nodes;
- ``bringup``: what starts the graph: the node list of the launch file and the graph runner (package
  ``vessel_bringup``);
- ``tools``: offline tools: data-folder loaders, calibration fit, pipeline, evaluation, fitting, training, bags
  (package ``vessel_tools``);
- ``apps``: demo, benchmarks, replay check, the ``vessel`` command line (package ``vessel_tools``).

The packages follow the same order (``PACKAGE_DEPENDS``): ``vessel_common`` imports none of the others, the runtime
packages import neither ``vessel_bringup`` nor ``vessel_tools``, and nothing imports ``vessel_tools``.

Every import counts, inside functions too. A new module must be given a layer here.
"""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("vessel_common", "vessel_calib", "vessel_detect", "vessel_track", "vessel_bringup", "vessel_tools")
LAYERS = ("common", "core", "ros", "nodes", "bringup", "tools", "apps")
ROS_MODULES = ("rclpy", "launch", "launch_ros", "rosidl_runtime_py", "builtin_interfaces", "rosbags", "mcap")

_BY_LAYER = {
    "common": """vessel_common vessel_common.errors vessel_common.imports vessel_common.paths vessel_common.state_file
                 vessel_common.command_line vessel_common.parameter_names vessel_common.parameter_table
                 vessel_common.input_gaps
                 vessel_common.ros_arguments vessel_common.graph_names
                 vessel_calib vessel_calib.geodesy
                 vessel_detect vessel_track vessel_tools""",
    "core": """vessel_calib.camera_model vessel_calib.calibration_parameters vessel_calib.params vessel_calib.gps_track
               vessel_calib.water_level vessel_calib.pinhole vessel_calib.radial_lens vessel_calib.camera_model_params
               vessel_calib.own_ship vessel_calib.camera_pose vessel_calib.attitude
               vessel_detect.frame_pose vessel_detect.image_view vessel_detect.annotation vessel_track.pose_input
               vessel_detect.box_ops vessel_detect.decoders vessel_detect.tiling vessel_detect.masks
               vessel_detect.image_codec vessel_detect.image_queue vessel_detect.appearance_model
               vessel_detect.size_prior vessel_detect.detector vessel_detect.model_store vessel_detect.detector_params
               vessel_detect.detections_csv vessel_detect.parameter_tables vessel_detect.replay_pacing
               vessel_detect.resume_files vessel_detect.horizon
               vessel_detect.class_names vessel_detect.network_input vessel_detect.bag_topics
               vessel_detect.detector_sharing
               vessel_track.deferred_imports vessel_track.tracker vessel_track.fusion
               vessel_track.selection vessel_track.smoothing vessel_track.distance_model vessel_track.error_model
               vessel_track.fuser_settings vessel_track.parameter_tables vessel_track.message_checks
               vessel_track.tracker_config vessel_track.association vessel_track.track_record
               vessel_track.selection_config vessel_track.trajectory_scoring vessel_track.offline_selection
               vessel_track.track_fuser vessel_track.collision""",
    "ros": """vessel_common.qos vessel_common.health vessel_common.parameter_declaration vessel_common.node_state
              vessel_common.lifecycle vessel_common.run vessel_common.node_parameters vessel_calib.camera_parameters
              vessel_common.message_types vessel_common.wire
              vessel_detect.bag_messages vessel_detect.bag_writer vessel_detect.bag_reader vessel_detect.bag_salvage
              vessel_detect.ros_messages vessel_detect.image_source vessel_detect.file_sources
              vessel_detect.live_sources vessel_detect.source_spec vessel_track.node_params
              vessel_detect.own_ship_messages vessel_detect.pose_messages""",
    "nodes": """vessel_detect.camera_node vessel_detect.detector_node vessel_detect.recorder_node
                vessel_detect.replay_detector_node vessel_track.tracker_node vessel_track.fuser_node
                vessel_track.gps_publisher_node""",
    "bringup": """vessel_bringup vessel_bringup.graph_nodes vessel_bringup.graph_watcher vessel_bringup.graph
                  vessel_bringup.graph_runner vessel_bringup.fleet vessel_bringup.fleet_watcher
                  vessel_bringup.node_host""",
    "tools": """vessel_tools.calib vessel_tools.calib.dataset vessel_tools.calib.calibration
                vessel_tools.calib.calibration_plot vessel_tools.calib.gps_association
                vessel_tools.calib.pairs_csv vessel_tools.calib.pair_checks vessel_tools.calib.homography
                vessel_tools.calib.box_anchor vessel_tools.calib.far_edge
                vessel_tools.detect vessel_tools.detect.dataset_detection vessel_tools.detect.detect_cli
                vessel_tools.detect.frame_boxes vessel_tools.detect.bag_build vessel_tools.detect.recall
                vessel_tools.detect.bag_merge vessel_tools.detect.own_ship_bag
                vessel_tools.detect.training vessel_tools.detect.training.augment vessel_tools.detect.training.labels
                vessel_tools.detect.training.loss vessel_tools.detect.training.model
                vessel_tools.detect.training.model_card
                vessel_tools.detect.training.settings vessel_tools.detect.training.train_cli
                vessel_tools.detect.training.trainer vessel_tools.detect.training.webcams
                vessel_tools.detect.image_folder vessel_tools.detect.image_scores vessel_tools.detect.image_cli
                vessel_tools.track vessel_tools.track.offline_data vessel_tools.track.pipeline
                vessel_tools.track.evaluation vessel_tools.track.appearance vessel_tools.track.distance_model_fit
                vessel_tools.track.error_model_fit vessel_tools.track.simulation
                vessel_tools.track.tracking_score vessel_tools.track.pipeline_results
                vessel_tools.view vessel_tools.view.state vessel_tools.view.status vessel_tools.view.geometry
                vessel_tools.view.server vessel_tools.view.foxglove_bridge vessel_tools.view.node
                vessel_tools.view.app""",
    "apps": """vessel_tools.bench_detector vessel_tools.replay_check vessel_tools.demo vessel_tools.demo_report
               vessel_tools.bench vessel_tools.bench_live vessel_tools.bench_restart vessel_tools.bench_soak
               vessel_tools.bench_messages
               vessel_tools.cli vessel_tools.calibrate vessel_tools.proc_monitor vessel_tools.results_page
               vessel_tools.parameter_docs
               vessel_tools.calibrate_options vessel_tools.calibrate_pairs vessel_tools.calibrate_box_anchor
               vessel_tools.calibrate_output vessel_tools.bench_graph vessel_tools.bench_report
               vessel_tools.view.bench vessel_tools.bench_cameras vessel_tools.bench_cameras_report""",
}
LAYER_OF = {module: layer for layer, names in _BY_LAYER.items() for module in names.split()}


def _modules() -> dict[str, Path]:
    found = {}
    for package in PACKAGES:
        root = REPO / "src" / package
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def _imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
            names |= {f"{node.module}.{alias.name}" for alias in node.names}
    return names


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: {other for other in _imports(path) if other in modules and other != name}
            for name, path in modules.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_every_module_has_a_layer():
    missing = sorted(set(_modules()) - set(LAYER_OF))
    stale = sorted(set(LAYER_OF) - set(_modules()))
    assert not missing, f"give these modules a layer in test/test_layers.py: {missing}"
    assert not stale, f"test/test_layers.py names modules that do not exist: {stale}"


def test_no_import_cycle():
    assert _cycles(_graph()) == []


def test_imports_go_only_downward():
    rank = {layer: i for i, layer in enumerate(LAYERS)}
    upward = sorted(f"{module} ({LAYER_OF[module]}) imports {other} ({LAYER_OF[other]})"
                    for module, others in _graph().items() for other in others
                    if module in LAYER_OF and other in LAYER_OF and rank[LAYER_OF[other]] > rank[LAYER_OF[module]])
    assert not upward, "\n".join(upward)


def test_the_core_imports_no_ros():
    modules = _modules()
    ros = sorted(f"{module} imports {name}" for module, path in modules.items()
                 if LAYER_OF.get(module) in ("common", "core")
                 for name in _imports(path)
                 if name.split(".")[0] in ROS_MODULES or name.split(".")[0].endswith("_msgs"))
    assert not ros, "\n".join(ros)


def test_the_checks_catch_a_cycle_and_an_upward_import():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


PACKAGE_DEPENDS = {"vessel_common": set(), "vessel_calib": {"vessel_common"},
                   "vessel_detect": {"vessel_common", "vessel_calib"},
                   "vessel_track": {"vessel_common", "vessel_calib"},
                   "vessel_bringup": {"vessel_common", "vessel_calib", "vessel_detect", "vessel_track"},
                   "vessel_tools": {"vessel_common", "vessel_calib", "vessel_detect", "vessel_track", "vessel_bringup"}}
"""Which of the project's packages each one may import. The runtime a robot installs (messages, common, calib,
detect, track) is at the bottom, the detector and the tracker are peers joined by topics; bringup starts the graph;
the offline tools sit on top and nothing imports them."""

RUNTIME_PACKAGES = ("vessel_common", "vessel_calib", "vessel_detect", "vessel_track")
OFFLINE_WORDS = ("training", "fit", "evaluation", "bench", "pipeline", "simulation", "dataset", "demo")


def test_the_runtime_imports_no_offline_tool():
    """A robot installs the runtime packages alone: none of their modules may reach bringup or the offline tools."""
    wrong = sorted(f"{module} imports {other}" for module, others in _graph().items() for other in others
                   if module.split(".")[0] in RUNTIME_PACKAGES and other.split(".")[0] not in RUNTIME_PACKAGES)
    assert not wrong, "\n".join(wrong)
    named = sorted(module for module in _modules() if module.split(".")[0] in RUNTIME_PACKAGES
                   and any(word in part for part in module.split(".")[1:] for word in OFFLINE_WORDS))
    assert not named, f"offline tools inside the runtime packages: {named}; move them to vessel_tools"


def test_packages_import_only_the_packages_below_them():
    wrong = sorted(f"{module} imports {other}" for module, others in _graph().items() for other in others
                   if other.split(".")[0] != module.split(".")[0]
                   and other.split(".")[0] not in PACKAGE_DEPENDS[module.split(".")[0]])
    assert not wrong, "\n".join(wrong)


def test_each_package_declares_the_packages_it_imports():
    import xml.etree.ElementTree as ElementTree

    for package in PACKAGE_DEPENDS:
        declared = {e.text for e in ElementTree.parse(REPO / "src" / package / "package.xml").getroot()
                    if e.tag in ("depend", "exec_depend")}
        used = {other.split(".")[0] for module, others in _graph().items() if module.split(".")[0] == package
                for other in others} - {package}
        assert used <= declared, f"{package}/package.xml lacks {sorted(used - declared)}"


def test_each_package_test_module_is_named_for_a_module_of_its_package():
    """``src/<package>/test/test_<module>[_<aspect>].py``: where to look for a module's tests, and the reverse."""
    unnamed = []
    for package in PACKAGES:
        names = {name.split(".")[-1] for name in _modules() if name.split(".")[0] == package}
        for path in sorted((REPO / "src" / package / "test").glob("test_*.py")):
            stem = path.stem[len("test_"):]
            if not any(stem == name or stem.startswith(f"{name}_") for name in names):
                unnamed.append(str(path.relative_to(REPO)))
    assert not unnamed, f"name these after the module they test: {unnamed}"
