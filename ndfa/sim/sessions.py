"""Many visits of one synthetic world: N layouts, with changes between each consecutive pair.

Sessions 0 and 1 are exactly the two-session world (`ndfa.sim.world.build_world`, same seed, same
mugs); each further session is made from the one before by the same change script
(`SimConfig.changes`, applied by `apply_changes`), drawn from a random stream of its own. So
`--sessions 2` is today's pair, and session k of an N-session scene does not depend on N.

A physical mug keeps its instance id in every session it stands in. `apply_changes` numbers added
mugs from its source's largest id, which may be the id of a mug removed in an earlier visit; such
an id is replaced by one no session has used, so that an id always names one mug.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ndfa.core.errors import SimError
from ndfa.sim.categories import SceneModel
from ndfa.sim.presets import SimConfig
from ndfa.sim.world import Change, Placement, World, apply_changes, build_world, model_category, place_clutter

MAX_SESSIONS = 100  # far more visits than a scene's tables hold changes for; a typo guard


@dataclass
class SessionWorlds:
    """The static scene of `base` (room, tables, models, colours, clutter) and one layout per session."""

    base: World                              # sessions 0 and 1, as the two-session code makes them
    layouts: list[dict[int, Placement]]      # instance id -> placement, per session
    changes: list[list[Change]]              # changes[k]: from session k to session k + 1

    def __len__(self) -> int:
        return len(self.layouts)

    def pair(self, k: int) -> World:
        """Sessions k -> k + 1 as a two-session world (what `world_ground_truth` and the renderer take)."""
        return dataclasses.replace(self.base, source=self.layouts[k], target=self.layouts[k + 1],
                                   changes=self.changes[k])


def session_names(n: int) -> list[str]:
    """File stems and meta names of N sessions: the pair keeps `source`/`target`."""
    return ["source", "target"] if n == 2 else [f"session_{k}" for k in range(n)]


def build_sessions(config: SimConfig, models: list[SceneModel], n: int) -> SessionWorlds:
    """N layouts of `config`'s scene; deterministic in `config.seed`."""
    if not 2 <= n <= MAX_SESSIONS:
        raise SimError(f"a scene has 2 to {MAX_SESSIONS} sessions, got {n}")
    if n == 2:
        world = build_world(config, models)
        return SessionWorlds(world, [world.source, world.target], [world.changes])
    # Clutter stands clear of every session's mugs, so it is placed once all layouts are known.
    base = build_world(dataclasses.replace(config, clutter_per_table=0), models)
    layouts, changes = [base.source, base.target], [base.changes]
    used = set(base.source) | set(base.target)
    colors = dict(base.colors)
    for k in range(2, n):
        before = layouts[-1]
        try:
            layout, pair_changes = apply_changes(base.tables, base.mugs, before, config.changes,
                                                 np.random.default_rng([config.seed, 2, k]), config.switch_within_table)
        except SimError as error:
            raise SimError(f"session {k}: {error}") from None
        layout, pair_changes = _fresh_ids(layout, pair_changes, before, used)
        color_rng = np.random.default_rng([config.seed, 3, k])
        for instance_id in sorted(set(layout) - used):
            colors[instance_id] = tuple(float(c) for c in color_rng.uniform(0.15, 0.95, size=3))
        used |= set(layout)
        layouts.append(layout)
        changes.append(pair_changes)
    clutter = place_clutter(base.tables, base.mugs, layouts, config.clutter_per_table,
                            np.random.default_rng([config.seed, 4])) if config.clutter_per_table else []
    return SessionWorlds(dataclasses.replace(base, colors=colors, clutter=clutter), layouts, changes)


def _fresh_ids(layout: dict[int, Placement], changes: list[Change], before: dict[int, Placement],
               used: set[int]) -> tuple[dict[int, Placement], list[Change]]:
    """`layout` and `changes` with every added mug whose id an earlier session used renumbered."""
    renamed: dict[int, int] = {}
    next_id = max(used | set(layout)) + 1
    for instance_id in sorted(set(layout) - set(before)):
        if instance_id in used:
            renamed[instance_id], next_id = next_id, next_id + 1
    if not renamed:
        return layout, changes
    layout = {renamed.get(i, i): dataclasses.replace(p, instance_id=renamed.get(i, i)) for i, p in layout.items()}
    changes = [dataclasses.replace(c, instance_id=renamed.get(c.instance_id, c.instance_id),
                                   partner=None if c.partner is None else renamed.get(c.partner, c.partner))
               for c in changes]
    return layout, changes


def history_truth(worlds: SessionWorlds, pose_world_level: np.ndarray) -> list[dict]:
    """Every mug over the sessions, JSON-ready: per session its placement (None: not there) in the
    recorded world frame, and per pair the change it underwent (None: unchanged or not there)."""
    kinds = [{c.instance_id: c.kind for c in pair} for pair in worlds.changes]
    out = []
    for instance_id in sorted(set().union(*worlds.layouts)):
        model = next(layout[instance_id].model_id for layout in worlds.layouts if instance_id in layout)
        where = []
        for layout in worlds.layouts:
            placement = layout.get(instance_id)
            where.append(None if placement is None else {
                "table_id": placement.table_id,
                "pose_world_object": (pose_world_level @ worlds.base.object_pose(placement)).tolist()})
        out.append({"instance_id": instance_id, "model_id": model,
                    "category": model_category(worlds.base.mugs[model]), "sessions": where,
                    "changes": [pair.get(instance_id) for pair in kinds]})
    return out

