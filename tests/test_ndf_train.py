"""Training, the losses, the inference API and the evaluation, on a tiny model and a few views."""

import numpy as np
import pytest
import torch

from ndfa.core.errors import ModelError
from ndfa.ndf.config import NDFConfig
from ndfa.ndf.encoder import DEFAULT_WEIGHTS, EncoderConfig, NDFEncoder
from ndfa.training.dataset import generate_views
from ndfa.training.losses import batch_hard_shape_loss
from ndfa.training.metrics import pair_separation, retrieval_top1, roc_auc
from ndfa.training.train import TrainConfig, train
from ndfa.training.views import ViewConfig

# The frame decoder with local points, max pooling, both direction cues and the gated center head:
# the training path with every loss term and every input.
TINY = NDFConfig(hidden=8, latent=16, knn=8, encoder_blocks=1, decoder_width=32, decoder_blocks=1, code_dim=16, gram_channels=4,
                 pooling="max", decoder="frame", local_points=4, up_cue=True, view_cue=True, center_head="gated")
FEW_VIEWS = ViewConfig(n_points=128, n_queries=128)


def test_batch_hard_loss_prefers_separated_codes():
    labels = torch.tensor([0, 1, 0, 1])
    separated = torch.tensor([[1.0, 0.0], [0.0, 1.0], [1.0, 0.1], [0.1, 1.0]])
    mixed = torch.tensor([[1.0, 0.0], [1.0, 0.1], [0.0, 1.0], [0.1, 1.0]])
    assert batch_hard_shape_loss(separated, labels) < 0 < batch_hard_shape_loss(mixed, labels)
    assert batch_hard_shape_loss(separated, labels, margin=0.5) == 0
    with pytest.raises(ValueError, match="two observations"):
        batch_hard_shape_loss(separated[:3], torch.tensor([0, 1, 2]))


def test_metrics_on_known_codes():
    codes = np.array([[1.0, 0.0], [0.9, 0.1], [0.0, 1.0], [0.1, 0.9]])
    labels = np.array([0, 0, 1, 1])
    assert retrieval_top1(codes, labels) == 1.0
    separation = pair_separation(codes, labels, 0.9)
    assert separation["auc"] == 1.0 and separation["same_above"] == 1.0 and separation["different_above"] == 0.0
    assert roc_auc(np.array([0.1, 0.4, 0.35, 0.8]), np.array([False, True, False, True])) == 1.0
    assert roc_auc(np.array([0.5, 0.5]), np.array([True, False])) == 0.5


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("train")
    config = TrainConfig(model=TINY, view=FEW_VIEWS, train_mugs=6, views_per_mug=3, val_mugs=3, val_views_per_mug=2,
                         batch_mugs=4, steps=40, steps_per_epoch=20, lr=3e-3, proxy_weight=0.1, param_weight=1.0)
    metrics = train(config, out)
    return config, out, metrics


@pytest.mark.slow
def test_training_lowers_the_loss_and_writes_metrics(tiny_run):
    config, out, metrics = tiny_run
    assert metrics["step"].to_list() == [20, 40]
    assert metrics["train_occ"][1] < metrics["train_occ"][0]
    assert metrics["train_param"][1] < metrics["train_param"][0]  # the shape parameters are read out of the codes
    assert (out / "checkpoint.pt").exists() and (out / "metrics.parquet").exists()
    for column in ("val_center_median_mm", "val_retrieval_top1", "val_auc", "val_occ_accuracy"):
        assert column in metrics.columns


@pytest.mark.slow
def test_training_resumes_where_it_stopped(tiny_run, tmp_path):
    config, out, metrics = tiny_run
    import dataclasses
    import shutil

    shutil.copytree(out, tmp_path / "run")
    other = dataclasses.replace(config, alpha=0.5)
    with pytest.raises(ModelError, match="other settings"):
        train(other, tmp_path / "run", resume=True)
    resumed = train(config, tmp_path / "run", resume=True)  # already complete: nothing to do
    assert resumed["step"].to_list() == [20, 40]
    longer = train(dataclasses.replace(config, steps=60, threads=1), tmp_path / "run", resume=True)
    assert longer["step"].to_list() == [20, 40, 60]


