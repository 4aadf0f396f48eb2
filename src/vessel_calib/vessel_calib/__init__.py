"""GPS-only camera calibration for monocular vessel tracking.

Geodesy, the camera model (homography + radial K1), the calibration fit and the parameter files.
"""
