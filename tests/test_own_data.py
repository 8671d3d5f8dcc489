"""The README's "Your own data" commands on a sensor's TUM folder (no groundtruth.txt, as a RealSense
recording has none): the import keeps the recording without poses, `ndfa info` says who estimates
them, and `ndfa detect` of the recording against itself estimates poses and up, finds the objects
and reports no change. On a slice of the 7-Scenes kitchen (its frames and lists, groundtruth.txt
left out)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ndfa.cli import app
from ndfa.io.recording import RecordingReader

pytestmark = pytest.mark.slow  # imports and runs ndfa detect end to end on real frames

REDKITCHEN = Path(__file__).resolve().parents[2] / "shared" / "data" / "redkitchen_7scenes"


def _sensor_folder(folder: Path, lines: slice) -> Path:
    """`lines` of the kitchen's depth.txt and rgb.txt in a TUM folder of their own, the images
    symlinked, and no groundtruth.txt."""
    for name in ("depth.txt", "rgb.txt"):
        rows = [row for row in (REDKITCHEN / name).read_text().splitlines() if not row.startswith("#")][lines]
        (folder / name.removesuffix(".txt")).mkdir(parents=True)
        (folder / name).write_text("".join(f"{row}\n" for row in rows))
        for row in rows:
            image = row.split()[1]
            (folder / image).symlink_to(REDKITCHEN / image)
    return folder


@pytest.mark.slow  # odometry and detection on 40 real frames: make test runs it, make check does not
@pytest.mark.skipif(not REDKITCHEN.is_dir(), reason=f"the 7-Scenes redkitchen sequence is not at {REDKITCHEN} "
                    "(../shared absent)")
def test_readme_own_data_commands_on_a_folder_without_groundtruth(tmp_path):
    # Frames 126-165: both mugs on the table in view (tests/test_registration_real.py).
    folder = _sensor_folder(tmp_path / "monday", slice(126, 166))
    recording = tmp_path / "monday.mcap"
    runner = CliRunner(env={"COLUMNS": "300"})

    result = runner.invoke(app, ["ingest", "tum", str(folder), "--out", str(recording),
                                 "--intrinsics", "585,585,320,240", "--depth-scale", "1000"])
    assert result.exit_code == 0, result.output
    assert "note:" in result.output and "no groundtruth.txt" in result.output and "ndfa detect" in result.output
    reader = RecordingReader(recording)
    assert len(reader) == 40 and not reader.has_poses and reader.meta["poses"] == "none"

    result = runner.invoke(app, ["info", str(recording)])
    assert result.exit_code == 0, result.output
    assert "estimated by `ndfa detect`" in result.output

    summary = tmp_path / "out.json"
    result = runner.invoke(app, ["detect", str(recording), str(recording), "--log", str(tmp_path / "out.rrd"),
                                 "--tables", str(tmp_path / "out"), "--json", str(summary), "--frame-step", "2"])
    assert result.exit_code == 0, result.output
    report = json.loads(summary.read_text())
    for session in ("source", "target"):
        world = report["world"][session]
        assert world["poses"].startswith("estimated") and world["up_estimate"]["ok"], world
    assert report["objects_source"] >= 2 and report["objects_target"] >= 2  # the two mugs
    assert report["changes"] == []
