"""TUM folders as converters and editors leave them (issue 31): lines out of time order, stamps in
milliseconds or nanoseconds, a byte order mark, a list that is a folder; and the recording's limits
on stamps and on the camera's focal length."""

import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import one_line
from test_tum import frame_ids, make_folder, pose_at

from ndfa.core.errors import IngestError, RecordingError
from ndfa.core.frame import Frame
from ndfa.io.ingest.tum import TumWarning, ingest_tum
from ndfa.io.ingest.tum_lists import read_list
from ndfa.io.recording import RecordingReader, RecordingWriter


def shuffled_lines(path: Path, order: list[int]) -> None:
    """Rewrite a list file with its data lines in `order` (comments first, as they were)."""
    lines = path.read_text().splitlines(keepends=True)
    comments = [line for line in lines if line.startswith("#")]
    data = [line for line in lines if not line.startswith("#")]
    path.write_text("".join(comments + [data[k] for k in order]))


def scaled_stamps(path: Path, factor: float, offset: float = 0.0) -> None:
    """Rewrite a list file with every stamp s as (s + offset) * factor."""
    out = []
    for line in path.read_text().splitlines(keepends=True):
        if line.startswith("#"):
            out.append(line)
            continue
        stamp, rest = line.split(" ", 1)
        out.append(f"{(float(stamp) + offset) * factor:.6f} {rest}")
    path.write_text("".join(out))


def test_lines_out_of_order_are_sorted_by_their_stamps(tmp_path):
    folder = make_folder(tmp_path / "tum")
    shuffled_lines(folder / "depth.txt", [3, 0, 4, 1, 2])
    shuffled_lines(folder / "rgb.txt", [1, 0, 2, 4, 3])
    shuffled_lines(folder / "groundtruth.txt", [*range(50, 0, -1), 0])
    with pytest.warns(TumWarning) as warned:
        summary = ingest_tum(folder, tmp_path / "out.mcap")
    messages = [str(w.message) for w in warned]
    for name, moved in (("depth.txt", "5 of 5"), ("rgb.txt", "4 of 5"), ("groundtruth.txt", "50 of 51")):
        assert any(f"{name}: lines not in time order" in m and f"sorted by timestamp ({moved} lines moved)" in m
                   for m in messages), messages
    assert summary.written == 5 and "synthetic" not in summary.timestamps
    frames = list(RecordingReader(tmp_path / "out.mcap").frames())
    assert frame_ids(frames) == [0, 1, 2, 3, 4]
    assert [f.rgb[0, 0, 0] for f in frames] == [0, 1, 2, 3, 4]  # paired by time, not by line
    for frame in frames:  # was: poses 1.5 m off, paired by line
        assert np.abs(frame.pose_world_camera - pose_at(frame.timestamp)).max() < 1e-6


@pytest.mark.parametrize("factor, unit", [(1e3, "milliseconds"), (1e6, "microseconds"), (1e9, "nanoseconds")])
def test_stamps_in_another_unit_are_read_as_seconds_with_a_warning(tmp_path, factor, unit):
    folder = make_folder(tmp_path / "tum")
    epoch = 1_305_031_102.0  # a TUM sequence's Unix time
    for name in ("depth.txt", "rgb.txt"):
        scaled_stamps(folder / name, factor, epoch)
    scaled_stamps(folder / "groundtruth.txt", 1.0, epoch)  # the poses in seconds, as TUM's
    with pytest.warns(TumWarning) as warned:
        summary = ingest_tum(folder, tmp_path / "out.mcap")
    messages = [str(w.message) for w in warned]
    assert sum(f"look like {unit}, not seconds" in m for m in messages) == 2, messages
    assert summary.written == 5
    frames = list(RecordingReader(tmp_path / "out.mcap").frames())
    assert [f.timestamp - epoch for f in frames] == pytest.approx([0.0, 0.1, 0.2, 0.3, 0.4], abs=1e-5)
    for frame in frames:
        assert np.abs(frame.pose_world_camera - pose_at(frame.timestamp - epoch)).max() < 1e-4


