"""Bad options and output paths fail at the edge, before any work, in one line naming the option
and the value (exit 2); the atomic writer never replaces a special file; a file that is no ndfa
checkpoint is said to be one; `ndfa detect` says why it could decide nothing."""

import os
from pathlib import Path

import numpy as np
import pytest
from conftest import one_line

from ndfa.core.errors import ModelError, OutputError
from ndfa.io.atomic import Staged, atomic_dir, atomic_path
from ndfa.io.recording import Frame, RecordingWriter
from ndfa.ndf.checkpoint import load_model
from ndfa.ndf.encoder import DEFAULT_WEIGHTS

NOWHERE = "/nonexistent/recording.mcap"  # reached only if the options were let through

BAD_OPTIONS = [
    (["detect", NOWHERE, NOWHERE, "--tree-length", "0"], "--tree-length", "got 0.0"),
    (["detect", NOWHERE, NOWHERE, "--tree-length", "-1.6"], "--tree-length", "got -1.6"),
    (["detect", NOWHERE, NOWHERE, "--association-distance", "nan"], "--association-distance", "got nan"),
    (["detect", NOWHERE, NOWHERE, "--edge-distance", "inf"], "--edge-distance", "got inf"),
    (["detect", NOWHERE, NOWHERE, "--shape-similarity", "1.5"], "--shape-similarity", "got 1.5"),
    (["detect", NOWHERE, NOWHERE, "--frame-step", "0"], "--frame-step", "got 0"),
    (["detect", NOWHERE, NOWHERE, "--threads", "-2"], "--threads", "got -2"),
    (["segment", NOWHERE, "--out", "x.mcap", "--stride", "0"], "--stride", "got 0"),
    (["eval", NOWHERE, NOWHERE, "--out", "o", "--nn-fraction", "0"], "--nn-fraction", "got 0.0"),
    (["eval", NOWHERE, NOWHERE, "--out", "o", "--tsdf-voxel", "-inf"], "--tsdf-voxel", "got -inf"),
    (["eval", "--sweep", "noise", "--values", "0", "--out", "o", "--workers", "0"], "--workers", "got 0"),
    (["poses", NOWHERE, "--out", "x.mcap", "--voxel-size", "0"], "--voxel-size", "got 0.0"),
    (["poses", NOWHERE, "--out", "x.mcap", "--max-range", "nan"], "--max-range", "got nan"),
    (["ingest", "sim", "--out", "o", "--step", "0"], "--step", "got 0.0"),
    (["ingest", "sim", "--out", "o", "--seed", "-1"], "--seed", "got -1"),
    (["ingest", "sim", "--out", "o", "--noise-scale", "nan"], "--noise-scale", "got nan"),
    (["ingest", "sim", "--out", "o", "--drift", "-0.1"], "--drift", "got -0.1"),
    (["ingest", "sim", "--out", "o", "--world-tilt", "90"], "--world-tilt", "got 90.0"),
    (["ingest", "sim", "--out", "o", "--models", "0"], "--models", "got 0"),
    (["ingest", "sim", "--out", "o", "--tables", "0x3"], "--tables", "'0x3'"),
    (["ingest", "sim", "--out", "o", "--mugs-per-table", "4-2"], "--mugs-per-table", "'4-2'"),
    (["ingest", "tum", NOWHERE, "--out", "x.mcap", "--depth-scale", "0"], "--depth-scale", "got 0.0"),
    (["ingest", "tum", NOWHERE, "--out", "x.mcap", "--max-dt", "inf"], "--max-dt", "got inf"),
    (["ingest", "tum", NOWHERE, "--out", "x.mcap", "--intrinsics", "0,525,319.5,239.5"], "--intrinsics", "0,525"),
    (["ingest", "bag", NOWHERE, "--out", "x.mcap", "--max-dt", "-1"], "--max-dt", "got -1.0"),
    (["export", "tum", NOWHERE, "--out", "o", "--depth-scale", "nan"], "--depth-scale", "got nan"),
    (["bench", "sim", "--frames", "0"], "--frames", "got 0"),
    (["train", "--out", "o", "--steps", "0"], "--steps", "got 0"),
    (["train", "--out", "o", "--lr", "nan"], "--lr", "got nan"),
    (["train", "--out", "o", "--batch-mugs", "1"], "--batch-mugs", "got 1"),
    (["train", "--out", "o", "--center-weight", "-1"], "--center-weight", "got -1.0"),
    (["ndf-eval", "--out", "o", "--v0", "1"], "--v0", "got 1.0"),
    (["ndf-eval", "--out", "o", "--mugs", "0"], "--mugs", "got 0"),
    (["train", "--out", "o", "--categories", "mug,plate"], "--categories", "'mug,plate'"),
    (["train", "--out", "o", "--categories", "mug,mug"], "--categories", "'mug,mug'"),
    (["ndf-eval", "--out", "o", "--categories", ""], "--categories", "''"),
    (["train", "--out", "o", "--checkpoint-every", "0"], "--checkpoint-every", "got 0"),
    (["ingest", "sim", "--out", "o", "--categories", "mug,saucer"], "--categories", "'mug,saucer'"),
]


