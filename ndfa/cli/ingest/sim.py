"""`ndfa ingest sim`: render a synthetic source/target pair of recordings (or N sessions) with ground truth."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from ndfa.cli.app import bar_per_label, console, err_console, progress_bar
from ndfa.cli.checks import category_list, in_range, input_dir, output_dir, positive, seed_range
from ndfa.cli.ingest import ingest_app
from ndfa.sim.chairs import MAX_CHAIRS
from ndfa.sim.furniture import MAX_FURNITURE
from ndfa.sim.handheld import MOTIONS
from ndfa.sim.mesh_io import load_mug_dir
from ndfa.sim.noise import DepthNoise
from ndfa.sim.presets import make_config
from ndfa.sim.trajectory import RAW_MAX_TURN_DEG

# Upper bounds of the scene's sizes and counts: past them a scene only takes memory and time (a
# 1000x1000 grid, 10,000 clutter pieces per table), never a useful recording.
MAX_GRID = 10  # tables per row and per column
MAX_MUGS_PER_TABLE = 30
MAX_MUGS = 1000  # models, and mugs added, removed, moved, switched or turned
MAX_CLUTTER = 50  # per table
_MUGS_WHY = f"at most {MAX_MUGS}: more than {MAX_GRID}x{MAX_GRID} tables hold"
mug_count = in_range(ge=0, le=MAX_MUGS, why=_MUGS_WHY)


def _parse_range(text: str, what: str) -> tuple[int, int]:
    try:
        lo, _, hi = text.partition("-")
        low, high = int(lo), int(hi or lo)
    except ValueError:
        raise typer.BadParameter(f"{what} must be N or LO-HI, got {text!r}") from None
    if not 0 <= low <= high <= MAX_MUGS_PER_TABLE:
        raise typer.BadParameter(f"{what} must be N or LO-HI with 0 <= LO <= HI <= {MAX_MUGS_PER_TABLE} (more than "
                                 f"a table holds), got {text!r}")
    return low, high


@ingest_app.command("sim")
def ingest_sim_command(
    out: Path = typer.Option(..., "--out", "-o", help="Output directory for source.mcap and target.mcap "
                             "(with --sessions N > 2: session_0.mcap ... session_{N-1}.mcap).", callback=output_dir),
    preset: str = typer.Option("paper", help="paper | sample | random | office (docs/sim_raw_sensor.md) | shelves "
                                             "(shelf units of 3-4 levels, docs/shelves.md)."),
    sessions: int = typer.Option(2, help="Sessions to render, with the change counts applied between each "
                                         "consecutive pair (docs/sessions.md).", callback=in_range(ge=2, le=100)),
    seed: int = typer.Option(0, help="Seed of everything random in the scene.", callback=seed_range),
    mesh_dir: Optional[Path] = typer.Option(None, help="Place these OBJ/PLY/STL/GLB mug meshes instead of procedural "
                                             "ones (units and up axis guessed unless --mesh-up is given).",
                                             callback=input_dir),
    mesh_up: str = typer.Option("auto", help="Up axis of the --mesh-dir meshes: auto (guessed per mesh, with a note) | z | y."),
    tables: Optional[str] = typer.Option(None, help="Table grid as ROWSxCOLS, e.g. 2x4."),
    mugs_per_table: Optional[str] = typer.Option(None, help="Mugs per table in the source, N or LO-HI."),
    models: Optional[int] = typer.Option(None, help="Number of distinct procedural mug models.",
                                          callback=in_range(ge=1, le=MAX_MUGS, why=_MUGS_WHY)),
    added: Optional[int] = typer.Option(None, help="Mugs added in the target.", callback=mug_count),
    removed: Optional[int] = typer.Option(None, help="Mugs removed in the target.", callback=mug_count),
    moved: Optional[int] = typer.Option(None, help="Mugs moved in the target.", callback=mug_count),
    switched: Optional[int] = typer.Option(None, help="Mugs that switch places (an even number).",
                                           callback=mug_count),
    source_route: Optional[str] = typer.Option(None, help="perimeter | corridor | weave | circles."),
    target_route: Optional[str] = typer.Option(None, help="perimeter | corridor | weave | circles."),
    step: Optional[float] = typer.Option(None, help="Camera travel between frames, metres.", callback=positive),
    noise: Optional[bool] = typer.Option(None, "--noise/--no-noise", help="Depth sensor noise on or off."),
    noise_scale: Optional[float] = typer.Option(None, help="Depth noise std as a multiple of the default sensor's.",
                                                callback=in_range(ge=0, le=100, why="beyond, the noise is the depth")),
    offset: Optional[float] = typer.Option(None, help="Target pose offset: max translation per axis, metres.",
                                           callback=in_range(ge=0, le=100, why="a room, not a city")),
    offset_yaw: Optional[float] = typer.Option(None, help="Target pose offset: max yaw, degrees.",
                                               callback=in_range(ge=0, le=180, why="a half turn either way")),
    offset_tilt: Optional[float] = typer.Option(None, help="Target pose offset: max roll and pitch, degrees.",
                                                callback=in_range(ge=0, le=90)),
    drift: Optional[float] = typer.Option(None, help="Target drift: random-walk translation step std, metres/frame.",
                                          callback=in_range(ge=0, le=1, why="metres per frame")),
    drift_yaw: Optional[float] = typer.Option(None, help="Target drift: random-walk yaw step std, degrees/frame.",
                                              callback=in_range(ge=0, le=180, why="degrees per frame")),
    textures: Optional[bool] = typer.Option(None, "--textures/--no-textures", help="Procedural colour texture on "
                                            "walls, floor and table tops (default: the preset's; office: on)."),
    clutter: Optional[int] = typer.Option(None, help="Clutter per table (bowls, cups, bottles, cans, boxes; papers, cables); static, "
                                                     "listed as clutter in the ground truth (default: the preset's; "
                                                     "office: 3).",
                                          callback=in_range(ge=0, le=MAX_CLUTTER, why="a table is full long before: "
                                                            "pieces that find no free spot are left out")),
    furniture: int = typer.Option(0, help="Pieces of furniture along the walls (cabinets, shelves, sideboards); "
                                          "static, part of the room: a room that does not fit itself turned or "
                                          "shifted (docs/registration.md).",
                                  callback=in_range(ge=0, le=MAX_FURNITURE, why="the walls are full long before")),
    chairs: int = typer.Option(0, help="Chairs pushed in at each table, as many as fit (their backs' top rails "
                                       "beside the tables' edges); static, part of the room.",
                               callback=in_range(ge=0, le=MAX_CHAIRS, why="a table's long sides seat no more")),
    motion: Optional[str] = typer.Option(None, help="Camera motion: smooth | handheld (sweeps up to 90 deg/s, pitch "
                                                    "towards the desks, shake, at --fps; default: the preset's, office: "
                                                    "handheld)."),
    fps: Optional[float] = typer.Option(None, help="Frame rate of the recording (default: the preset's; office: 30).",
                                        callback=in_range(gt=0, le=1000, why="frames per second of a camera")),
    raw: bool = typer.Option(False, "--raw", help="Record as a sensor does: no instance masks, no camera poses "
                                                  "(/tf); the true poses stay in the ground truth."),
    world_tilt: float = typer.Option(0.0, help="Tilt the recorded world frame this many degrees away from z-up "
                                               "(random roll/pitch axis from the seed).",
                                   callback=in_range(gt=-90, lt=90)),
    max_turn: Optional[float] = typer.Option(None, help="Most the camera turns between frames, degrees; 0: unlimited "
                                                        f"(default: {RAW_MAX_TURN_DEG:g} with --raw, else unlimited).",
                                            callback=in_range(ge=0, le=180)),
    categories: Optional[str] = typer.Option(None, help="Object categories the scene places, comma-separated "
                                             "(mug,bowl,cup,bottle,can,box or all; default: mug). The shipped NDF "
                                             "(v2) knows mugs alone: its objects' category is reported unknown.",
                                             callback=category_list),
    rotated: int = typer.Option(0, help="Mugs turned in place about up in the target (unchanged mugs with a handle).",
                                callback=mug_count),
    rotated_deg: tuple[float, float] = typer.Option((45.0, 180.0), help="MIN MAX: the range (degrees) each "
                                                    "--rotated mug turns by, in either sense."),
) -> None:
    """Render a synthetic source/target pair of recordings (or N sessions) with ground truth."""
    from ndfa.io.ingest.synthetic import check_output_dir, ingest_sim  # lazy: the renderer imports open3d (seconds)

    config = make_config(preset, seed)
    overrides: dict = {}
    if tables is not None:
        rows, _, cols = tables.lower().partition("x")
        if not (rows.isdigit() and cols.isdigit() and 1 <= int(rows) <= MAX_GRID and 1 <= int(cols) <= MAX_GRID):
            raise typer.BadParameter(f"--tables must be ROWSxCOLS, each from 1 to {MAX_GRID} (the room, its route "
                                     f"and the rendering grow with the grid), got {tables!r}")
        overrides.update(table_rows=int(rows), table_cols=int(cols), total_mugs=None)
    if mugs_per_table is not None:
        overrides.update(mugs_per_table=_parse_range(mugs_per_table, "--mugs-per-table"), total_mugs=None)
    if models is not None:
        overrides["mug_models"] = models
    counts = {k: v for k, v in dict(added=added, removed=removed, moved=moved, switched=switched).items() if v is not None}
    if counts:
        overrides["changes"] = {**config.changes, **counts}
    if source_route is not None:
        overrides["source_route"] = source_route
    if target_route is not None:
        overrides["target_route"] = target_route
    if step is not None:
        overrides["trajectory"] = dataclasses.replace(config.trajectory, step_m=step)
    if motion is not None:
        if motion not in MOTIONS:
            raise typer.BadParameter(f"--motion must be one of {', '.join(MOTIONS)}, got {motion!r}")
        overrides["trajectory"] = dataclasses.replace(overrides.get("trajectory", config.trajectory), motion=motion)
    if fps is not None:
        overrides["fps"] = fps
    if max_turn is None:
        max_turn = RAW_MAX_TURN_DEG if raw else 0.0
    if max_turn:
        trajectory = overrides.get("trajectory", config.trajectory)
        overrides["trajectory"] = dataclasses.replace(trajectory, max_turn_deg=max_turn)
    if noise is not None or noise_scale is not None:
        overrides["depth_noise"] = DepthNoise().scaled(1.0 if noise_scale is None else noise_scale)
        if noise is False:
            overrides["depth_noise"] = DepthNoise.off()
    error = {k: v for k, v in dict(offset_translation_m=offset, offset_yaw_deg=offset_yaw, offset_tilt_deg=offset_tilt,
                                   drift_translation_m=drift, drift_yaw_deg=drift_yaw).items() if v is not None}
    if error:
        overrides["target_pose_error"] = dataclasses.replace(config.target_pose_error, **error)
    overrides.update(raw=raw, world_tilt_deg=world_tilt, rotated=rotated, rotated_deg=tuple(rotated_deg),
                     furniture=furniture, chairs_per_table=chairs)
    if textures is not None:
        overrides["textures"] = textures
    if clutter is not None:
        overrides["clutter_per_table"] = clutter
    if categories is not None:
        overrides["categories"] = tuple(categories.split(","))
    config = make_config(preset, seed, **overrides)

    check_output_dir(out)
    user_models = None
    if mesh_dir is not None:
        user_models = load_mug_dir(mesh_dir, up=mesh_up, on_note=lambda note: err_console.print(
            f"note: {note}", highlight=False, soft_wrap=True))

    with progress_bar(transient=False) as progress:
        summaries = ingest_sim(config, out, models=user_models, on_progress=bar_per_label(progress, "rendering "),
                               sessions=sessions)

    surfaces = f"{config.table_rows * config.table_cols} tables" if config.shelves is None else "shelf units"
    table = Table(title=f"{config.preset} scene, seed {config.seed}: {surfaces} -> {out}")
    kinds = ("added", "removed", "moved", "switched") + (("rotated",) if rotated else ())
    for column in ("session", "frames", "mugs", *kinds, "size"):
        table.add_column(column, justify="left" if column == "session" else "right")
    for s in summaries:
        table.add_row(s.path.name, str(s.frames), str(s.objects),
                      *(str(s.changes.get(k, "")) for k in kinds),
                      f"{s.size_bytes / 1e6:.1f} MB")
    console.print(table)
