"""The results page is rendered from a demo's summary.json, and refuses a file that is not one."""

from __future__ import annotations

import json

from vessel_tools import results_page

BLOCK = {"n": 98, "m_per_100m": 5.46, "median_m": 4.8, "p80_m": 11.2, "p80_pct": 9.0, "share_under_20m": 0.96,
         "coverage": 0.8167, "frames_covered": 98, "frames_in_view": 120}
SUMMARY = {"online": {"per_video": {"13": dict(BLOCK, n=29)}, "splits": {"13-16": BLOCK}},
           "online_covariance": {"splits": {"13-16": {"n": 98, "nees_mean": 0.71, "inside_68": 0.94,
                                                      "inside_95": 0.98, "inside_99": 1.0}}},
           "offline": {"per_video": {}, "splits": {"13-16": dict(BLOCK, m_per_100m=6.23, coverage=1.0,
                                                                 frames_covered=120)}},
           "runs": [{"video": 13, "frames_out": 36, "frames_expected": 36, "seconds": 12.0}]}


def test_the_page_has_every_table_of_the_summary(tmp_path, capsys):
    summary = tmp_path / "summary.json"
    summary.write_text(json.dumps(SUMMARY))
    out = tmp_path / "results.md"
    assert results_page.main([str(summary), "--out", str(out)]) == 0
    page = out.read_text()
    assert "| 13-16 | 98 | 5.46 | 4.8 | 11.2 | 9.0 | 96 % | 82 % (98/120) |" in page
    assert "| video 13 | 29 |" in page and "| 13-16 | 98 | 6.23 |" in page
    assert "94 / 98 / 100 % of 98 errors" in page and "| 13 | 36 / 36 | 12.0 |" in page
    assert "do not edit by hand" in page


def test_a_missing_or_foreign_file_is_one_error_line(tmp_path, capsys):
    assert results_page.main([str(tmp_path / "none.json")]) == 2
    assert "run ./vessel demo first" in capsys.readouterr().err
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"graph_fps": 3.0}))
    assert results_page.main([str(other)]) == 2
    assert "no 'online' scores" in capsys.readouterr().err
    broken = tmp_path / "broken.json"
    broken.write_text("{")
    assert results_page.main([str(broken)]) == 2
    assert capsys.readouterr().err.startswith("error: ")


def test_a_summary_of_the_wrong_shape_is_one_error_line(tmp_path, capsys):
    """`{"online": "x"}` used to end in an AttributeError traceback, `{"online": {}}` in an empty page."""
    cases = {"string": {"online": "x"}, "empty": {"online": {}},
             "bad_block": {"online": {"splits": {"13-16": "x"}}}, "bad_runs": dict(SUMMARY, runs=[3])}
    for name, summary in cases.items():
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(summary))
        out = tmp_path / f"{name}.md"
        assert results_page.main([str(path), "--out", str(out)]) == 2, name
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1 and "summary.json of ./vessel demo" in err, err
        assert not out.exists()
