"""The fuzz property itself catches what it must (issue 31's long pass counts on it): a traceback,
a hang, a temporary file left beside the output, an existing output changed by a failed run, an
error line that names no input. Each case runs a stand-in for `ndfa.cli.main`."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

import ndfa.cli
from tests.fuzz.property import CHECKED, check_cli

pytestmark = pytest.mark.fuzz

EARLIER = b"an earlier output"


def fail_with(error: str):  # noqa: ANN201
    def main() -> None:
        print(error, file=sys.stderr)
        raise SystemExit(2)
    return main


@pytest.fixture(autouse=True)
def uncounted():
    """These stand-ins are no generated inputs: the pass's count leaves them out."""
    before = CHECKED.copy()
    yield
    CHECKED.clear()
    CHECKED.update(before)


@pytest.fixture
def output(tmp_path: Path) -> Path:
    out = tmp_path / "out.mcap"
    out.write_bytes(EARLIER)
    return out


def run(monkeypatch, main, output: Path, deadline_s: float = 10.0):  # noqa: ANN001, ANN201
    monkeypatch.setattr(ndfa.cli, "main", main)
    return check_cli(["info", "in.mcap"], ["in.mcap"], output=output, deadline_s=deadline_s)


def test_a_clean_failure_passes(monkeypatch, output):
    assert run(monkeypatch, fail_with("error: in.mcap: not an MCAP file"), output).code == 2
    assert output.read_bytes() == EARLIER


def test_a_traceback_is_caught(monkeypatch, output):
    def main() -> None:
        raise RuntimeError("boom")
    with pytest.raises(AssertionError, match="exit code 1"):
        run(monkeypatch, main, output)


def test_a_hang_is_caught(monkeypatch, output):
    def main() -> None:
        while True:
            pass
    with pytest.raises(AssertionError, match=r"exit code -1(.|\n)*ran longer than"):  # CPU or, on a busy machine, wall
        run(monkeypatch, main, output, deadline_s=0.2)


def test_a_temporary_file_left_beside_the_output_is_caught(monkeypatch, output):
    def main() -> None:
        (output.parent / ".out.mcap.tmp-123").write_bytes(b"half")
        fail_with("error: in.mcap: cut short")()
    with pytest.raises(AssertionError, match=r"left \['.out.mcap.tmp-123'\] beside the output"):
        run(monkeypatch, main, output)


def test_an_existing_output_changed_by_a_failed_run_is_caught(monkeypatch, output):
    def main() -> None:
        output.write_bytes(b"half a recording")
        fail_with("error: in.mcap: cut short")()
    with pytest.raises(AssertionError, match="a failed run changed the existing"):
        run(monkeypatch, main, output)


def test_an_error_that_names_no_input_is_caught(monkeypatch, output):
    with pytest.raises(AssertionError, match="does not name the input"):
        run(monkeypatch, fail_with("error: something went wrong"), output)
