"""The classes of issue 31: integers of any size in every range-checked option, TUM lists in other
time units, outputs that are (links to) inputs, and `ndfa detect` failing after its outputs
started, with outputs of an earlier run in place."""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ndfa.io.recording import RecordingReader
from tests.fuzz.mcap_inputs import read_messages, rewritten_recording
from tests.fuzz.property import CHECKED, Outcome, check_cli, kept_on_failure, run_cli
from tests.fuzz.seeds import SEED
from tests.fuzz.test_fuzz_tum import check_ingest_tum
from tests.fuzz.tum_inputs import apply_edits

pytestmark = pytest.mark.fuzz

TINY = SEED / "tiny.mcap"
TUM = SEED / "tum"
NOWHERE = "/nonexistent/recording.mcap"

# (command with a quick failure after the options pass, the integer options it range-checks). The
# failure after parsing (no such recording, an unknown preset) keeps an accepted value from
# starting minutes of work; what matters is that parsing never raises or hangs.
INTEGER_OPTIONS = [
    (["detect", NOWHERE, NOWHERE], ["--frame-step", "--threads"]),
    (["ingest", "sim", "--preset", "nope", "--out", "{out}"],
     ["--seed", "--sessions", "--models", "--added", "--removed", "--moved", "--switched", "--clutter", "--rotated"]),
    (["eval", NOWHERE, NOWHERE, "--out", "{out}"], ["--frame-step", "--workers"]),
    (["segment", NOWHERE, "--out", "{out}/x.mcap"], ["--stride"]),
    (["view", NOWHERE], ["--port"]),
    (["poses", NOWHERE, "--out", "{out}/x.mcap"], ["--stride"]),
]


def huge_integers() -> st.SearchStrategy[str]:
    """Integers as a user could type them: around every power of two a machine integer has, far
    beyond 1e308 (a float's end), negative, and with leading zeros or a sign."""
    edges = [2**k + d for k in (31, 32, 53, 63, 64, 128, 1024) for d in (-1, 0, 1)]
    return st.one_of(
        st.sampled_from(edges).map(str),
        st.integers(min_value=1, max_value=1200).map(lambda digits: "1" + "0" * digits),
        st.integers(min_value=-(10**400), max_value=10**400).map(str),
        st.integers(min_value=0, max_value=10**30).map(lambda n: "+" + str(n)),
        st.integers(min_value=0, max_value=10**6).map(lambda n: "000" + str(n)),
    )


def test_huge_integers_in_options(fuzz_settings):
    @fuzz_settings
    @given(st.sampled_from(INTEGER_OPTIONS).flatmap(
        lambda entry: st.tuples(st.just(entry[0]), st.sampled_from(entry[1]), huge_integers())))
    def run(case: tuple[list[str], str, str]) -> None:
        command, option, value = case
        with tempfile.TemporaryDirectory() as scratch:
            args = [part.format(out=Path(scratch) / "out") for part in command] + [option, value]
            outcome = run_cli(args)
            CHECKED["integer options"] += 1
            assert outcome.code == 2, outcome.describe()  # each command ends early: see INTEGER_OPTIONS
            lines = [line for line in outcome.stderr.splitlines() if line.strip()]
            if command[0] == "detect":  # an accepted value gets as far as its progress lines ("NDF runtime: ...")
                assert not any("Traceback" in line or line.startswith("warning") for line in lines), outcome.describe()
                lines = lines[-1:]
            assert len(lines) == 1 and lines[0].startswith("error: ") and len(lines[0]) < 400, outcome.describe()
            assert not (Path(scratch) / "out").exists(), outcome.describe()

    run()


def _scaled(path: Path, scale: float, offset: float) -> None:
    out = []
    for line in path.read_text().splitlines(keepends=True):
        parts = line.split(" ", 1)
        try:
            stamp = float(parts[0])
        except ValueError:
            out.append(line)
            continue
        out.append(f"{(stamp + offset) * scale!r} {parts[1] if len(parts) > 1 else ''}")
    path.write_text("".join(out))


