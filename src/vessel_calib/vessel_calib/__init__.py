"""GPS-only camera calibration for monocular vessel tracking: geodesy, camera model (homography + radial K1), calibration fit and parameter files."""
