import os

import pytest
import yaml
from calib_synthetic import CAMERA_LAT, CAMERA_LON

from vessel_calib.camera_model import CameraModel
from vessel_calib.errors import CalibrationError
from vessel_calib.params import (
    atomic_write_text,
    load_camera_params,
    load_camera_yaml,
    read_params_yaml,
    write_camera_yaml,
    write_params_yaml,
)

PAPER_H = [[-441.0, 379.0, -1000.0], [-217.0, -56.5, -548.0], [-0.512, -0.144, 1.0]]


@pytest.fixture
def camera():
    return CameraModel(PAPER_H, -4.053e-7, camera_lat=CAMERA_LAT, camera_lon=CAMERA_LON)


def test_round_trip(tmp_path, camera):
    path = write_camera_yaml(tmp_path / "cal.yaml", camera, header="fitted by a test")
    text = path.read_text()
    assert text.startswith("# fitted by a test\n/**:\n  ros__parameters:\n    camera:\n")
    doc = yaml.safe_load(text)
    block = doc["/**"]["ros__parameters"]["camera"]
    assert all(isinstance(v, float) for v in block["H"]) and isinstance(block["image_width"], int)
    assert load_camera_yaml(path) == camera
    assert [p.name for p in tmp_path.iterdir()] == ["cal.yaml"]  # no temp file left behind


def test_flattened_and_node_scoped_blocks(tmp_path, camera):
    params = {f"camera.{k}": v for k, v in camera.to_params().items()}
    write_params_yaml(tmp_path / "flat.yaml", {"tracker": params})
    assert load_camera_yaml(tmp_path / "flat.yaml") == camera
    blocks = read_params_yaml(tmp_path / "flat.yaml")
    assert "tracker" in blocks


def mutate(tmp_path, camera, **changes):
    params = camera.to_params()
    for key, value in changes.items():
        if value is None:
            params.pop(key)
        else:
            params[key] = value
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": {"camera": params}}}))
    return path


@pytest.mark.parametrize("changes, match", [
    ({"H": [1.0, 2.0, 3.0, 2.0, 4.0, 6.0, 0.0, 0.0, 1.0]}, "singular"),
    ({"H": [1.0] * 8}, "9 numbers"),
    ({"H": ["a"] * 9}, r"H\[0\] must be a number"),
    ({"H": "identity"}, "H must be a list"),
    ({"K1": "small"}, "K1 must be a number"),
    ({"K1": 1.0}, "K1"),
    ({"image_width": 1280.5}, "image_width must be a positive integer"),
    ({"camera_lat": 123.0}, "latitude"),
    ({"center_x": None}, "missing key.*center_x"),
])
def test_loader_rejects_with_reason(tmp_path, camera, changes, match):
    path = mutate(tmp_path, camera, **changes)
    with pytest.raises(CalibrationError, match=match) as info:
        load_camera_yaml(path)
    assert "bad.yaml" in str(info.value)


def test_loader_rejects_non_parameter_files(tmp_path):
    path = tmp_path / "x.yaml"
    path.write_text("just: a mapping\n")
    with pytest.raises(CalibrationError, match="ros__parameters"):
        load_camera_params(path)
    path.write_text("/**:\n  ros__parameters:\n    other: 1\n")
    with pytest.raises(CalibrationError, match="camera"):
        load_camera_params(path)
    path.write_text("/**: [unclosed\n")
    with pytest.raises(CalibrationError, match="not valid YAML"):
        load_camera_params(path)
    with pytest.raises(CalibrationError, match="cannot read"):
        load_camera_params(tmp_path / "missing.yaml")


def test_atomic_write_keeps_old_file_on_failure(tmp_path, monkeypatch):
    path = tmp_path / "cal.yaml"
    path.write_text("old")

    def boom(*args):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError):
        atomic_write_text(path, "new")
    assert path.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["cal.yaml"]


def test_non_finite_values_refused(tmp_path):
    with pytest.raises(CalibrationError, match="non-finite"):
        write_params_yaml(tmp_path / "x.yaml", {"/**": {"a": float("nan")}})
    assert not (tmp_path / "x.yaml").exists()
