"""Every library the packages import is a dependency their package.xml declares (what rosdep installs).

The packages used to import launch_ros, scipy, matplotlib, onnxruntime, mcap, rosbags and filterpy without
declaring them, so `rosdep install` on a ROS machine left the nodes failing at import.
"""

from __future__ import annotations

import ast
import sys
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("vessel_common", "vessel_calib", "vessel_detect", "vessel_track", "vessel_bringup", "vessel_tools")
ROSDEP_KEY = {
    "numpy": "python3-numpy", "cv2": "python3-opencv", "yaml": "python3-yaml", "scipy": "python3-scipy",
    "matplotlib": "python3-matplotlib", "onnxruntime": "python3-onnxruntime-pip", "mcap": "python3-mcap-pip",
    "rosbags": "python3-rosbags-pip", "filterpy": "python3-filterpy-pip", "websockets": "python3-websockets",
}
OPTIONAL = {"torch", "onnx2torch", "onnx", "backports", "compression", "vessel_detect", "foxglove", "selenium"}
"""The training extra (requirements-train.txt), the view extra (requirements-view.txt: foxglove-sdk for
``view --foxglove-port``, selenium for the browser test), version fallbacks imported inside try blocks, and
vessel_detect: the
calibration tool runs its detector for a calibration without labels when it is installed (``calibrate --from
detections``; an ImportError says so), and declaring it would make vessel_calib and vessel_detect depend on each
other."""


def _imports(package: str) -> set[str]:
    found = set()
    root = REPO / "src" / package
    for path in [*root.joinpath(package).rglob("*.py"), *root.glob("launch/*.py")]:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                found |= {alias.name.split(".")[0] for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                found.add(node.module.split(".")[0])
    return found - set(sys.stdlib_module_names) - OPTIONAL - {package, "__future__"}


def _declared(package: str) -> set[str]:
    tree = ElementTree.parse(REPO / "src" / package / "package.xml")
    return {e.text.strip() for e in tree.getroot() if e.tag in ("depend", "exec_depend") and e.text}


@pytest.mark.parametrize("package", PACKAGES)
def test_every_import_is_a_declared_dependency(package):
    missing = sorted(ROSDEP_KEY.get(name, name) for name in _imports(package)
                     if ROSDEP_KEY.get(name, name) not in _declared(package))
    assert not missing, f"src/{package}/package.xml lacks <exec_depend> of {missing}"


def test_the_pip_only_keys_have_rosdep_rules():
    rules = yaml.safe_load((REPO / "rosdep" / "vessel_tracking.yaml").read_text())
    used = set().union(*(_declared(p) for p in PACKAGES))
    assert {key for key in used if key.endswith("-pip")} <= set(rules)
