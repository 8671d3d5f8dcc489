"""TUM RGB-D import and export: lossless round trips of the sample recordings, and messy folders."""

from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from ndfa.cli import app
from ndfa.core.errors import ExportError, IngestError, NdfaError
from ndfa.core.geometry import make_pose, quaternion_xyzw_from_matrix, rotation_z
from ndfa.io.export.tum import export_tum
from ndfa.io.ingest.tum import TumWarning, ingest_tum
from ndfa.io.ingest.tum_folder import DEFAULT_INTRINSICS, INTRINSICS_PRESETS, read_tum_folder
from ndfa.io.recording import RecordingReader

SAMPLE = Path(__file__).resolve().parent.parent / "recordings" / "sample"


@pytest.fixture(scope="module")
def round_trip(tmp_path_factory) -> dict[str, tuple[Path, Path]]:
    """session -> (TUM folder, re-imported recording) for both sample recordings."""
    out = tmp_path_factory.mktemp("tum")
    result = {}
    for session in ("source", "target"):
        folder = out / session
        export_tum(SAMPLE / f"{session}.mcap", folder)
        summary = ingest_tum(folder, out / f"{session}.mcap")
        assert summary.written == summary.indexed == len(RecordingReader(SAMPLE / f"{session}.mcap"))
        assert summary.dropped == {} and summary.warnings == []
        result[session] = folder, out / f"{session}.mcap"
    return result


@pytest.mark.parametrize("session", ["source", "target"])
def test_export_then_import_gives_the_recording_back(round_trip, session):
    original, copy = RecordingReader(SAMPLE / f"{session}.mcap"), RecordingReader(round_trip[session][1])
    assert len(copy) == len(original) and copy.has_instances
    assert copy.ground_truth == original.ground_truth
    assert copy.meta["source"] == "tum" and copy.meta["intrinsics"]["source"] == "calibration.txt"
    for a, b in zip(original.frames(), copy.frames(), strict=True):
        assert (a.index, a.timestamp) == (b.index, b.timestamp)
        assert np.array_equal(a.depth, b.depth)  # both in millimetres
        assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.instances, b.instances)
        assert np.array_equal(a.K, b.K)
        assert np.abs(a.pose_world_camera - b.pose_world_camera).max() < 1e-6
        if a.pose_world_camera_true is None:
            assert b.pose_world_camera_true is None
        else:
            assert np.abs(a.pose_world_camera_true - b.pose_world_camera_true).max() < 1e-6


@pytest.mark.slow
def test_detection_on_the_round_trip_finds_the_same_changes(round_trip):
    from ndfa.run.detect import run_detection

    def changes(source: Path, target: Path) -> list[tuple]:
        return [(c.session, c.object_id, c.kind) for c in run_detection(source, target).changes]

    expected = changes(SAMPLE / "source.mcap", SAMPLE / "target.mcap")
    assert expected  # the sample pair has changes to find
    assert changes(round_trip["source"][1], round_trip["target"][1]) == expected


def test_export_refuses_a_folder_with_files(round_trip, tmp_path):
    (tmp_path / "keep.txt").write_text("mine")
    with pytest.raises(ExportError, match="already exists"):
        export_tum(SAMPLE / "source.mcap", tmp_path)
    assert [p.name for p in tmp_path.iterdir()] == ["keep.txt"]


# -- messy folders, built by hand: 8x6 images, depth 1 m + i mm marks frame i ------------------

H, W = 6, 8


def pose_at(t: float) -> np.ndarray:
    """A camera moving along x at 1 m/s and turning about z at 1 rad/s."""
    return make_pose(rotation_z(t), np.array([t, 0.0, 1.0]))


