"""Importers: each turns one kind of input into recordings that follow `ndfa.io.recording`."""

from typing import Callable

import numpy as np

from ndfa.core.frame import Frame

# Poses for an input without its own: called once per frame, in order, with the frame (its pose
# the input's, or the identity where it has none); returns the frame's camera-to-world pose.
# `ndfa.trajectory.kiss.DepthOdometry(...).update` is one.
PoseEstimator = Callable[[Frame], np.ndarray]

# How far in stamp (seconds) a colour image or mask may be from the depth image it is paired with,
# by default (TUM's associate.py default; the same for bags).
MAX_DT_S = 0.02
