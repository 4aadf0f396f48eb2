"""Synthetic cameras, frames and ONNX models for the tests (not installed)."""
