"""Offline tools of the detector: training, bag building, the detect command line, recall and ranking."""
