"""``./vessel detect quantize``: the int8 model is written whole, into a new folder, or not at all."""

import numpy as np
import pytest

from vessel_common.errors import ModelError
from vessel_fixtures.onnx_synthetic import write_constant_output_model
from vessel_tools.detect.training.quantize import quantize_model

pytest.importorskip("onnxruntime.quantization", reason="onnxruntime.quantization is not installed")

SHAPE = (1, 3, 32, 64)


def calibration_tensors(count: int = 3) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    return [rng.uniform(0, 255, SHAPE).astype(np.float32) for _ in range(count)]


def test_the_int8_model_is_written_into_a_folder_that_did_not_exist_and_runs(tmp_path):
    import onnxruntime as ort

    output = np.arange(12, dtype=np.float32).reshape(1, 2, 6)
    model = write_constant_output_model(tmp_path / "m.onnx", output, input_shape=list(SHAPE))
    (tmp_path / "m.names").write_text("vessel_of_interest\nvessel\n")
    out = tmp_path / "new" / "folder" / "m.int8.onnx"
    quantize_model(model, out, calibration_tensors())
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    result = session.run(None, {"images": calibration_tensors(1)[0]})[0]
    np.testing.assert_allclose(result, output, atol=0.1)  # int8 steps of a 0-11 range: about 0.05
    assert (out.parent / "m.int8.names").read_text() == "vessel_of_interest\nvessel\n"
    assert sorted(p.name for p in out.parent.iterdir()) == ["m.int8.names", "m.int8.onnx"]  # no leftovers


def test_a_failed_quantization_names_the_model_and_keeps_the_earlier_output(tmp_path):
    broken = tmp_path / "broken.onnx"
    broken.write_bytes(b"not an onnx model")
    out = tmp_path / "m.int8.onnx"
    out.write_bytes(b"the earlier int8 model")
    with pytest.raises(ModelError, match="quantizing .*broken.onnx failed"):
        quantize_model(broken, out, calibration_tensors())
    assert out.read_bytes() == b"the earlier int8 model"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken.onnx", "m.int8.onnx"]
