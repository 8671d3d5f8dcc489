"""Which frames a run uses (`ndfa.run.rate`, `--frame-step`, `--rate`): the rule on timestamps,
the recording's timestamps without decoding, and the frames spread among the used ones."""

from __future__ import annotations

import numpy as np
import pytest

from ndfa.io.recording import RecordingReader
from ndfa.io.recording.reader import SEEK_GAP_FRAMES, _sparse
from ndfa.run.rate import at_rate, recorded_seconds, used_positions
from ndfa.run.stream import RunOptions
from ndfa.run.world import spread
from tests.test_sessions import SAMPLE


def jittered(hz: float, n: int, jitter_s: float = 0.002, seed: int = 0) -> list[float]:
    rng = np.random.default_rng(seed)
    return list(np.arange(n) / hz + rng.uniform(-jitter_s, jitter_s, n))


def test_a_30_hz_stream_at_15_hz_uses_every_second_frame_despite_jitter():
    assert at_rate(jittered(30, 90), 15) == list(range(0, 90, 2))


def test_at_rate_uses_frames_at_most_so_often():
    times = jittered(30, 91)
    assert at_rate(times, 10) == list(range(0, 91, 3))
    assert at_rate(times, 20) == list(range(0, 91, 2))   # 20 Hz is not a step of 30 Hz: every 2nd, 15 Hz
    assert at_rate(times, 30) == list(range(91))
    assert at_rate(times, 100) == list(range(91))        # slower than the rate: every frame
    used = at_rate(times, 7)
    assert min(np.diff([times[p] for p in used])) >= 0.9 / 7


def test_a_recordings_time_counts_its_last_frames_period_too():
    assert recorded_seconds(jittered(30, 300, jitter_s=0.0)) == pytest.approx(10.0)
    assert recorded_seconds(jittered(5, 339, jitter_s=0.001)) == pytest.approx(339 / 5, abs=0.01)
    assert recorded_seconds([3.0]) == 0.0


def test_a_pause_in_the_recording_takes_the_first_frame_after_it():
    times = [0.0, 0.033, 0.066, 1.0, 1.033, 1.066, 1.1]
    assert at_rate(times, 15) == [0, 2, 3, 5]


def test_a_rate_must_be_positive():
    with pytest.raises(ValueError, match="rate_hz"):
        at_rate([0.0, 1.0], 0)


def test_used_positions_by_step_or_by_rate_not_both():
    reader = RecordingReader(SAMPLE / "source.mcap")
    assert used_positions(reader) == range(len(reader))
    assert used_positions(reader, 3) == range(0, len(reader), 3)
    assert RunOptions(frame_step=3).positions(reader) == range(0, len(reader), 3)
    step = float(np.median(np.diff(reader.timestamps())))
    assert list(used_positions(reader, rate_hz=0.5 / step)) == list(range(0, len(reader), 2))
    with pytest.raises(ValueError, match="give one of them"):
        used_positions(reader, 2, 1.0)


def test_the_timestamps_from_the_index_are_the_frames_timestamps():
    reader = RecordingReader(SAMPLE / "source.mcap")
    decoded = [frame.timestamp for frame in reader.frames()]
    assert reader.timestamps() == decoded
    # Without message indexes the file is read through: the same times.
    reader._chunk_indexes = []
    assert reader.timestamps() == decoded


def test_frames_at_positions():
    reader = RecordingReader(SAMPLE / "source.mcap")
    indices = [frame.index for frame in reader.frames()]
    assert [f.index for f in reader.frames(positions=[0, 5, 6, 40])] == [indices[p] for p in (0, 5, 6, 40)]
    assert [f.index for f in reader.frames(positions=range(1, 20, 4))] == [f.index for f in reader.frames(1, 20, 4)]
    assert list(reader.frames(positions=[])) == []
    with pytest.raises(ValueError, match="increase"):
        list(reader.frames(positions=[5, 3]))


def test_frames_far_apart_are_read_by_seeking_and_are_the_frames_a_read_through_gives():
    reader = RecordingReader(SAMPLE / "source.mcap")
    every = list(reader.frames())
    for positions in (range(0, len(every), SEEK_GAP_FRAMES), range(3, len(every), 7), [1, 9, 30, 31, len(every) - 1]):
        assert _sparse(positions)
        seeking = list(reader.frames(positions=positions))
        assert len(seeking) == len(positions)
        for frame, position in zip(seeking, positions):
            expected = every[position]
            assert (frame.index, frame.timestamp) == (expected.index, expected.timestamp)
            np.testing.assert_array_equal(frame.depth, expected.depth)
            np.testing.assert_array_equal(frame.rgb, expected.rgb)
            np.testing.assert_array_equal(frame.instances, expected.instances)
            np.testing.assert_array_equal(frame.pose_world_camera, expected.pose_world_camera)
    assert not _sparse(range(0, len(every), 2)) and not _sparse([4])


def test_spread_is_the_grid_where_every_frame_is_used_and_the_nearest_used_frames_otherwise():
    assert spread(339, 40) == list(range(0, 339, 8))
    assert spread(339, 40, range(339)) == list(range(0, 339, 8))
    assert spread(339, 40, range(0, 339, 2)) == list(range(0, 339, 8))   # a step that divides the grid's
    odd = spread(100, 20, range(0, 100, 2))                                # grid step 5: 0, 5, 10, ...
    assert odd[:4] == [0, 4, 10, 14]                                       # 5 -> 4 (a tie: the earlier)
    assert all(p % 2 == 0 for p in odd) and odd == sorted(set(odd))
    assert spread(100, 20, [0, 50, 99]) == [0, 50, 99]                     # none twice
