"""The shape of a recording's /ndfa/ground_truth message, checked when a recording is opened.

The message is loose JSON (the simulator's scene description), but the evaluation and `ndfa info`
index into parts of it: a recording written by another tool, or damaged, must fail on open with
one line naming the field, not deep inside the scoring with a KeyError."""

from __future__ import annotations

import math
from typing import Any

from ndfa.core.events import SESSIONS


def changed_instances(ground_truth: dict[str, Any]) -> dict[int, str]:
    """Instance id -> change kind, from a recording's ground-truth JSON."""
    return {int(o["instance_id"]): o["change"] for o in ground_truth.get("objects", [])
            if o.get("change") not in (None, "unchanged")}


# The true changes a report of each kind describes rightly (a "moved" report also needs one mug at
# both ends: a removed mug and a different mug added elsewhere are not a move, unless the two are
# of one model: `identical_moves`).
RIGHT_KIND = {"added": ("added", "moved", "switched"), "removed": ("removed", "moved", "switched"),
              "moved": ("moved", "switched"), "rotated": ("rotated",)}

# The model id `ndfa plant` gives the recording's own objects: each is itself, none another's twin.
REAL_MODEL = "real"


def identical_moves(ground_truth: dict[str, Any]) -> frozenset[tuple[int, int]]:
    """(left, arrived) instance-id pairs of one model: a mug that left its source place (removed,
    moved or switched) and another of its model that arrived at a target place (added, moved or
    switched). Two mugs of one model have one shape: which of them stands where is in no view, so
    a mug of that model gone from here and one come there is, to any observer, a move, and a
    "moved" report from the one to the other is of the right kind. Objects without a model id,
    or with `REAL_MODEL`, pair with none."""
    left, arrived = [], []
    for o in ground_truth.get("objects", []):
        model = o.get("model_id")
        if model in (None, REAL_MODEL):
            continue
        if o.get("change") in ("removed", "moved", "switched"):
            left.append((int(o["instance_id"]), model))
        if o.get("change") in ("added", "moved", "switched"):
            arrived.append((int(o["instance_id"]), model))
    return frozenset((a, b) for a, model in left for b, other in arrived if model == other and a != b)


def kind_is_right(kind: str, instance_id: int, partner_id: int | None, truth: dict[int, str],
                  identical: frozenset[tuple[int, int]] = frozenset()) -> bool:
    """Whether a report of `kind` on the mug `instance_id` (a move: from the mug `partner_id`, its
    source object's; None: unknown) is right for the true changes `truth` (`changed_instances`);
    `identical`: the removed and added mugs of one model (`identical_moves`)."""
    if kind == "moved" and (partner_id, instance_id) in identical:
        return True
    if truth.get(instance_id, "unchanged") not in RIGHT_KIND.get(kind, ()):
        return False
    return kind != "moved" or partner_id == instance_id


def ground_truth_problem(truth: dict[str, Any]) -> str | None:
    """What is wrong with a ground-truth message, or None when the parts ndfa reads are well formed."""
    for key, kind in (("objects", list), ("clutter", list), ("tables", list), ("changes", dict)):
        if key in truth and not isinstance(truth[key], kind):
            return f'"{key}" must be a JSON {"array" if kind is list else "object"}, got {type(truth[key]).__name__}'
    if "session" in truth and not isinstance(truth["session"], str):
        return f'"session" must be a string, got {type(truth["session"]).__name__}'
    for position, item in enumerate(truth.get("objects", [])):
        problem = _item_problem(item, with_poses_per_session=True)
        if problem:
            return f'"objects"[{position}] {problem}'
    for position, item in enumerate(truth.get("clutter", [])):
        problem = _item_problem(item, with_poses_per_session=False)
        if problem:
            return f'"clutter"[{position}] {problem}'
    tilt = truth.get("world_tilt")
    if tilt and not (isinstance(tilt, dict) and _is_pose(tilt.get("pose_world_level"))):
        return '"world_tilt" must be an object with a 4x4 "pose_world_level"'
    visible = truth.get("visible")
    if visible is not None and not (isinstance(visible, dict) and all(
            isinstance(ids, list) and all(_is_id(i) for i in ids) for ids in visible.values())):
        return '"visible" must map sessions to arrays of instance ids'
    return None


def _item_problem(item: Any, with_poses_per_session: bool) -> str | None:
    if not isinstance(item, dict):
        return f"must be a JSON object, got {type(item).__name__}"
    if not _is_id(item.get("instance_id")):
        return f'has no integer "instance_id" >= 0 (got {item.get("instance_id")!r})'
    if with_poses_per_session:
        if item.get("change") is not None and not isinstance(item["change"], str):
            return f'"change" must be a string, got {type(item["change"]).__name__}'
        for session in SESSIONS:
            placed = item.get(session)
            if placed and not (isinstance(placed, dict) and _is_pose(placed.get("pose_world_object"))):
                return f'"{session}" must be null or an object with a 4x4 "pose_world_object"'
        return None
    if not isinstance(item.get("kind"), str):
        return 'has no string "kind"'
    if not _is_pose(item.get("pose_world_object")):
        return 'has no 4x4 "pose_world_object"'
    return None


def _is_id(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _is_pose(value: Any) -> bool:
    """A 4x4 nested list of finite numbers."""
    return (isinstance(value, list) and len(value) == 4 and all(
        isinstance(row, list) and len(row) == 4 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in row)
        for row in value))
