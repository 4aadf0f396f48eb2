"""Fixtures of the vessel_calib tests; puts this folder on sys.path so tests can import calib_synthetic."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from vessel_calib.dataset import Dataset
from vessel_common.paths import default_data_dir


@pytest.fixture(scope="session")
def dataset() -> Dataset:
    path = default_data_dir()
    if path is None:
        pytest.skip("shared data set not found: set VESSEL_DATA or put it at <repo>/../shared/aitas")
    return Dataset(path)
