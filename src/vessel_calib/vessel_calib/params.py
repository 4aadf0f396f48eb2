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
import re
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from vessel_calib.camera_model import CameraModel
from vessel_common.errors import CalibrationError

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


def yaml_value_text(value: Any) -> str:
    """One YAML value on one line: floats exactly (``repr``), NaN as ``.nan``, lists and mappings in flow style."""
    value = _plain_keep_nan(value)
    if isinstance(value, float):
        return ".nan" if math.isnan(value) else (repr(value) if math.isfinite(value) else
                                                 (".inf" if value > 0 else "-.inf"))
    if isinstance(value, list):
        return "[" + ", ".join(yaml_value_text(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{yaml_value_text(str(k))}: {yaml_value_text(v)}" for k, v in value.items()) + "}"
    # Inside a one-item flow list a string is quoted where a flow context needs it (commas, colons), so the text
    # is valid both as a block value and inside a flow list or mapping.
    return yaml.safe_dump([value], default_flow_style=True, width=10000).strip()[1:-1]


def _plain_keep_nan(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, tuple):
        return list(value)
    if isinstance(value, np.generic):
        return value.item()
    return value


_KEY_LINE = re.compile(r"""^(?P<indent> *)(?P<key>"[^"]*"|'[^']*'|[^\s#:'"][^:#]*?) *:(?P<rest>(?:\s.*)?)$""")


def _key_line(line: str):
    """(indent, key, rest) of a ``key: ...`` line, or None."""
    match = _KEY_LINE.match(line)
    if not match:
        return None
    key = match["key"]
    if key[:1] in "\"'":
        key = key[1:-1]
    return len(match["indent"]), key, match["rest"]


def _split_comment(rest: str) -> tuple[str, str]:
    """``' value  # comment'`` -> (value text, comment text without '#'), honouring quotes."""
    quote = ""
    for i, ch in enumerate(rest):
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch == "#" and (i == 0 or rest[i - 1] in " \t"):
            return rest[:i].strip(), rest[i + 1:].strip()
    return rest.strip(), ""


def _is_content(line: str) -> bool:
    stripped = line.strip()
    return bool(stripped) and not stripped.startswith("#")


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip(" "))


def _span_end(lines: list[str], start: int) -> int:
    """End (exclusive) of the section headed by ``lines[start]``: its more-indented content lines."""
    indent = _indent(lines[start])
    end = start + 1
    for i in range(start + 1, len(lines)):
        if not _is_content(lines[i]):
            continue
        if _indent(lines[i]) <= indent:
            break
        end = i + 1
    return end


def _children(lines: list[str], start: int, end: int) -> dict[str, int]:
    """Keys directly under the section ``lines[start]`` (up to ``end``) -> their line index."""
    found: dict[str, int] = {}
    child_indent = None
    for i in range(start + 1, end):
        if not _is_content(lines[i]):
            continue
        indent = _indent(lines[i])
        if child_indent is None:
            child_indent = indent
        if indent == child_indent:
            parsed = _key_line(lines[i])
            if parsed:
                found.setdefault(parsed[1], i)
    return found


def _is_block_header(line: str) -> bool:
    parsed = _key_line(line)
    return parsed is not None and _split_comment(parsed[2])[0] == ""


def _replace_block_text(lines: list[str], node: str, block: str, values: Mapping[str, Any],
                        comments: Mapping[str, str]) -> list[str] | None:
    """``lines`` with ``<node>: ros__parameters: <block>:`` set to ``values``.

    None if the layout is not block-style YAML this can edit.
    """
    top = _top_level_keys(lines)
    if top is None:
        return None
    if node not in top:
        tail = [""] if lines and lines[-1].strip() else []
        return (lines + tail + [f"{yaml_value_text(node)}:", "  ros__parameters:", f"    {block}:"]
                + _key_lines(values, comments, 6))
    node_at = top[node]
    if not _is_block_header(lines[node_at]):
        return None
    node_end = _span_end(lines, node_at)
    params_at = _children(lines, node_at, node_end).get("ros__parameters")
    if params_at is None:
        indent = _indent(lines[node_at]) + 2
        insert = [f"{' ' * indent}ros__parameters:", f"{' ' * (indent + 2)}{block}:"]
        return lines[:node_end] + insert + _key_lines(values, comments, indent + 4) + lines[node_end:]
    if not _is_block_header(lines[params_at]):
        return None
    params_end = _span_end(lines, params_at)
    block_at = _children(lines, params_at, params_end).get(block)
    if block_at is None:
        siblings = [i for i in range(params_at + 1, params_end) if _is_content(lines[i])]
        indent = _indent(lines[siblings[0]]) if siblings else _indent(lines[params_at]) + 2
        insert = [f"{' ' * indent}{block}:"] + _key_lines(values, comments, indent + 2)
        return lines[:params_end] + insert + lines[params_end:]
    return _rewrite_block(lines, block_at, values, comments)


def _top_level_keys(lines: list[str]) -> dict[str, int] | None:
    """The file's top-level keys (node names) -> their line index; None if a top-level line is not a key."""
    top = {}
    for i, line in enumerate(lines):
        if _is_content(line) and _indent(line) == 0:
            parsed = _key_line(line)
            if parsed is None:
                return None
            top.setdefault(parsed[1], i)
    return top


