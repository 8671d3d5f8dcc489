"""Which frames a run uses (`ndfa.run.rate`, `--frame-step`, `--rate`): the rule on timestamps,
the recording's timestamps without decoding, and the frames spread among the used ones."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from ndfa.io.recording import RecordingReader, RecordingWriter
from ndfa.io.recording.reader import SEEK_GAP_FRAMES, _sparse
from ndfa.run.rate import (
    DEFAULT_RATE_HZ,
    ODOMETRY_RATE_HZ,
    at_rate,
    chosen_rate,
    recorded_seconds,
    tracked_and_used,
    used_positions,
)
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


class _Stamps:
    """A recording as `used_positions` reads it: its length and its timestamps."""

    def __init__(self, times: list[float]) -> None:
        self.times = times

    def __len__(self) -> int:
        return len(self.times)

    def timestamps(self) -> list[float]:
        return self.times


def test_a_run_uses_a_fast_camera_at_the_default_rate_and_a_slow_one_whole():
    fast, slow = _Stamps(jittered(30, 300)), _Stamps(jittered(DEFAULT_RATE_HZ, 40))
    assert list(RunOptions().positions(fast)) == list(range(0, 300, round(30 / DEFAULT_RATE_HZ)))
    assert list(RunOptions().positions(slow)) == list(range(40))
    # A frame step replaces the rate; a rate of None (`--rate 0`) uses every frame.
    assert list(RunOptions(frame_step=2).positions(fast)) == list(range(0, 300, 2))
    assert list(RunOptions(rate_hz=None).positions(fast)) == list(range(300))
    assert list(RunOptions(rate_hz=15).positions(fast)) == list(range(0, 300, 2))
    assert chosen_rate(None) == DEFAULT_RATE_HZ and chosen_rate(0) is None and chosen_rate(10) == 10
    assert chosen_rate(None, frame_step=3) is None


def test_the_odometry_tracks_more_frames_than_the_pass_uses_and_every_one_of_those():
    fast = _Stamps(jittered(30, 300))
    tracked, used = RunOptions().tracked_and_used(fast)
    assert list(tracked) == list(range(0, 300, round(30 / ODOMETRY_RATE_HZ)))
    assert list(used) == list(range(0, 300, round(30 / DEFAULT_RATE_HZ))) and set(used) <= set(tracked)
    # Odd rates too: the pass's frames are picked among the odometry's.
    tracked, used = tracked_and_used(fast, rate_hz=4, odometry_rate_hz=11)
    assert set(used) <= set(tracked) and len(used) < len(tracked)
    assert min(np.diff([fast.times[p] for p in used])) >= 0.9 / 4
    # A frame step, every frame (`--rate 0`), or no faster odometry rate: the same frames for both.
    for options in (RunOptions(frame_step=3), RunOptions(rate_hz=None), RunOptions(odometry_rate_hz=None),
                    RunOptions(rate_hz=20)):
        tracked, used = options.tracked_and_used(fast)
        assert list(tracked) == list(used) == list(options.positions(fast))


def test_detect_uses_a_30_hz_recording_at_the_default_rate_and_every_frame_at_rate_0(ndfa, tmp_path):
    reader = RecordingReader(SAMPLE / "source.mcap")
    paths = [tmp_path / "a.mcap", tmp_path / "b.mcap"]
    for path in paths:  # the sample's first 30 frames, stamped as a 30 Hz camera would
        with RecordingWriter(path, {"source": "sim", "session": path.stem}) as writer:
            for i, frame in enumerate(reader.frames(stop=30)):
                writer.write_frame(dataclasses.replace(frame, index=i, timestamp=i / 30.0))
    used = len(range(0, 30, round(30 / DEFAULT_RATE_HZ)))
    code, _, err = ndfa("detect", *paths, "--json", tmp_path / "default.json")
    assert code == 0, err
    assert f"{used} of its 30 frames used (--rate {DEFAULT_RATE_HZ:g}, the default" in " ".join(err.split())
    assert json.loads((tmp_path / "default.json").read_text())["frames"] == 2 * used
    code, _, err = ndfa("detect", *paths, "--rate", "0", "--json", tmp_path / "every.json")
    assert code == 0, err
    assert "frames used" not in err and json.loads((tmp_path / "every.json").read_text())["frames"] == 60


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
