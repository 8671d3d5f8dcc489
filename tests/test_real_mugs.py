"""The real-mug protocol of `ndfa ndf-eval --real` (`ndfa.eval.real_mugs`): its bookkeeping on
hand-made numbers, the whole protocol on a rendered table with two mugs of known centers, bad
input, and the real 7-Scenes redkitchen sequence (skipped when ../shared is absent)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from ndfa.core.errors import DataError, IngestError
from ndfa.core.frame import Frame
from ndfa.core.geometry import look_at, make_pose, transform_points
from ndfa.eval.real_mugs import evaluate_real_mugs
from ndfa.eval.real_mugs.protocol import (
    ProtocolConfig,
    azimuth_span_deg,
    azimuths_deg,
    code_similarity,
    encode_views,
    horizontal_spread,
    largest_move,
    measure,
    pooled_spreads,
    time_windows,
    wall_circle,
)
from ndfa.eval.real_mugs.source import open_sequence
from ndfa.eval.real_mugs.tracks import MugTracks, TrackConfig, find_mugs, no_mugs_message, require_mugs
from ndfa.ndf.encoder import NDFEncoder

REDKITCHEN = Path(__file__).resolve().parents[2] / "shared" / "data" / "redkitchen_7scenes"


# -- bookkeeping on hand-made numbers ------------------------------------------------------------

def test_azimuth_is_the_direction_from_the_mug_to_the_camera_and_the_span_wraps_round():
    mug = np.array([1.0, 2.0])
    cameras = mug + np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -2.0], [1.0, -1.0]])
    np.testing.assert_allclose(azimuths_deg(cameras, mug), [0.0, 90.0, 180.0, 270.0, 315.0])
    assert azimuth_span_deg(np.array([350.0, 10.0, 5.0])) == pytest.approx(20.0)  # across 0, not 345
    assert azimuth_span_deg(np.array([0.0, 90.0, 180.0])) == pytest.approx(180.0)
    assert azimuth_span_deg(np.array([42.0])) == 0.0


def test_spreads_are_rms_distances_from_the_mean_horizontally_and_in_height():
    # Four points on a 3 cm circle about (5, 5), heights 1 +- 2 mm.
    points = np.array([[5.03, 5.0, 1.002], [5.0, 5.03, 0.998], [4.97, 5.0, 1.002], [5.0, 4.97, 0.998]])
    assert horizontal_spread(points) == pytest.approx(0.03)
    assert largest_move(points) == pytest.approx(0.06)
    spreads = pooled_spreads([(points, points * 0 + points.mean(axis=0))])  # a center that does not move
    assert spreads["centroid"] == pytest.approx(0.03) and spreads["centroid_height"] == pytest.approx(0.002)
    assert spreads["center"] == 0.0 and spreads["ratio"] == 0.0
    # Pooled over two sets: each about its own mean, so a shift between the sets adds nothing.
    pooled = pooled_spreads([(points, points), (points + [1.0, 0.0, 0.0], points)])
    assert pooled["centroid"] == pytest.approx(0.03) and pooled["ratio"] == pytest.approx(1.0)
    assert np.isnan(pooled_spreads([])["ratio"])


def test_windows_are_the_shortest_runs_that_span_the_angle_within_the_time_limit():
    # A camera at 12 deg/s for 12 s, one view every 0.5 s; the centroid moves 2 mm per view.
    times = np.arange(0.0, 12.0, 0.5)
    azimuths = (350.0 + 12.0 * times) % 360.0
    centroids = np.stack([0.002 * np.arange(len(times)), np.zeros(len(times)), np.zeros(len(times))], axis=1)
    windows = time_windows(times, azimuths, centroids, ProtocolConfig(min_angle_deg=45, max_window_s=10))
    assert windows == [(0, 9), (9, 18)]  # 4 s and 48 deg each (the first across 0 deg); 6 views left over
    for start, stop in windows:
        assert azimuth_span_deg(azimuths[start:stop]) >= 45.0 > azimuth_span_deg(azimuths[start:stop - 1])
    # The centroid must also move: 2 cm takes 11 views (5 s), 7 cm more than the 10 s allowed.
    assert time_windows(times, azimuths, centroids, ProtocolConfig(min_centroid_move_m=0.02)) == [(0, 11), (11, 22)]
    assert time_windows(times, azimuths, centroids, ProtocolConfig(min_centroid_move_m=0.07)) == []
    # Nor can 45 degrees be had within 3.5 s.
    assert time_windows(times, azimuths, centroids, ProtocolConfig(max_window_s=3.5)) == []


def test_code_similarity_separates_same_and_cross_mug_pairs():
    rng = np.random.default_rng(0)
    a, b = rng.standard_normal(16), rng.standard_normal(16)
    codes = np.stack([a + 0.05 * rng.standard_normal(16) for _ in range(4)] + [b + 0.05 * rng.standard_normal(16) for _ in range(3)])
    tracks = np.array([0, 0, 0, 0, 1, 1, 1])
    figures = code_similarity(codes, tracks, delta_s=0.7)
    assert figures["same_pairs"] == 6 + 3 and figures["cross_pairs"] == 12
    assert figures["code_auc"] == 1.0 and figures["same_above_delta_s"] == 1.0
    expected = float(a @ b / np.linalg.norm(a) / np.linalg.norm(b))
    assert figures["mean_code_cosine"] == pytest.approx(expected, abs=0.05)
    assert figures["cross_cosine_median"] == pytest.approx(expected, abs=0.05)
    # Pairs that involve mug 1 only: its 3 same pairs and the 12 cross pairs.
    assert code_similarity(codes, tracks, 0.7, focus=1)["same_pairs"] == 3
    # One code for both mugs: the codes cannot tell them apart.
    assert code_similarity(np.ones((7, 16)), tracks, 0.7)["code_auc"] == 0.5


# -- the protocol on a rendered table ------------------------------------------------------------

def _rendered_table(n_views: int = 25):
    """A table with a white and a dark mug (known centers), seen by a camera going 120 degrees
    round it, one frame every 0.2 s: the frames (no masks) and the mugs' true world centers."""
    from ndfa.sim.camera import PinholeCamera
    from ndfa.sim.render import RenderObject, SceneRenderer
    from ndfa.sim.scene import Table
    from ndfa.sim.splits import make_split_mug
    from ndfa.training.object_samples import object_center

    table = Table(0, (0.0, 0.0), size_xy=(1.2, 0.8))
    objects = [RenderObject(table.mesh(), 0, (0.55, 0.4, 0.3))]
    centers = []
    for instance, (x, colour) in enumerate([(-0.25, 0.95), (0.25, 0.25)], start=1):
        mug = make_split_mug("test", instance)
        pose = table.pose_world_top @ make_pose(np.eye(3), np.array([x, 0.05, 0.0]))
        objects.append(RenderObject(mug.mesh.transformed(pose), instance, (colour, colour, colour)))
        centers.append(transform_points(pose, object_center(mug)[None])[0])
    renderer = SceneRenderer(objects)
    camera = PinholeCamera()
    frames = []
    for i, azimuth in enumerate(np.radians(np.linspace(-150.0, -30.0, n_views))):
        eye = np.array([1.1 * np.cos(azimuth), 1.1 * np.sin(azimuth), table.height + 0.5])
        pose = look_at(eye, np.array([0.0, 0.0, table.height]))
        view = renderer.render(camera, pose)
        frames.append(Frame(index=i, timestamp=0.2 * i, rgb=view.rgb, depth=view.depth, K=camera.K,
                            pose_world_camera=pose))
    return frames, np.array(centers)


