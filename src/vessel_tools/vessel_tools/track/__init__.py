"""Offline tools of tracking: the ROS-free pipeline, evaluation, simulation and the model fits."""
