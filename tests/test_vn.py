"""Vector-neuron layers: every layer commutes with rotations, the invariant layer ignores them."""

import pytest
import torch
from conftest import random_rotation, relative_error

from ndfa.ndf.vn import (
    VNEdgeConv,
    VNLayerNorm,
    VNLeakyReLU,
    VNLinear,
    VNResnetBlock,
    vn_invariant,
    vn_max_pool,
    vn_mean_pool,
)

SEEDS = [0, 1, 2, 3]


def rotate(x: torch.Tensor, rotation: torch.Tensor) -> torch.Tensor:
    """Rotate channels-last vector features `[..., 3, C]`: each channel x_c -> R x_c."""
    return torch.einsum("ij,...jc->...ic", rotation, x)




def features(seed: int, *shape: int) -> torch.Tensor:
    return torch.randn(*shape, generator=torch.Generator().manual_seed(seed))


def assert_equivariant(layer, x: torch.Tensor, seed: int) -> None:
    rotation = random_rotation(seed)
    with torch.no_grad():
        error = relative_error(layer(rotate(x, rotation)), rotate(layer(x), rotation))
    assert error <= 1e-4, error


@pytest.mark.parametrize("seed", SEEDS)
def test_linear_relu_and_block_are_equivariant(seed):
    torch.manual_seed(seed)
    x = features(seed, 4, 50, 3, 8)  # [B, N, 3, C]
    assert_equivariant(VNLinear(8, 5), x, seed)
    assert_equivariant(VNLeakyReLU(8), x, seed)
    assert_equivariant(VNLeakyReLU(8, negative_slope=0.0), x, seed)
    block = VNResnetBlock(8, 6)
    nn_init_nonzero(block)
    assert_equivariant(block, x, seed)


def nn_init_nonzero(module: torch.nn.Module) -> None:
    """Blocks start as identity + shortcut (zero last layer); give them weights that do something."""
    with torch.no_grad():
        for parameter in module.parameters():
            parameter.add_(0.3 * torch.randn_like(parameter))


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("train", [True, False])
def test_layer_norm_is_equivariant_in_train_and_eval_mode(seed, train):
    norm = VNLayerNorm(8)
    nn_init_nonzero(norm)
    norm.train(train)
    assert_equivariant(norm, features(seed, 4, 50, 3, 8), seed)
    assert_equivariant(norm, features(seed, 1, 3, 8), seed)  # a batch of one pooled feature too


def test_leaky_relu_clips_only_the_part_against_its_direction():
    relu = VNLeakyReLU(1, negative_slope=0.0)
    with torch.no_grad():
        relu.direction.weight.fill_(1.0)
    x = torch.tensor([[1.0], [2.0], [0.0]])  # k = x, so x.k > 0: passes unchanged
    assert torch.allclose(relu(x), x)
    leaky = VNLeakyReLU(2, negative_slope=0.2)
    with torch.no_grad():
        leaky.direction.weight.copy_(torch.tensor([[0.0, 1.0], [1.0, 0.0]]))  # k_0 = x_1, k_1 = x_0
    x = torch.tensor([[1.0, -1.0], [1.0, 0.0], [0.0, 0.0]])  # x_0 . x_1 = -1 < 0 for both channels
    out = leaky(x)
    # channel 0 = (1, 1, 0) loses 80% of its component along (-1, 0, 0), which is (1, 0, 0)
    assert torch.allclose(out[:, 0], torch.tensor([0.2, 1.0, 0.0]))


@pytest.mark.parametrize("seed", SEEDS)
def test_edge_conv_matches_the_plain_composition_and_is_equivariant(seed):
    torch.manual_seed(seed)
    conv = VNEdgeConv(3, 16)
    edges = features(seed, 2, 30, 8, 3, 3)  # [B, N, K, 3, in_c]
    with torch.no_grad():
        plain = conv.act(conv.linear(edges)).mean(-3)
        assert relative_error(conv(edges), plain) <= 1e-5
    assert_equivariant(conv, edges, seed)


@pytest.mark.parametrize("seed", SEEDS)
def test_pooling_is_equivariant(seed):
    x = features(seed, 4, 50, 3, 8)
    assert_equivariant(vn_mean_pool, x, seed)
    torch.manual_seed(seed)
    direction = VNLinear(8, 8)
    assert_equivariant(lambda v: vn_max_pool(v, direction(v)), x, seed)
    pooled = vn_max_pool(x, direction(x))
    assert pooled.shape == (4, 3, 8)
    # each output channel is one of the input points' vectors
    matches = (x - pooled.unsqueeze(1)).abs().sum(-2).min(1).values  # [B, C]
    assert torch.all(matches == 0)


@pytest.mark.parametrize("seed", SEEDS)
def test_invariant_layer_ignores_rotations(seed):
    torch.manual_seed(seed)
    x = features(seed, 4, 3, 8)  # [B, 3, C]
    to_frame = VNLinear(8, 3)
    rotation = random_rotation(seed)
    with torch.no_grad():
        invariant = vn_invariant(x, to_frame(x))
        rotated = vn_invariant(rotate(x, rotation), to_frame(rotate(x, rotation)))
    assert invariant.shape == (4, 8, 3)
    assert relative_error(rotated, invariant) <= 1e-4
    gram = vn_invariant(x, x)
    assert torch.allclose(gram, gram.transpose(-1, -2))
