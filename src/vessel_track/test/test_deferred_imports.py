"""The tracking nodes start without SciPy and filterpy, which load in the background (restart time, #18)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from vessel_track import deferred_imports


def test_the_tracking_nodes_import_without_scipy_or_filterpy():
    code = ("import sys, vessel_track.tracker_node, vessel_track.fuser_node, vessel_track.gps_publisher_node\n"
            "print(sorted({m.split('.')[0] for m in sys.modules} & {'scipy', 'filterpy'}))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_the_deferred_functions_are_scipy_and_filterpy():
    rows, cols = deferred_imports.linear_sum_assignment(np.array([[4.0, 1.0], [2.0, 8.0]]))
    assert rows.tolist() == [0, 1] and cols.tolist() == [1, 0]
    kf = deferred_imports.kalman_filter(dim_x=4, dim_z=2)
    assert type(kf).__module__.startswith("filterpy.kalman")
    assert kf.x.shape == (4, 1) and kf.H.shape == (2, 4)


def test_a_preload_that_fails_stops_the_node_with_one_line():
    code = ("import sys\nfrom rclpy.node import Node\nfrom vessel_common.run import run_node\n"
            "sys.exit(run_node(lambda: Node('preload_probe'), ['probe'], preload=['vessel_no_such_module']))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    assert "error: cannot import vessel_no_such_module" in done.stderr
    assert "./vessel setup" in done.stderr and "Traceback" not in done.stderr


def _waits_for_the_import_lock(setup: str, start: str, module: str) -> None:
    """In a fresh process: ``start`` (a thread that imports ``module``) waits while the import lock is held."""
    code = (f"import sys, threading\nfrom vessel_common import imports\n{setup}\n"
            f"with imports._IMPORT_LOCK:\n    worker = {start}\n    worker.join(1.0)\n"
            f"    print(worker.is_alive(), {module!r} in sys.modules)\n"
            f"worker.join(60)\nprint(worker.is_alive(), {module!r} in sys.modules)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split("\n")[:2] == ["True False", "False True"]


def test_a_deferred_import_waits_while_another_thread_imports():
    # The preload thread and a first callback importing SciPy at once can get a partly initialised module;
    # the deferred functions wait for the process-wide import lock instead of importing beside it.
    _waits_for_the_import_lock(
        "from vessel_track import deferred_imports",
        "threading.Thread(target=deferred_imports.kalman_filter, args=(4, 2)); worker.start()", "filterpy")


def test_the_preload_waits_for_the_import_lock_too():
    _waits_for_the_import_lock("from vessel_common.run import _Preloader",
                               "_Preloader(['colorsys']).thread", "colorsys")


def test_a_library_that_cannot_be_imported_is_one_clear_error(monkeypatch):
    from vessel_common.errors import VesselError

    monkeypatch.setitem(sys.modules, "filterpy.kalman", None)  # what Python does for a module it cannot import
    with pytest.raises(VesselError, match=r"cannot import filterpy.kalman .*\./vessel setup"):
        deferred_imports.kalman_filter(dim_x=4, dim_z=2)
