"""Test fixtures, not installed.

Synthetic cameras, frames, tracks and ONNX models, the challenge videos as bags, and the probe node.
"""