def _rewrite_block(lines: list[str], block_at: int, values: Mapping[str, Any],
                   comments: Mapping[str, str]) -> list[str]:
    """``lines`` with the block headed at ``block_at`` holding ``values``; its keys keep their lines and comments.

    A block written flow style on one line (``camera: {K1: 0}``) becomes a block-style one.
    """
    block_end = _span_end(lines, block_at)
    block_indent = _indent(lines[block_at])
    head, comment = _split_comment(_key_line(lines[block_at])[2])
    old_comments: dict[str, str] = {}
    key_indent = block_indent + 2
    old_lines: dict[str, str] = {}
    if head:  # flow style on one line: rewrite it as a block
        header = f"{' ' * block_indent}{_key_line(lines[block_at])[1]}:" + (f"  # {comment}" if comment else "")
    else:
        header = lines[block_at]
        old = _children(lines, block_at, block_end)
        if old:
            key_indent = _indent(lines[min(old.values())])
        for key, i in sorted(old.items(), key=lambda item: item[1]):
            old_comments[key] = _split_comment(_key_line(lines[i])[2])[1]
            old_lines[key] = lines[i]
    return (lines[:block_at] + [header] + _key_lines(values, comments, key_indent, old_comments, old_lines)
            + lines[block_end:])


def _key_lines(values: Mapping[str, Any], comments: Mapping[str, str], indent: int,
               old_comments: Mapping[str, str] | None = None, old_lines: Mapping[str, str] | None = None
               ) -> list[str]:
    """The block's lines: keys already in the file first, in their order and with their comments.

    A key whose value does not change keeps its line as it was; a changed one keeps its comment's column.
    """
    old_comments = old_comments or {}
    old_lines = old_lines or {}
    order = [key for key in old_comments if key in values] + [key for key in values if key not in old_comments]
    out = []
    for key in order:
        text = yaml_value_text(values[key])
        old_line = old_lines.get(key)
        if old_line is not None and _same_value(old_line, text):
            out.append(old_line)
            continue
        comment = old_comments.get(key) or comments.get(key, "")
        line = f"{' ' * indent}{key}: {text}"
        if comment:
            column = _comment_column(old_line) if old_line is not None else None
            line = line.ljust(column) + f"# {comment}" if column and column >= len(line) + 2 else \
                f"{line}  # {comment}"
        out.append(line)
    return out


def _same_value(line: str, value_text: str) -> bool:
    """Whether the ``key: value`` ``line`` already holds the value ``value_text`` stands for."""
    try:
        return yaml.safe_load(_split_comment(_key_line(line)[2])[0] or "null") == yaml.safe_load(value_text)
    except yaml.YAMLError:
        return False


def _comment_column(line: str) -> int | None:
    """Where the comment of a ``key: value    # comment`` line starts when it is aligned to a column, or None.

    More than two spaces before the ``#`` mark an aligned comment; two are the plain layout, kept as such.
    """
    comment = _split_comment(_key_line(line)[2])[1]
    if not comment:
        return None
    column = line.rfind("#", 0, len(line) - len(comment))
    return column if line[column - 3:column] == "   " else None


def update_params_block(path, node: str, block: str, values: Mapping[str, Any],
                        comments: Mapping[str, str] | None = None) -> Path:
    """Set ``<node>: ros__parameters: <block>:`` to ``values`` in a ROS parameter YAML, keeping the rest of it.

    The file is edited as text so its comments and layout survive (a fitting tool pointed at a documented
    parameter file must not strip it); each key keeps its comment, new keys get ``comments[key]``. The result is
    parsed back and must equal the old document with only that block replaced; a layout this cannot edit that
    way (flow-style node blocks, anchors) is rewritten as plain YAML when the file has no comments to lose, and
    refused otherwise. Creates the file if needed; written atomically.
    """
    path = Path(path)
    comments = dict(comments or {})
    text = ""
    document: dict = {}
    if path.exists():
        try:
            text = path.read_text(encoding="utf-8")
            document = yaml.safe_load(text) or {}
        except OSError as exc:
            raise CalibrationError(f"cannot read parameter file {path}: {exc.strerror or exc}") from None
        except yaml.YAMLError as exc:
            raise CalibrationError(f"{path}: not valid YAML ({str(exc).splitlines()[0]}); fix it or write to a "
                                   "new file") from None
        if not isinstance(document, dict):
            raise CalibrationError(f"{path}: expected a ROS parameter file (a mapping of node names)")
    node_block = document.get(node, {})
    params = node_block.get("ros__parameters", {}) if isinstance(node_block, dict) else None
    if not isinstance(node_block, dict) or not isinstance(params, dict):
        raise CalibrationError(f"{path}: '{node}' has no 'ros__parameters' mapping")
    expected = dict(document)
    written = {str(k): yaml.safe_load(yaml_value_text(v)) for k, v in values.items()}
    expected[node] = {**node_block, "ros__parameters": {**params, block: written}}
    lines = text.splitlines()
    edited = _replace_block_text(lines, node, block, values, comments)
    if edited is not None:
        new_text = "\n".join(edited) + "\n"
        if _same_document(yaml.safe_load(new_text), expected):
            return atomic_write_text(path, new_text)
    if any(line.lstrip().startswith("#") or " #" in line for line in lines):
        raise CalibrationError(f"{path}: cannot set {node}.{block} in place without losing the file's comments "
                               "(its layout is not plain block-style YAML); write to a new file and copy the "
                               f"'{block}' block over")
    return atomic_write_text(path, yaml.safe_dump(expected, sort_keys=False, default_flow_style=None))


def _same_document(a: Any, b: Any) -> bool:
    return yaml.safe_dump(a, sort_keys=True) == yaml.safe_dump(b, sort_keys=True)


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


def node_blocks(blocks: Mapping[str, Mapping[str, Any]], node: str) -> list[dict]:
    """The blocks of ``read_params_yaml`` that apply to ``node``, weakest first.

    ``/**``, then the node's own (``node`` or ``/node``): updating a dict with them in order gives the
    node-specific value precedence, as ROS does.
    """
    return [dict(blocks[name]) for name in (ALL_NODES, node, f"/{node}") if name in blocks]


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
