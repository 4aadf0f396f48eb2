"""Synthetic cameras, frames, tracks and ONNX models, the challenge videos as bags, and the probe node, for the tests
(not installed)."""
