"""Image sources, rosbag2 MCAP tools, camera ingest and ONNX vessel detector nodes."""
