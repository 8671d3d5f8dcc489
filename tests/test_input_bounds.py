"""Nothing hung (issue 31): numeric options of any size are checked without overflow, sizes and
counts have upper bounds that say why, and the simulator's work is bounded before it starts."""

import time
from pathlib import Path

import pytest
from conftest import one_line

from ndfa.core.errors import SimError

SAMPLE = Path(__file__).parents[1] / "recordings" / "sample"
HUGE = "1" + "0" * 400


@pytest.mark.parametrize("args, fragments", [
    (["detect", SAMPLE / "source.mcap", SAMPLE / "target.mcap", "--frame-step", HUGE],
     ["--frame-step", "(401 digits)", "leaves 1 of the 62 frames"]),
    (["ingest", "sim", "--out", "{tmp}/o", "--seed", HUGE], ["--seed", "64-bit", "(401 digits)"]),
    (["ingest", "sim", "--out", "{tmp}/o", "--clutter", HUGE], ["--clutter", "<= 50", "(401 digits)"]),
    (["ingest", "sim", "--out", "{tmp}/o", "--added", HUGE], ["--added", "<= 1000"]),
    (["detect", SAMPLE / "source.mcap", SAMPLE / "target.mcap", "--threads", HUGE], ["--threads", "<= 1024"]),
    (["train", "--out", "{tmp}/o", "--seed", HUGE], ["--seed", "64-bit"]),
])
def test_huge_integers_are_refused_in_one_line(tmp_path, ndfa, args, fragments):
    line = one_line(ndfa(*[str(a).format(tmp=tmp_path) for a in args]), *fragments)
    assert len(line) < 300  # the 401 digits are not printed
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("args, fragments", [
    (["--clutter", "10000"], ["--clutter", "<= 50", "full long before"]),
    (["--tables", "1000x1000"], ["--tables", "from 1 to 10"]),
    (["--step", "1e-6"], ["route is", "19200000 frames", "choose a step from 0.00192"]),
    (["--step", "100"], ["0 frames"]),
    (["--mugs-per-table", "1-1000"], ["--mugs-per-table", "<= 30"]),
    (["--offset", "1e300"], ["--offset", "a room"]),
    (["--furniture", "1000"], ["--furniture", "<= 40", "walls are full"]),
])
def test_sizes_that_would_hang_the_simulator_are_refused_at_once(tmp_path, ndfa, args, fragments):
    started = time.monotonic()
    one_line(ndfa("ingest", "sim", "--preset", "sample", "--out", tmp_path / "o", *args), *fragments)
    assert time.monotonic() - started < 60  # was: no output in 120 s, memory climbing
    assert not (tmp_path / "o").exists()


def test_a_frame_step_that_leaves_one_frame_is_refused(ndfa):
    one_line(ndfa("detect", SAMPLE / "source.mcap", SAMPLE / "target.mcap", "--frame-step", "10000"),
             "--frame-step 10000 leaves 1 of the 62 frames", "source.mcap", "at most 61")


def test_a_rate_that_leaves_one_frame_or_comes_with_a_frame_step_is_refused(ndfa):
    one_line(ndfa("detect", SAMPLE / "source.mcap", SAMPLE / "target.mcap", "--rate", "0.001"),
             "--rate 0.001 leaves 1 of the 62 frames", "source.mcap", "span")
    one_line(ndfa("detect", SAMPLE / "source.mcap", SAMPLE / "target.mcap", "--rate", "15", "--frame-step", "2"),
             "--rate and --frame-step", "give one of them")
    one_line(ndfa("detect", SAMPLE / "source.mcap", SAMPLE / "target.mcap", "--rate", "-1"), "--rate")


def test_the_route_bound_is_the_simulators_own():
    import numpy as np

    from ndfa.sim.scene import table_grid
    from ndfa.sim.trajectory import MAX_ROUTE_FRAMES, TrajectoryConfig, camera_poses

    tables = table_grid(1, 1)
    with pytest.raises(SimError, match=f"outside 2-{MAX_ROUTE_FRAMES}"):
        camera_poses(tables, TrajectoryConfig(step_m=1e-6), np.random.default_rng(0))
    assert len(camera_poses(tables, TrajectoryConfig(), np.random.default_rng(0))) > 2


def test_clutter_stops_at_a_full_table(monkeypatch):
    """Asking far more clutter than a table holds costs what a full table costs: the first piece
    that finds no spot ends that table."""
    import numpy as np

    import ndfa.sim.world as world
    from ndfa.sim.scene import table_grid

    rng = np.random.default_rng(0)
    tables = table_grid(1, 2)
    made = []
    real_mesh = world.make_clutter_mesh
    monkeypatch.setattr(world, "make_clutter_mesh", lambda kind, rng: made.append(kind) or real_mesh(kind, rng))
    items = world.place_clutter(tables, {}, [{}], 10_000, rng)
    assert 0 < len(items) < 10_000
    assert len(made) <= 5 * (len(items) + len(tables))  # up to five shapes a piece, and one failed piece a table