@pytest.mark.parametrize("factor, unit", [(1e3, "milliseconds"), (1e6, "microseconds"), (1e9, "nanoseconds")])
@pytest.mark.parametrize("start", [0.0, 1234.5])
def test_stamps_since_the_start_in_another_unit_are_told_by_their_interval(tmp_path, factor, unit, start):
    """Stamps counted from the recording's start (0, 33, 67, ... ms) are too small for their size to
    tell the unit: a 30 Hz recording read as seconds looked like 0.03 Hz, with poses placed at the
    wrong times."""
    stamps = tuple(k / 30 for k in range(5))
    folder = make_folder(tmp_path / "tum", stamps=stamps, groundtruth=(-0.05, 0.2))
    for name in ("depth.txt", "rgb.txt", "groundtruth.txt"):
        scaled_stamps(folder / name, factor, start)
    with pytest.warns(TumWarning) as warned:
        summary = ingest_tum(folder, tmp_path / "out.mcap")
    messages = [str(w.message) for w in warned]
    for name in ("depth.txt", "rgb.txt", "groundtruth.txt"):
        assert sum(f"{name}: timestamps" in m and f"look like {unit}, not seconds" in m for m in messages) == 1, messages
    assert any("depth.txt" in m and "(30 lines per second, where seconds would give" in m for m in messages), messages
    assert summary.written == 5
    frames = list(RecordingReader(tmp_path / "out.mcap").frames())
    assert [f.timestamp - start for f in frames] == pytest.approx(stamps, abs=1e-5)
    for frame in frames:
        assert np.abs(frame.pose_world_camera - pose_at(frame.timestamp - start)).max() < 1e-4


@pytest.mark.parametrize("stamps", [(0.0, 1.0, 2.0, 3.0, 4.0), (0.0, 0.004, 0.008, 0.012, 0.016), (7.0, 12.0)])
def test_stamps_in_seconds_at_any_plausible_rate_stay_seconds(tmp_path, stamps):
    """A list thinned to 1 frame per second, a 250 Hz camera, one frame per 5 s: seconds, no warning."""
    folder = make_folder(tmp_path / "tum", stamps=stamps, groundtruth=(stamps[0] - 0.05, stamps[-1] + 0.05))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        summary = ingest_tum(folder, tmp_path / "out.mcap")
    assert summary.written == len(stamps)
    frames = list(RecordingReader(tmp_path / "out.mcap").frames())
    assert [f.timestamp for f in frames] == pytest.approx(stamps)


def test_poses_at_a_rate_either_unit_fits_take_the_depth_lists_unit(tmp_path):
    """Motion capture at 1 kHz in milliseconds (1 ms apart) fits seconds too (1 Hz): the depth
    list's milliseconds decide."""
    (tmp_path / "groundtruth.txt").write_text("".join(f"{k}.0 0 0 0 0 0 0 1\n" for k in range(10)))
    assert read_list(tmp_path, "groundtruth.txt", required=True).per_second == 1.0
    in_ms = read_list(tmp_path, "groundtruth.txt", required=True, likely_per_second=1e3)
    assert in_ms.per_second == 1e3 and in_ms.stamps[-1] == pytest.approx(0.009)
    assert "look like milliseconds" in in_ms.warnings[0]


def test_stamps_no_unit_makes_seconds_are_refused_with_the_hint(tmp_path):
    folder = make_folder(tmp_path / "tum", groundtruth=None)
    scaled_stamps(folder / "depth.txt", 1e300, 1.0)
    with pytest.raises(IngestError, match=r"depth\.txt: timestamps up to 1\.4e\+300 are no time in seconds.*TUM lists "
                                          r"hold seconds"):
        ingest_tum(folder, tmp_path / "out.mcap")
    assert not (tmp_path / "out.mcap").exists()


