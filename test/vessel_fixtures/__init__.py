"""Synthetic cameras, frames, tracks and ONNX models, and the probe node, for the tests (not installed)."""
