"""Starts the vessel-tracking graph: the node list of the launch file and the graph runner."""
