"""Where the mugs stand in each session, and what changed between the sessions.

A `World` is the whole synthetic ground truth: static room and tables, the mug models, one
layout per session (instance id -> placement), the change labels and the clutter (non-mug
objects that stand still in both sessions). It is pure data; rendering
and writing recordings happen elsewhere (`ndfa.io.ingest.synthetic`).

A physical mug keeps its instance id in both sessions, so a moved or switched mug is the same id
at a new place. Changes are counted per object, as the paper counts them: a switch of two mugs
is two changes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ndfa.core.errors import SimError
from ndfa.sim.categories import SceneModel
from ndfa.sim.chairs import Chair, table_chairs
from ndfa.sim.clutter import (
    CLUTTER_FIRST_ID,
    CLUTTER_KINDS,
    ClutterItem,
    make_clutter_mesh,
)
from ndfa.sim.clutter import footprint_radius as mesh_footprint_radius
from ndfa.sim.furniture import FurniturePiece, wall_furniture
from ndfa.sim.presets import SimConfig
from ndfa.sim.scene import Room, Table, room_around, table_grid
from ndfa.sim.shelves import ShelfLevel, ShelfUnit, shelf_units
from ndfa.sim.splits import TEST_SEEDS, make_split_mug, make_split_object
from ndfa.sim.table_space import Placement, TableSpace, footprint_radius

CHANGE_KINDS = ("added", "removed", "moved", "switched")
ROTATED = "rotated"  # a mug turned in place about up (`turn_in_place`; not one of the change script's kinds)
SESSIONS = ("source", "target")


@dataclass(frozen=True)
class Change:
    """One changed object. `partner` is the other mug of a switch, `angle_deg` a rotated mug's turn."""

    instance_id: int
    kind: str
    partner: int | None = None
    angle_deg: float | None = None  # "rotated": the turn about up, degrees (counter-clockwise seen from above)


@dataclass
class World:
    tables: list[Table]
    room: Room
    mugs: dict[str, SceneModel]
    source: dict[int, Placement]
    target: dict[int, Placement]
    changes: list[Change]
    colors: dict[int, tuple[float, float, float]] = field(default_factory=dict)
    clutter: list[ClutterItem] = field(default_factory=list)
    furniture: list[FurniturePiece] = field(default_factory=list)  # along the walls: part of the room
    shelf_units: list[ShelfUnit] = field(default_factory=list)  # their levels are `tables`
    chairs: list[Chair] = field(default_factory=list)  # pushed in at the tables: part of the room

    def layout(self, session: str) -> dict[int, Placement]:
        if session not in SESSIONS:
            raise SimError(f"unknown session {session!r}; expected one of {SESSIONS}")
        return self.source if session == "source" else self.target

    def table(self, table_id: int) -> Table:
        return self.tables[table_id - 1]

    def object_pose(self, placement: Placement) -> np.ndarray:
        return placement.pose_world_object(self.table(placement.table_id))

    def clutter_pose(self, item: ClutterItem) -> np.ndarray:
        return item.pose_world_object(self.table(item.table_id))

    def change_counts(self) -> dict[str, int]:
        """Changes per kind; "rotated" only when there are any (a scene without keeps its counts)."""
        kinds = CHANGE_KINDS + ((ROTATED,) if any(c.kind == ROTATED for c in self.changes) else ())
        return {kind: sum(c.kind == kind for c in self.changes) for kind in kinds}


# The widest object a scene's table or shelf board takes (footprint radius about its axis, handle
# included): a 45 cm shoebox leaves a 1.2 x 0.8 m table no room for three more objects. Mugs reach 8 cm.
MAX_SCENE_RADIUS_M = 0.15
# The tallest object a shelf scene takes: boards stand 25 cm apart or more, the camera passes 20 cm over a board.
MAX_SHELF_HEIGHT_M = 0.2


def procedural_models(config: SimConfig) -> list[SceneModel]:
    """`config.mug_models` distinct procedural models from the test split, chosen by the seed.
    Mugs alone (`config.categories == ("mug",)`): the seed's mugs as always. With several
    categories each model's category is drawn from a stream of its own, every category at least
    once when there are as many models, and an object too wide for a table (`MAX_SCENE_RADIUS_M`)
    or too tall for a shelf (`MAX_SHELF_HEIGHT_M`) gives way to the category's next test object."""
    rng = np.random.default_rng([config.seed, 1])
    indices = rng.choice(len(TEST_SEEDS), size=config.mug_models, replace=False)
    if config.categories == ("mug",):
        return [make_split_mug("test", int(i)) for i in sorted(indices)]
    cycle = [config.categories[k % len(config.categories)] for k in range(config.mug_models)]
    drawn = np.random.default_rng([config.seed, 8]).permutation(cycle)
    max_height = MAX_SHELF_HEIGHT_M if config.shelves is not None else np.inf
    models: list[SceneModel] = []
    for index, category in zip(sorted(int(i) for i in indices), drawn):
        for attempt in range(1000):
            model = make_split_object(str(category), "test", (index + attempt) % len(TEST_SEEDS))
            bounds = model.mesh.vertices
            if footprint_radius(model) <= MAX_SCENE_RADIUS_M and np.ptp(bounds[:, 2]) <= max_height:
                break
        models.append(model)
    return models


