"""The checked-in corpus replayed through the property: the seeds (which must import and open
cleanly) and the inputs earlier fuzz runs found breaking it (corpus/regressions/, one per class)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tests.fuzz.property import check_cli
from tests.fuzz.seeds import CORPUS

pytestmark = pytest.mark.fuzz


def _command(entry: Path, out: Path) -> list[str]:
    if entry.suffix == ".mcap":
        return ["info", str(entry)]
    if entry.is_dir() and (entry / "depth.txt").exists() or "tum" in entry.parts:
        return ["ingest", "tum", str(entry), "--out", str(out)]
    return ["ingest", "bag", str(entry), "--out", str(out)]


ENTRIES = sorted([*(CORPUS / "seed").iterdir(), *(p for kind in (CORPUS / "regressions").iterdir()
                                                  for p in kind.iterdir())])


@pytest.mark.parametrize("entry", ENTRIES, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_corpus_entry(entry: Path, tmp_path: Path) -> None:
    local = tmp_path / entry.name  # a copy: a run must not write into the checked-in corpus
    if entry.is_dir():
        shutil.copytree(entry, local)
    else:
        shutil.copyfile(entry, local)
    out = tmp_path / "out" / "rec.mcap"
    out.parent.mkdir()
    outcome = check_cli(_command(local, out), [str(local)], output=out)
    seed = entry.parent.name == "seed"
    assert outcome.code == (0 if seed else 2), outcome.describe()