def write_png(path: Path, pixels: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(pixels).save(path)


def make_folder(root: Path, stamps=(0.0, 0.1, 0.2, 0.3, 0.4), rgb_offset=0.01, depth_dir="depth",
                groundtruth: tuple[float, float] | None = (-0.05, 0.45), comments=True) -> Path:
    """A TUM folder: depth frame i at stamps[i] (depth 1 m + i mm), rgb frame i at stamps[i] +
    rgb_offset (red = i), groundtruth at 100 Hz over the given span."""
    header = "# color images\n# file: 'messy.bag'\n# timestamp filename\n" if comments else ""
    rgb_lines, depth_lines = [header], [header.replace("color", "depth")]
    for i, stamp in enumerate(stamps):
        write_png(root / depth_dir / f"{stamp:.6f}.png", np.full((H, W), 5 * (1000 + i), np.uint16))
        write_png(root / "rgb" / f"{stamp + rgb_offset:.6f}.png", np.full((H, W, 3), [i, 0, 0], np.uint8))
        depth_lines.append(f"{stamp:.6f} {depth_dir}/{stamp:.6f}.png\n")
        rgb_lines.append(f"{stamp + rgb_offset:.6f} rgb/{stamp + rgb_offset:.6f}.png\n")
    (root / "depth.txt").write_text("".join(depth_lines))
    (root / "rgb.txt").write_text("".join(rgb_lines))
    if groundtruth is not None:
        lines = ["# ground truth trajectory\n# timestamp tx ty tz qx qy qz qw\n" if comments else ""]
        for t in np.arange(groundtruth[0], groundtruth[1] + 1e-9, 0.01):
            pose = pose_at(t)
            values = [*pose[:3, 3], *quaternion_xyzw_from_matrix(pose[:3, :3])]
            lines.append(f"{t:.4f} " + " ".join(f"{v:.9f}" for v in values) + "\n")
        (root / "groundtruth.txt").write_text("".join(lines))
    return root


def frame_ids(frames) -> list[int]:
    """Which frames of make_folder these are, from their depth."""
    return [int(round(f.depth[0, 0] * 1000)) - 1000 for f in frames]


def read(folder: Path, **options) -> list:
    return list(read_tum_folder(folder, **options))


def test_a_tidy_folder_with_comments_reads_with_interpolated_poses(tmp_path):
    frames = read(make_folder(tmp_path / "tum"))
    assert frame_ids(frames) == [0, 1, 2, 3, 4]
    assert [f.rgb[0, 0, 0] for f in frames] == [0, 1, 2, 3, 4]  # each depth frame got its own rgb
    assert [f.timestamp for f in frames] == pytest.approx([0.0, 0.1, 0.2, 0.3, 0.4])
    for frame in frames:  # groundtruth stamps hit the depth stamps up to rounding: interpolation is exact here
        assert np.abs(frame.pose_world_camera - pose_at(frame.timestamp)).max() < 1e-6
    fx, fy, cx, cy = DEFAULT_INTRINSICS
    assert np.array_equal(frames[0].K, [[fx, 0, cx], [0, fy, cy], [0, 0, 1]])


def test_poses_are_interpolated_between_groundtruth_samples(tmp_path):
    frames = read(make_folder(tmp_path / "tum", stamps=(0.005, 0.105, 0.215)))
    for frame in frames:
        assert np.abs(frame.pose_world_camera - pose_at(frame.timestamp)).max() < 1e-9


def test_frames_outside_the_groundtruth_span_are_dropped_and_counted(tmp_path):
    folder = make_folder(tmp_path / "tum", groundtruth=(0.15, 0.45))
    summary = ingest_tum(folder, tmp_path / "out.mcap", intrinsics="fr3")
    assert summary.written == 3 and summary.indexed == 5
    assert summary.dropped == {"outside the groundtruth time span (groundtruth.txt)": 2}
    reader = RecordingReader(tmp_path / "out.mcap")
    assert reader.meta["intrinsics"]["source"] == "TUM preset fr3"
    assert next(reader.frames()).K[0, 0] == INTRINSICS_PRESETS["fr3"][0]
    assert reader.meta["dropped"] == summary.dropped


def test_depth_frames_without_rgb_within_max_dt_are_kept_without_colour(tmp_path):
    folder = make_folder(tmp_path / "tum", rgb_offset=0.03)
    summary = ingest_tum(folder, tmp_path / "out.mcap", max_dt=0.02)
    assert summary.written == 5 and summary.depth_without_rgb == 5
    assert all(f.rgb is None for f in RecordingReader(tmp_path / "out.mcap").frames())


def test_a_depths_directory_is_accepted(tmp_path):
    folder = make_folder(tmp_path / "tum", depth_dir="depths")
    assert len(read(folder)) == 5
    text = (folder / "depth.txt").read_text().replace("depths/", "depth/")  # lines name depth/, files in depths/
    (folder / "depth.txt").write_text(text)
    assert len(read(folder)) == 5


def test_a_missing_png_is_skipped_and_counted(tmp_path):
    folder = make_folder(tmp_path / "tum")
    (folder / "depth" / "0.200000.png").unlink()
    (folder / "rgb" / "0.310000.png").unlink()
    summary = ingest_tum(folder, tmp_path / "out.mcap")
    assert summary.written == 3
    assert summary.dropped == {"missing depth PNG": 1, "missing rgb PNG": 1}
    assert frame_ids(RecordingReader(tmp_path / "out.mcap").frames()) == [0, 1, 4]


def test_unusable_stamps_fall_back_to_file_order(tmp_path):
    stamps = (0.0, -0.2, 0.1, 0.3)  # a negative stamp: no order by time can be trusted
    folder = make_folder(tmp_path / "tum", stamps=stamps, groundtruth=None)
    gt = "".join(f"{t} {i} 0 1 0 0 0 1\n" for i, t in enumerate(stamps))  # one pose per frame
    (folder / "groundtruth.txt").write_text(gt)
    with pytest.warns(TumWarning) as warned:
        summary = ingest_tum(folder, tmp_path / "out.mcap")
    messages = [str(w.message) for w in warned]
    assert any("depth.txt: timestamps cannot be used (line 5 has the negative timestamp -0.2)" in m for m in messages)
    assert any("groundtruth.txt: pairing poses with depth.txt line by line" in m for m in messages)
    assert summary.written == 4 and "file order" in summary.timestamps
    reader = RecordingReader(tmp_path / "out.mcap")
    assert "synthetic" in reader.meta["timestamps"]
    frames = list(reader.frames())
    assert frame_ids(frames) == [0, 1, 2, 3]  # file order
    assert [f.rgb[0, 0, 0] for f in frames] == [0, 1, 2, 3]
    assert [f.timestamp for f in frames] == pytest.approx([0, 1 / 30, 2 / 30, 3 / 30])
    assert [f.pose_world_camera[0, 3] for f in frames] == [0, 1, 2, 3]


def test_missing_depth_txt_names_the_file(tmp_path):
    folder = make_folder(tmp_path / "tum")
    (folder / "depth.txt").unlink()
    with pytest.raises(IngestError, match=r"depth\.txt: no such file"):
        read(folder)


def test_an_8_bit_depth_png_names_the_file(tmp_path):
    folder = make_folder(tmp_path / "tum")
    write_png(folder / "depth" / "0.100000.png", np.full((H, W), 7, np.uint8))
    with pytest.raises(IngestError, match=r"0\.100000\.png: .*16-bit.*8-bit"):
        read(folder)


def test_depth_65535_is_no_reading(tmp_path):
    # Kinect / 7-Scenes write 65535 where the sensor saw nothing; it must not become a 65.5 m wall.
    folder = make_folder(tmp_path / "tum")
    depth = np.full((H, W), 1500, np.uint16)
    depth[2:4, 3:6] = 65535
    write_png(folder / "depth" / "0.100000.png", depth)
    frame = read(folder, depth_scale=1000.0)[1]
    assert (frame.depth[2:4, 3:6] == 0).all()
    assert frame.depth[0, 0] == pytest.approx(1.5) and int((frame.depth == 0).sum()) == 6


def test_no_groundtruth_and_no_estimator_keeps_the_recording_without_poses(tmp_path):
    # A sensor's folder has no groundtruth.txt: the recording says "poses": "none" (ndfa detect estimates them).
    folder = make_folder(tmp_path / "tum", groundtruth=None)
    summary = ingest_tum(folder, tmp_path / "out.mcap")
    assert summary.written == 5 and summary.poses == "none"
    assert len(summary.notes) == 1 and "no groundtruth.txt" in summary.notes[0] and "ndfa detect" in summary.notes[0]
    reader = RecordingReader(tmp_path / "out.mcap")
    assert not reader.has_poses and reader.meta["poses"] == "none" and reader.meta["poses_note"] == summary.notes[0]
    assert len(list(reader.frames())) == 5
    with pytest.raises(IngestError, match="no groundtruth.txt"):  # a reader that needs poses still says so
        read(folder)


def test_an_estimator_gives_the_poses(tmp_path):
    folder = make_folder(tmp_path / "tum", groundtruth=None)
    seen = []

    def estimate(frame):
        seen.append(frame)
        return pose_at(frame.timestamp)

    summary = ingest_tum(folder, tmp_path / "out.mcap", estimate_poses=estimate)
    assert len(seen) == 5 and all(f.rgb is None for f in seen)
    assert summary.written == 5 and summary.poses.startswith("estimated")
    for frame in RecordingReader(tmp_path / "out.mcap").frames():
        assert np.abs(frame.pose_world_camera - pose_at(frame.timestamp)).max() < 1e-6


def test_estimated_poses_keep_the_groundtruth_as_true_poses(tmp_path):
    folder = make_folder(tmp_path / "tum")
    summary = ingest_tum(folder, tmp_path / "out.mcap", estimate_poses=lambda frame: np.eye(4))
    reader = RecordingReader(tmp_path / "out.mcap")
    assert reader.meta["poses"] == summary.poses and "kept as the true poses" in summary.poses
    for frame in reader.frames():
        assert np.array_equal(frame.pose_world_camera, np.eye(4))
        assert np.abs(frame.pose_world_camera_true - pose_at(frame.timestamp)).max() < 1e-6


def test_masks_become_instances(tmp_path):
    folder = make_folder(tmp_path / "tum")
    for i, stamp in enumerate((0.0, 0.1, 0.2, 0.3, 0.4)):
        write_png(tmp_path / "labels" / f"{stamp:.6f}.png", np.full((H, W), 300 + i, np.uint16))
    frames = read(folder, masks=tmp_path / "labels")
    assert [int(f.instances[0, 0]) for f in frames] == [300, 301, 302, 303, 304]


def test_cli_imports_and_exports(tmp_path):
    folder = make_folder(tmp_path / "tum")
    runner = CliRunner()
    result = runner.invoke(app, ["ingest", "tum", str(folder), "--out", str(tmp_path / "a.mcap"),
                                 "--intrinsics", "500,501,3.5,2.5"])
    assert result.exit_code == 0, result.output
    assert "frames written" in result.output
    assert RecordingReader(tmp_path / "a.mcap").meta["intrinsics"]["fy"] == 501
    result = runner.invoke(app, ["export", "tum", str(tmp_path / "a.mcap"), "--out", str(tmp_path / "again")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "again" / "calibration.txt").read_text().splitlines()[-1] == "500.0 501.0 3.5 2.5"


def test_frames_splits_one_walk_into_two_sessions(tmp_path):
    """`--frames 0:2` and `--frames 2:` import the first two and the remaining three paired frames, renumbered."""
    folder = make_folder(tmp_path / "tum")
    runner = CliRunner()
    for text, out in (("0:2", "first.mcap"), ("2:", "last.mcap")):
        result = runner.invoke(app, ["ingest", "tum", str(folder), "--out", str(tmp_path / out), "--frames", text])
        assert result.exit_code == 0, result.output
    first, last = RecordingReader(tmp_path / "first.mcap"), RecordingReader(tmp_path / "last.mcap")
    assert [f.index for f in first.frames()] == [0, 1] and [f.index for f in last.frames()] == [0, 1, 2]
    depth_mm = [round(float(f.depth[0, 0]) * 1000) for r in (first, last) for f in r.frames()]
    assert depth_mm == [1000, 1001, 1002, 1003, 1004]  # frame i has depth 1 m + i mm: nothing lost, no overlap
    assert np.allclose(next(last.frames()).pose_world_camera, pose_at(0.2), atol=1e-6)
    assert last.meta["frames_selected"] == {"start": 2, "stop": 5, "of": 5}


@pytest.mark.parametrize("text, problem", [("5:", "selects no frame: the folder has 5"), ("3:1", "not a range"),
                                           ("two", "must be START:STOP")])
def test_frames_that_select_nothing_are_refused(tmp_path, text, problem):
    folder = make_folder(tmp_path / "tum")
    result = CliRunner().invoke(app, ["ingest", "tum", str(folder), "--out", str(tmp_path / "a.mcap"), "--frames", text])
    assert isinstance(result.exception, NdfaError) and problem in str(result.exception)  # the entry point: exit 2
    assert not (tmp_path / "a.mcap").exists()


# -- bad input found by the fuzz suite (issue 18) -------------------------------------------------------

@pytest.mark.parametrize("quaternion", ["0 0 0 0", "1e300 1e300 1e300 1e300"])
def test_an_impossible_quaternion_in_groundtruth_names_the_line(tmp_path, quaternion):
    """A zero quaternion once became a NaN pose (a numpy warning, then an error naming a depth PNG)."""
    folder = make_folder(tmp_path / "tum", comments=False)
    lines = (folder / "groundtruth.txt").read_text().splitlines()
    lines[3] = " ".join(lines[3].split()[:4]) + " " + quaternion
    (folder / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    result = CliRunner().invoke(app, ["ingest", "tum", str(folder), "--out", str(tmp_path / "out.mcap")])
    assert isinstance(result.exception, IngestError)
    assert "groundtruth.txt, line 4" in str(result.exception) and "is no rotation" in str(result.exception)
    assert not (tmp_path / "out.mcap").exists()


def test_an_import_of_no_frames_fails(tmp_path):
    """An empty depth.txt, or every depth PNG missing, once wrote a recording of 0 frames and exited 0."""
    folder = make_folder(tmp_path / "tum")
    (folder / "depth.txt").write_text("# nothing\n")
    with pytest.raises(IngestError, match=r"no frames to import: depth.txt lists no depth images"):
        ingest_tum(folder, tmp_path / "out.mcap")
    folder = make_folder(tmp_path / "tum2")
    for png in (folder / "depth").iterdir():
        png.unlink()
    with pytest.raises(IngestError, match=r"no frames to import: all 5 depth images of depth.txt were dropped "
                                          r"\(5 missing depth PNG\)"):
        ingest_tum(folder, tmp_path / "out.mcap")
    assert not (tmp_path / "out.mcap").exists()


def test_non_finite_intrinsics_in_calibration_txt_name_the_file(tmp_path):
    folder = make_folder(tmp_path / "tum")
    (folder / "calibration.txt").write_text("# fx fy cx cy\nnan 525 319.5 239.5\n")
    with pytest.raises(IngestError, match=r"calibration.txt: intrinsics must have finite fx, fy > 0"):
        ingest_tum(folder, tmp_path / "out.mcap")
