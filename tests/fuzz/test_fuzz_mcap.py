"""`ndfa info` (the recording reader) and, for a few inputs, `ndfa detect` on mutated and foreign
MCAP files."""

from __future__ import annotations

import tempfile
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz.mcap_inputs import foreign_mcap, mutated_mcap, read_messages, rewritten_recording
from tests.fuzz.property import Outcome, check_cli, kept_on_failure, run_cli
from tests.fuzz.seeds import SEED

pytestmark = pytest.mark.fuzz

TINY = SEED / "tiny.mcap"


def info_is_sane(outcome: Outcome) -> None:
    assert "frames" in outcome.stdout and "session" in outcome.stdout, outcome.describe()


def check_info(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "input.mcap"
        path.write_bytes(data)
        with kept_on_failure(path):
            check_cli(["info", str(path)], [str(path)], check_result=info_is_sane)


def check_detect(data: bytes, as_source: bool) -> None:
    """`ndfa detect` with the tiny recording on the other side; --up z: the tiny world has no planes."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "input.mcap"
        path.write_bytes(data)
        json_out = Path(folder) / "out.json"
        pair = [str(path), str(TINY)] if as_source else [str(TINY), str(path)]
        with kept_on_failure(path):
            check_cli(["detect", *pair, "--up", "z", "--threads", "1", "--json", str(json_out)],
                      [str(path), str(TINY)], output=json_out, progress_on_stderr=True)


def test_mutated_recordings(fuzz_settings):
    seed = TINY.read_bytes()

    @fuzz_settings
    @given(mutated_mcap(seed))
    def run(data: bytes) -> None:
        check_info(data)

    run()


def test_rewritten_recordings(fuzz_settings):
    messages = read_messages(TINY)

    @fuzz_settings
    @given(rewritten_recording(messages))
    def run(data: bytes) -> None:
        check_info(data)

    run()


def test_foreign_mcaps(fuzz_settings):
    @fuzz_settings
    @given(foreign_mcap())
    def run(data: bytes) -> None:
        check_info(data)

    run()


@pytest.mark.slow
def test_detect_on_mutated_recordings(fuzz_settings):
    """detect is slow (it loads the NDF): a fifth of the examples of the other generators."""
    seed, messages = TINY.read_bytes(), read_messages(TINY)
    # The first run imports what detect needs (torch, open3d: ~10 s on a busy machine), which the
    # per-input deadline must not count; an import cut off by the deadline would break later runs.
    run_cli(["detect", str(TINY), str(TINY), "--up", "z", "--threads", "1"], deadline_s=300)

    @fuzz_settings.__class__(fuzz_settings, max_examples=max(fuzz_settings.max_examples // 5, 3))
    @given(st.one_of(mutated_mcap(seed), rewritten_recording(messages)), st.booleans())
    def run(data: bytes, as_source: bool) -> None:
        check_detect(data, as_source)

    run()
