"""Shipped weights by name (`--weights mugs | objects`) and NDF v3's categories."""
from pathlib import Path

from conftest import one_line

from ndfa.cli.checks import shipped_weights
from ndfa.ndf.encoder import DEFAULT_WEIGHTS, WEIGHTS_DIR, NDFEncoder
from ndfa.sim.categories import CATEGORIES


def test_a_bare_name_means_the_shipped_weights_unless_a_file_has_that_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert shipped_weights(Path("mugs")) == DEFAULT_WEIGHTS
    assert shipped_weights(Path("objects")) == WEIGHTS_DIR / "ndf_objects.pt"
    assert shipped_weights(Path("nothing")) == Path("nothing")          # left to "no such file"
    assert shipped_weights(Path("sub/objects")) == Path("sub/objects")  # a path is never a name
    (tmp_path / "objects").write_bytes(b"")
    assert shipped_weights(Path("objects")) == Path("objects")          # the user's file wins


def test_the_objects_weights_name_every_category_and_the_mugs_weights_none():
    assert set(NDFEncoder(weights=WEIGHTS_DIR / "ndf_objects.pt").categories) == set(CATEGORIES)
    assert NDFEncoder(weights=DEFAULT_WEIGHTS).categories == ()


def test_detect_takes_a_shipped_name_and_names_a_wrong_one(ndfa, tmp_path):
    missing = tmp_path / "missing.mcap"
    # The name is taken: what fails is the recording, checked before the NDF loads (its frames' rate).
    line = one_line(ndfa("detect", missing, missing, "--weights", "objects"), "missing.mcap", "no such file")
    assert "--weights" not in line
    one_line(ndfa("detect", missing, missing, "--weights", "bowls"), "--weights bowls: no such file")
