"""Expected position error as a function of range: the paper's ``e = 0.0555 d``, refitted from scored runs.

The fuser puts ``expected_error_m`` on every track and the GPS publisher turns it into the NavSatFix covariance,
so consumers know that a fix 1 km out is worth far less than one at 100 m. The model is fitted by

    python -m vessel_track.error_model fit SCORES.csv --out FILE.yaml [--kind origin|affine|quantile]

from the per-prediction scores ``./vessel eval`` writes (``scores.csv``: columns ``error_m`` and
``distance_m``), and stored in the ``fuser`` block of the parameter file (``error_model.*``).

Kinds: ``origin`` the least-squares line through the origin (the paper's, ``Σ e d / Σ d²``), ``affine``
least squares with a constant (never negative), ``quantile`` the line through the origin below which a given
share of the errors lie (an upper bound rather than an average).
"""
from __future__ import annotations

import argparse
import csv
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vessel_calib.errors import DataError, VesselError
from vessel_calib.params import update_params_block

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


def fit_error_model(distance_m, error_m, kind: str = "origin", quantile: float = 0.8,
                    source: str = "") -> ErrorModel:
    """Fit the model to scored predictions (rows with a non-finite value or d <= 0 are ignored)."""
    d = np.asarray(distance_m, dtype=float).reshape(-1)
    e = np.asarray(error_m, dtype=float).reshape(-1)
    if d.shape != e.shape:
        raise DataError(f"error model fit: {d.size} distances but {e.size} errors")
    ok = np.isfinite(d) & np.isfinite(e) & (d > 0) & (e >= 0)
    d, e = d[ok], e[ok]
    if d.size < 2:
        raise DataError(f"error model fit: needs at least 2 scored predictions with distance > 0, got {d.size}")
    if kind == "origin":
        return ErrorModel(float(np.sum(e * d) / np.sum(d * d)), 0.0, "origin", 0.5, int(d.size), source)
    if kind == "affine":
        A = np.column_stack([d, np.ones_like(d)])
        (slope, intercept), *_ = np.linalg.lstsq(A, e, rcond=None)
        if intercept < 0:  # a negative error at short range is meaningless: fall back to the origin fit
            return ErrorModel(float(np.sum(e * d) / np.sum(d * d)), 0.0, "affine", 0.5, int(d.size), source)
        if slope < 0:
            return ErrorModel(0.0, float(np.mean(e)), "affine", 0.5, int(d.size), source)
        return ErrorModel(float(slope), float(intercept), "affine", 0.5, int(d.size), source)
    if kind == "quantile":
        if not 0 < quantile < 1:
            raise DataError(f"error model fit: quantile must be in (0, 1), got {quantile!r}")
        return ErrorModel(float(np.quantile(e / d, quantile)), 0.0, "quantile", float(quantile), int(d.size),
                          source)
    raise DataError(f"error model fit: kind must be one of {', '.join(KINDS)}, got {kind!r}")


def read_scores_csv(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read ``distance_m`` and ``error_m`` columns of a scores CSV (as written by the evaluation)."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such scores file; write one with `./vessel eval ... --out DIR`")
    distances: list[float] = []
    errors: list[float] = []
    with path.open(newline="") as handle:
        reader = csv.DictReader(handle)
        missing = {"distance_m", "error_m"} - set(reader.fieldnames or [])
        if missing:
            raise DataError(f"{path}: missing column(s) {', '.join(sorted(missing))}; expected the scores.csv "
                            f"the evaluation writes (columns distance_m, error_m)")
        for row_number, row in enumerate(reader, start=2):
            try:
                distances.append(float(row["distance_m"]) if row["distance_m"] != "" else math.nan)
                errors.append(float(row["error_m"]) if row["error_m"] != "" else math.nan)
            except ValueError:
                raise DataError(f"{path}: row {row_number}: distance_m/error_m is not a number") from None
    return np.asarray(distances), np.asarray(errors)


def update_params_file(path: Path, node: str, block: str, values: dict) -> None:
    """Set ``<node>: ros__parameters: <block>: values`` in a ROS parameter YAML, keeping everything else.

    Comments and layout of the file survive (``vessel_calib.params.update_params_block``); keys new to the
    file get the fuser parameter's description as their comment. Creates the file if needed; written atomically.
    """
    from vessel_track.node_params import FUSER_PARAMETERS

    descriptions = {key: FUSER_PARAMETERS[f"{block}.{key}"][0] for key in values
                    if f"{block}.{key}" in FUSER_PARAMETERS}
    update_params_block(path, node, block, values, descriptions)


def main(argv: list[str] | None = None) -> int:
    """Command line: ``fit SCORES.csv --out FILE.yaml``."""
    parser = argparse.ArgumentParser(prog="python -m vessel_track.error_model", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    fit = sub.add_parser("fit", help="fit the error model to a scores.csv and store it in a parameter file")
    fit.add_argument("scores", type=Path, nargs="+", help="scores.csv file(s) written by the evaluation")
    fit.add_argument("--out", type=Path, required=True, help="parameter YAML to write/update (fuser block)")
    fit.add_argument("--kind", choices=KINDS, default="origin", help="origin (the paper's), affine, quantile")
    fit.add_argument("--quantile", type=float, default=0.8, help="share of errors below the line (quantile)")
    fit.add_argument("--node", default="fuser", help="node block to write into (default: fuser)")
    fit.add_argument("--source", default=None,
                     help="where the scores come from, for the file (error_model.source; default 'fit on DIR/FILE')")
    args = parser.parse_args(argv)
    try:
        parts = [read_scores_csv(p) for p in args.scores]
        d = np.concatenate([p[0] for p in parts])
        e = np.concatenate([p[1] for p in parts])
        source = args.source or "fit on " + ", ".join(f"{p.parent.name}/{p.name}" if p.parent.name else p.name
                                                      for p in args.scores)
        model = fit_error_model(d, e, args.kind, args.quantile, source=source)
        update_params_file(args.out, args.node, "error_model", model.to_params())
    except VesselError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(f"error model ({model.kind}, {model.n_points} points): expected error = {model.intercept_m:.2f} m + "
          f"{100 * model.slope:.2f} m per 100 m  -> {args.out} ({args.node}.error_model)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
