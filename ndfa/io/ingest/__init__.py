"""Importers: each turns one kind of input into recordings that follow `ndfa.io.recording`."""

from typing import Callable

import numpy as np

from ndfa.io.recording import Frame

# Poses for an input without its own: called once per frame, in order, with the frame (its pose
# the input's, or the identity where it has none); returns the frame's camera-to-world pose.
# `ndfa.trajectory.kiss.DepthOdometry(...).update` is one.
PoseEstimator = Callable[[Frame], np.ndarray]
