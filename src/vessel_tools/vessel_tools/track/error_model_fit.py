"""Fit the error model (``error_model.ErrorModel``) from scored runs and write it into a parameter file.

    ./vessel fit error-model SCORES.csv --out FILE.yaml [--kind origin|affine|quantile]

from the per-prediction scores ``./vessel eval`` writes (``scores.csv``: columns ``error_m`` and
``distance_m``); the ``fuser`` block's ``error_model.*`` changes, the rest of the file stays.

Kinds: ``origin`` the least-squares line through the origin (the paper's, ``Σ e d / Σ d²``), ``affine``
least squares with a constant (never negative), ``quantile`` the line through the origin below which a given
share of the errors lie (an upper bound rather than an average).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from pathlib import Path

import numpy as np

from vessel_calib.params import update_params_block
from vessel_common.command_line import command_line_tool
from vessel_common.errors import DataError
from vessel_track.error_model import KINDS, ErrorModel
from vessel_track.parameter_tables import FUSER_PARAMETERS


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
    descriptions = {key: FUSER_PARAMETERS[f"{block}.{key}"].description for key in values
                    if f"{block}.{key}" in FUSER_PARAMETERS}
    update_params_block(path, node, block, values, descriptions)


@command_line_tool
def main(argv: list[str] | None = None) -> int:
    """Command line: ``SCORES.csv --out FILE.yaml``."""
    parser = argparse.ArgumentParser(prog="./vessel fit error-model",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("scores", type=Path, nargs="+", help="scores.csv file(s) written by the evaluation")
    parser.add_argument("--out", type=Path, required=True, help="parameter YAML to write/update (fuser block)")
    parser.add_argument("--kind", choices=KINDS, default="origin", help="origin (the paper's), affine, quantile")
    parser.add_argument("--quantile", type=float, default=0.8, help="share of errors below the line (quantile)")
    parser.add_argument("--node", default="fuser", help="node block to write into (default: fuser)")
    parser.add_argument("--source", default=None,
                        help="where the scores come from, for the file (error_model.source; default 'fit on DIR/FILE')")
    args = parser.parse_args(argv)
    parts = [read_scores_csv(p) for p in args.scores]
    d = np.concatenate([p[0] for p in parts])
    e = np.concatenate([p[1] for p in parts])
    source = args.source or "fit on " + ", ".join(f"{p.parent.name}/{p.name}" if p.parent.name else p.name
                                                  for p in args.scores)
    model = fit_error_model(d, e, args.kind, args.quantile, source=source)
    update_params_file(args.out, args.node, "error_model", model.to_params())
    print(f"error model ({model.kind}, {model.n_points} points): expected error = {model.intercept_m:.2f} m + "
          f"{100 * model.slope:.2f} m per 100 m  -> {args.out} ({args.node}.error_model)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
