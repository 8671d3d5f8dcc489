"""The sample pair shipped in recordings/sample is what the generator makes today."""

from pathlib import Path

import numpy as np
import pytest

from ndfa.io.ingest.synthetic import world_ground_truth
from ndfa.io.recording import RecordingReader
from ndfa.sim.presets import make_config
from ndfa.sim.world import build_world, procedural_models

SAMPLE = Path(__file__).parents[1] / "recordings" / "sample"


@pytest.mark.parametrize("session", ["source", "target"])
def test_shipped_sample_matches_the_generator(session):
    reader = RecordingReader(SAMPLE / f"{session}.mcap")
    config = make_config("sample", reader.meta["seed"])
    expected = world_ground_truth(build_world(config, procedural_models(config)), config)
    truth = reader.ground_truth
    assert truth["objects"] == expected["objects"]
    assert truth["changes"] == expected["changes"] and truth["changes"]["total"] == 5
    frames = list(reader.frames())
    assert len(frames) > 30
    assert frames[0].depth.shape == (config.camera.height, config.camera.width)
    assert all(np.count_nonzero(f.depth) > 0.5 * f.depth.size for f in frames)
    assert sum(np.count_nonzero(f.instances) for f in frames) > 10_000
