"""`ndfa ingest tum` on broken TUM folders."""

from __future__ import annotations

import tempfile
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ndfa.io.recording import RecordingReader
from tests.fuzz.property import Outcome, check_cli, kept_on_failure
from tests.fuzz.seeds import SEED
from tests.fuzz.tum_inputs import apply_edits, tum_edits

pytestmark = pytest.mark.fuzz

TUM = SEED / "tum"
EXISTING = b"an earlier recording, which a failed import must leave alone"


def check_ingest_tum(folder: Path, out: Path) -> None:
    def sane(outcome: Outcome) -> None:
        reader = RecordingReader(out)
        assert len(reader) >= 1 and "frames written" in outcome.stdout, outcome.describe()

    with kept_on_failure(folder):
        check_cli(["ingest", "tum", str(folder), "--out", str(out)], [str(folder)], output=out, check_result=sane)


def test_broken_tum_folders(fuzz_settings):
    @fuzz_settings
    @given(tum_edits(TUM), st.booleans())
    def run(edits: list[tuple], existing_output: bool) -> None:
        with tempfile.TemporaryDirectory() as scratch:
            folder = apply_edits(TUM, Path(scratch) / "tum", edits)
            out = Path(scratch) / "out" / "rec.mcap"
            out.parent.mkdir()
            if existing_output:
                out.write_bytes(EXISTING)
            check_ingest_tum(folder, out)

    run()
