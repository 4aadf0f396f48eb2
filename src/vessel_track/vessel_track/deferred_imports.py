"""The core's SciPy-backed pieces, imported on first use instead of with the module.

``scipy.optimize`` and ``filterpy.kalman`` (which pulls in ``scipy.stats``) are most of a tracking node's start-up
time. A node restarted after a crash has to import them and to be discovered again; ``run_node(preload=MODULES)``
imports them in a background thread while the node connects, so the restart costs the longer of the two, not
their sum. Both import through ``vessel_common.imports.import_serialized``: SciPy imported by two threads at once
can fail.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from vessel_common.imports import import_serialized

if TYPE_CHECKING:
    from filterpy.kalman import KalmanFilter

MODULES = ("scipy.optimize", "filterpy.kalman")
"""What a node using the tracker or the target selection preloads."""


def linear_sum_assignment(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``scipy.optimize.linear_sum_assignment`` (rows, columns of the cheapest assignment)."""
    return import_serialized("scipy.optimize").linear_sum_assignment(cost)


def kalman_filter(dim_x: int, dim_z: int) -> KalmanFilter:
    """A new ``filterpy.kalman.KalmanFilter``."""
    return import_serialized("filterpy.kalman").KalmanFilter(dim_x=dim_x, dim_z=dim_z)
