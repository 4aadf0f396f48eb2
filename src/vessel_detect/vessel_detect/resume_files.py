"""Where a restarted camera or recorder carries on (their ``resume_file``): small JSON files, written atomically.

``./vessel graph --respawn`` and the launch file's ``respawn:=true`` give the camera and the recorder a
``resume_file`` in the run's state folder, beside the tracker's and the fuser's state files (removed at the start of
a run, so a new run starts from the beginning). The camera writes where its replay is after every item it publishes
(the source, the source's start time and a ``ReplayPosition``); a restarted camera carries on after it instead of
replaying from the first frame. The recorder writes the bags of its recording; a restarted recorder records into
the next part beside them (``OUT.1``, ``OUT.2``, ...) instead of refusing the existing ``OUT``, which stays as it was
(``./vessel bag recover OUT`` makes it readable if it was not closed). ``recording_parts`` lists a recording's parts.
ROS-free.
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

from vessel_common.errors import DataError
from vessel_detect.replay_pacing import ReplayPosition

SCHEMA = "vessel_resume"
VERSION = 1


class ResumeFileError(DataError):
    """A resume file that is not one of this schema, version and node; the message says why (it is not used)."""


def write_json_atomically(path: Path, data: dict) -> None:
    """Write ``data`` to ``path`` through a temporary file renamed over it: a kill leaves the old file or the new one.

    OSError when the disk refuses (the old file then stays as it was).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        temporary.write_text(json.dumps(data, separators=(",", ":")), encoding="utf-8")
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)


def read_resume_file(path: Path, node: str) -> dict | None:
    """The contents of ``node``'s resume file; None when there is none; ResumeFileError when it is not one."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError) as error:
        raise ResumeFileError(f"resume file {path} is unreadable ({error})") from None
    try:
        data = json.loads(text)
    except ValueError as error:
        raise ResumeFileError(f"resume file {path} is not JSON ({error})") from None
    header = {key: data.get(key) for key in ("schema", "version", "node")} if isinstance(data, dict) else None
    if header != {"schema": SCHEMA, "version": VERSION, "node": node}:
        raise ResumeFileError(f"{path} is not a {node} resume file of version {VERSION}")
    return data


def _record(node: str, **fields: object) -> dict:
    return {"schema": SCHEMA, "version": VERSION, "node": node, **fields}


# --------------------------------------------------------------------------------------------------------- camera
def camera_record(source: str, first_ns: int | None, start_utc: float | None, position: ReplayPosition) -> dict:
    """What the camera writes to its resume file after each item it handled."""
    return _record("camera", source=source, first_ns=first_ns, start_utc=start_utc, position=position.as_dict())


def camera_start_utc(data: dict | None, source: str) -> float | None:
    """The start time the camera before the restart gave its source (a video or folder stamped from it), if any.

    A restarted camera opens the source with it, so its frames carry the stamps they had before the restart.
    """
    if not data or data.get("source") != source:
        return None
    start = data.get("start_utc")
    return float(start) if type(start) in (int, float) and math.isfinite(start) else None


def camera_resume_point(data: dict | None, source: str, first_ns: int | None) -> tuple[ReplayPosition | None, str]:
    """Where a restarted camera carries on, from its resume file's ``data``, and what happened, in words.

    None (from the first frame) when there is no file or it is of another source or start time.
    """
    if data is None:
        return None, "no resume file: from the first frame"
    if data.get("source") != source or data.get("first_ns") != first_ns:
        return None, (f"the resume file is of another source ({data.get('source')!r} starting at "
                      f"{data.get('first_ns')}): from the first frame")
    try:
        position = ReplayPosition.from_dict(data.get("position"))
    except ValueError as error:
        raise ResumeFileError(f"the resume file's position: {error}") from None
    return position, (f"carrying on after the item stamped {position.stamp_ns / 1e9:.3f} s (pass {position.loop}): "
                      f"{position.frames_sent} frames were sent before the restart")


# ------------------------------------------------------------------------------------------------------- recorder
def recording_parts(output: Path) -> list[Path]:
    """A recording's bags in order: ``output``, then the parts a restarted recorder continued into (``output.N``)."""
    output = Path(output)
    pattern = re.compile(re.escape(output.name) + r"\.([1-9][0-9]*)")
    parts = []
    if output.parent.is_dir():
        parts = [p for p in output.parent.iterdir() if p.is_dir() and pattern.fullmatch(p.name)]
    parts.sort(key=lambda p: int(p.name.rsplit(".", 1)[1]))
    return ([output] if output.exists() else []) + parts


def recorder_output(data: dict | None, output: str) -> tuple[Path | None, list[Path]]:
    """Where a recorder writes, from its resume file's ``data`` and its ``output`` parameter.

    (None, []) on a first start (no file, or one of another output: the caller uses ``output``); on a restart (the
    file names the bags this recording wrote) the next free part beside the first, ``OUT.N``, and the earlier parts.
    """
    if not data:
        return None, []
    parts = data.get("parts")
    if not isinstance(parts, list) or not parts or not all(isinstance(part, str) for part in parts):
        raise ResumeFileError("the recorder's resume file names no bag")
    first = Path(parts[0])
    if output and Path(output).expanduser() != first:
        return None, []
    number = max([int(p.name.rsplit(".", 1)[1]) for p in recording_parts(first)[1:]] + [0]) + 1
    while first.with_name(f"{first.name}.{number}").exists():
        number += 1
    return first.with_name(f"{first.name}.{number}"), [Path(part) for part in parts]


def recorder_record(parts: list[Path]) -> dict:
    """What the recorder writes to its resume file once its bag is open: every part of the recording so far."""
    return _record("recorder", parts=[str(part) for part in parts])
