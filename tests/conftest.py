"""Shared test helpers for the NDF tests."""

import pytest
import torch


def pytest_addoption(parser):
    parser.addoption("--fuzz-examples", type=int, default=None,
                     help="Examples per fuzz generator (tests/fuzz), drawn at random: the long pass. "
                          "Default: a short derandomized pass.")


@pytest.fixture(autouse=True)
def one_torch_thread():
    """Tests use tiny tensors: a second thread costs more in synchronisation than it saves, and on a
    shared machine a busy core makes every parallel op wait (the toy fit took 67 s instead of 2 s)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def random_rotation(seed: int) -> torch.Tensor:
    """A uniformly random proper rotation (float32), from the QR decomposition of a Gaussian matrix."""
    g = torch.Generator().manual_seed(1000 + seed)
    q, r = torch.linalg.qr(torch.randn(3, 3, generator=g, dtype=torch.float64))
    q = q * torch.sign(torch.diagonal(r))  # unique QR: the distribution becomes uniform
    if torch.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q.float()


def relative_error(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).norm() / b.norm())