@pytest.mark.parametrize("args, option, value", BAD_OPTIONS, ids=[" ".join(a[0:2] + a[-2:]) for a, _, _ in BAD_OPTIONS])
def test_out_of_range_options_fail_before_any_work(ndfa, tmp_path, monkeypatch, args, option, value):
    monkeypatch.chdir(tmp_path)
    one_line(ndfa(*args), option, value)
    assert list(tmp_path.iterdir()) == []  # nothing was made: no output folder, no temporary


def test_a_usage_error_is_one_line_too(ndfa):
    one_line(ndfa("detect", NOWHERE, NOWHERE, "--frame-step", "two"), "--frame-step", "--help")
    one_line(ndfa("detect", NOWHERE), "give two or more session recordings")


@pytest.fixture
def odd_paths(tmp_path):
    """An existing folder, a file, a FIFO and a folder nobody can write in."""
    (tmp_path / "folder").mkdir()
    (tmp_path / "file").write_text("keep me")
    os.mkfifo(tmp_path / "fifo")
    return tmp_path


def test_output_paths_are_checked_before_the_run(ndfa, odd_paths):
    d = odd_paths
    source = target = NOWHERE  # a run would fail on these; the paths must fail first
    cases = [
        (["detect", source, target, "--json", d / "folder"], "--json", "is a directory"),
        (["detect", source, target, "--log", d / "folder"], "--log", "is a directory"),
        (["detect", source, target, "--tables", d / "file"], "--tables", "is a file"),
        (["detect", source, target, "--json", "/dev/null"], "--json /dev/null", "special file"),
        (["detect", source, target, "--log", d / "fifo"], "--log", "special file"),
        (["detect", source, target, "--json", d / "file" / "summary.json"], "--json", "is not a directory"),
        (["detect", source, target, "--json", "/proc/ndfa/summary.json"], "--json", "cannot write in /proc"),
        (["ingest", "tum", NOWHERE, "--out", d / "folder"], "--out", "is a directory"),
        (["ingest", "sim", "--out", d / "file"], "--out", "is a file"),
        (["poses", NOWHERE, "--out", d / "x.mcap", "--tum-out", d / "fifo"], "--tum-out", "special file"),
        (["export", "bag", NOWHERE, "--out", "/dev/null"], "--out", "special file"),
        (["ndf-eval", "--out", d / "file"], "--out", "is a file"),
        (["train", "--out", d / "o", "--log", d / "folder"], "--log", "is a directory"),
    ]
    for args, *fragments in cases:
        one_line(ndfa(*args), *fragments)
    assert sorted(p.name for p in d.iterdir()) == ["fifo", "file", "folder"]  # no temporary left anywhere
    assert (d / "file").read_text() == "keep me" and list((d / "folder").iterdir()) == []


def test_the_atomic_writer_never_replaces_a_special_file(odd_paths):
    d = odd_paths
    for special in (d / "fifo", Path("/dev/null")):
        with pytest.raises(OutputError, match="special file"):
            with atomic_path(special) as temporary:
                temporary.write_text("x")
    with pytest.raises(OutputError, match="is a directory"):
        with atomic_path(d / "folder") as temporary:
            temporary.write_text("x")
    with pytest.raises(OutputError, match="is a file"):
        with atomic_dir(d / "file") as temporary:
            (temporary / "a").write_text("x")
    with pytest.raises(OutputError, match="in the way"):
        Staged(d / "file" / "inner.json")
    staged = Staged(d / "late.json")  # a FIFO made after the writer started: refused at the rename
    staged.temporary.write_text("x")
    os.mkfifo(d / "late.json")
    with pytest.raises(OutputError, match="special file"):
        staged.commit()
    assert (d / "fifo").is_fifo() and (d / "late.json").is_fifo() and (d / "file").read_text() == "keep me"
    assert sorted(p.name for p in d.iterdir()) == ["fifo", "file", "folder", "late.json"]


