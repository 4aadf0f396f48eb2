"""bag_build with an own_ship.csv: /own_ship/fix and /own_ship/imu land in each video's bag, in time order."""

import csv
import json
import math
import shutil

import numpy as np
import pytest

from vessel_calib.own_ship import attitude_reading
from vessel_detect import bag_messages, bag_reader, bag_topics
from vessel_fixtures import detect_synthetic as synthetic
from vessel_tools.detect import bag_build, own_ship_bag

DAY0 = math.floor(synthetic.START_UTC / 86400.0) * 86400.0


def run_cli(args, capsys):
    status = bag_build.main([str(a) for a in args])
    out, err = capsys.readouterr()
    return status, out, err


def attitude_at(t):
    """A rolling, pitching, yawing ship (degrees); the heading swings through north."""
    return ((5.0 + 10.0 * math.sin(t / 7.0)) % 360.0, 2.0 * math.sin(t / 2.0), 5.0 * math.sin(t / 3.0))


def write_own_ship(path, start_s, end_s, *, compass_only=(), no_position=(), hole=None, step_s=0.05):
    """own_ship.csv at 20 Hz over [start, end] (epoch s); returns {utc_s text: (lat, lon, heading, pitch, roll)}."""
    rows = {}
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["utc_s", "lat", "lon", "heading_deg", "pitch_deg", "roll_deg"])
        for k in range(int(round((end_s - start_s) / step_s)) + 1):
            t = start_s + k * step_s
            if hole is not None and hole[0] < t < hole[1]:
                continue
            utc_s = f"{t - DAY0:.2f}"
            heading, pitch, roll = (round(v, 4) for v in attitude_at(t - start_s))
            lat, lon = round(32.70297 + 1e-6 * k, 8), -117.234631
            if any(a <= t <= b for a, b in compass_only):
                pitch = roll = None
            if any(a <= t <= b for a, b in no_position):
                lat = lon = None
            writer.writerow([utc_s, *("" if v is None else v for v in (lat, lon, heading, pitch, roll))])
            rows[utc_s] = (lat, lon, heading, pitch, roll)
    return rows


def read_own_ship(path):
    """(fixes, imus) of a bag: [(stamp ns, status, lat, lon)], [(stamp ns, frame_id, AttitudeReading)]; log times."""
    with bag_reader.BagReader(path) as reader:
        times = [m.log_time_ns for m in reader.messages()]
        fixes, imus = [], []
        for message in reader.messages([bag_topics.DEFAULT_OWN_SHIP_FIX_TOPIC, bag_topics.DEFAULT_OWN_SHIP_IMU_TOPIC]):
            decoded = reader.decode(message)
            stamp = bag_messages.ns_of_stamp(decoded.header.stamp)
            # logged ahead of their stamps, so a replay hands each image the samples after it (own_ship_bag.LEAD_NS)
            assert stamp - message.log_time_ns == own_ship_bag.LEAD_NS and decoded.header.frame_id == "base_link"
            if message.msgtype == bag_topics.IMU:
                q = decoded.orientation
                imus.append((stamp, attitude_reading((q.x, q.y, q.z, q.w), list(decoded.orientation_covariance))))
            else:
                assert message.msgtype == bag_topics.NAV_SAT_FIX
                fixes.append((stamp, decoded.status.status, decoded.latitude, decoded.longitude))
    assert times == sorted(times)
    return fixes, imus


def expected_in(rows, lo, hi):
    return {utc_s: row for utc_s, row in rows.items() if lo <= DAY0 + float(utc_s) <= hi}


def check_against_rows(fixes, imus, rows):
    """Every fix and attitude of the bag is the CSV's row at that stamp; the right number of each."""
    stamps = {bag_messages.sec_to_ns(DAY0 + float(utc_s)): row for utc_s, row in rows.items()}
    assert [f[0] for f in fixes] == sorted(stamps)
    assert len(imus) == len(stamps)  # every row here has a heading
    for stamp, status, lat, lon in fixes:
        want = stamps[stamp]
        if want[0] is None:
            assert status == bag_topics.STATUS_NO_FIX and math.isnan(lat) and math.isnan(lon)
        else:
            assert (status, lat, lon) == (bag_topics.STATUS_FIX, want[0], want[1])
    for stamp, reading in imus:
        heading, pitch, roll = stamps[stamp][2:]
        a = reading.attitude
        assert reading.ok and abs((a.heading_deg - heading + 180.0) % 360.0 - 180.0) < 1e-9
        if pitch is None:
            assert not a.has_tilt
        else:
            assert (a.pitch_deg, a.roll_deg) == pytest.approx((pitch, roll), abs=1e-9)


def test_own_ship_topics_of_a_generated_dataset(tmp_path, capsys):
    data = synthetic.write_dataset(tmp_path / "data", videos=(13, 14), frames_per_video=5)
    first, last = data.stamps[13][0], data.stamps[14][-1]
    hole = (first + 6.0, first + 9.0)
    rows = write_own_ship(data.path / "own_ship.csv", first - 20.0, last + 20.0, hole=hole,
                          compass_only=[(first - 5.0, first + 2.0)], no_position=[(first + 3.0, first + 4.0)])
    status, out, err = run_cli(["--data", data.path, "--videos", "13,14", "--out", tmp_path / "bags"], capsys)
    assert status == 0, err
    margin = bag_build.BuildOptions().own_ship_margin_s
    for video in (13, 14):
        stamps = data.stamps[video]
        want = expected_in(rows, stamps[0] - margin, stamps[-1] + margin)
        fixes, imus = read_own_ship(tmp_path / "bags" / f"video_{video}")
        check_against_rows(fixes, imus, want)
        gaps = " (1 gaps over 1 s)" if video == 13 else ""
        assert f"{len(want)} own-ship fixes and {len(want)} attitudes{gaps}, " in out
    assert any(not r.attitude.has_tilt for _, r in read_own_ship(tmp_path / "bags" / "video_13")[1])