def test_tum_stamps_in_other_units(fuzz_settings):
    """Every list's stamps shifted by a drawn unit (1e-3 ... 1e21) and epoch, independently."""
    lists = ["rgb.txt", "depth.txt", "groundtruth.txt"]

    @fuzz_settings
    @given(st.lists(st.tuples(st.sampled_from([1.0, 1e3, 1e6, 1e9, 1e-3, 1e12, 1e21, 1e300]),
                              st.sampled_from([0.0, 1.3e9, 1.7e9, 1e10, 2e10])), min_size=3, max_size=3),
           st.booleans())
    def run(units: list[tuple[float, float]], existing_output: bool) -> None:
        with tempfile.TemporaryDirectory() as scratch:
            folder = apply_edits(TUM, Path(scratch) / "tum", [])
            for name, (scale, offset) in zip(lists, units):
                if (folder / name).is_file():
                    _scaled(folder / name, scale, offset)
            out = Path(scratch) / "out" / "rec.mcap"
            out.parent.mkdir()
            if existing_output:
                out.write_bytes(b"an earlier recording")
            check_ingest_tum(folder, out)

    run()


def test_tum_stamps_since_the_start_in_other_units(fuzz_settings):
    """Every list in one unit (seconds, ms, µs, ns), counted from a drawn start (0 or later, not
    since 1970: too small for their size to tell the unit), a camera at 1 to 150 Hz with jitter: the
    import must give the frames their times in seconds and warn exactly when the unit was not seconds."""
    seed_stamps = [float(line.split()[0]) for line in (TUM / "depth.txt").read_text().splitlines()
                   if line.strip() and not line.startswith("#")]

    @fuzz_settings
    @given(st.sampled_from([(1.0, "seconds"), (1e3, "milliseconds"), (1e6, "microseconds"), (1e9, "nanoseconds")]),
           st.one_of(st.just(0.0), st.floats(0.0, 1e5)), st.floats(1.0, 150.0),
           st.lists(st.floats(0.0, 0.2), min_size=len(seed_stamps), max_size=len(seed_stamps)))
    def run(unit: tuple[float, str], start: float, rate_hz: float, jitter: list[float]) -> None:
        per_second, name = unit
        seconds = [start + (k + jitter[k]) / rate_hz for k in range(len(seed_stamps))]
        new_stamp = {stamp: seconds[k] * per_second for k, stamp in enumerate(seed_stamps)}
        with tempfile.TemporaryDirectory() as scratch:
            folder = apply_edits(TUM, Path(scratch) / "tum", [])
            for list_name in ("rgb.txt", "depth.txt", "groundtruth.txt"):
                lines = (folder / list_name).read_text().splitlines(keepends=True)
                (folder / list_name).write_text("".join(
                    line if line.startswith("#") else f"{new_stamp[float(line.split(' ', 1)[0])]!r} {line.split(' ', 1)[1]}"
                    for line in lines))
            out = Path(scratch) / "rec.mcap"

            def right_times(outcome: Outcome) -> None:
                times = [frame.timestamp for frame in RecordingReader(out).frames()]
                assert times == pytest.approx(seconds, rel=1e-9, abs=1e-6), outcome.describe()
                warned = f"look like {name}, not seconds" in outcome.stdout + outcome.stderr  # rich prints warnings on stdout
                assert warned == (per_second != 1.0), outcome.describe()

            with kept_on_failure(folder):
                outcome = check_cli(["ingest", "tum", str(folder), "--out", str(out)], [str(folder)], output=out,
                                    check_result=right_times)
            assert outcome.code == 0, outcome.describe()

    run()


def _digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha1(p.read_bytes()).hexdigest() if p.is_file() else "dir"
            for p in sorted(folder.rglob("*")) if not p.is_symlink()}


