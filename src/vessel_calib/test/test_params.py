import os

import pytest
import yaml

from vessel_calib.camera_model import CameraModel
from vessel_calib.params import (
    atomic_write_text,
    load_camera_params,
    load_camera_yaml,
    read_params_yaml,
    update_params_block,
    write_camera_yaml,
    write_params_yaml,
)
from vessel_common.errors import CalibrationError
from vessel_fixtures.calib_synthetic import CAMERA_LAT, CAMERA_LON

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


DOCUMENTED = """\
# The graph's parameters. This header must survive a refit.
/**:
  ros__parameters:
    use_sim_time: false   # keep me

fuser:
  ros__parameters:
    input_topic: /vessel/tracks/screen  # topic comment
    distance_model:
      a: 1.0   # width = a / depth + b
      b: 2.0
      old_key: 3   # dropped: the fit no longer writes it
    fusion:
      anchor_offset: 0.05  # the detector's boxes
    # a comment between blocks
    error_model:
      slope: 0.0908  # per metre
tracker:
  ros__parameters: {min_hits: 3}  # flow style elsewhere is left alone
"""


def test_update_block_keeps_comments_order_and_every_other_block(tmp_path):
    """A fitting tool pointed at a documented parameter file replaces one block and loses nothing else."""
    path = tmp_path / "graph.yaml"
    path.write_text(DOCUMENTED)
    update_params_block(path, "fuser", "distance_model",
                        {"b": 20.5, "a": 4825.857747169489, "source": "labels 7-12, x"},
                        comments={"source": "where it comes from", "a": "not used: the file has a comment"})
    text = path.read_text()
    doc = yaml.safe_load(text)
    assert doc["fuser"]["ros__parameters"]["distance_model"] == {"a": 4825.857747169489, "b": 20.5,
                                                                  "source": "labels 7-12, x"}
    before = yaml.safe_load(DOCUMENTED)
    for node in ("/**", "tracker"):
        assert doc[node] == before[node]
    for block in ("fusion", "error_model", "input_topic"):
        assert doc["fuser"]["ros__parameters"][block] == before["fuser"]["ros__parameters"][block]
    lines = text.splitlines()
    for line in DOCUMENTED.splitlines():
        if "old_key" not in line and not line.lstrip().startswith(("a:", "b:")):
            assert line in lines, line
    block = lines[lines.index("    distance_model:") + 1:lines.index("    fusion:")]
    assert block == ["      a: 4825.857747169489   # width = a / depth + b".replace("   #", "  #"),
                     "      b: 20.5", "      source: 'labels 7-12, x'  # where it comes from"]


def test_update_block_leaves_the_lines_of_unchanged_values_as_they_were(tmp_path):
    """A refit that gives the same values used to realign their comments and requote strings: a diff of nothing."""
    path = tmp_path / "graph.yaml"
    original = ("detector:\n  ros__parameters:\n    size_prior:\n"
                "      dimension: width            # the box size compared\n"
                "      model: [1.5, 2.0]   # a, b\n"
                "      source: labels 7-12, camera x.yaml  # where it comes from\n")
    path.write_text(original)
    update_params_block(path, "detector", "size_prior",
                        {"dimension": "width", "model": [1.5, 2.0], "source": "labels 7-12, camera x.yaml"})
    assert path.read_text() == original
    update_params_block(path, "detector", "size_prior",
                        {"dimension": "height", "model": [1.5, 2.0], "source": "labels 7-12, camera x.yaml"})
    assert path.read_text() == original.replace("dimension: width ", "dimension: height")  # its comment's column


def test_update_block_adds_missing_blocks_and_files(tmp_path):
    path = tmp_path / "graph.yaml"
    path.write_text(DOCUMENTED)
    update_params_block(path, "fuser", "offline", {"iterations": 5, "threshold": float("nan")},
                        {"iterations": "passes"})
    update_params_block(path, "gps_publisher", "error_model", {"slope": 0.05})
    doc = yaml.safe_load(path.read_text())
    offline = doc["fuser"]["ros__parameters"]["offline"]
    assert offline["iterations"] == 5 and offline["threshold"] != offline["threshold"]
    assert "      iterations: 5  # passes" in path.read_text().splitlines()
    assert doc["gps_publisher"] == {"ros__parameters": {"error_model": {"slope": 0.05}}}
    assert path.read_text().startswith("# The graph's parameters.")
    fresh = tmp_path / "new" / "fresh.yaml"
    update_params_block(fresh, "fuser", "error_model", {"slope": 0.07, "source": "a: b"})
    assert yaml.safe_load(fresh.read_text()) == {"fuser": {"ros__parameters": {"error_model": {
        "slope": 0.07, "source": "a: b"}}}}


def test_update_block_rewrites_a_flow_style_block_and_refuses_to_drop_comments(tmp_path):
    """A one-line flow block becomes a block; a flow-style node with comments in the file is refused, untouched."""
    path = tmp_path / "flow.yaml"
    path.write_text("fuser:\n  ros__parameters:\n    fusion: {anchor_offset: 0.05, weights_mode: paper}\n")
    update_params_block(path, "fuser", "fusion", {"anchor_offset": 0.05, "weights_mode": "fitted"})
    assert path.read_text() == "fuser:\n  ros__parameters:\n    fusion:\n      anchor_offset: 0.05\n" \
                               "      weights_mode: fitted\n"
    path.write_text(DOCUMENTED)
    with pytest.raises(CalibrationError, match="without losing the file's comments"):
        update_params_block(path, "tracker", "gate", {"px": 40.0})
    assert path.read_text() == DOCUMENTED
    bare = tmp_path / "bare.yaml"
    bare.write_text("tracker:\n  ros__parameters: {min_hits: 3}\n")
    update_params_block(bare, "tracker", "gate", {"px": 40.0})
    assert yaml.safe_load(bare.read_text()) == {"tracker": {"ros__parameters": {"min_hits": 3, "gate": {"px": 40.0}}}}
    bad = tmp_path / "bad.yaml"
    bad.write_text("fuser: [1, 2\n")
    with pytest.raises(CalibrationError, match="not valid YAML"):
        update_params_block(bad, "fuser", "fusion", {"a": 1})