def test_the_wall_circle_finds_the_axis_of_a_mug_seen_from_one_side():
    rng = np.random.default_rng(0)
    axis_xy, radius = np.array([0.3, -0.2]), 0.04
    angle = rng.uniform(np.radians(-75), np.radians(75), 2000)  # the half facing the camera, at +x
    height = rng.uniform(0.0, 0.095, 2000)
    wall = np.column_stack([axis_xy + radius * np.column_stack([np.cos(angle), np.sin(angle)]), height - 0.75])
    wall += rng.normal(0.0, 0.001, wall.shape)
    handle = np.column_stack([rng.normal(0.3, 0.004, 150), rng.normal(-0.25, 0.004, 150), rng.uniform(-0.71, -0.67, 150)])
    stray = rng.uniform([0.2, -0.3, -0.75], [0.5, 0.0, -0.65], (60, 3))  # background at the silhouette
    points = np.vstack([wall, handle, stray])
    x, y, fitted = wall_circle(points)
    assert np.hypot(x - axis_xy[0], y - axis_xy[1]) < 0.0015 and abs(fitted - radius) < 0.0015
    assert np.linalg.norm(points[:, :2].mean(axis=0) - axis_xy) > 0.015  # where the visible centroid is
    assert np.isnan(wall_circle(points[:20])).all()  # too few points in the band


@pytest.fixture(scope="module")
def rendered():
    frames, centers = _rendered_table()
    found = find_mugs(frames, TrackConfig(min_views=5))
    per_view = encode_views(found.views, NDFEncoder())
    return frames, centers, found, per_view