@pytest.mark.slow
def test_encoder_gives_world_frame_codes(tiny_run):
    _, out, _ = tiny_run
    encoder = NDFEncoder(out / "checkpoint.pt")
    views = generate_views("test", [0], 2, 0, FEW_VIEWS, workers=1)
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 2.0, 3.0]
    code, moved = encoder.encode_batch([views["points"][0]] * 2, [np.eye(4), pose])
    assert code.shape_code.shape == (TINY.code_dim,) and code.z.shape == (TINY.latent, 3)
    assert np.allclose(moved.center_world, code.center_world + [1.0, 2.0, 3.0], atol=1e-5)
    assert np.allclose(moved.shape_code, code.shape_code, atol=1e-5)
    assert 0.0 <= code.mean_occupancy <= 1.0
    again = encoder.encode(views["points"][0], np.eye(4))
    assert np.allclose(again.shape_code, code.shape_code, atol=1e-6)  # batched vs single: float rounding only


@pytest.mark.slow
def test_encoder_takes_up_from_the_camera_pose(tiny_run):
    """Turning the world under the same camera turns world up as the camera sees it: a model with
    the up cue then encodes the same cloud differently, and the same cloud under a camera turned
    about world up (up unchanged in the camera frame) alike, center turned with the pose."""
    from scipy.spatial.transform import Rotation

    _, out, _ = tiny_run
    encoder = NDFEncoder(out / "checkpoint.pt")
    cloud = generate_views("test", [0], 1, 0, FEW_VIEWS, workers=1)["points"][0]
    level = np.eye(4)
    level[:3, :3] = Rotation.from_euler("x", -90, degrees=True).as_matrix()  # camera z forward = world y
    yawed, tilted = level.copy(), level.copy()
    yawed[:3, :3] = Rotation.from_euler("z", 70, degrees=True).as_matrix() @ level[:3, :3]
    tilted[:3, :3] = Rotation.from_euler("y", 60, degrees=True).as_matrix() @ level[:3, :3]
    base, turned, other = encoder.encode_batch([cloud] * 3, [level, yawed, tilted])
    assert np.allclose(turned.shape_code, base.shape_code, atol=1e-4)
    turn = yawed[:3, :3] @ level[:3, :3].T
    assert np.allclose(turned.center_world, turn @ base.center_world, atol=1e-5)
    assert not np.allclose(other.shape_code, base.shape_code, atol=1e-3)


@pytest.mark.slow
def test_encoder_refuses_bad_input(tiny_run, tmp_path):
    _, out, _ = tiny_run
    encoder = NDFEncoder(out / "checkpoint.pt")
    with pytest.raises(ModelError, match="at least"):
        encoder.encode(np.zeros((1, 3)), np.eye(4))
    with pytest.raises(ModelError, match="at least"):
        encoder.encode(np.zeros((0, 3)), np.eye(4))
    with pytest.raises(ModelError, match="NaN"):
        encoder.encode(np.full((50, 3), np.nan), np.eye(4))
    with pytest.raises(ModelError, match="shape"):
        encoder.encode(np.zeros((50, 2)), np.eye(4))
    with pytest.raises(ModelError, match="not found"):
        NDFEncoder(tmp_path / "missing.pt")
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes((out / "checkpoint.pt").read_bytes()[:1000])
    with pytest.raises(ModelError, match="corrupt.pt"):
        NDFEncoder(corrupt)
    with pytest.raises(ModelError, match="center method"):
        NDFEncoder(out / "checkpoint.pt", EncoderConfig(center="median"))


@pytest.mark.slow
def test_evaluation_reports_every_figure(tiny_run):
    from ndfa.training.ndf_eval import evaluate_ndf

    _, out, _ = tiny_run
    views = generate_views("test", [0, 1], 2, 0, FEW_VIEWS, workers=1)
    summary, per_view = evaluate_ndf(out / "checkpoint.pt", views=views, iou_grid=12)
    for key in ("center_median_mm_head", "center_median_mm_reconstruction", "center_median_mm_weighted",
                "retrieval_top1", "auc", "same_above", "different_above", "iou_mean"):
        assert np.isfinite(summary[key]), key
    assert len(per_view) == 4 and 0.0 <= summary["iou_mean"] <= 1.0
    # The sweep's row at the encoder's v0 is the headline IoU.
    assert summary["iou_mean_v0_0.5"] == pytest.approx(summary["iou_mean"])
    assert 0.0 <= summary["iou_mean_true_shape_displaced"] <= 1.0


