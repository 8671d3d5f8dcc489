"""Reading ahead in a background thread (`ndfa.io.recording.prefetch`)."""

from __future__ import annotations

import threading

import pytest

from ndfa.io.recording.prefetch import prefetched


def test_same_items_in_the_same_order():
    assert list(prefetched(iter(range(100)), depth=3)) == list(range(100))
    assert list(prefetched(iter(range(5)), depth=0)) == list(range(5))


def test_an_error_of_the_producer_reaches_the_caller_after_the_items_before_it():
    def items():
        yield 1
        yield 2
        raise ValueError("frame 3 is broken")

    seen = []
    with pytest.raises(ValueError, match="frame 3"):
        for item in prefetched(items(), depth=2):
            seen.append(item)
    assert seen == [1, 2]


def test_a_caller_that_stops_early_stops_the_thread_and_closes_the_source():
    closed = threading.Event()

    def items():
        try:
            for i in range(10_000):
                yield i
        finally:
            closed.set()

    for item in prefetched(items(), depth=2):
        if item == 3:
            break
    assert closed.wait(2.0)
    assert not any(t.name == "ndfa-prefetch" and t.is_alive() for t in threading.enumerate())


def test_recording_frames_read_ahead_are_the_frames():
    from pathlib import Path

    import numpy as np

    from ndfa.io.recording.reader import RecordingReader

    reader = RecordingReader(Path(__file__).parents[1] / "recordings" / "sample" / "target.mcap")
    direct = list(reader.frames(stop=6))
    ahead = list(prefetched(reader.frames(stop=6), depth=2))
    assert len(direct) == len(ahead) == 6
    for a, b in zip(direct, ahead):
        assert a.index == b.index and np.array_equal(a.depth, b.depth) and np.array_equal(a.pose_world_camera, b.pose_world_camera)
