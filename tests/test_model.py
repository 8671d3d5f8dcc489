"""The NDF model: equivariance of z and the center, invariance of the shape code and occupancy,
checkpoints, and that it can learn occupancy at all."""

import dataclasses
import math

import pytest
import torch
from conftest import random_rotation, relative_error

from ndfa.core.errors import ModelError
from ndfa.ndf.checkpoint import load_model
from ndfa.ndf.config import NDFConfig
from ndfa.ndf.decoder import object_frame
from ndfa.ndf.model import NDFModel
from ndfa.training.checkpoint import save_checkpoint
from ndfa.training.losses import frame_loss

SEEDS = [0, 1, 2]
SMALL = NDFConfig(hidden=16, latent=16, knn=8, encoder_blocks=2, decoder_width=32, decoder_blocks=1, code_dim=8)


def view(seed: int, batch: int = 2, n: int = 300) -> torch.Tensor:
    """A zero-centred, mug-sized (about 10 cm) random cloud in metres, `[B, N, 3]`."""
    points = 0.05 * torch.randn(batch, n, 3, generator=torch.Generator().manual_seed(seed))
    return points - points.mean(1, keepdim=True)


def trained_looking(model: NDFModel, seed: int) -> NDFModel:
    """Residual blocks start as identities; perturb every weight so the test exercises them all."""
    torch.manual_seed(seed)
    with torch.no_grad():
        for parameter in model.parameters():
            parameter.add_(0.1 * torch.randn_like(parameter))
    return model.eval()


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize(
    "config",
    [NDFConfig(), NDFConfig(pooling="max", decoder="frame", local_points=4), NDFConfig(code_head="norms", pooling="max"),
     NDFConfig(up_cue=True, view_cue=True, center_head="gated", decoder="frame", local_points=4),
     NDFConfig(up_cue=True, view_cue=True, center_head="gated", decoder="frame", categories=("mug", "bowl", "box"))],
    ids=["default", "frame-local-max", "norms-max", "cues-gated-frame", "categories"],
)
def test_rotating_the_view_rotates_z_and_center_and_keeps_code_and_occupancy(seed, config):
    model = trained_looking(NDFModel(config), seed)
    points = view(seed)
    queries = 0.08 * torch.randn(2, 64, 3, generator=torch.Generator().manual_seed(seed + 100))
    # The direction cues rotate with the view (models without cues ignore them).
    up, view_ray = torch.randn(2, 2, 3, generator=torch.Generator().manual_seed(seed + 200))
    rotation = random_rotation(seed)
    with torch.no_grad():
        out = model(points, queries, up, view_ray)
        rotated = model(points @ rotation.T, queries @ rotation.T, up @ rotation.T, view_ray @ rotation.T)
    assert out["z"].shape == (2, config.latent, 3)
    code_dim = config.code_dim_out
    assert out["shape_code"].shape == (2, code_dim)
    assert out["center_offset"].shape == (2, 3)
    assert out["occupancy_logits"].shape == (2, 64)
    assert relative_error(rotated["z"], out["z"] @ rotation.T) <= 1e-4
    assert relative_error(rotated["center_offset"], out["center_offset"] @ rotation.T) <= 1e-4
    assert relative_error(rotated["shape_code"], out["shape_code"]) <= 1e-4
    assert relative_error(rotated["occupancy_logits"], out["occupancy_logits"]) <= 1e-4
    assert ("category_logits" in out) == bool(config.categories)
    if config.categories:  # the category is read from the code, so it is as invariant
        assert out["category_logits"].shape == (2, len(config.categories))
        assert relative_error(rotated["category_logits"], out["category_logits"]) <= 1e-4


