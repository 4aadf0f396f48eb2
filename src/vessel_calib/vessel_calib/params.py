"""Read, validate and atomically write ROS 2 parameter YAML files, including the ``camera:`` calibration block.

File shape (what ``ros2 run ... --ros-args --params-file FILE`` loads)::

    /**:
      ros__parameters:
        camera:
          camera_lat: 32.70297
          camera_lon: -117.234631
          image_width: 1280
          image_height: 720
          H: [-441.0, 379.0, -1000.0, -217.0, -56.5, -548.0, -0.512, -0.144, 1.0]
          K1: -4.053e-07
          center_x: 640.0
          center_y: 360.0
          heading_deg: 76.476          # derived, informational
          horizon_ideal_abc: [...]     # derived, informational
          horizon_y_center: 421.7      # derived, informational

The loader also accepts the block under a node name instead of ``/**`` and ROS's flattened ``camera.H: [...]``
spelling.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from vessel_calib.camera_model import CameraModel
from vessel_calib.errors import CalibrationError

ALL_NODES = "/**"


def atomic_write_text(path, text: str) -> Path:
    """Write ``text`` to ``path`` via a temporary file in the same folder and a rename: never a half file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; a parameter file is read by other users' nodes
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return path


def _plain(value: Any) -> Any:
    """Numpy scalars/arrays -> plain Python, so the YAML has ROS-friendly types only."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return [_plain(v) for v in value.tolist()]
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if isinstance(value, float) and not math.isfinite(value):
        raise CalibrationError(f"refusing to write non-finite value {value!r} into a ROS parameter file")
    return value


class _Dumper(yaml.SafeDumper):
    """Block style for mappings, flow style for lists of scalars (H on one line)."""


def _represent_list(dumper, data):
    flow = all(not isinstance(v, list | dict) for v in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_Dumper.add_representer(list, _represent_list)


def dump_params_yaml(params_by_node: Mapping[str, Mapping[str, Any]], header: str = "") -> str:
    """YAML text for ``{node_name: {param: value}}`` wrapped in ``ros__parameters``."""
    doc = {}
    for node, params in params_by_node.items():
        if not isinstance(params, Mapping):
            raise CalibrationError(f"parameters of node {node!r} must be a mapping")
        doc[str(node)] = {"ros__parameters": _plain(params)}
    text = yaml.dump(doc, Dumper=_Dumper, sort_keys=False, default_flow_style=False, width=200)
    if header:
        text = "".join(f"# {line}\n" if line else "#\n" for line in header.splitlines()) + text
    return text


def write_params_yaml(path, params_by_node: Mapping[str, Mapping[str, Any]], header: str = "") -> Path:
    """Atomically write a ROS parameter file, e.g. ``{"/**": {"camera": model.to_params()}}``."""
    return atomic_write_text(path, dump_params_yaml(params_by_node, header))


def write_camera_yaml(path, model: CameraModel, header: str = "", extra: Mapping[str, Any] | None = None) -> Path:
    """Atomically write the calibration file: ``/**: ros__parameters: camera: {...}`` (plus ``extra`` params)."""
    if model.camera_lat is None:
        raise CalibrationError("the camera model has no camera position; give camera_lat/camera_lon")
    block: dict[str, Any] = {"camera": model.to_params()}
    if extra:
        block.update(extra)
    return write_params_yaml(path, {ALL_NODES: block}, header)


def read_params_yaml(path) -> dict:
    """Parse a ROS parameter YAML into ``{node: {param: value}}`` (the ``ros__parameters`` contents)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise CalibrationError(f"cannot read parameter file {path}: {exc.strerror or exc}") from None
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise CalibrationError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(doc, Mapping):
        raise CalibrationError(f"{path}: expected a ROS parameter file (a mapping like '/**: ros__parameters: ...')")
    out = {}
    for node, body in doc.items():
        if isinstance(body, Mapping) and isinstance(body.get("ros__parameters"), Mapping):
            out[str(node)] = dict(body["ros__parameters"])
    if not out:
        raise CalibrationError(
            f"{path}: no 'ros__parameters' block found; expected '/**: ros__parameters: camera: ...'")
    return out


def camera_block(params: Mapping[str, Any]) -> dict | None:
    """The ``camera`` parameters of one node's block, nested (``camera: {...}``) or flattened (``camera.H``)."""
    nested = params.get("camera")
    if isinstance(nested, Mapping):
        return dict(nested)
    flat = {k[len("camera."):]: v for k, v in params.items() if isinstance(k, str) and k.startswith("camera.")}
    return flat or None


def load_camera_params(path) -> dict:
    """The ``camera:`` block of a parameter file (``/**`` preferred, else the first node that has one)."""
    blocks = read_params_yaml(path)
    order = [ALL_NODES] + [n for n in blocks if n != ALL_NODES]
    for node in order:
        if node in blocks:
            block = camera_block(blocks[node])
            if block is not None:
                return block
    raise CalibrationError(f"{path}: no 'camera:' block under ros__parameters; write it with the calibrate tool")


def load_camera_yaml(path) -> CameraModel:
    """Load and validate the calibration file into a CameraModel.

    Raises CalibrationError naming the file and the key for missing keys, wrong types, non-finite values,
    a singular H or an absurd K1.
    """
    params = load_camera_params(path)
    return CameraModel.from_params(params, where=f"{path}: camera")
