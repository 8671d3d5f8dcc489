"""The paper's baselines (NN point differencing, PMT-style TSDF submaps) on a hand-made scene of two
mugs, one of which moves 5 cm; and `ndfa eval`, which prints Table I for ndfa and both baselines."""

from pathlib import Path

import numpy as np
import polars as pl
import pytest
from typer.testing import CliRunner

from ndfa.cli import app
from ndfa.core.geometry import look_at, make_pose
from ndfa.eval.baselines import BaselineError, run_baseline
from ndfa.eval.baselines.nn import NNBaseline, NNConfig, voxel_downsample
from ndfa.eval.baselines.tsdf import Submap, TSDFBaseline, TSDFConfig
from ndfa.eval.table import open_for_baselines
from ndfa.io.recording import Frame, RecordingWriter
from ndfa.sim.camera import PinholeCamera
from ndfa.sim.mesh import box_mesh
from ndfa.sim.mug import make_mug
from ndfa.sim.render import RenderObject, SceneRenderer

SAMPLE = Path(__file__).parents[1] / "recordings" / "sample"
CAMERA = PinholeCamera.from_fov(320, 240, 60.0)
STAYS, MOVES, ADDED = 1, 2, 3


def _render(mugs: dict[int, tuple[float, float]], eyes_x: np.ndarray) -> list[Frame]:
    """Frames of mugs (id -> x, y on a table top at z = 0.75, a wall behind), seen from 0.6 m."""
    objects = [RenderObject(box_mesh((1.2, 0.6, 0.75), (0.0, 0.0, 0.375))),
               RenderObject(box_mesh((1.2, 0.05, 1.5), (0.0, 0.5, 0.75)))]
    for instance_id, (x, y) in mugs.items():
        mesh = make_mug(instance_id).mesh.transformed(make_pose(np.eye(3), np.array([x, y, 0.75])))
        objects.append(RenderObject(mesh, instance_id))
    renderer = SceneRenderer(objects)
    frames = []
    for index, x in enumerate(eyes_x):
        pose = look_at(np.array([x, -0.6, 0.95]), np.array([0.0, 0.0, 0.8]))
        view = renderer.render(CAMERA, pose)
        frames.append(Frame(index, float(index), None, view.depth, CAMERA.K, pose, view.instance))
    return frames


@pytest.fixture(scope="module")
def scene() -> tuple[list[Frame], list[Frame]]:
    """Source: mugs 1 and 2; target, from other poses: mug 1 in place, mug 2 5 cm to the right."""
    source = _render({STAYS: (-0.12, 0.0), MOVES: (0.12, 0.0)}, np.linspace(-0.3, 0.3, 7))
    target = _render({STAYS: (-0.12, 0.0), MOVES: (0.17, 0.0)}, np.linspace(-0.25, 0.25, 5))
    return source, target


def _changed(decisions) -> set[int]:
    return {d.instance_id for d in decisions}


def test_nn_marks_the_moved_mug_and_not_the_one_that_stayed(scene):
    baseline = NNBaseline()
    decisions = run_baseline(baseline, *scene)
    assert _changed(decisions) == {MOVES}
    assert decisions[0].kind == "changed" and "no source point within 2 mm" in decisions[0].reason
    assert max(baseline.unmatched_fractions[STAYS]) < 0.3 <= min(baseline.unmatched_fractions[MOVES])
    scores = baseline.candidate_scores()  # reported iff the score reaches r
    assert {i for i, s in scores.items() if s >= baseline.threshold} == {MOVES} and scores[STAYS] > 0


def test_nn_reports_added_and_removed_mugs(scene):
    source, _ = scene
    target = _render({STAYS: (-0.12, 0.0), ADDED: (0.3, 0.1)}, np.linspace(-0.25, 0.25, 5))
    baseline = NNBaseline()
    decisions = run_baseline(baseline, source, target)
    assert {(d.instance_id, d.kind) for d in decisions} == {(ADDED, "added"), (MOVES, "removed")}
    assert {i for i, s in baseline.candidate_scores().items() if s >= 1.0} == {ADDED, MOVES}  # whatever r is


def test_tsdf_marks_the_moved_mug_and_not_the_one_that_stayed(scene):
    baseline = TSDFBaseline()
    decisions = run_baseline(baseline, *scene)
    assert _changed(decisions) == {MOVES}
    assert ("source", STAYS) in baseline.persistent and ("target", STAYS) in baseline.persistent
    assert baseline.comparisons[("source", MOVES)].conflicting > 50
    scores = baseline.candidate_scores()  # the peak conflict as a multiple of the fewest that conflict
    assert {i for i, s in scores.items() if s >= baseline.threshold} == {MOVES} and 0 <= scores[STAYS] < 1


def test_submap_lookup_reads_the_signed_distance_to_a_wall():
    config = TSDFConfig(voxel_m=0.02, submap_length_m=0.32)
    submap = Submap(1, np.array([0.0, 0.0, 1.0]), config)
    frame = Frame(0, 0.0, None, np.full((240, 320), 1.0, np.float32), CAMERA.K, np.eye(4))
    from ndfa.eval.baselines.tsdf import DepthView

    view = DepthView.of(frame)
    submap.integrate(view, view.rgbd())
    distance, observed = submap.lookup(np.array([[0.0, 0.0, 0.97], [0.0, 0.0, 1.01], [0.0, 0.0, 1.2]]))
    assert observed.tolist() == [True, True, False]       # 20 cm behind the wall: never seen
    assert distance[:2] == pytest.approx([0.03, -0.01], abs=1e-3)
    assert np.abs(submap.iso_surface_points()[:, 2] - 1.0).max() < 1e-3


