"""``./vessel view``: the water seen live, as a web page of the project's own and as a Foxglove source.

Layers inside, lowest first: ``state`` and ``geometry`` (ROS-free: the vessels of each camera, the camera's field of
view, the JSON the page reads, throttling), ``server`` (ROS-free: HTTP and WebSocket, per-client bounded queues),
``foxglove_bridge`` (the same state in Foxglove's schemas), ``node`` (the thin rclpy node that feeds the state) and
``app`` (the command line, optionally starting the graph as ``./vessel graph`` does). ``bench`` measures what
clients cost the graph.
"""