def test_on_a_rendered_table_the_two_mugs_are_two_tracks_brightest_first(rendered):
    frames, centers, found, per_view = rendered
    assert found.mugs == 2 and found.frames == len(frames)
    for mug, center in enumerate(centers):  # mug 0 is the white one, at x = -0.25
        view = per_view.filter(pl.col("track") == mug)
        assert len(view) >= 0.8 * len(frames)
        centroid = view.select("centroid_x", "centroid_y").to_numpy()
        assert np.all(np.linalg.norm(centroid - center[:2], axis=1) < 0.06)
    brightness = [per_view.filter(pl.col("track") == mug)["brightness"].median() for mug in (0, 1)]
    assert brightness[0] > brightness[1] + 50


def test_on_a_rendered_table_the_azimuths_are_the_cameras_directions_and_the_ndf_center_stays_put(rendered):
    frames, centers, found, per_view = rendered
    summary, windows = measure(per_view, ProtocolConfig(max_window_s=3.0))
    for mug, center in enumerate(centers):
        view = per_view.filter(pl.col("track") == mug)
        cameras = view.select("camera_x", "camera_y").to_numpy()
        true_azimuth = azimuths_deg(cameras, center[:2])
        difference = (view["azimuth_deg"].to_numpy() - true_azimuth + 180.0) % 360.0 - 180.0
        assert np.abs(difference).max() < 3.0  # about the mean visible centroid, a cm or two off the center
        # The NDF's center of a rendered mug is within a centimetre of the true one (model card: ~3 mm).
        ndf = view.select("center_x", "center_y", "center_z").to_numpy()
        assert np.median(np.linalg.norm(ndf - center, axis=1)) < 0.01
        row = summary.filter(pl.col("mug") == str(mug)).to_dicts()[0]
        assert row["azimuth_span_deg"] == pytest.approx(azimuth_span_deg(true_azimuth), abs=3.0)
        # All views: the spreads are those of the table's own columns, and the NDF is the steadier.
        centroid = view.select("centroid_x", "centroid_y", "centroid_z").to_numpy()
        assert row["all_views_centroid_mm"] == pytest.approx(1e3 * horizontal_spread(centroid))
        assert row["all_views_center_mm"] == pytest.approx(1e3 * horizontal_spread(ndf))
        assert row["all_views_centroid_mm"] > 5.0 and row["all_views_ratio"] < 0.5
    # Windows of 3 s (15 views, 75 deg of the orbit) span >= 45 deg each, and the "all" row pools them.
    assert len(windows) >= 2 and (windows["azimuth_span_deg"] >= 45.0).all() and (windows["seconds"] <= 3.0).all()
    assert summary.filter(pl.col("mug") == "all")["windows"][0] == len(windows)
    assert summary.filter(pl.col("mug") == "all")["same_pairs"][0] > 0


def test_pose_errors_cancel_in_the_pose_free_spreads(rendered):
    frames, centers, found, per_view = rendered
    for mug, center in enumerate(centers):  # exact poses: each view's wall circle is on the mug's axis
        wall = per_view.filter(pl.col("track") == mug).select("wall_x", "wall_y").to_numpy()
        assert np.median(np.linalg.norm(wall - center[:2], axis=1)) < 0.005
    config = ProtocolConfig(max_window_s=3.0, min_centroid_move_m=0.0)  # windows by time and azimuth only
    summary, windows = measure(per_view, config)
    # A pose error moves every estimate of one view alike: the plain spreads grow, the pose-free do not.
    shift = np.random.default_rng(1).normal(0.0, 0.01, (len(per_view), 2))
    shifted = per_view.with_columns(*[(pl.col(f"{name}_{axis}") + shift[:, i]).alias(f"{name}_{axis}")
                                      for name in ("centroid", "center", "wall") for i, axis in enumerate("xy")])
    moved, _ = measure(shifted, config)
    row, moved_row = summary.filter(pl.col("mug") == "all").to_dicts()[0], moved.filter(pl.col("mug") == "all").to_dicts()[0]
    assert moved_row["windowed_center_mm"] > row["windowed_center_mm"] + 3.0
    for name in ("windowed_pose_free_centroid_mm", "windowed_pose_free_center_mm", "windowed_pose_free_ratio"):
        assert moved_row[name] == pytest.approx(row[name], rel=1e-6)
    assert 0.0 < row["windowed_pose_free_ratio"] < 0.5 and row["windowed_pose_free_centroid_mm"] > 2.0
    assert windows["pose_free_ratio"].is_finite().all()