def model_category(model: SceneModel) -> str:
    """The category of a scene's model: a `CategoryObject`'s, "mug" for a `Mug` (procedural or from a file)."""
    return getattr(model, "category", "mug")


def build_world(config: SimConfig, models: list[SceneModel]) -> World:
    """Tables, room, source layout and the changed target layout for `config`, with `models` as
    the mug models to place. Deterministic in `config.seed`."""
    if not models:
        raise SimError("no mug models to place")
    units: list[ShelfUnit] = []
    levels: list[ShelfLevel] = []
    if config.shelves is None:
        tables = table_grid(config.table_rows, config.table_cols)
    else:
        units, levels = shelf_units(config.shelves, np.random.default_rng([config.seed, 7]))
        tables = list(levels)
    mugs = {m.model_id: m for m in models}
    rng = np.random.default_rng([config.seed, 2])
    counts = _mugs_per_table(len(tables), config.mugs_per_table, config.total_mugs, rng)
    source = place_source(tables, mugs, counts, rng)
    for _ in range(100):  # on shelves, until every level number holds a change (the first draw elsewhere)
        target, changes = apply_changes(tables, mugs, source, config.changes, rng, config.switch_within_table)
        if not levels or _levels_changed(levels, source, target, changes) == {t.level for t in levels}:
            break
    if config.rotated:  # from a stream of its own: the other changes stay the seed's
        target, turned = turn_in_place(target, changes, mugs, config.rotated, config.rotated_deg,
                                       np.random.default_rng([config.seed, 5]))
        changes = changes + turned
    color_rng = np.random.default_rng([config.seed, 3])
    colors = {i: tuple(float(c) for c in color_rng.uniform(0.15, 0.95, size=3)) for i in sorted(source.keys() | target.keys())}
    # Clutter last, from a stream of its own: adding it moves no mug of the same seed's scene.
    clutter = place_clutter(tables, mugs, [source, target], config.clutter_per_table,
                            np.random.default_rng([config.seed, 4])) if config.clutter_per_table else []
    room = room_around(tables)
    furniture = wall_furniture(room, config.furniture, np.random.default_rng([config.seed, 6])) if config.furniture else []
    chairs = (table_chairs(tables, config.chairs_per_table, np.random.default_rng([config.seed, 16]))
              if config.chairs_per_table and config.shelves is None else [])
    return World(tables, room, mugs, source, target, changes, colors, clutter, furniture, units, chairs)


def _levels_changed(levels: list[ShelfLevel], source: dict[int, Placement], target: dict[int, Placement],
                    changes: list[Change]) -> set[int]:
    """The level numbers (`ShelfLevel.level`) a change left or reached."""
    tables = [p.table_id for c in changes for layout in (source, target) if (p := layout.get(c.instance_id))]
    return {levels[t - 1].level for t in tables}


def _mugs_per_table(n_tables: int, per_table: tuple[int, int], total: tuple[int, int] | None,
                    rng: np.random.Generator) -> list[int]:
    lo, hi = per_table
    if total is not None and not (n_tables * lo <= total[1] and total[0] <= n_tables * hi):
        raise SimError(f"{total[0]}-{total[1]} mugs cannot stand {lo}-{hi} to a table on {n_tables} tables")
    for _ in range(10_000):
        counts = [int(c) for c in rng.integers(lo, hi, size=n_tables, endpoint=True)]
        if total is None or total[0] <= sum(counts) <= total[1]:
            return counts
    raise SimError(f"could not draw {lo}-{hi} mugs per table summing to {total}")


def place_source(
    tables: list[Table],
    mugs: dict[str, SceneModel],
    counts_per_table: list[int],
    rng: np.random.Generator,
) -> dict[int, Placement]:
    """Source layout: `counts_per_table[i]` mugs on table i+1, every model used once before any repeats."""
    model_ids = list(mugs)
    total = sum(counts_per_table)
    order = list(rng.permutation(model_ids)) + list(rng.choice(model_ids, size=max(0, total - len(model_ids))))
    space = TableSpace(tables, mugs)
    layout: dict[int, Placement] = {}
    next_id = 1
    for table, count in zip(tables, counts_per_table):
        for _ in range(count):
            model_id = str(order[next_id - 1])
            xy = space.find_spot(table.table_id, model_id, rng)
            if xy is None:
                raise SimError(f"cannot fit {count} mugs on table {table.table_id} of size {table.size_xy}")
            placement = Placement(next_id, model_id, table.table_id, (float(xy[0]), float(xy[1])), float(rng.uniform(-np.pi, np.pi)))
            layout[next_id] = placement
            space.add(placement)
            next_id += 1
    return layout