@pytest.fixture(scope="module")
def not_checkpoints(tmp_path_factory):
    import zipfile

    import torch

    d = tmp_path_factory.mktemp("weights")
    (d / "random.pt").write_bytes(np.random.default_rng(0).bytes(4096))
    (d / "text.pt").write_text("weights: shipped\n")
    (d / "empty.pt").write_bytes(b"")
    with zipfile.ZipFile(d / "archive.pt", "w") as archive:
        archive.writestr("readme.txt", "not torch")
    shipped = DEFAULT_WEIGHTS.read_bytes()
    (d / "truncated.pt").write_bytes(shipped[: len(shipped) // 2])
    torch.save({"model": torch.zeros(3)}, d / "foreign.pt")
    content = torch.load(DEFAULT_WEIGHTS, weights_only=True)
    state = dict(content["state_dict"])
    state[next(iter(state))] = torch.zeros(5, 5)
    torch.save({"config": content["config"], "state_dict": state}, d / "reshaped.pt")
    torch.save({"config": content["config"] | {"hidden": 64}, "state_dict": content["state_dict"]}, d / "other.pt")
    return d


@pytest.mark.parametrize("name, why", [
    ("random.pt", "not a torch file"), ("text.pt", "not a torch file"), ("empty.pt", "empty file"),
    ("archive.pt", "a zip archive, but not a torch file"), ("truncated.pt", "truncated or corrupt"),
    ("foreign.pt", "no 'config' and 'state_dict'"), ("reshaped.pt", "tensors of another shape"),
    ("other.pt", "weights of another model"),
])
def test_a_file_that_is_no_checkpoint_is_named_in_one_line(not_checkpoints, name, why):
    with pytest.raises(ModelError) as error:
        load_model(not_checkpoints / name)
    message = str(error.value)
    assert message.startswith(f"{not_checkpoints / name}: not an ndfa checkpoint (") and why in message
    assert "\n" not in message and len(message) < 300 + len(str(not_checkpoints))


def test_weights_are_checked_before_the_recordings_are_read(ndfa, not_checkpoints):
    one_line(ndfa("detect", NOWHERE, NOWHERE, "--weights", not_checkpoints / "random.pt"),
             "random.pt: not an ndfa checkpoint (not a torch file)")
    one_line(ndfa("bench", "ndf", "--weights", not_checkpoints / "reshaped.pt"), "not an ndfa checkpoint")
    one_line(ndfa("ndf-eval", "--weights", not_checkpoints / "missing.pt"), "--weights", "no such file")


def _recording(path: Path, box_row: int, depth: float | None) -> Path:
    """Three frames of a z-up world with one object (instance 1) at `box_row`, or none."""
    K = np.array([[300.0, 0, 80], [0, 300.0, 60], [0, 0, 1]])
    with RecordingWriter(path, {"source": "test", "session": path.stem}) as writer:
        for i in range(3):
            frame_depth = np.full((120, 160), 2.0, dtype=np.float32)
            instances = np.zeros((120, 160), dtype=np.uint16)
            if depth is not None:
                instances[box_row:box_row + 20, 60:80] = 1
                frame_depth[box_row:box_row + 20, 60:80] = depth
            writer.write_frame(Frame(i, 1.0 + i, None, frame_depth, K, np.eye(4), instances))
    return path


@pytest.mark.slow
def test_detect_says_why_it_decided_nothing(ndfa, tmp_path):
    source = _recording(tmp_path / "source.mcap", 20, 1.0)
    elsewhere = _recording(tmp_path / "elsewhere.mcap", 80, 1.5)
    code, out, err = ndfa("detect", source, elsewhere, "--up", "z", "--threads", "1")
    assert code == 0
    warning = next(line for line in err.splitlines() if "share no objects" in line)
    assert "1 target objects" in warning and "1 source objects" in warning and "0 change(s)" in warning

    empty = _recording(tmp_path / "empty.mcap", 0, None)
    code, out, err = ndfa("detect", source, empty, "--up", "z", "--threads", "1")
    assert code == 0
    assert "warning: the target has no objects: none of its 3 frames has an object mask" in err
    assert "share no objects" not in err
