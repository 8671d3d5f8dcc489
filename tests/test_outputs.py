"""Nothing lost (issue 31): a command's outputs are committed together, only when it succeeds; a
failed or interrupted run leaves each pre-existing output byte for byte and no temporary or empty
folder; an output that is, or leads to, one of the run's inputs is refused before any work."""

import os
from pathlib import Path

import pytest
from conftest import one_line

from ndfa.core.errors import NdfaError
from ndfa.io.atomic import Staged, all_or_nothing, atomic_dir, atomic_path, declare_output, outside_all_or_nothing

SAMPLE = Path(__file__).parents[1] / "recordings" / "sample"


def snapshot(folder: Path) -> dict[str, bytes | None]:
    """Every path under `folder` (hidden ones too) with its bytes (None: a folder)."""
    return {str(p.relative_to(folder)): (None if p.is_dir() else p.read_bytes()) for p in sorted(folder.rglob("*"))}


# -- the block itself -----------------------------------------------------------------------------

def test_a_failed_block_puts_every_output_back(tmp_path):
    (tmp_path / "old.txt").write_text("old")
    (tmp_path / "empty").mkdir()
    before = snapshot(tmp_path)
    with pytest.raises(RuntimeError), all_or_nothing():
        declare_output(tmp_path / "made" / "deeper" / "new.txt")
        with atomic_path(tmp_path / "old.txt") as temporary:
            temporary.write_text("new")
        with atomic_path(tmp_path / "old.txt") as temporary:  # replaced twice: the first one is what comes back
            temporary.write_text("newer")
        with atomic_path(tmp_path / "made" / "deeper" / "new.txt") as temporary:
            temporary.write_text("new")
        with atomic_dir(tmp_path / "empty") as temporary:
            (temporary / "inside").write_text("x")
        open_writer = Staged(tmp_path / "never.txt")  # a writer the failure stops before it commits
        open_writer.temporary.write_text("half")
        assert (tmp_path / "old.txt").read_text() == "newer"  # later steps read what earlier ones wrote
        raise RuntimeError("late failure")
    assert snapshot(tmp_path) == before


def test_an_interruption_is_a_failure_too(tmp_path):
    before = snapshot(tmp_path)
    with pytest.raises(KeyboardInterrupt), all_or_nothing():
        with atomic_path(tmp_path / "a.rrd") as temporary:
            temporary.write_text("partial")
        raise KeyboardInterrupt
    assert snapshot(tmp_path) == before


def test_a_successful_block_keeps_the_outputs_and_nothing_else(tmp_path):
    (tmp_path / "old.txt").write_text("old")
    with all_or_nothing():
        with atomic_path(tmp_path / "old.txt") as temporary:
            temporary.write_text("new")
        Staged(tmp_path / "forgotten.txt").temporary.write_text("never committed")
    assert snapshot(tmp_path) == {"old.txt": b"new"}


def test_progress_outside_the_block_survives_its_failure(tmp_path):
    with pytest.raises(RuntimeError), all_or_nothing():
        with outside_all_or_nothing(), atomic_path(tmp_path / "checkpoint.pt") as temporary:
            temporary.write_text("step 5000")
        raise RuntimeError
    assert snapshot(tmp_path) == {"checkpoint.pt": b"step 5000"}


# -- ndfa detect ------------------------------------------------------------------------------------

def _previous_outputs(folder: Path) -> dict[str, Path]:
    """A --log, --tables and --json as an earlier run left them."""
    (folder / "tables").mkdir()
    (folder / "tables" / "observations.parquet").write_bytes(b"an earlier run's table")
    (folder / "run.rrd").write_bytes(os.urandom(4096))
    (folder / "summary.json").write_text('{"earlier": true}')
    return {"--log": folder / "run.rrd", "--tables": folder / "tables", "--json": folder / "summary.json"}


def test_detect_failing_late_leaves_the_previous_outputs(tmp_path, ndfa, monkeypatch):
    import ndfa.cli.detect as detect_module

    def fail_after_ten(progress):
        def on_frame(label, done, total):
            if label == "target" and done == 10:
                raise NdfaError("observation 0: failed on purpose, after the outputs started")
        return on_frame

    monkeypatch.setattr(detect_module, "bar_per_label", fail_after_ten)
    outputs = _previous_outputs(tmp_path)
    before = snapshot(tmp_path)
    args = [SAMPLE / "source.mcap", SAMPLE / "target.mcap", "--frame-step", "2"]
    code, _, err = ndfa("detect", *args, *[x for option, path in outputs.items() for x in (option, path)])
    assert code == 2 and err.strip().splitlines()[-1].startswith("error: observation 0: failed on purpose"), err
    assert snapshot(tmp_path) == before


def test_detect_failing_early_leaves_no_temporary_or_folder(tmp_path, ndfa):
    not_mcap = tmp_path / "demo.rrd"
    not_mcap.write_bytes(b"not an mcap file")
    before = snapshot(tmp_path)
    code, _, err = ndfa("detect", not_mcap, SAMPLE / "target.mcap", "--log", tmp_path / "new" / "keep2.rrd",
                        "--tables", tmp_path / "tables", "--json", tmp_path / "out" / "s.json")
    assert code == 2 and "demo.rrd" in err
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("option", ["--json", "--log", "--tables"])
def test_an_output_that_is_an_input_is_refused_before_any_work(tmp_path, ndfa, option):
    source = tmp_path / "src.mcap"
    source.write_bytes((SAMPLE / "source.mcap").read_bytes())
    (tmp_path / "sub").mkdir()
    link = tmp_path / "link.mcap"
    link.symlink_to(source)
    before = snapshot(tmp_path)
    for alias in (source, tmp_path / "sub" / ".." / "src.mcap", link):
        code, out, err = ndfa("detect", source, SAMPLE / "target.mcap", option, alias)
        assert code == 2 and len(err.strip().splitlines()) == 1 and out == "", err
        assert option in err and ("is the input" in err or "is a file, expected a directory" in err)
    assert snapshot(tmp_path) == before


def test_two_outputs_on_one_path_are_refused(tmp_path, ndfa):
    one_line(ndfa("detect", SAMPLE / "source.mcap", SAMPLE / "target.mcap", "--log", tmp_path / "x",
                  "--json", tmp_path / "x"), "--json", "is also --log")


@pytest.mark.parametrize("command, fragment", [
    (("ingest", "tum", "{folder}", "--out", "{folder}"), "is a directory, expected a file"),
    (("poses", "{recording}", "--out", "{recording}"), "is the input"),
    (("segment", "{recording}", "--out", "{link}"), "is the input"),
    (("export", "bag", "{recording}", "--out", "{recording}"), "is the input"),
    (("export", "tum", "{recording}", "--out", "{folder}/../tum"), "not an empty directory"),
    (("plant", "{recording}", "{recording}", "--out", "{folder}", "--log", "{recording}"), "is the input"),
    (("info", "{recording}"), "{recording}"),  # no outputs: reads, and says the file is no recording
])
def test_every_command_refuses_to_write_over_its_input(tmp_path, ndfa, command, fragment):
    folder = tmp_path / "tum"
    folder.mkdir()
    (folder / "rgb.txt").write_text("# a list the import reads\n")
    recording = tmp_path / "r.mcap"
    recording.write_bytes(b"stands for a recording")
    (tmp_path / "link.mcap").symlink_to(recording)
    before = snapshot(tmp_path)
    names = {"folder": folder, "recording": recording, "link": tmp_path / "link.mcap"}
    one_line(ndfa(*[part.format(**names) for part in command]), fragment.format(**names))
    assert snapshot(tmp_path) == before
