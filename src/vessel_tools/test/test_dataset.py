import json
import shutil

import pytest

from vessel_common.errors import DataError
from vessel_common.paths import default_data_dir, parse_videos, repo_root
from vessel_tools.calib.dataset import Dataset


def test_parse_videos():
    assert parse_videos("7-12") == [7, 8, 9, 10, 11, 12]
    assert parse_videos("7,9,13-14") == [7, 9, 13, 14]
    assert parse_videos([9, 7, 7]) == [7, 9]
    assert parse_videos(None) is None
    for bad in ("x", "12-7", "", "-3"):
        with pytest.raises(DataError):
            parse_videos(bad)


def test_repo_root():
    assert (repo_root() / "src" / "vessel_calib").is_dir()


def test_default_data_dir_env(monkeypatch, tmp_path):
    monkeypatch.setenv("VESSEL_DATA", str(tmp_path))
    (tmp_path / "camera.json").write_text("{}")
    assert default_data_dir() == tmp_path


def write_minimal(folder):
    folder.mkdir(exist_ok=True)
    (folder / "camera.json").write_text(json.dumps({"camera_lat": 32.70297, "camera_lon": -117.234631,
                                                    "image_width": 1280, "image_height": 720}))
    (folder / "frames.csv").write_text("video,frame,utc,has_label,file\n"
                                       "7,0,2020-09-30T23:59:58.000Z,1,frames/7/00000.jpg\n"
                                       "7,100,2020-10-01T00:00:02.000Z,1,frames/7/00100.jpg\n")


def test_minimal_folder_optional_files_absent(tmp_path):
    write_minimal(tmp_path)
    ds = Dataset(tmp_path)
    assert ds.videos() == [7]
    assert ds.labels() == [] and ds.gt_1hz() == [] and len(ds.gps_track()) == 0
    assert ds.frames()[1].stamp - ds.frames()[0].stamp == 4.0
    with pytest.raises(DataError, match="no calibration"):
        ds.camera_model()
    assert ds.check_videos([7]) == [7] and ds.check_videos(None) == [7] and ds.check_videos("7") == [7]
    with pytest.raises(DataError, match=r"video\(s\) 8, 99 not in .*frames.csv \(it has 7\); fix --videos"):
        ds.check_videos([99, 7, 8])


def test_seconds_of_day_across_midnight(tmp_path):
    write_minimal(tmp_path)
    (tmp_path / "screen_labels.csv").write_text(
        "video,frame,t_utc_s,x1,y1,x2,y2,primary,lat,lon,gps_ok\n"
        "7,0,86398.0,10,20,30,40,1,32.7,-117.2,1\n"
        "7,100,2.0,10,20,30,40,1,32.7,-117.2,1\n")
    labels = Dataset(tmp_path).labels()
    assert labels[1].stamp - labels[0].stamp == 4.0
    assert labels[0].center == (20.0, 30.0)


@pytest.mark.parametrize("line, match", [
    ("7,0,86398.0,ten,20,30,40,1,32.7,-117.2,1", "row 2, column 'x1'"),
    ("7,0,86398.0,10,20,30,40,1,,-117.2,1", "gps_ok=1"),
    ("7,0,86398.0,10,20,30,40,maybe,32.7,-117.2,1", "column 'primary'"),
    ("7,0,86398.0,50,20,30,40,1,32.7,-117.2,1", "x2 < x1"),
])
def test_malformed_labels_name_file_row_column(tmp_path, line, match):
    write_minimal(tmp_path)
    (tmp_path / "screen_labels.csv").write_text(
        "video,frame,t_utc_s,x1,y1,x2,y2,primary,lat,lon,gps_ok\n" + line + "\n")
    with pytest.raises(DataError, match=match) as info:
        Dataset(tmp_path).labels()
    assert "screen_labels.csv" in str(info.value)


def test_missing_required_files(tmp_path):
    with pytest.raises(DataError, match="does not exist"):
        Dataset(tmp_path / "nope")
    with pytest.raises(DataError, match="camera.json"):
        Dataset(tmp_path)
    write_minimal(tmp_path)
    (tmp_path / "frames.csv").write_text("video,frame\n7,0\n")
    with pytest.raises(DataError, match="missing column"):
        Dataset(tmp_path).frames()
    (tmp_path / "camera.json").write_text("{not json")
    with pytest.raises(DataError, match="JSON"):
        Dataset(tmp_path)


def test_shared_data(dataset):
    assert dataset.videos() == list(range(6, 18))
    assert len(dataset.frames()) == 432 and len(dataset.frames([7])) == 36
    frame = dataset.frames([7])[0]
    assert frame.stamp == pytest.approx(1601494588.25) and frame.path.is_file()
    train = [lab for lab in dataset.labels("7-12") if lab.gps_ok]
    val = [lab for lab in dataset.labels("13-17") if lab.gps_ok]
    assert len(train) == 66 and len(val) == 78
    assert len(dataset.labels(primary_only=False)) == 264
    # label stamps agree with the frame clock
    stamps = {(f.video, f.frame): f.stamp for f in dataset.frames()}
    common = [lab for lab in train if (lab.video, lab.frame) in stamps]
    assert len(common) > 30
    assert all(abs(stamps[(lab.video, lab.frame)] - lab.stamp) < 0.01 for lab in common)
    gt = dataset.gt_1hz([13])
    assert gt and all(r.stamp == int(r.stamp) for r in gt)
    assert len(dataset.gps_track()) == 2359
    assert dataset.video_splits()[13] == "val"
    cam = dataset.camera_model()
    assert cam.camera_lat == pytest.approx(32.70297)


def test_copy_of_shared_data_with_corrupt_fixes(dataset, tmp_path):
    folder = tmp_path / "copy"
    folder.mkdir()
    for name in ("camera.json", "frames.csv"):
        shutil.copy(dataset.path / name, folder / name)
    (folder / "target_gps_fixes.csv").write_text("fix_index,utc_s,t_spread_s,lat,lon\n0,1,1.0,32.7,-117.2\n"
                                                 "1,2,2.0,,\n2,3,oops,32.7,-117.2\n")
    with pytest.raises(DataError, match="row 4, column 't_spread_s'"):
        Dataset(folder).gps_track()