def apply_changes(
    tables: list[Table],
    mugs: dict[str, SceneModel],
    source: dict[int, Placement],
    counts: dict[str, int],
    rng: np.random.Generator,
    switch_within_table: bool = True,
) -> tuple[dict[int, Placement], list[Change]]:
    """Target layout from the source one by the change script `counts` (objects per kind).

    Removed, moved and switched mugs are drawn from distinct source instances; switched pairs
    have different models (swapping two identical mugs is no change) and, by default, stand on
    the same table as in the paper's scenes. Added mugs get new instance ids.
    """
    unknown = set(counts) - set(CHANGE_KINDS)
    if unknown:
        raise SimError(f"unknown change kinds {sorted(unknown)}; expected {CHANGE_KINDS}")
    n_added, n_removed, n_moved, n_switched = (counts.get(k, 0) for k in CHANGE_KINDS)
    if n_switched % 2:
        raise SimError(f"switched changes come in pairs; got an odd count {n_switched}")
    if n_removed + n_moved + n_switched > len(source):
        raise SimError(f"{n_removed + n_moved + n_switched} removed/moved/switched mugs asked of {len(source)} in the source")

    available = [int(i) for i in rng.permutation(list(source))]
    changes: list[Change] = []
    source_space = TableSpace(tables, mugs)
    for placement in source.values():
        source_space.add(placement)
    pairs = _switch_pairs(source, available, n_switched // 2, switch_within_table, source_space)
    for a, b in pairs:
        available.remove(a)
        available.remove(b)
        changes += [Change(a, "switched", b), Change(b, "switched", a)]
    removed, available = available[:n_removed], available[n_removed:]
    moved = available[:n_moved]
    changes += [Change(i, "removed") for i in removed]

    changed = set(removed) | set(moved) | {i for pair in pairs for i in pair}
    target = {i: p for i, p in source.items() if i not in changed}
    space = TableSpace(tables, mugs)
    for placement in target.values():
        space.add(placement)

    for a, b in pairs:  # each takes the other's spot, picked up and put down at a new yaw
        for mover, spot in ((source[a], source[b]), (source[b], source[a])):
            placement = Placement(mover.instance_id, mover.model_id, spot.table_id, spot.xy, float(rng.uniform(-np.pi, np.pi)))
            if not space.fits(spot.table_id, np.array(spot.xy), space.radius[mover.model_id]):
                raise SimError(f"switched mug {mover.instance_id} does not fit at mug {spot.instance_id}'s place")
            target[mover.instance_id] = placement
            space.add(placement)
    for instance_id in moved:
        mover = source[instance_id]
        target[instance_id] = _place_somewhere(space, tables, mover.instance_id, mover.model_id, rng, avoid=mover)
        changes.append(Change(instance_id, "moved"))
    next_id = max(source) + 1
    model_ids = list(mugs)
    for _ in range(n_added):
        model_id = str(rng.choice(model_ids))
        target[next_id] = _place_somewhere(space, tables, next_id, model_id, rng)
        changes.append(Change(next_id, "added"))
        next_id += 1
    return target, changes


def turn_in_place(target: dict[int, Placement], changes: list[Change], mugs: dict[str, SceneModel], count: int,
                  degrees: tuple[float, float], rng: np.random.Generator) -> tuple[dict[int, Placement], list[Change]]:
    """`count` mugs that `changes` left alone turned in place about their axis, each by an angle
    drawn uniformly from `degrees` (inclusive range) in a random sense: the target layout and the
    "rotated" changes. Only mugs with a handle turn (a mug without one looks the same turned); a
    mesh from a file is taken to have one. A turn keeps the mug's footprint circle, so it fits."""
    changed = {c.instance_id for c in changes} | {c.partner for c in changes if c.partner is not None}
    candidates = [i for i in sorted(target) if i not in changed and _has_handle(mugs[target[i].model_id])]
    if count > len(candidates):
        raise SimError(f"{count} rotated mugs asked, but only {len(candidates)} unchanged mugs with a handle")
    target = dict(target)
    turned = []
    for instance_id in sorted(int(i) for i in rng.choice(candidates, size=count, replace=False)):
        angle = float(rng.uniform(*degrees)) * float(rng.choice([-1.0, 1.0]))
        placement = target[instance_id]
        yaw = float((placement.yaw + np.radians(angle) + np.pi) % (2 * np.pi) - np.pi)
        target[instance_id] = Placement(instance_id, placement.model_id, placement.table_id, placement.xy, yaw)
        turned.append(Change(instance_id, ROTATED, angle_deg=angle))
    return target, turned


def _has_handle(model: SceneModel) -> bool:
    """A mug's handle (a mesh from a file is taken to have one); the other categories have none."""
    return model.params is None or getattr(model.params, "handle_shape", "none") != "none"


def _switch_pairs(source: dict[int, Placement], candidates: list[int], n_pairs: int, within_table: bool,
                  space: TableSpace) -> list[tuple[int, int]]:
    """Pairs of different mugs that fit into each other's place among the other source mugs
    (a conservative test: removed and moved mugs only free more space)."""
    pairs: list[tuple[int, int]] = []
    used: set[int] = set()
    used_tables: set[int] = set()
    for a in candidates:
        if len(pairs) == n_pairs:
            break
        if a in used or (within_table and source[a].table_id in used_tables):
            continue
        for b in candidates:
            pa, pb = source[a], source[b]
            if b == a or b in used or pa.model_id == pb.model_id:
                continue
            if within_table and pa.table_id != pb.table_id:
                continue
            if not _fit_swapped(space, pa, pb):
                continue
            pairs.append((a, b))
            used |= {a, b}
            used_tables.add(pa.table_id)
            break
    if len(pairs) < n_pairs:
        raise SimError(f"cannot find {n_pairs} pairs of different mugs to switch")
    return pairs


def _fit_swapped(space: TableSpace, a: Placement, b: Placement) -> bool:
    saved_a = space.occupied[a.table_id].pop(a.instance_id)
    saved_b = space.occupied[b.table_id].pop(b.instance_id)
    fits = space.fits(b.table_id, np.array(b.xy), space.radius[a.model_id]) and \
        space.fits(a.table_id, np.array(a.xy), space.radius[b.model_id])
    space.occupied[a.table_id][a.instance_id] = saved_a
    space.occupied[b.table_id][b.instance_id] = saved_b
    return fits


def _place_somewhere(space: TableSpace, tables: list[Table], instance_id: int, model_id: str,
                     rng: np.random.Generator, avoid: Placement | None = None) -> Placement:
    """A free spot on a random table; for a moved mug, at least 10 cm from where it stood."""
    for table_id in rng.permutation([t.table_id for t in tables]):
        for _ in range(20):
            xy = space.find_spot(int(table_id), model_id, rng)
            if xy is None:
                break
            if avoid is not None and avoid.table_id == table_id and np.linalg.norm(xy - np.array(avoid.xy)) < 0.10:
                continue
            placement = Placement(instance_id, model_id, int(table_id), (float(xy[0]), float(xy[1])), float(rng.uniform(-np.pi, np.pi)))
            space.add(placement)
            return placement
    raise SimError(f"no free spot left on any table for mug {instance_id}")


def place_clutter(tables: list[Table], mugs: dict[str, SceneModel], layouts: list[dict[int, Placement]],
                  per_table: int, rng: np.random.Generator) -> list[ClutterItem]:
    """`per_table` pieces of clutter on every table, clear of every mug of every layout (so of
    both sessions: clutter stands still while mugs move) and of each other. A piece that finds
    no free spot after a few shapes is left out, and the table is then full: its remaining pieces
    are not tried (so a count far beyond what a table holds costs no more than a full table); a
    crowded table gets less clutter, never a collision; the ground truth lists what was placed."""
    if max((i for layout in layouts for i in layout), default=0) >= CLUTTER_FIRST_ID:
        raise SimError(f"mug instance ids reach the clutter ids (from {CLUTTER_FIRST_ID})")
    space = TableSpace(tables, mugs)
    for session, layout in enumerate(layouts):
        for placement in layout.values():
            space.occupied[placement.table_id][(session, placement.instance_id)] = (
                np.array(placement.xy), space.radius[placement.model_id])
    items: list[ClutterItem] = []
    for table in tables:
        for _ in range(per_table):
            placed = False
            for _attempt in range(5):  # a smaller shape may fit where a big one did not
                kind = str(rng.choice(CLUTTER_KINDS))
                mesh = make_clutter_mesh(kind, rng)
                radius = mesh_footprint_radius(mesh)
                xy = space.find_spot_for_radius(table.table_id, radius, rng, tries=100)
                if xy is None:
                    continue
                instance_id = CLUTTER_FIRST_ID + len(items)
                color = tuple(float(c) for c in rng.uniform(0.1, 0.9, size=3))
                items.append(ClutterItem(instance_id, kind, table.table_id, (float(xy[0]), float(xy[1])),
                                         float(rng.uniform(-np.pi, np.pi)), mesh, color))
                space.occupied[table.table_id][("clutter", instance_id)] = (np.array(xy), radius)
                placed = True
                break
            if not placed:
                break  # the table is full
    return items
