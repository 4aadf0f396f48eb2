"""Expected position error as a function of range: the paper's ``e = 0.0555 d``, refitted from scored runs.

The fuser puts ``expected_error_m`` on every track and the GPS publisher turns it into the NavSatFix covariance,
so consumers know that a fix 1 km out is worth far less than one at 100 m. The model is fitted by
``./vessel fit error-model`` (``error_model_fit.py``) and stored in the ``fuser`` block of the
parameter file (``error_model.*``).

Kinds: ``origin`` the least-squares line through the origin (the paper's, ``Σ e d / Σ d²``), ``affine``
least squares with a constant (never negative), ``quantile`` the line through the origin below which a given
share of the errors lie (an upper bound rather than an average).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vessel_common.errors import DataError

#: The paper's figure: 5.55 m of error per 100 m of distance.
PAPER_SLOPE = 0.0555

#: Mean of the radial (2-D) error of an isotropic Gaussian with unit standard deviation per axis: sqrt(pi/2).
MEAN_RADIAL_ERROR_PER_SIGMA = math.sqrt(math.pi / 2.0)

KINDS = ("origin", "affine", "quantile")


@dataclass(frozen=True)
class ErrorModel:
    """``expected_error_m(d) = intercept_m + slope * d`` (d in metres from the camera)."""

    slope: float = PAPER_SLOPE
    intercept_m: float = 0.0
    kind: str = "origin"
    quantile: float = 0.5
    n_points: int = 0
    source: str = "paper"

    def __post_init__(self) -> None:
        """Reject a model that would give negative or non-finite errors."""
        if not (math.isfinite(self.slope) and self.slope >= 0):
            raise DataError(f"error model: slope must be a finite number >= 0 (m per m), got {self.slope!r}")
        if not (math.isfinite(self.intercept_m) and self.intercept_m >= 0):
            raise DataError(f"error model: intercept_m must be a finite number >= 0, got {self.intercept_m!r}")
        if self.kind not in KINDS:
            raise DataError(f"error model: kind must be one of {', '.join(KINDS)}, got {self.kind!r}")

    def expected_error_m(self, distance_m):
        """Expected horizontal error (m) at ``distance_m`` from the camera (scalar or array)."""
        d = np.abs(np.asarray(distance_m, dtype=float))
        value = self.intercept_m + self.slope * d
        return float(value) if value.ndim == 0 else value

    def sigma_per_axis_m(self, distance_m):
        """Standard deviation per horizontal axis of an isotropic Gaussian whose mean radial error is the model's.

        Used for the NavSatFix covariance: variance per axis = sigma^2.
        """
        return np.asarray(self.expected_error_m(distance_m)) / MEAN_RADIAL_ERROR_PER_SIGMA

    def to_params(self) -> dict:
        """Parameter-file form (the ``error_model`` block of the fuser)."""
        return {
            "kind": self.kind,
            "slope": float(self.slope),
            "intercept_m": float(self.intercept_m),
            "quantile": float(self.quantile),
            "n_points": int(self.n_points),
            "source": str(self.source),
        }

    @classmethod
    def from_params(cls, params: dict) -> ErrorModel:
        """Build from the ``error_model`` block; missing keys take the paper's values."""
        try:
            return cls(
                slope=float(params.get("slope", PAPER_SLOPE)),
                intercept_m=float(params.get("intercept_m", 0.0)),
                kind=str(params.get("kind", "origin")),
                quantile=float(params.get("quantile", 0.5)),
                n_points=int(params.get("n_points", 0)),
                source=str(params.get("source", "paper")),
            )
        except (TypeError, ValueError) as error:
            raise DataError(f"error model: a value of the error_model block is not a number: {error}") from None
