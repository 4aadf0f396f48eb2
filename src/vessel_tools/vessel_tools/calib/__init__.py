"""Offline tools of the camera model: the calibration fit from GPS, its picture, the dataset folders."""