def test_voxel_downsample_keeps_one_mean_point_per_voxel():
    points = np.array([[0.0001, 0.0, 0.0], [0.0003, 0.0, 0.0], [0.0021, 0.0, 0.0]])
    assert np.allclose(voxel_downsample(points, 0.001), [[0.0002, 0.0, 0.0], [0.0021, 0.0, 0.0]])


def test_baseline_parameters_are_checked():
    with pytest.raises(BaselineError):
        NNConfig(distance_m=0.0)
    with pytest.raises(BaselineError):
        TSDFConfig(voxel_m=0.2, submap_length_m=0.32)


@pytest.mark.slow
def test_eval_prints_table_one_and_writes_it_with_precision_recall_curves(tmp_path):
    result = CliRunner().invoke(app, ["eval", str(SAMPLE / "source.mcap"), str(SAMPLE / "target.mcap"),
                                      "--out", str(tmp_path), "--pr-curve"])
    assert result.exit_code == 0, result.output
    for method in ("NN", "PMT", "ndfa"):
        assert method in result.output
    table = pl.read_parquet(tmp_path / "table.parquet")
    assert table["method"].to_list() == ["NN", "PMT", "ndfa"]
    assert (table["tp"] + table["fn"]).to_list() == [5, 5, 5]  # the sample has five changed mugs
    assert {"precision", "recall", "seconds"} <= set(table.columns)
    assert (tmp_path / "table.md").read_text().startswith("| method |")
    # ndfa's kinds, right / reports per kind (the baselines say "changed", not which change)
    kinds = dict(zip(table["method"].to_list(), table["kinds"].to_list()))
    assert kinds["NN"] == kinds["PMT"] == []
    assert {k["kind"] for k in kinds["ndfa"]} >= {"added", "moved"}
    assert all(0 <= k["right"] <= k["reports"] for k in kinds["ndfa"])
    assert "kinds right" in result.output and "kinds right" in (tmp_path / "table.md").read_text()
    # ... and per true change, its mugs named by a report of a right kind (the kinds' recall)
    found = dict(zip(table["method"].to_list(), table["kinds_found"].to_list()))
    assert found["NN"] == found["PMT"] == [] and found["ndfa"]
    assert all(0 <= k["found"] <= k["mugs"] for k in found["ndfa"])
    assert sum(k["mugs"] for k in found["ndfa"]) == 5  # the sample's five changed mugs, each counted once
    assert "kinds found" in result.output and "kinds found" in (tmp_path / "table.md").read_text()
    # --pr-curve: each method's threshold swept; at its default threshold each curve is its table row
    curves = pl.read_parquet(tmp_path / "pr_curve.parquet")
    assert curves.columns == ["method", "threshold", "default", "tp", "fp", "fn", "precision", "recall"]
    defaults = curves.filter(pl.col("default")).sort("method")
    assert defaults.select("method", "tp", "fp", "fn").rows() == table.sort("method").select(
        "method", "tp", "fp", "fn").rows()
    for method, rows in curves.group_by("method"):
        rows = rows.sort("threshold", descending=True)
        assert len(rows) > 1 and (rows["tp"] + rows["fn"]).unique().to_list() == [5]
        assert rows["tp"].diff().drop_nulls().min() >= 0 and rows["fp"].diff().drop_nulls().min() >= 0
    assert "AP" in result.output and "replay" not in result.output  # no note: the replay is the run
    from PIL import Image

    assert Image.open(tmp_path / "pr_curve.png").size[0] >= 400


def _write(path: Path, frames: list[Frame], truth: dict | None) -> Path:
    with RecordingWriter(path, {"source": "test", "session": path.stem}) as writer:
        for frame in frames:
            writer.write_frame(frame)
        if truth is not None:
            writer.write_ground_truth(truth)
    return path


def test_recordings_without_ground_truth_or_masks_are_refused(tmp_path, scene):
    source, target = scene
    truth = {"objects": [{"instance_id": STAYS, "change": "unchanged"}, {"instance_id": MOVES, "change": "moved"}]}
    with_masks = _write(tmp_path / "source.mcap", source[:2], truth)
    no_truth = _write(tmp_path / "no_truth.mcap", target[:2], None)
    with pytest.raises(BaselineError, match="no ground truth"):
        open_for_baselines(with_masks, no_truth)
    unmasked = [Frame(f.index, f.timestamp, None, f.depth, f.K, f.pose_world_camera) for f in target[:2]]
    no_masks = _write(tmp_path / "no_masks.mcap", unmasked, truth)
    with pytest.raises(BaselineError, match="no instance masks"):
        open_for_baselines(with_masks, no_masks)
    result = CliRunner().invoke(app, ["eval", str(with_masks), str(no_masks), "--out", str(tmp_path / "out")])
    assert result.exit_code != 0 and isinstance(result.exception, BaselineError)
    with pytest.raises(BaselineError, match="instance mask"):
        NNBaseline().add_source(unmasked[0])
