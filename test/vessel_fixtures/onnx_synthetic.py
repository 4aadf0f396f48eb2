"""Tiny ONNX models written by hand (no ``onnx`` package needed), for tests and for checking a set-up.

:func:`constant_output_model` makes a model whose input is an image tensor of any shape and whose output is a
fixed tensor: a YOLO-family output with known boxes lets the whole detector (session, letterbox, decoder, NMS,
tiling) be tested end to end without a trained network, and a wrong input shape tests the model checks.
The protobuf is encoded directly (ONNX IR 7, opset 13).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

_FLOAT = 1  # TensorProto.DataType.FLOAT
_ATTRIBUTE_INT = 2


def _varint(value: int) -> bytes:
    out = bytearray()
    value &= (1 << 64) - 1
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _field_varint(number: int, value: int) -> bytes:
    return _varint(number << 3) + _varint(value)


def _field_bytes(number: int, payload: bytes) -> bytes:
    return _varint((number << 3) | 2) + _varint(len(payload)) + payload


def _string(number: int, text: str) -> bytes:
    return _field_bytes(number, text.encode("utf-8"))


def _tensor(name: str, array: np.ndarray) -> bytes:
    array = np.ascontiguousarray(array, dtype="<f4")
    body = b"".join(_field_varint(1, int(d)) for d in array.shape)
    body += _field_varint(2, _FLOAT) + _string(8, name) + _field_bytes(9, array.tobytes())
    return body


def _value_info(name: str, shape: list[int | str]) -> bytes:
    dims = b""
    for d in shape:
        dims += _field_bytes(1, _field_varint(1, d) if isinstance(d, int) else _string(2, d))
    tensor_type = _field_varint(1, _FLOAT) + _field_bytes(2, dims)
    return _string(1, name) + _field_bytes(2, _field_bytes(1, tensor_type))


def _node(op_type: str, inputs: list[str], outputs: list[str], name: str, attributes: bytes = b"") -> bytes:
    body = b"".join(_string(1, i) for i in inputs) + b"".join(_string(2, o) for o in outputs)
    return body + _string(3, name) + _string(4, op_type) + attributes


def constant_output_model(
    output: np.ndarray,
    input_shape: list[int | str] = (1, 3, 416, 416),
    input_name: str = "images",
    output_name: str = "output",
) -> bytes:
    """Bytes of an ONNX model mapping an input of ``input_shape`` to the constant ``output``.

    The input is used (its mean times zero is added) so runtimes keep it as a real input.
    """
    output = np.asarray(output, dtype=np.float32)
    keepdims_0 = _field_bytes(5, _string(1, "keepdims") + _field_varint(3, 0) + _field_varint(20, _ATTRIBUTE_INT))
    nodes = (
        _field_bytes(1, _node("ReduceMean", [input_name], ["input_mean"], "mean", keepdims_0))
        + _field_bytes(1, _node("Mul", ["input_mean", "zero"], ["nothing"], "times_zero"))
        + _field_bytes(1, _node("Add", ["constant", "nothing"], [output_name], "plus_constant"))
    )
    graph = (
        nodes
        + _string(2, "constant_output")
        + _field_bytes(5, _tensor("zero", np.zeros((), np.float32)))
        + _field_bytes(5, _tensor("constant", output))
        + _field_bytes(11, _value_info(input_name, list(input_shape)))
        + _field_bytes(12, _value_info(output_name, list(output.shape)))
    )
    opset = _string(1, "") + _field_varint(2, 13)
    return _field_varint(1, 7) + _string(2, "vessel_fixtures.onnx_synthetic") + _field_bytes(7, graph) + _field_bytes(
        8, opset
    )


def write_constant_output_model(path: str | Path, output: np.ndarray, **kwargs) -> Path:
    """Write :func:`constant_output_model` to ``path``."""
    path = Path(path)
    path.write_bytes(constant_output_model(output, **kwargs))
    return path