def test_other_topic_names_and_no_own_ship_without_the_file(tmp_path, capsys):
    data = synthetic.write_dataset(tmp_path / "data", videos=(13,), frames_per_video=3)
    status, out, err = run_cli(["--data", data.path, "--out", tmp_path / "plain"], capsys)
    assert status == 0, err
    assert "own-ship" not in out
    with bag_reader.BagReader(tmp_path / "plain" / "video_13") as reader:
        assert bag_topics.DEFAULT_OWN_SHIP_IMU_TOPIC not in reader.topics
    stamps = data.stamps[13]
    rows = write_own_ship(data.path / "own_ship.csv", stamps[0] - 1.0, stamps[-1] + 1.0)
    status, out, err = run_cli(["--data", data.path, "--out", tmp_path / "named", "--own-ship-imu-topic", "/ship/att",
                                "--own-ship-fix-topic", "/ship/gps", "--own-ship-margin-s", "0"], capsys)
    assert status == 0, err
    with bag_reader.BagReader(tmp_path / "named" / "video_13") as reader:
        count = len(expected_in(rows, stamps[0], stamps[-1]))  # no margin: the frames' window only
        assert reader.message_count("/ship/att") == reader.message_count("/ship/gps") == count == 160
        assert bag_topics.DEFAULT_OWN_SHIP_IMU_TOPIC not in reader.topics
    status, out, err = run_cli(["--data", data.path, "--out", tmp_path / "x", "--own-ship-imu-topic", "imu"], capsys)
    assert status == 2 and "--own-ship-imu-topic 'imu' is not an absolute topic name" in err


@pytest.mark.parametrize(("bad", "column"), [("abc", "pitch_deg"), ("", "roll_deg")])
def test_a_bad_own_ship_csv_is_one_error_line_naming_the_row(tmp_path, capsys, bad, column):
    data = synthetic.write_dataset(tmp_path / "data", videos=(13,), frames_per_video=3)
    path = data.path / "own_ship.csv"
    write_own_ship(path, data.stamps[13][0], data.stamps[13][-1])
    lines = path.read_text().splitlines()
    fields = lines[4].split(",")
    fields[4 if column == "pitch_deg" else 5] = bad
    lines[4] = ",".join(fields)
    path.write_text("\n".join(lines) + "\n")
    status, out, err = run_cli(["--data", data.path, "--out", tmp_path / "bags"], capsys)
    assert status == 2 and "Traceback" not in err
    error_lines = [line for line in err.splitlines() if line.strip()]
    assert len(error_lines) == 1 and error_lines[0].startswith("error:")
    assert f"own_ship.csv, row 5, column '{column}'" in error_lines[0] and "correct or delete that row" in err
    assert not (tmp_path / "bags" / "video_13").exists()


@pytest.mark.data
def test_shared_dataset_video_with_an_own_ship(tmp_path, capsys):
    from vessel_common.paths import default_data_dir
    from vessel_tools.calib.dataset import Dataset

    shared = default_data_dir()
    if shared is None:
        pytest.skip("shared dataset ../shared/aitas (or $VESSEL_DATA) is absent")
    data = tmp_path / "ship"
    data.mkdir()
    for name in ("frames.csv", "target_gps_fixes.csv"):
        shutil.copy(shared / name, data / name)
    (data / "frames").symlink_to((shared / "frames").resolve())
    camera = json.loads((shared / "camera.json").read_text())
    camera["reference_attitude"] = {"heading_deg": 76.0, "pitch_deg": 0.0, "roll_deg": 0.0}
    (data / "camera.json").write_text(json.dumps(camera))
    records = Dataset(shared).frames([15])
    rows = write_own_ship(data / "own_ship.csv", math.floor(records[0].stamp) - 10.0,
                          math.ceil(records[-1].stamp) + 10.0)
    status, out, err = run_cli(["--data", data, "--videos", "15", "--out", tmp_path / "bags"], capsys)
    assert status == 0, err
    fixes, imus = read_own_ship(tmp_path / "bags" / "video_15")
    margin = bag_build.BuildOptions().own_ship_margin_s
    want = expected_in(rows, records[0].stamp - margin, records[-1].stamp + margin)
    assert len(want) > 20 * (records[-1].stamp - records[0].stamp)
    check_against_rows(fixes, imus, want)
    with bag_reader.BagReader(tmp_path / "bags" / "video_15") as reader:
        frame_ns = [bag_messages.sec_to_ns(t) for t, _ in reader.images()]
    assert frame_ns == [bag_messages.sec_to_ns(r.stamp) for r in records]
    # the attitude is there around every frame, at most a sample step away
    imu_ns = np.array([s for s, _ in imus])
    assert all(np.min(np.abs(imu_ns - f)) <= 25_000_000 for f in frame_ns)
