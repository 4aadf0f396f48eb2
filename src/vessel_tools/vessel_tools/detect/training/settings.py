"""Settings of a training run, importable without PyTorch (the command line reads their defaults)."""

from __future__ import annotations

from dataclasses import dataclass, field

from vessel_tools.detect.training.augment import AugmentSettings
from vessel_tools.detect.training.webcams import WebcamSettings


@dataclass(frozen=True)
class TrainSettings:
    """Optimisation and export settings of one training run."""

    epochs: int = 50
    batch_size: int = 8
    learning_rate: float = 6e-4
    weight_decay: float = 5e-4
    warmup_epochs: float = 1.0
    seed: int = 0
    threads: int = 2
    input_hw: tuple[int, int] = (352, 1280)
    band_margin_px: float = 40.0
    val_every: int = 5
    val_score: float = 0.05
    augment: AugmentSettings = field(default_factory=AugmentSettings)
    webcam: WebcamSettings = field(default_factory=WebcamSettings)
