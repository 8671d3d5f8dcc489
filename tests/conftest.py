"""Shared test helpers: the NDF tests' rotations, and running the `ndfa` command in process."""

import sys

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


@pytest.fixture
def ndfa(monkeypatch, capsys):
    """Run `ndfa ARGS` in this process, as the installed command does (`ndfa.cli.main`): (exit
    code, stdout, stderr)."""
    from ndfa.cli import main

    def run(*args):
        monkeypatch.setattr(sys, "argv", ["ndfa", *map(str, args)])
        try:
            main()
            code = 0
        except SystemExit as done:
            code = done.code
        captured = capsys.readouterr()
        return code, captured.out, captured.err

    return run


def one_line(result, *fragments):
    """Assert that `ndfa` failed with exit code 2 and one line on stderr holding every fragment; the line."""
    code, out, err = result
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, err
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    return lines[0]


@pytest.fixture(scope="session")
def small_raw_pair(tmp_path_factory):
    """A small raw pair (no masks, no poses), 160 x 120, about 100 frames in all: odometry, up
    from the planes and the scene alignment all run on it."""
    import dataclasses

    from ndfa.io.ingest.synthetic import ingest_sim
    from ndfa.sim.camera import PinholeCamera
    from ndfa.sim.noise import DepthNoise
    from ndfa.sim.presets import make_config

    config = make_config("sample", 3, depth_noise=DepthNoise.off(), camera=PinholeCamera().scaled(0.25))
    config = dataclasses.replace(config, trajectory=dataclasses.replace(config.trajectory, step_m=0.3),
                                 raw=True, textures=True)
    out = tmp_path_factory.mktemp("raw")
    ingest_sim(config, out)
    return out