@pytest.mark.slow
def test_displaced_true_shape_iou_falls_with_the_center_error(tiny_run):
    from ndfa.training.ndf_eval import reconstruction_iou

    _, out, _ = tiny_run
    views = generate_views("test", [0], 3, 0, FEW_VIEWS, workers=1)
    errors = np.array([[0.0, 0.0, 0.0], [0.002, 0.0, 0.0], [0.0, 0.006, 0.0]])
    _, _, displaced = reconstruction_iou(NDFEncoder(out / "checkpoint.pt"), views, 24, errors)
    # No error: the true shape on itself; a mug's thin walls lose overlap fast as it moves.
    assert displaced[0] == pytest.approx(1.0)
    assert 0.2 < displaced[2] < displaced[1] < 0.95


def test_shipped_weights_load_and_encode():
    from ndfa.core.geometry import invert_pose

    encoder = NDFEncoder()  # the package's default weights
    views = generate_views("test", [0], 1, 0, ViewConfig(), workers=1)
    # World = the mug's frame (z up, as the model's up cue expects), camera where the view put it.
    pose_world_camera = invert_pose(views["pose_camera_object"][0].astype(np.float64))
    code = encoder.encode(views["points"][0], pose_world_camera)
    assert np.all(np.isfinite(code.shape_code)) and np.all(np.isfinite(code.center_world))
    # The shipped model's center is within a few centimetres of the true one on an unseen mug.
    true_center = pose_world_camera[:3, :3] @ views["center"][0] + pose_world_camera[:3, 3]
    assert np.linalg.norm(code.center_world - true_center) < 0.05


def test_proxies_of_a_trained_model_start_at_its_mean_codes():
    from ndfa.ndf.checkpoint import load_model
    from ndfa.training.trained_parts import TrainingHeads
    from ndfa.training.validate import encode_views

    model, _ = load_model(DEFAULT_WEIGHTS)
    views = generate_views("train", [0, 1, 2, 3], 3, 0, ViewConfig(), workers=1)
    heads = TrainingHeads(TrainConfig(train_mugs=4, proxy_weight=0.1), model, views)
    codes = model.shape_code(encode_views(model, views))  # with the views' up and view ray
    similarity = torch.nn.functional.normalize(codes, dim=1) @ torch.nn.functional.normalize(heads.proxies, dim=1).T
    own = torch.from_numpy(views["object_index"].astype(np.int64))
    assert (similarity.argmax(dim=1) == own).float().mean() >= 0.75  # each view sits near its own mug's proxy


@pytest.mark.slow
@pytest.mark.parametrize("part", ["code_head", "decoder"])
def test_refitting_one_part_keeps_the_rest(tiny_run, tmp_path, part):
    import dataclasses

    from ndfa.ndf.checkpoint import load_model

    config, out, _ = tiny_run
    # The decoder refit may change the decoder's kind: the frame decoder's weights are not loaded.
    model_config = dataclasses.replace(TINY, decoder="dots", local_points=0) if part == "decoder" else TINY
    refit = dataclasses.replace(config, model=model_config, init_weights=str(out / "checkpoint.pt"), train_only=part,
                                steps=20, batch_mugs=3 if part == "decoder" else 6)
    metrics = train(refit, tmp_path / part)
    before = load_model(out / "checkpoint.pt")[0].state_dict()
    after = load_model(tmp_path / part / "checkpoint.pt")[0].state_dict()
    prefix = {"code_head": "gram_code.", "decoder": "decoder."}[part]
    assert all(torch.equal(after[name], value) for name, value in before.items() if not name.startswith(prefix))
    if part == "code_head":
        assert not torch.equal(after["gram_code.mlp.0.weight"], before["gram_code.mlp.0.weight"])
        assert "train_shape" in metrics.columns and "train_occ" not in metrics.columns
    else:  # a fresh decoder of the other kind: the dots decoder's frame layer makes 3 vectors, the frame one 2
        assert after["decoder.frame.linear.weight"].shape[0] == 3 and before["decoder.frame.linear.weight"].shape[0] == 2
        assert "train_occ" in metrics.columns and "train_shape" not in metrics.columns
    with pytest.raises(ModelError, match="needs --init"):
        train(dataclasses.replace(refit, init_weights=None), tmp_path / "no-init")