def test_the_callers_centring_removes_a_translation():
    model = trained_looking(NDFModel(SMALL), 0)
    # Centre in float64 as a caller should: in float32, subtracting a centroid metres away from the
    # origin already loses ~1e-7 m per coordinate, and pooled features are small differences.
    points = view(0).double() + 0.3  # a view somewhere off the origin
    queries = points[:, :20] + 0.01
    shift = torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64)
    with torch.no_grad():
        outputs = []
        for p, q in ((points, queries), (points + shift, queries + shift)):
            centroid = p.mean(1, keepdim=True)
            outputs.append(model((p - centroid).float(), (q - centroid).float()))
    for key in outputs[0]:
        assert relative_error(outputs[1][key], outputs[0][key]) <= 1e-4, key


def test_a_model_with_cues_needs_them_and_uses_them():
    model = trained_looking(NDFModel(dataclasses.replace(SMALL, up_cue=True, view_cue=True)), 0)
    points, up, view_ray = view(0), torch.tensor([[0.0, 0.0, 1.0]] * 2), torch.tensor([[0.0, 1.0, 0.0]] * 2)
    with pytest.raises(ModelError, match="up, view_ray"):
        model.encode(points)
    with pytest.raises(ModelError, match="view_ray"):
        model.encode(points, up=up)
    with torch.no_grad():
        z = model.encode(points, up, view_ray)
        assert relative_error(model.encode(points, 5 * up, 0.1 * view_ray), z) <= 1e-5  # directions only
        assert relative_error(model.encode(points, view_ray, up), z) > 1e-2


def test_object_frame_is_orthonormal_right_handed_and_rotates_with_its_input():
    vectors = torch.randn(5, 3, 2, generator=torch.Generator().manual_seed(3))
    frame = object_frame(vectors)
    assert torch.allclose(frame.transpose(-1, -2) @ frame, torch.eye(3).expand(5, 3, 3), atol=1e-5)
    assert torch.allclose(torch.linalg.det(frame), torch.ones(5), atol=1e-5)
    # The first axis follows the first vector; the second lies in the plane of the two.
    assert torch.allclose(frame[..., 0], torch.nn.functional.normalize(vectors[..., 0], dim=-1), atol=1e-5)
    assert torch.allclose((frame[..., 2] * vectors[..., 1]).sum(-1), torch.zeros(5), atol=1e-5)
    rotation = random_rotation(3)
    assert relative_error(object_frame(rotation @ vectors), rotation @ frame) <= 1e-5


def test_frame_loss_is_zero_when_aligned_and_invariant_to_rotation():
    rotation_camera_object = torch.stack([random_rotation(s) for s in range(4)])
    aligned = rotation_camera_object[..., [2, 0]]  # axis (mug z) and handle (mug x) directions
    assert frame_loss(2.0 * aligned, rotation_camera_object).item() == pytest.approx(0.0, abs=1e-6)
    assert frame_loss(-aligned, rotation_camera_object).item() == pytest.approx(2.0, abs=1e-6)
    guess = torch.randn(4, 3, 2, generator=torch.Generator().manual_seed(0))
    rotation = random_rotation(9)
    assert frame_loss(rotation @ guess, rotation @ rotation_camera_object).item() == pytest.approx(
        frame_loss(guess, rotation_camera_object).item(), abs=1e-5)


def test_center_offset_is_in_metres():
    model = trained_looking(NDFModel(SMALL), 0)
    doubled_scale = NDFModel(dataclasses.replace(SMALL, input_scale=2 * SMALL.input_scale))
    doubled_scale.load_state_dict(model.state_dict())
    points = view(0)
    with torch.no_grad():
        # Same weights, twice the input scale and half the metric input: same network input, so the
        # offset in metres must halve.
        offset = model.center_offset(model.encode(points))
        halved = doubled_scale.center_offset(doubled_scale.encode(points / 2))
    assert relative_error(halved, offset / 2) <= 1e-4


