"""The paper's settings (``config/paper.yaml``) for tests that check one rule at a time against them."""

from __future__ import annotations

import dataclasses
from pathlib import Path

PAPER_PARAMS = Path(__file__).resolve().parents[2] / "config" / "paper.yaml"


def paper_tracker_config(**changes):
    """``TrackerConfig`` of config/paper.yaml, with ``changes``."""
    from vessel_track.tracker_config import load_tracker_config

    return dataclasses.replace(load_tracker_config(PAPER_PARAMS), **changes)


def paper_fuser_settings():
    """``FuserSettings`` of config/paper.yaml."""
    from vessel_track.fuser_settings import load_fuser_settings

    return load_fuser_settings(PAPER_PARAMS)


def paper_selection(**changes):
    """``SelectionConfig`` of config/paper.yaml, with ``changes``."""
    return dataclasses.replace(paper_fuser_settings().selection, **changes)


def paper_simulation_settings(camera):
    """The simulated world's fuser settings (its box-size model) with the paper's selection and offline pass.

    A simulated detector's scores are confidences of any boat, not the trained detector's probabilities of the
    vessel of interest that the tuned selection reads, so simulations run the paper's trajectory score.
    """
    from vessel_tools.track.simulation import fuser_settings_of_simulation

    paper = paper_fuser_settings()
    return dataclasses.replace(fuser_settings_of_simulation(camera), selection=paper.selection, offline=paper.offline)
