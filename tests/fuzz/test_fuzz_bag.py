"""`ndfa ingest bag` (and `--list`) on broken ROS1 and ROS2 bags."""

from __future__ import annotations

import tempfile
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ndfa.io.recording import RecordingReader
from tests.fuzz.bag_inputs import (
    broken_bag_spec,
    broken_metadata,
    copy_ros2,
    mutated_mcap,
    mutated_ros1,
    ros2_storage_file,
    write_broken_bag,
)
from tests.fuzz.property import Blob, Outcome, check_cli, kept_on_failure
from tests.fuzz.seeds import SEED

pytestmark = pytest.mark.fuzz

EXISTING = b"an earlier recording, which a failed import must leave alone"


@pytest.fixture(scope="module")
def sqlite_seed(tmp_path_factory) -> Path:
    """The ROS2 sqlite3 flavour (28 KB, not checked in), with compressed images."""
    from ndfa.io.export.bag import export_bag

    out = tmp_path_factory.mktemp("seed") / "ros2-sqlite3"
    export_bag(SEED / "tiny.mcap", out, version=2, storage="sqlite3", compressed=True, color_format="png")
    return out


def check_ingest_bag(bag: Path, scratch: Path, existing_output: bool, list_only: bool = False) -> None:
    out = scratch / "out" / "rec.mcap"
    out.parent.mkdir(exist_ok=True)
    if existing_output:
        out.write_bytes(EXISTING)

    def sane(outcome: Outcome) -> None:
        if list_only:
            assert "topic" in outcome.stdout, outcome.describe()
        else:
            assert len(RecordingReader(out)) >= 1 and "frames written" in outcome.stdout, outcome.describe()

    args = ["ingest", "bag", str(bag), "--list"] if list_only else ["ingest", "bag", str(bag), "--out", str(out)]
    with kept_on_failure(bag):
        check_cli(args, [str(bag)], output=out, check_result=sane)


def test_mutated_ros1_bags(fuzz_settings):
    seed = (SEED / "tiny.bag").read_bytes()

    @fuzz_settings
    @given(mutated_ros1(seed), st.booleans(), st.integers(0, 9))
    def run(data: bytes, existing_output: bool, list_one_in_ten: int) -> None:
        with tempfile.TemporaryDirectory() as scratch:
            bag = Path(scratch) / "input.bag"
            bag.write_bytes(data)
            check_ingest_bag(bag, Path(scratch), existing_output, list_only=list_one_in_ten == 0)

    run()


@pytest.mark.parametrize("flavour", ["mcap", "sqlite3"])
def test_mutated_ros2_bags(fuzz_settings, sqlite_seed, flavour):
    """The storage file mutated (the MCAP by its record fields, the SQLite file by bytes), or the
    metadata.yaml broken."""
    seed = SEED / "ros2-mcap" if flavour == "mcap" else sqlite_seed
    storage = ros2_storage_file(seed).read_bytes()
    metadata = (seed / "metadata.yaml").read_text()
    storage_mutation = mutated_mcap(storage) if flavour == "mcap" else st.builds(
        lambda at, bit, cut: Blob(storage[:cut][:at] + bytes([storage[at] ^ (1 << bit)]) + storage[at + 1:cut]
                                  if at < cut else storage[:cut]),
        st.integers(0, len(storage) - 1), st.integers(0, 7), st.integers(0, len(storage)))

    @fuzz_settings
    @given(st.one_of(st.tuples(st.just("storage"), storage_mutation), st.tuples(st.just("metadata"),
                                                                                broken_metadata(metadata))),
           st.booleans())
    def run(mutation: tuple, existing_output: bool) -> None:
        with tempfile.TemporaryDirectory() as scratch:
            bag = copy_ros2(seed, Path(scratch) / "bag")
            if mutation[0] == "storage":
                ros2_storage_file(bag).write_bytes(mutation[1])
            else:
                (bag / "metadata.yaml").write_text(mutation[1])
            check_ingest_bag(bag, Path(scratch), existing_output)

    run()


def test_bags_with_broken_messages(fuzz_settings):
    @fuzz_settings
    @given(broken_bag_spec(), st.booleans())
    def run(spec: dict, existing_output: bool) -> None:
        with tempfile.TemporaryDirectory() as scratch:
            bag = write_broken_bag(Path(scratch) / "bag", spec)
            check_ingest_bag(bag, Path(scratch), existing_output)

    run()
