"""Where the project's files are, and the video lists the tools take (``7-12``, ``7,9,13-17``).

The repository root, files named relative to it, the shared data set.

Plain helpers with no dependency on anything else of the project but its error class, so every layer may use them.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from vessel_common.errors import DataError


def repo_root() -> Path:
    """The project root (the folder holding ``src/``): ``$VESSEL_ROOT`` (set by ./vessel), else found from here."""
    if os.environ.get("VESSEL_ROOT"):
        return Path(os.environ["VESSEL_ROOT"])
    here = Path(__file__).resolve()
    for parent in here.parents:
        if (parent / "src" / "vessel_common").is_dir() and (parent / "pyproject.toml").exists():
            return parent
    # Installed (non-symlink) package: fall back to the working directory or its parents.
    cwd = Path.cwd().resolve()
    for parent in (cwd, *cwd.parents):
        if (parent / "src" / "vessel_common").is_dir():
            return parent
    return cwd


def in_repo(path) -> Path:
    """``path``, or for a relative path not found from the working folder, the repository's file of that name.

    The shipped configuration names its files (models, tide tables, cues) relative to the repository root.
    """
    candidate = Path(str(path)).expanduser()
    if candidate.is_absolute() or candidate.is_file():
        return candidate
    return repo_root() / candidate


def repo_file(relative: str) -> str | None:
    """The repository's file ``relative`` (e.g. ``config/aitas.yaml``) as a string, None when it is absent."""
    path = repo_root() / relative
    return str(path) if path.is_file() else None


def default_data_dir() -> Path | None:
    """``$VESSEL_DATA`` if set, else ``<repo>/../shared/aitas``; None when that folder does not exist."""
    env = os.environ.get("VESSEL_DATA")
    candidates = [Path(env).expanduser()] if env else []
    candidates.append(repo_root().parent / "shared" / "aitas")
    for candidate in candidates:
        if (candidate / "camera.json").is_file():
            return candidate
    return None


def parse_videos(spec: str | Iterable[int] | None) -> list[int] | None:
    """``"7-12"``, ``"7,9,13-17"`` or an iterable of ints -> sorted list; None stays None (all videos)."""
    if spec is None:
        return None
    if not isinstance(spec, str):
        return sorted({int(v) for v in spec})
    videos: set[int] = set()
    for part in spec.replace(" ", "").split(","):
        if not part:
            continue
        try:
            if "-" in part:
                lo, hi = part.split("-", 1)
                lo_i, hi_i = int(lo), int(hi)
                if hi_i < lo_i or lo_i < 0:
                    raise ValueError
                videos.update(range(lo_i, hi_i + 1))
            else:
                if int(part) < 0:
                    raise ValueError
                videos.add(int(part))
        except ValueError:
            raise DataError(f"bad video list {spec!r}: use e.g. 7-12 or 7,9,13-17") from None
    if not videos:
        raise DataError(f"bad video list {spec!r}: it names no video")
    return sorted(videos)


def output_file(path: str | Path) -> Path:
    """``path``, with the folder it goes in made now: a tool checks its output before the work that fills it.

    A path under a file or in a folder that is not writable fails here, at once, instead of after a long run.
    """
    path = Path(path)
    if path.is_dir():
        raise DataError(f"output {path} is a folder: give a file name")
    path.parent.mkdir(parents=True, exist_ok=True)
    if not os.access(path.parent, os.W_OK):
        raise DataError(f"cannot write into {path.parent}: no permission; give another output path")
    return path
