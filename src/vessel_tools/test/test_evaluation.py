"""Scoring like the paper on a generated miniature dataset, plus a check on the real one when present."""
import csv
import json

import numpy as np
import pytest

from vessel_calib import geodesy
from vessel_common.errors import DataError
from vessel_tools.track.evaluation import (
    FIX_COLUMNS,
    covariance_consistency,
    format_covariance_line,
    main,
    metrics,
    read_predictions,
    score_fix_covariances,
)
from vessel_tools.track.simulation import CHALLENGE_CAMERA_LATLON, CHALLENGE_H, CHALLENGE_K1

LAT0, LON0 = CHALLENGE_CAMERA_LATLON
DAY = 1601424000.0  # 2020-09-30 00:00 UTC


def _iso(epoch):
    from datetime import UTC, datetime

    return datetime.fromtimestamp(epoch, UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"


def make_dataset(root, gap=None):
    """Two videos of 10 frames 4 s apart; the vessel moves 2 m/s east-north-east 150-230 m out."""
    root.mkdir(parents=True, exist_ok=True)
    camera = {"camera_lat": LAT0, "camera_lon": LON0, "image_width": 1280, "image_height": 720,
              "distortion_centre": [640, 360],
              "calibrations": {"paper_corrected_H00_negative": {"H": [list(r) for r in CHALLENGE_H],
                                                                "K1": CHALLENGE_K1}}}
    (root / "camera.json").write_text(json.dumps(camera))
    frames = ["video,frame,utc,has_label,file"]
    starts = {13: DAY + 71752.0, 14: DAY + 71900.0}
    for video, t0 in starts.items():
        for k in range(10):
            frames.append(f"{video},{100 * k},{_iso(t0 + 4.0 * k)},0,frames/{video}/{100 * k:05d}.jpg")
    (root / "frames.csv").write_text("\n".join(frames) + "\n")
    fixes = ["fix_index,utc_s,t_spread_s,lat,lon"]
    i = 0
    for video, t0 in starts.items():
        for s in range(-2, 44):
            t = t0 + s
            if gap is not None and gap[0] <= t - t0 <= gap[1] and video == 13:
                continue
            x, y = 120.0 + 2.0 * s, 40.0 + 0.5 * s
            lat, lon = geodesy.local_to_gps(x, y, LAT0, LON0)
            fixes.append(f"{i},{int(t - DAY)},{t - DAY:.3f},{lat:.9f},{lon:.9f}")
            i += 1
    (root / "target_gps_fixes.csv").write_text("\n".join(fixes) + "\n")
    return starts


def truth_xy(t, t0):
    s = t - t0
    return 120.0 + 2.0 * s, 40.0 + 0.5 * s


def write_predictions(path, starts, offset_m=5.0, skip=()):
    lines = ["video,t_utc_s,lat,lon"]
    for video, t0 in starts.items():
        for k in range(10):
            if (video, k) in skip:
                continue
            t = t0 + 4.0 * k
            x, y = truth_xy(t, t0)
            lat, lon = geodesy.local_to_gps(x + offset_m, y, LAT0, LON0)
            lines.append(f"{video},{t - DAY:.3f},{lat:.9f},{lon:.9f}")
    lines.append("13,not-a-number,1,2")
    path.write_text("\n".join(lines) + "\n")


def test_metrics_match_the_definitions():
    e = np.array([1.0, 2.0, 10.0, 4.0])
    d = np.array([100.0, 50.0, 400.0, 200.0])
    m = metrics(e, d)
    assert m["m_per_100m"] == pytest.approx(100 * np.sum(e * d) / np.sum(d * d))
    assert m["median_m"] == pytest.approx(3.0)
    assert m["p80_pct"] == pytest.approx(np.percentile(100 * e / d, 80))
    assert m["range_bias_pct"] is None          # not without the estimates' ranges
    assert metrics([], [])["n"] == 0


def test_range_bias_says_which_way_the_ranges_are_off():
    d = np.array([100.0, 50.0, 400.0])
    too_close = metrics(0.05 * d, d, 0.95 * d)
    assert too_close["range_bias_pct"] == pytest.approx(-5.0)
    assert metrics(0.05 * d, d, 1.05 * d)["range_bias_pct"] == pytest.approx(5.0)
    assert metrics([], [], [])["range_bias_pct"] is None


def test_scoring_a_known_offset(tmp_path, capsys):
    data = tmp_path / "data"
    starts = make_dataset(data, gap=(14.5, 21.5))  # no GPS between 14.5 s and 21.5 s of video 13
    predictions = tmp_path / "predictions.csv"
    write_predictions(predictions, starts, offset_m=5.0, skip={(14, 3), (14, 4)})
    out = tmp_path / "eval"
    assert main([str(predictions), "--data", str(data), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "m/100m" in printed and "video 13" in printed
    summary = json.loads((out / "summary.json").read_text())
    overall = summary["overall"]
    assert overall["median_m"] == pytest.approx(5.0, abs=0.01)
    assert overall["p80_m"] == pytest.approx(5.0, abs=0.01)
    assert overall["range_bias_pct"] is not None and abs(overall["range_bias_pct"]) <= 100 * 5.0 / 150.0 + 0.01
    assert "range bias" in printed
    # Frames at 16 s and 20 s of video 13 fall in the GPS gap: not scored and not in view.
    v13 = summary["per_video"]["13"]
    assert v13["n"] == 8 and v13["n_no_truth"] == 2 and v13["frames_in_view"] == 8
    v14 = summary["per_video"]["14"]
    assert v14["frames_in_view"] == 10 and v14["frames_covered"] == 8 and v14["coverage"] == pytest.approx(0.8)
    with open(out / "scores.csv") as handle:
        rows = list(csv.DictReader(handle))
    d = np.array([float(r["distance_m"]) for r in rows if r["error_m"]])
    assert overall["m_per_100m"] == pytest.approx(100 * 5.0 * d.sum() / (d * d).sum(), rel=1e-3)
    assert summary["settings"]["skipped_rows"] == 1
    assert "13-16" not in summary["splits"]
    for name in ("error_vs_distance.png", "error_hist.png", "map_video13.png", "map_video14.png"):
        assert (out / name).stat().st_size > 1000


def test_covariance_consistency_tells_honest_from_overconfident_and_conservative():
    rng = np.random.default_rng(4)
    C = np.array([[400.0, 150.0], [150.0, 100.0]])    # long along one axis, as a range-dominated fix
    errors = rng.multivariate_normal([0.0, 0.0], C, size=20000)
    covs = np.repeat(C[None], len(errors), axis=0)
    honest = covariance_consistency(errors[:, 0], errors[:, 1], covs)
    assert honest["inside_68"] == pytest.approx(0.683, abs=0.01)
    assert honest["inside_95"] == pytest.approx(0.95, abs=0.005)
    assert honest["nees_mean"] == pytest.approx(2.0, abs=0.05) and honest["n"] == 20000
    assert covariance_consistency(errors[:, 0], errors[:, 1], covs / 4)["inside_95"] < 0.55     # claims too much
    assert covariance_consistency(errors[:, 0], errors[:, 1], covs * 4)["inside_68"] > 0.98     # conservative
    bad = covs[:3].copy()
    bad[1] = np.nan
    bad[2] = [[1.0, 2.0], [2.0, 1.0]]                                                            # not positive definite
    assert covariance_consistency([1.0, 1.0, 1.0], [0.0, np.nan, 0.0], bad)["n"] == 1
    assert covariance_consistency([], [], np.zeros((0, 2, 2)))["n"] == 0


def test_fix_covariances_are_scored_against_the_gps(tmp_path):
    """The demo's fixes.csv: a fix 5 m east of the truth with a 5 m east std is one sigma out."""
    data = tmp_path / "data"
    starts = make_dataset(data)
    write_predictions(tmp_path / "p.csv", starts, offset_m=5.0)
    rows = [line for line in (tmp_path / "p.csv").read_text().splitlines()[1:] if "not-a-number" not in line]
    lines = [",".join(FIX_COLUMNS)] + [row + ",25.0,0.0,1.0" for row in rows]
    (tmp_path / "fixes.csv").write_text("\n".join(lines) + "\n")
    from vessel_tools.calib.dataset import Dataset

    summary = score_fix_covariances(tmp_path / "fixes.csv", Dataset(data), [13, 14])
    overall = summary["overall"]
    assert overall["n"] == 20 and overall["nees_mean"] == pytest.approx(1.0, abs=0.01)
    assert overall["inside_68"] == 1.0 and summary["per_video"]["13"]["n"] == 10
    assert "100 / 100 / 100 % of 20 errors" in format_covariance_line("overall", overall)
    (tmp_path / "bad.csv").write_text("video,t_utc_s,lat,lon\n")
    with pytest.raises(DataError, match="cov_ee_m2"):
        score_fix_covariances(tmp_path / "bad.csv", Dataset(data), [13])


def test_bad_input_gives_one_line_and_status_2(tmp_path, capsys):
    data = tmp_path / "data"
    make_dataset(data)
    assert main([str(tmp_path / "nope.csv"), "--data", str(data)]) == 2
    assert capsys.readouterr().err.startswith("error: ")
    bad = tmp_path / "bad.csv"
    bad.write_text("video,time,lat,lon\n")
    assert main([str(bad), "--data", str(data)]) == 2
    assert "t_utc_s" in capsys.readouterr().err
    with pytest.raises(DataError):
        read_predictions(tmp_path / "nope.csv")


def test_rows_that_cannot_be_scored_are_skipped_and_counted_by_reason(tmp_path):
    path = tmp_path / "odd.csv"
    path.write_text("video,t_utc_s,lat,lon\n"
                    "13,70000.0,32.7,-117.2\n"
                    "13,70001.0,32.7,-117.2,extra\n"   # one field too many
                    "inf,70002.0,32.7,-117.2\n"
                    "1e30,70003.0,32.7,-117.2\n"
                    "13.5,70004.0,32.7,-117.2\n"
                    "13,70005.0,95,-117.2\n"
                    "13,abc,32.7,-117.2\n")
    predictions = read_predictions(path)
    assert len(predictions) == 1 and predictions.skipped_rows == 6
    assert predictions.skipped_reasons == {
        "more fields than the header": 1, "video not a whole number in 0-1000000": 3,
        "latitude or longitude out of range": 1, "not a number": 1}


@pytest.mark.data
def test_gps_itself_scores_zero_on_the_shared_data(tmp_path):
    from vessel_common.paths import default_data_dir
    from vessel_tools.calib.dataset import Dataset

    root = default_data_dir()
    if root is None:
        pytest.skip("../shared/aitas is absent (set VESSEL_DATA to run this test)")
    dataset = Dataset(root)
    track = dataset.gps_track()
    frames = dataset.frames([15])
    stamps = np.array([f.stamp for f in frames])
    lat, lon, valid = track.interpolate(stamps, max_gap_s=3.0)
    lines = ["video,t_utc_s,lat,lon"] + [f"15,{t % 86400:.3f},{a:.9f},{b:.9f}"
                                          for t, a, b, v in zip(stamps, lat, lon, valid, strict=True) if v]
    (tmp_path / "p.csv").write_text("\n".join(lines) + "\n")
    assert main([str(tmp_path / "p.csv"), "--data", str(root), "--out", str(tmp_path / "o.json"), "--no-plots"]) == 0
    summary = json.loads((tmp_path / "o.json").read_text())
    assert summary["overall"]["max_m"] < 0.01
    assert summary["overall"]["coverage"] == pytest.approx(1.0)
