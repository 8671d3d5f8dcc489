"""Open3D on one thread while it estimates poses, so that the same frames give the same poses.

Open3D's CPU kernels run on oneTBB threads, whose partial sums (the RGB-D odometry's normal
equations) meet in whatever order the scheduler gives: two runs on the same frames differ.
Measured on the first half of the 7-Scenes kitchen (250 frames, 2 cores): the first frame pair's
odometry moved by up to 1.1 mm between runs, the session's poses by 0.2 mm, and `ndfa detect
--poses estimate --frame-step 2` on the kitchen halves found 12 target objects in one run and 11
in the next (`OMP_NUM_THREADS` does not reach TBB). On one thread the same frames give the same
poses bit for bit, at 1.3x the time (that session's pose estimation 17.7 -> 23.1 s).

Not needed elsewhere, as measured: the scene alignment's seeded RANSAC (`ndfa.run.align`) drew the
same fit four times over at one and at two threads. KISS-ICP (depth-only poses) runs on its own
threads (`OdometryConfig.threads`), which this does not reach: two of its estimates of the same
kitchen half differed by 4e-14 m.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

OPEN3D_THREADS = 1  # the threads Open3D's estimators run on (see the module docstring)


@contextmanager
def open3d_threads(threads: int = OPEN3D_THREADS) -> Iterator[None]:
    """Within the block Open3D uses at most `threads` CPU threads (0: as many as it likes); the
    limit is process-wide, and the one before is restored after."""
    import open3d as o3d

    previous = o3d.utility.get_max_threads()
    o3d.utility.set_max_threads(threads)
    try:
        yield
    finally:
        o3d.utility.set_max_threads(previous)
