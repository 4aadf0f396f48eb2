"""The detector-run CSV: what ``detect run`` writes, every reader reads back; bad files name the problem."""
import numpy as np
import pytest

from vessel_common.errors import DataError
from vessel_detect.detections_csv import CSV_COLUMNS, csv_row, read_detections_csv


def _write(path, rows):
    path.write_text("\n".join([",".join(CSV_COLUMNS)] + [",".join(r) for r in rows]) + "\n")
    return path


def test_rows_round_trip_grouped_by_frame(tmp_path):
    path = _write(tmp_path / "run.csv", [csv_row(13, 0, [10.04, 20.0, 30.0, 40.0], 0.98765),
                                         csv_row(13, 0, [1, 2, 3, 4], 0.5, class_id=2),
                                         csv_row(14, 100, [5, 6, 7, 8], 0.25)])
    grouped = read_detections_csv(path)
    assert sorted(grouped) == [(13, 0), (14, 100)]
    boxes, scores = grouped[(13, 0)]
    np.testing.assert_allclose(boxes, [[10.0, 20.0, 30.0, 40.0], [1, 2, 3, 4]])
    np.testing.assert_allclose(scores, [0.9877, 0.5])
    assert csv_row(1, 2, [1, 2, 3, 4], 0.5)[-2:] == ["8", ""]     # COCO boat unless told; no p_target


def test_bad_files_name_the_file_the_row_and_the_fix(tmp_path):
    with pytest.raises(DataError, match="not found: write one with './vessel detect run'"):
        read_detections_csv(tmp_path / "absent.csv")
    with pytest.raises(DataError, match="or use --detections labels"):
        read_detections_csv(tmp_path / "absent.csv", "or use --detections labels")
    bad = _write(tmp_path / "bad.csv", [csv_row(13, 0, [1, 2, 3, 4], 0.5), ["13", "1", "x", "2", "3", "4", "0.5", "8"]])
    with pytest.raises(DataError, match=r"bad.csv, row 3: .* must be numbers"):
        read_detections_csv(bad)
    short = tmp_path / "short.csv"
    short.write_text("video,frame,x1,y1,x2,y2\n13,0,1,2,3,4\n")
    with pytest.raises(DataError, match="lacks column"):
        read_detections_csv(short)


def test_p_target_is_written_and_read_as_the_confidence(tmp_path):
    path = _write(tmp_path / "run.csv", [csv_row(13, 0, [1, 2, 3, 4], 0.9, class_id=1, p_target=0.125),
                                         csv_row(13, 0, [5, 6, 7, 8], 0.5, class_id=0)])
    rows = path.read_text().splitlines()
    assert rows[0].endswith(",p_target") and rows[1].endswith(",1,0.1250") and rows[2].endswith(",0,")
    _, confidences = read_detections_csv(path)[(13, 0)]
    np.testing.assert_allclose(confidences, [0.125, 0.5])
    old = tmp_path / "old.csv"  # files written before the column existed still read
    old.write_text("video,frame,x1,y1,x2,y2,score,class_id\n13,0,1,2,3,4,0.5,8\n")
    assert read_detections_csv(old)[(13, 0)][1].tolist() == [0.5]


def test_the_reader_can_keep_the_detector_score_instead_of_p_target(tmp_path):
    path = tmp_path / "d.csv"
    path.write_text("video,frame,x1,y1,x2,y2,score,class_id,p_target\n7,0,1,2,3,4,0.6,1,0.05\n7,0,5,6,7,8,0.3,0,\n")
    assert read_detections_csv(path)[(7, 0)][1].tolist() == [0.05, 0.3]
    assert read_detections_csv(path, confidence="score")[(7, 0)][1].tolist() == [0.6, 0.3]
    with pytest.raises(ValueError, match="confidence"):
        read_detections_csv(path, confidence="p")


def test_a_non_finite_box_or_score_is_refused_by_row(tmp_path):
    """NaN and inf parse as floats; they used to pass into the tracker unnoticed while "x" was refused."""
    for name, cells in (("nan_box", ["13", "1", "nan", "2", "3", "4", "0.5", "8", ""]),
                        ("inf_score", ["13", "1", "1", "2", "3", "4", "inf", "8", ""]),
                        ("nan_p_target", ["13", "1", "1", "2", "3", "4", "0.5", "0", "nan"]),
                        ("nan_score_under_p_target", ["13", "1", "1", "2", "3", "4", "nan", "0", "0.7"])):
        path = _write(tmp_path / f"{name}.csv", [csv_row(13, 0, [1, 2, 3, 4], 0.5), cells])
        for confidence in ("p_target", "score"):
            with pytest.raises(DataError, match=rf"{name}.csv, row 3: .* must be finite"):
                read_detections_csv(path, confidence=confidence)
    empty_target = _write(tmp_path / "empty_target.csv", [["13", "1", "1", "2", "3", "4", "0.5", "0", ""]])
    assert read_detections_csv(empty_target)[(13, 1)][1].tolist() == [0.5]  # an empty p_target: the score


def test_a_file_without_a_box_in_the_videos_asked_for_is_refused(tmp_path, capsys):
    from vessel_detect.detections_csv import require_rows_for

    path = _write(tmp_path / "run9.csv", [csv_row(9, 0, [1, 2, 3, 4], 0.5)])
    detections = read_detections_csv(path)
    require_rows_for(detections, [9, 13], path)
    require_rows_for(detections, None, path)
    with pytest.raises(DataError, match=r"run9.csv has no box in videos 13 \(its boxes are in videos 9\)"):
        require_rows_for(detections, [13], path)
    header = _write(tmp_path / "header.csv", [])  # what a detector that found nothing writes: said, not refused
    require_rows_for(read_detections_csv(header), [13], header)
    assert "header.csv holds no box: every frame of videos 13 counts as one where the detector found nothing" in \
        capsys.readouterr().err