@pytest.mark.slow
def test_fresh_decoder_of_another_size_trains_with_the_rest_from_init(tiny_run, tmp_path):
    import dataclasses

    from ndfa.ndf.checkpoint import load_model

    config, out, _ = tiny_run
    smaller = dataclasses.replace(TINY, decoder_width=16)
    run = dataclasses.replace(config, model=smaller, init_weights=str(out / "checkpoint.pt"), init_fresh="decoder", steps=3)
    train(run, tmp_path / "fresh")
    before = load_model(out / "checkpoint.pt")[0].state_dict()
    after = load_model(tmp_path / "fresh" / "checkpoint.pt")[0].state_dict()
    assert after["decoder.query_in.weight"].shape[0] == 16 and before["decoder.query_in.weight"].shape[0] == 32
    # Everything trains: the encoder moved away from the init's weights.
    encoder = [name for name in before if name.startswith("encoder.")]
    assert encoder and any(not torch.equal(after[name], before[name]) for name in encoder)
    with pytest.raises(ModelError, match="do not fit"):  # without init_fresh the other size cannot load
        train(dataclasses.replace(run, init_fresh="none"), tmp_path / "no-fresh")


@pytest.mark.slow
def test_headline_counts_the_detector_regime_and_box_twins(tiny_run):
    from ndfa.training.ndf_eval import box_twins, evaluate_ndf

    _, out, _ = tiny_run
    views = generate_views("test", [0, 1, 2], 3, 0, ViewConfig(n_points=128, n_queries=64, distance_range_m=(0.2, 0.8)), workers=1)
    summary, per_view = evaluate_ndf(out / "checkpoint.pt", views=views, iou_grid=0)
    regime = per_view["detector_regime"].to_numpy()
    assert summary["views_within_2m"] == regime.sum() > 1
    assert np.all(per_view["n_visible"].to_numpy()[regime] >= 300)
    assert summary["retrieval_top1_within_2m"] <= summary["retrieval_top1_within_2m_twins_merged"] <= 1.0
    assert "iou_mean" not in summary
    twins = box_twins("test", views)
    assert twins.shape == (3, 3) and np.all(np.diag(twins)) and np.array_equal(twins, twins.T)


@pytest.mark.slow
def test_refitting_the_center_fits_each_head_and_keeps_the_rest(tiny_run, tmp_path):
    import dataclasses

    from ndfa.ndf.checkpoint import load_model

    config, out, _ = tiny_run
    refit = dataclasses.replace(config, model=dataclasses.replace(TINY, center_refits=3),
                                init_weights=str(out / "checkpoint.pt"), train_only="center_refit", steps=20, batch_mugs=6,
                                steps_per_epoch=5)
    metrics = train(refit, tmp_path / "centers")
    before = load_model(out / "checkpoint.pt")[0].state_dict()
    after, _ = load_model(tmp_path / "centers" / "checkpoint.pt")
    assert after.config.center_refits == 3
    weights = after.state_dict()
    assert all(torch.equal(weights[name], value) for name, value in before.items())  # the center head too
    last = [weights[f"center_refit.members.{k}.weights.2.weight"] for k in range(3)]
    assert all(w.abs().max() > 0 for w in last)  # each head left its zero start
    assert not torch.equal(last[0], last[1])
    assert metrics["train_center"][-1] < metrics["train_center"][0]
    with pytest.raises(ModelError, match="center_refits > 0"):
        train(dataclasses.replace(refit, model=TINY), tmp_path / "none")
    with pytest.raises(ModelError, match="train_only center_refit"):
        train(dataclasses.replace(refit, train_only="all"), tmp_path / "all")
