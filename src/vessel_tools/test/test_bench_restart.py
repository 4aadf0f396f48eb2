"""``./vessel bench restart``: the figures of a run against the uninterrupted one, and its command line."""

from __future__ import annotations

import math

import pytest

from vessel_tools import bench_restart
from vessel_tools.bench_restart import Run

S = 1_000_000_000  # ns per s


def _run(stamps_s, arrivals_s, lat_offset=0.0, killed_at=None, stderr=""):
    run = Run(killed_at=killed_at, stderr=stderr)
    for stamp, arrival in zip(stamps_s, arrivals_s, strict=True):
        run.fixes[int(stamp * S)] = (32.7 + lat_offset, -117.23)
        run.arrivals.append((arrival, int(stamp * S)))
    return run


def test_time_to_the_next_fix_lost_fixes_and_deviation_from_the_uninterrupted_run():
    reference = _run(range(0, 40, 4), [float(k) for k in range(10)])
    # killed at t=3.5 s, after the fix stamped 12; fixes 16 and 20 never came; the rest 1e-5 deg (1.1 m) north
    run = _run([0, 4, 8, 12, 24, 28, 32, 36], [0.0, 1.0, 2.0, 3.0, 6.2, 7.0, 8.0, 9.0], killed_at=3.5,
               stderr="[graph] tracker exited with status -9: restarting it (restart 1 of at most 5)")
    for stamp in (24, 28, 32, 36):
        run.fixes[stamp * S] = (32.7 + 1e-5, -117.23)
    figures = bench_restart._figures(reference, run, "tracker", mode="state file", errors={}, reference_errors={})
    assert figures["next_fix_s"] == pytest.approx(2.7)
    assert figures["fixes_lost"] == 2 and figures["fixes_expected_after_kill"] == 6
    assert figures["fixes_compared"] == 4 and figures["max_deviation_m_first_fixes"] == pytest.approx(1.11, abs=0.01)
    assert figures["fixes_deviating_over_1m"] == 4 and figures["restarted"] and figures["restart"] == "state file"
    assert math.isnan(figures["mean_error_m_first_fixes"])  # no GPS: nothing to score


def test_errors_against_the_gps_count_the_fixes_worse_than_the_uninterrupted_run():
    reference = _run([0, 4, 8], [0.0, 1.0, 2.0])
    run = _run([0, 4, 8], [0.0, 2.5, 3.0], killed_at=0.5)
    errors = {4 * S: 12.0, 8 * S: 3.0}
    reference_errors = {4 * S: 5.0, 8 * S: 3.5}
    figures = bench_restart._figures(reference, run, "fuser", mode="cold", errors=errors,
                                     reference_errors=reference_errors)
    assert figures["fixes_worse_than_uninterrupted_by_over_5m"] == 1 and figures["restart"] == "cold"
    assert figures["mean_error_m_first_fixes"] == 7.5 and figures["mean_error_m_uninterrupted_same_stamps"] == 4.25


def test_the_report_gives_median_and_worst_per_node_and_mode():
    runs = [{"node": "tracker", "restart": "state file", "next_fix_s": t, "fixes_lost": 0,
             "max_deviation_m_first_fixes": 0.0, "mean_error_m_first_fixes": 5.0,
             "mean_error_m_uninterrupted_same_stamps": 5.0, "fixes_worse_than_uninterrupted_by_over_5m": 0}
            for t in (1.5, 2.0, 4.0)]
    text = bench_restart.format_report({"bag": "B", "rate": 4.0, "reference_fixes": 36, "kill_after": 10,
                                        "runs": runs})
    assert "tracker       state file                2.00 / 4.00  (3 runs)" in text


def test_a_promoted_hot_standby_counts_as_the_restart():
    reference = _run([0, 4, 8], [0.0, 1.0, 2.0])
    run = _run([0, 4, 8], [0.0, 1.0, 2.0], killed_at=0.5,
               stderr="[graph] fuser exited with status -9: promoted its hot standby /standby_2/fuser (restart 1 of "
                      "at most 5); starting a new standby")
    figures = bench_restart._figures(reference, run, "fuser", mode="hot standby, state file", errors={},
                                     reference_errors={})
    assert figures["restarted"] and figures["restart"] == "hot standby, state file" and figures["fixes_lost"] == 0


@pytest.mark.parametrize("argv, says", [(["--nodes", "camera"], "unknown"), (["--kill-after", "0"], "at least 1"),
                                        (["--repeat", "0"], "at least 1")])
def test_bad_options_are_refused(argv, says, capsys):
    with pytest.raises(SystemExit):
        bench_restart.parse_args(argv)
    assert says in capsys.readouterr().err