def test_bad_config_is_refused():
    with pytest.raises(ModelError, match="code_head"):
        NDFConfig(code_head="pca")
    with pytest.raises(ModelError, match="pooling"):
        NDFConfig(pooling="sum")
    with pytest.raises(ModelError, match="decoder"):
        NDFConfig(decoder="grid")
    with pytest.raises(ModelError, match="local_points"):
        NDFConfig(decoder="dots", local_points=4)
    with pytest.raises(ModelError, match="positive"):
        NDFConfig(latent=0)
    with pytest.raises(ModelError, match="center_head"):
        NDFConfig(center_head="mlp")
    with pytest.raises(ModelError, match="center_refits"):
        NDFConfig(center_refits=-1)
    with pytest.raises(ModelError, match="direction cue"):
        NDFConfig(latent=2, up_cue=True, view_cue=True)
    with pytest.raises(ModelError, match="categories"):
        NDFConfig(categories=("mug",))
    with pytest.raises(ModelError, match="categories"):
        NDFConfig(categories=("mug", "mug"))
    with pytest.raises(ModelError, match="no category head"):
        NDFModel(SMALL).category_logits(torch.zeros(1, SMALL.code_dim))


@pytest.mark.parametrize("categories", [(), ("mug", "box")])
def test_checkpoint_round_trip(tmp_path, categories):
    config = dataclasses.replace(SMALL, code_head="norms", categories=categories)
    model = trained_looking(NDFModel(config), 0)
    path = tmp_path / "run" / "ndf.pt"
    save_checkpoint(path, model, config, {"step": 7, "loss": [0.5, 0.25]})
    assert [p.name for p in path.parent.iterdir()] == ["ndf.pt"]  # no temporary left behind
    loaded, extra = load_model(path)
    assert loaded.config == config and not loaded.training
    assert extra == {"step": 7, "loss": [0.5, 0.25]}
    points, queries = view(1), view(2)[:, :32]
    with torch.no_grad():
        expected, got = model(points, queries), loaded(points, queries)
    for key in expected:
        assert torch.equal(got[key], expected[key]), key


def test_checkpoints_from_before_the_decoder_option_load_with_the_dots_decoder(tmp_path):
    config = dataclasses.replace(SMALL, decoder="dots", local_points=0)
    model = trained_looking(NDFModel(config), 0)
    old_config = {k: v for k, v in dataclasses.asdict(config).items() if k not in ("decoder", "local_points")}
    torch.save({"config": old_config, "state_dict": model.state_dict()}, tmp_path / "old.pt")
    loaded, _ = load_model(tmp_path / "old.pt")
    assert loaded.config.decoder == "dots"


def test_missing_corrupt_or_foreign_checkpoints_raise_model_error(tmp_path):
    with pytest.raises(ModelError, match="missing.pt.*not found"):
        load_model(tmp_path / "missing.pt")

    path = tmp_path / "ndf.pt"
    save_checkpoint(path, NDFModel(SMALL), SMALL, {})
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(ModelError, match=r"truncated.pt: not an ndfa checkpoint \(a truncated or corrupt torch file\)"):
        load_model(truncated)

    text = tmp_path / "notes.pt"
    text.write_text("not a checkpoint")
    with pytest.raises(ModelError, match="notes.pt"):
        load_model(text)

    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(3)}, foreign)
    with pytest.raises(ModelError, match="foreign.pt.*not an ndfa checkpoint"):
        load_model(foreign)

    mismatched = tmp_path / "mismatched.pt"
    content = torch.load(path, weights_only=True)
    content["config"]["latent"] = 32  # weights of a 16-vector latent under a 32-vector config
    torch.save(content, mismatched)
    with pytest.raises(ModelError, match="mismatched.pt: not an ndfa checkpoint .weights of another model"):
        load_model(mismatched)

    with pytest.raises(ValueError, match="reserved"):
        save_checkpoint(tmp_path / "x.pt", NDFModel(SMALL), SMALL, {"config": {}})


