"""What runs the graph and the offline tools from one command line: demo, graph runner, benchmarks, ``vessel``."""
