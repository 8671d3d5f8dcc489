"""Frames to object observations: instance masks (or, later, geometric segmentation) to partial point clouds."""
