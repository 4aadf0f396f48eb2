"""Dataset.own_ship and Dataset.reference_attitude: a dataset folder of a camera on a ship."""

import json
import math

import pytest

from vessel_calib.own_ship import ShipAttitude
from vessel_common.errors import DataError
from vessel_fixtures import detect_synthetic as synthetic
from vessel_tools.calib.dataset import Dataset

DAY0 = math.floor(synthetic.START_UTC / 86400.0) * 86400.0


def dataset_with(tmp_path, own_ship: str | None = None, reference=None):
    data = synthetic.write_dataset(tmp_path / "data", videos=(13,), frames_per_video=2)
    if own_ship is not None:
        (data.path / "own_ship.csv").write_text("utc_s,lat,lon,heading_deg,pitch_deg,roll_deg\n" + own_ship)
    if reference is not None:
        camera = json.loads((data.path / "camera.json").read_text())
        camera["reference_attitude"] = reference
        (data.path / "camera.json").write_text(json.dumps(camera))
    return Dataset(data.path)


def test_no_own_ship_csv_and_no_reference_attitude(tmp_path):
    dataset = dataset_with(tmp_path)
    assert dataset.own_ship() is None and dataset.reference_attitude() is None


def test_own_ship_samples_are_epoch_stamped_like_the_other_files_and_cached(tmp_path):
    sod = synthetic.START_UTC - DAY0
    dataset = dataset_with(tmp_path, f"{sod:.2f},32.7,-117.2,76.0,0.5,-1.0\n{sod + 0.05:.2f},32.7,-117.2,76.5,,\n")
    samples = dataset.own_ship()
    assert [s.stamp for s in samples] == pytest.approx([DAY0 + round(sod, 2), DAY0 + round(sod + 0.05, 2)], abs=1e-6)
    assert abs(samples[0].stamp - synthetic.START_UTC) < 0.01
    assert samples[0].attitude == ShipAttitude(76.0, 0.5, -1.0) and samples[1].attitude == ShipAttitude(76.5)
    assert dataset.own_ship() is samples


def test_a_bad_own_ship_row_names_the_file_and_row(tmp_path):
    dataset = dataset_with(tmp_path, "70000,32.7,-117.2,76.0,0.5,-1.0\n70000.05,32.7,-117.2,north,0.5,-1.0\n")
    with pytest.raises(DataError, match=r"own_ship.csv, row 3, column 'heading_deg': expected a number"):
        dataset.own_ship()


def test_reference_attitude(tmp_path):
    full = dataset_with(tmp_path / "a", reference={"heading_deg": 76, "pitch_deg": 0.0, "roll_deg": 0.0,
                                                   "meaning": "the calibration's H holds at this attitude"})
    assert full.reference_attitude() == ShipAttitude(76.0, 0.0, 0.0)
    compass = dataset_with(tmp_path / "b", reference={"heading_deg": 76.0, "pitch_deg": None})
    assert compass.reference_attitude() == ShipAttitude(76.0)


@pytest.mark.parametrize(("reference", "what"), [
    ({"pitch_deg": 0.0, "roll_deg": 0.0}, "'heading_deg' must be a number of degrees, got None"),
    ({"heading_deg": "76"}, "'heading_deg' must be a number of degrees"),
    ({"heading_deg": 76.0, "pitch_deg": 1.0}, "only one of pitch and roll"),
    ({"heading_deg": 76.0, "pitch_deg": math.inf, "roll_deg": 0.0}, "'pitch_deg' must be a number"),
    ([76.0, 0.0, 0.0], "must be an object"),
])
def test_a_bad_reference_attitude_is_named(tmp_path, reference, what):
    dataset = dataset_with(tmp_path, reference=reference)
    with pytest.raises(DataError, match="camera.json: 'reference_attitude'") as error:
        dataset.reference_attitude()
    assert what in str(error.value)
