"""The challenge videos as bags, built in a child process as ``./vessel bag build`` builds them."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path


def build_video_bags(data_dir: Path, out: Path, videos: str, env: dict | None = None, timeout_s: float = 300) -> Path:
    """Build the bags of ``videos`` (e.g. "13,14") from ``data_dir`` into ``out``; fails with the builder's stderr."""
    done = subprocess.run([sys.executable, "-m", "vessel_tools.detect.bag_build", "--data", str(data_dir),
                           "--videos", videos, "--out", str(out)], env=env, capture_output=True, text=True,
                          timeout=timeout_s)
    assert done.returncode == 0, done.stderr[-2000:]
    return Path(out)