def test_the_writer_refuses_a_stamp_mcap_cannot_hold(tmp_path):
    frame = Frame(0, 2e10, None, np.ones((4, 4), np.float32), np.diag([300.0, 300.0, 1.0]), np.eye(4), None)
    with RecordingWriter(tmp_path / "x.mcap", {"source": "test", "session": "x"}) as writer:
        with pytest.raises(RecordingError, match=r"frame 0 has timestamp 2e\+10 s, outside what MCAP holds.*seconds\?"):
            writer.write_frame(frame)
        writer.write_frame(Frame(0, 1.0, None, np.ones((4, 4), np.float32), np.diag([300.0, 300.0, 1.0]),
                                 np.eye(4), None))


def test_a_byte_order_mark_is_skipped(tmp_path):
    folder = make_folder(tmp_path / "tum", comments=False)
    for name in ("depth.txt", "rgb.txt", "groundtruth.txt"):
        (folder / name).write_bytes(b"\xef\xbb\xbf" + (folder / name).read_bytes())
    assert ingest_tum(folder, tmp_path / "out.mcap").written == 5


def test_a_list_that_is_a_folder_is_named(tmp_path):
    folder = make_folder(tmp_path / "tum")
    (folder / "rgb.txt").unlink()
    (folder / "rgb.txt").mkdir()
    with pytest.raises(IngestError, match=r"rgb\.txt: is a directory, not a list file"):
        ingest_tum(folder, tmp_path / "out.mcap")  # was: read as missing, every frame without colour


def test_a_zero_focal_length_names_the_file_and_channel(tmp_path, monkeypatch):
    with pytest.raises(ValueError, match="focal lengths fx, fy > 0"):  # ndfa itself never writes one
        Frame(0, 1.0, None, np.ones((4, 4), np.float32), np.zeros((3, 3)), np.eye(4), None)
    # A recording from elsewhere may carry one: written here with the frame's own check switched off.
    monkeypatch.setattr(Frame, "validate", lambda self: None)
    path = tmp_path / "k0.mcap"
    with RecordingWriter(path, {"source": "test", "session": "x"}) as writer:
        writer.write_frame(Frame(0, 1.0, None, np.ones((4, 4), np.float32), np.zeros((3, 3)), np.eye(4), None))
    monkeypatch.undo()
    with pytest.raises(RecordingError, match=rf"{path}: channel /camera/calibration at .*: K must be finite with focal "
                                             r"lengths fx, fy > 0, got fx 0, fy 0"):
        RecordingReader(path)


@pytest.mark.parametrize("args, fragment", [
    (["--session", ""], "--session must be a non-empty name, got ''"),
    (["--session", "  "], "--session must be a non-empty name"),
    (["--intrinsics", "525,525,1e308,1e308"], "at most 100000 pixels"),
    (["--intrinsics", "0,525,320,240"], "fx and fy must be > 0"),
])
def test_ingest_tum_options_out_of_reason_are_refused(tmp_path, ndfa, args, fragment):
    folder = make_folder(tmp_path / "tum")
    one_line(ndfa("ingest", "tum", folder, "--out", tmp_path / "out.mcap", *args), fragment)
    assert not (tmp_path / "out.mcap").exists()


def test_ingest_tum_makes_missing_folders_as_detect_log_does(tmp_path, ndfa):
    folder = make_folder(tmp_path / "tum")
    code, _, err = ndfa("ingest", "tum", folder, "--out", tmp_path / "new" / "deeper" / "out.mcap")
    assert code == 0, err
    assert len(RecordingReader(tmp_path / "new" / "deeper" / "out.mcap")) == 5
    (folder / "depth.txt").unlink()  # a failing import: the folders it made go again
    code, _, err = ndfa("ingest", "tum", folder, "--out", tmp_path / "other" / "deeper" / "out.mcap")
    assert code == 2 and "depth.txt" in err
    assert not (tmp_path / "other").exists()


def test_a_symbolic_link_loop_is_called_one(tmp_path, ndfa):
    folder = make_folder(tmp_path / "tum")
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    one_line(ndfa("ingest", "tum", folder, "--out", tmp_path / "out.mcap", "--masks", tmp_path / "loop"),
             "--masks", "a symbolic link that leads nowhere (broken, or a loop)")