# (command, its output option) whose output may be pointed at one of its inputs.
ALIASED_OUTPUTS = [
    (["detect", "{a}", "{b}", "--up", "z", "--threads", "1"], ["--json", "--log"]),
    (["poses", "{a}"], ["--out"]),
    (["segment", "{a}"], ["--out"]),
    (["export", "bag", "{a}"], ["--out"]),
    (["plant", "{a}", "{b}", "--out", "{scratch}/planted"], ["--log"]),
]


def test_outputs_that_are_inputs(fuzz_settings):
    """The output named as an input, through a symbolic link, `..`, or a hard link: refused before
    any work, every input as it was."""

    @fuzz_settings
    @given(st.sampled_from(ALIASED_OUTPUTS).flatmap(lambda entry: st.tuples(st.just(entry[0]), st.sampled_from(entry[1]))),
           st.sampled_from(["a", "b"]), st.sampled_from(["same", "symlink", "dotdot", "hardlink"]))
    def run(case: tuple[list[str], str], which: str, alias: str) -> None:
        command, option = case
        with tempfile.TemporaryDirectory() as scratch:
            root = Path(scratch)
            (root / "in").mkdir()
            for name in ("a", "b"):
                (root / "in" / f"{name}.mcap").write_bytes(TINY.read_bytes())
            if which == "b" and "{b}" not in command:
                which = "a"
            target = root / "in" / f"{which}.mcap"
            path = {"same": target, "dotdot": root / "in" / ".." / "in" / target.name,
                    "symlink": root / "link.mcap", "hardlink": root / "hard.mcap"}[alias]
            if alias == "symlink":
                path.symlink_to(target)
            elif alias == "hardlink":
                os.link(target, path)
            before = _digest(root / "in")
            args = [part.format(a=root / "in" / "a.mcap", b=root / "in" / "b.mcap", scratch=root) for part in command]
            outcome = check_cli(args + [option, str(path)], [option])
            assert outcome.code == 2 and "is the input" in outcome.stderr, outcome.describe()
            assert _digest(root / "in") == before, outcome.describe()
            assert not (root / "planted").exists(), outcome.describe()

    run()


@pytest.mark.slow  # 25 detect runs, each writing a Rerun file and tables: about a minute
def test_detect_failing_after_its_outputs_started(fuzz_settings):
    """A target recording damaged past its first frame (it opens, then fails mid-run), or a sound
    one: with an earlier run's --log, --tables and --json in place, a failed run leaves them byte
    for byte and nothing else; a successful one replaces them."""
    import ndfa.log.rerun_sink  # noqa: F401  (imported here, not within the first input's deadline)
    import ndfa.log.table_sink  # noqa: F401
    import ndfa.run.detect  # noqa: F401

    messages = read_messages(TINY)

    @fuzz_settings
    @given(rewritten_recording(messages), st.booleans())
    def run(data: bytes, earlier: bool) -> None:
        with tempfile.TemporaryDirectory() as scratch:
            root = Path(scratch)
            target = root / "target.mcap"
            target.write_bytes(data)
            outputs = root / "outputs"
            outputs.mkdir()
            if earlier:
                (outputs / "run.rrd").write_bytes(os.urandom(2048))
                (outputs / "tables").mkdir()
                (outputs / "tables" / "observations.parquet").write_bytes(b"an earlier table")
                (outputs / "summary.json").write_text("{}")
            before = _digest(outputs)

            def sane(outcome: Outcome) -> None:
                assert (outputs / "summary.json").read_text() != "{}", outcome.describe()
                assert not [p for p in outputs.rglob(".*")], outcome.describe()

            with kept_on_failure(target):
                outcome = check_cli(["detect", str(TINY), str(target), "--up", "z", "--threads", "1",
                                     "--log", str(outputs / "run.rrd"), "--tables", str(outputs / "tables"),
                                     "--json", str(outputs / "summary.json")],
                                    [str(target), str(TINY)], check_result=sane, progress_on_stderr=True,
                                    deadline_s=30)  # the run writes a Rerun file and parquet tables as well
            if outcome.code == 2:
                assert _digest(outputs) == before, outcome.describe()

    run()