def toy_batch(generator: torch.Generator, batch: int = 16, n_points: int = 128, n_queries: int = 256):
    """Half-views of spheres and cubes of 3-6 cm (radius / half-side), randomly rotated: points on
    the half of the surface facing a random direction, and queries in a box 1.3 times the shape's
    size, labelled inside (1) or outside (0). Half-views, because a full sphere or cube is too
    symmetric for an equivariant code: no nonzero vector is left unchanged by all of its rotations,
    so z would be 0 for every size."""
    size = 0.03 + 0.03 * torch.rand(batch, 1, 1, generator=generator)
    is_cube = torch.arange(batch).reshape(batch, 1) % 2 == 1
    rotation = torch.stack([random_rotation(int(s)) for s in torch.randint(0, 10_000, (batch,), generator=generator)])
    facing = torch.nn.functional.normalize(torch.randn(batch, 1, 3, generator=generator), dim=-1)
    direction = torch.nn.functional.normalize(torch.randn(batch, n_points, 3, generator=generator), dim=-1)
    direction = torch.where((direction * facing).sum(-1, keepdim=True) < 0, -direction, direction)
    on_cube = direction / direction.abs().amax(-1, keepdim=True)  # radial projection onto the cube
    points = size * torch.where(is_cube.unsqueeze(-1), on_cube, direction) @ rotation.transpose(1, 2)
    queries = 1.3 * size * (2 * torch.rand(batch, n_queries, 3, generator=generator) - 1) @ rotation.transpose(1, 2)
    local = queries @ rotation / size  # back in the shape's own frame, in units of its size
    inside = torch.where(is_cube, local.abs().amax(-1) < 1, local.norm(dim=-1) < 1)
    centroid = points.mean(1, keepdim=True)  # as the caller does: the view's centroid, not the shape's
    return points - centroid, queries - centroid, inside.float()


@pytest.mark.slow
def test_a_tiny_model_learns_toy_occupancy():
    torch.manual_seed(0)
    points, queries, inside = toy_batch(torch.Generator().manual_seed(0))
    model = NDFModel(dataclasses.replace(SMALL, pooling="max"))  # max-pooling learned faster here
    optimiser = torch.optim.Adam(model.parameters(), lr=1e-2)
    losses = []
    for _ in range(48):
        logits = model(points, queries)["occupancy_logits"]
        loss = torch.nn.functional.binary_cross_entropy_with_logits(logits, inside)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        losses.append(loss.item())
    rate = inside.mean().item()
    constant_guess = -(rate * math.log(rate) + (1 - rate) * math.log(1 - rate))  # best loss without looking
    final = sum(losses[-5:]) / 5
    assert final < 0.7 * constant_guess, (losses[0], final, constant_guess)  # about 0.36 vs 0.64


def test_refitted_center_heads_give_the_center_and_leave_the_decoder_its_origin():
    config = NDFConfig(up_cue=True, view_cue=True, center_head="gated", decoder="frame", local_points=4)
    model = trained_looking(NDFModel(dataclasses.replace(config, center_refits=3)), 0)
    single = NDFModel(config).eval()
    single.load_state_dict({k: v for k, v in model.state_dict().items() if not k.startswith("center_refit.")})
    up, view_ray = torch.randn(2, 2, 3, generator=torch.Generator().manual_seed(200))
    queries = 0.08 * torch.randn(2, 64, 3, generator=torch.Generator().manual_seed(100))
    rotation = random_rotation(0)
    with torch.no_grad():
        out, alone = model(view(0), queries, up, view_ray), single(view(0), queries, up, view_ray)
        members = model.center_offset_members(out["z"])
        assert members.shape == (3, 2, 3)
        assert torch.allclose(out["center_offset"], members.mean(0), atol=1e-7)
        assert (members[0] - members[1]).abs().max() > 1e-4  # each from its own start
        assert (out["center_offset"] - alone["center_offset"]).abs().max() > 1e-4  # the refits give the center
        assert torch.equal(out["occupancy_logits"], alone["occupancy_logits"])  # the decoder's origin is the head's
        assert torch.equal(model.frame_origin(out["z"]), alone["center_offset"])
        turned = model.center_offset_members(model.encode(view(0) @ rotation.T, up @ rotation.T, view_ray @ rotation.T))
        assert relative_error(turned, members @ rotation.T) <= 1e-4  # each refit rotates with the view
