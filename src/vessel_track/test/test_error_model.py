"""Error model: fits and the fit tool."""
import numpy as np
import pytest
import yaml

from vessel_common.errors import DataError
from vessel_tools.track.error_model_fit import fit_error_model, main
from vessel_track.error_model import PAPER_SLOPE, ErrorModel


def test_paper_default_and_sigma():
    model = ErrorModel()
    assert model.expected_error_m(100.0) == pytest.approx(5.55)
    # An isotropic Gaussian with this sigma per axis has the model's mean radial error.
    rng = np.random.default_rng(0)
    sigma = float(model.sigma_per_axis_m(200.0))
    radial = np.hypot(*rng.normal(0, sigma, (2, 200000)))
    assert radial.mean() == pytest.approx(model.expected_error_m(200.0), rel=0.01)


def test_fits_recover_known_lines():
    rng = np.random.default_rng(1)
    d = rng.uniform(20, 800, 500)
    e = 0.04 * d * rng.uniform(0.5, 1.5, d.size)
    origin = fit_error_model(d, e, "origin")
    assert origin.slope == pytest.approx(0.04, rel=0.05)
    assert origin.slope == pytest.approx(np.sum(e * d) / np.sum(d * d))
    affine = fit_error_model(d, 3.0 + 0.02 * d + rng.normal(0, 0.5, d.size), "affine")
    assert affine.intercept_m == pytest.approx(3.0, abs=0.3)
    assert affine.slope == pytest.approx(0.02, rel=0.05)
    q = fit_error_model(d, e, "quantile", quantile=0.8)
    assert np.mean(e <= q.expected_error_m(d)) == pytest.approx(0.8, abs=0.01)
    with pytest.raises(DataError):
        fit_error_model([1.0], [1.0])
    with pytest.raises(DataError):
        ErrorModel(slope=-1.0)


def test_fit_tool_writes_and_merges_the_parameter_file(tmp_path, capsys):
    scores = tmp_path / "scores.csv"
    scores.write_text("video,t_utc_s,error_m,distance_m\n13,1,5.0,100\n13,2,10.0,200\n13,3,,\n14,4,2.5,50\n")
    out = tmp_path / "params.yaml"
    out.write_text("fuser:\n  ros__parameters:\n    fusion: {anchor: 0.5}\ntracker:\n  ros__parameters: {a: 1}\n")
    assert main([str(scores), "--out", str(out)]) == 0
    doc = yaml.safe_load(out.read_text())
    assert doc["tracker"]["ros__parameters"] == {"a": 1}
    assert doc["fuser"]["ros__parameters"]["fusion"] == {"anchor": 0.5}
    block = doc["fuser"]["ros__parameters"]["error_model"]
    assert block["slope"] == pytest.approx(0.05)
    assert block["n_points"] == 3
    assert ErrorModel.from_params(block).expected_error_m(100) == pytest.approx(5.0)
    assert "5.00 m per 100 m" in capsys.readouterr().out
    assert block["source"] == "fit on " + f"{tmp_path.name}/scores.csv"
    assert main([str(scores), "--out", str(out), "--source", "online pipeline, videos 7-12"]) == 0
    assert yaml.safe_load(out.read_text())["fuser"]["ros__parameters"]["error_model"]["source"] == \
        "online pipeline, videos 7-12"


def test_fit_tool_keeps_the_documented_parameter_file(tmp_path):
    """Refitting into the shipped config/aitas.yaml changes the error model only: every comment stays."""
    from pathlib import Path

    shipped = Path(__file__).resolve().parents[3] / "config" / "aitas.yaml"
    out = tmp_path / "aitas.yaml"
    out.write_text(shipped.read_text())
    scores = tmp_path / "scores.csv"
    scores.write_text("video,t_utc_s,error_m,distance_m\n13,1,5.0,100\n13,2,10.0,200\n")
    assert main([str(scores), "--out", str(out)]) == 0
    before, after = shipped.read_text().splitlines(), out.read_text().splitlines()
    assert len(after) == len(before)
    changed = [(a, b) for a, b in zip(before, after, strict=True) if a != b]
    assert changed and all(a.split(":")[0] == b.split(":")[0] and a.split(":")[0].strip() in ("slope", "n_points",
                                                                                            "source")
                           for a, b in changed), changed
    assert all(a.split("#", 1)[1] == b.split("#", 1)[1] for a, b in changed)
    old, new = yaml.safe_load(shipped.read_text()), yaml.safe_load(out.read_text())
    assert new["fuser"]["ros__parameters"]["error_model"]["slope"] == pytest.approx(0.05)
    new["fuser"]["ros__parameters"]["error_model"] = old["fuser"]["ros__parameters"]["error_model"]
    assert new == old


def test_fit_tool_reports_bad_input_without_traceback(tmp_path, capsys):
    assert main([str(tmp_path / "missing.csv"), "--out", str(tmp_path / "x.yaml")]) == 2
    assert capsys.readouterr().err.startswith("error: ")
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    assert main([str(bad), "--out", str(tmp_path / "x.yaml")]) == 2
    assert "distance_m" in capsys.readouterr().err
    assert ErrorModel().slope == PAPER_SLOPE