@pytest.mark.slow
def test_a_recording_of_the_table_gives_the_same_views_through_the_whole_protocol(rendered, tmp_path):
    from ndfa.io.recording import RecordingWriter

    frames, centers, found, per_view = rendered
    with RecordingWriter(tmp_path / "table.mcap", {"source": "sim", "session": "table"}) as writer:
        for frame in frames:
            writer.write_frame(frame)
    result = evaluate_real_mugs(tmp_path / "table.mcap", [None], tracks=TrackConfig(min_views=5))
    assert result.tracks.mugs == 2 and "synthetic" in result.sequence.up
    assert result.views["track"].to_list() == per_view["track"].to_list()
    # Depth is stored in millimetres (masks and resampling change a little): centers within 5 mm.
    for axis in "xyz":
        assert np.abs(result.views[f"center_{axis}"].to_numpy() - per_view[f"center_{axis}"].to_numpy()).max() < 5e-3
    assert result.summary["mug"].to_list() == ["0", "1", "all"]


# -- failures --------------------------------------------------------------------------------------

def test_no_mugs_is_explained_in_one_line():
    tracks = MugTracks(views=[], mugs=0, frames=40, frames_with_segments=0, observations=0, track_sizes=[], min_views=10)
    assert "no mug-sized cluster above a support plane in any of 40 frames" in no_mugs_message(tracks, 2)
    tracks = MugTracks(views=[], mugs=1, frames=40, frames_with_segments=30, observations=35, track_sizes=[25, 6, 4],
                       min_views=10)
    with pytest.raises(DataError, match=r"^seq: 1 mug found \(wanted 2\): 35 observations in 40 frames fell into 3 "
                                        r"position tracks of 25, 6, 4 views; a mug needs 10"):
        require_mugs(tracks, 2, "seq")


def test_bad_folders_fail_with_one_line(tmp_path):
    with pytest.raises(IngestError, match="no such folder"):
        open_sequence(tmp_path / "missing")
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(IngestError, match="not a TUM RGB-D folder"):
        open_sequence(tmp_path / "notes.txt")
    with pytest.raises(IngestError, match="depth.txt"):
        open_sequence(tmp_path)
    (tmp_path / "depth").mkdir()
    from PIL import Image

    Image.fromarray(np.full((48, 64), 1500, dtype=np.uint16)).save(tmp_path / "depth" / "0.png")
    (tmp_path / "depth.txt").write_text("0.0 depth/0.png\n")
    with pytest.raises(IngestError, match="no groundtruth.txt"):
        open_sequence(tmp_path)


@pytest.mark.slow
def test_cli_real_with_a_bad_folder_exits_2_with_one_line_and_keeps_the_old_tables(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "real_summary.parquet").write_bytes(b"an earlier run's table")
    (tmp_path / "seq").mkdir()
    result = subprocess.run([sys.executable, "-m", "ndfa.cli", "ndf-eval", "--real", str(tmp_path / "seq"), "--out", str(out)],
                            cwd=Path(__file__).resolve().parents[1], capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stderr
    assert result.stderr.strip().count("\n") == 0 and "depth.txt: no such file" in result.stderr
    assert (out / "real_summary.parquet").read_bytes() == b"an earlier run's table"


# -- the real sequence ---------------------------------------------------------------------------

@pytest.mark.slow
@pytest.mark.skipif(not REDKITCHEN.is_dir(), reason=f"the 7-Scenes redkitchen sequence is not at {REDKITCHEN} "
                    "(../shared absent)")
def test_redkitchen_gives_the_white_and_the_patterned_mug_and_finite_figures():
    result = evaluate_real_mugs(REDKITCHEN, [None], frame_step=8)
    assert result.tracks.mugs == 2
    mugs = result.summary.filter(pl.col("mug") != "all").to_dicts()
    # test_registration_real.py's positions: the white mug at (-0.72, 1.80), the patterned at (0.26, 1.66).
    assert np.hypot(mugs[0]["mug_x"] + 0.72, mugs[0]["mug_y"] - 1.80) < 0.06
    assert np.hypot(mugs[1]["mug_x"] - 0.26, mugs[1]["mug_y"] - 1.66) < 0.06
    assert mugs[0]["brightness"] > mugs[1]["brightness"]
    everything = result.summary.filter(pl.col("mug") == "all").to_dicts()[0]
    for key in ("all_views_centroid_mm", "all_views_center_mm", "same_cosine_median", "cross_cosine_median", "code_auc"):
        assert np.isfinite(everything[key]), key
