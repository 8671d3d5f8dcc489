"""Score a `ndfa detect --tables` run on raw (mask-less) simulated recordings, by position.

    python scripts/score_raw.py TABLES_DIR TARGET.mcap [--unscored 9,10,12] [--radius 0.07] [-v]

Without masks, `ndfa detect` does not score: its objects' ids are segment labels. Here each
reported change's object (and a move's source object) is matched to the nearest ground-truth item
(mug or clutter) of its session by the horizontal distance of the object's center (within
`--radius`); `ndfa.eval.scoring.score` then scores those ids as for masked runs. A report matched
to nothing gets an id of its own (an FP); one on clutter is an FP listed in `clutter_fp`.
Visibility is not known without masks: `--unscored` drops mugs that the masked run of the same
scene lists as unscored (random seed 4: 9,10,12). Used for docs/segmentation.md.
"""
import argparse
import json

import numpy as np
import polars as pl

from ndfa.eval.scoring import score
from ndfa.io.recording import RecordingReader

p = argparse.ArgumentParser()
p.add_argument("tables")
p.add_argument("target")
p.add_argument("--unscored", default="")
p.add_argument("--radius", type=float, default=0.07)
p.add_argument("-v", action="store_true")
a = p.parse_args()

gt = RecordingReader(a.target).ground_truth
items = {"source": [], "target": []}
for o in gt["objects"]:
    for s in ("source", "target"):
        if o.get(s):
            items[s].append((int(o["instance_id"]), np.array(o[s]["pose_world_object"])[:2, 3], o["change"]))
for c in gt.get("clutter", []):
    for s in ("source", "target"):
        items[s].append((int(c["instance_id"]), np.array(c["pose_world_object"])[:2, 3], "clutter:" + c["kind"]))

objects = pl.read_parquet(f"{a.tables}/objects.parquet")
decisions = pl.read_parquet(f"{a.tables}/decisions.parquet")
centers = {(r["session"], r["object_id"]): np.array([r["center_x"], r["center_y"]]) for r in objects.iter_rows(named=True)}

fresh = [-1]


def match(session, object_id):
    c = centers[(session, object_id)]
    best = min(items[session], key=lambda it: np.linalg.norm(it[1] - c))
    d = float(np.linalg.norm(best[1] - c))
    if d <= a.radius:
        return best[0], best[2], d
    fresh[0] -= 1
    return fresh[0], f"nothing (nearest {best[0]} {best[2]} at {d:.2f})", d


changes = [r for r in decisions.iter_rows(named=True) if r["kind"] != "unchanged"]
moved = {(r["session"], r["object_id"]) for r in changes if r["kind"] == "moved"}
changes = [r for r in changes if r["kind"] == "moved" or (r["session"], r["object_id"]) not in moved]
reported = []
for r in changes:
    iid, what, d = match(r["session"], r["object_id"])
    ids = [iid]
    line = f"  {r['kind']:8s} {r['session']} obj {r['object_id']:3d} frame {r['frame']:4d} -> {iid} ({what}, {d:.3f} m)"
    if r["kind"] == "moved" and r["partner_id"] is not None:
        piid, pwhat, pd = match("source", r["partner_id"])
        ids.append(piid)
        line += f"; from source obj {r['partner_id']} -> {piid} ({pwhat}, {pd:.3f} m)"
    reported += ids
    if a.v:
        print(line)
unscored = {int(x) for x in a.unscored.split(",") if x}
gt_scored = dict(gt, objects=[o for o in gt["objects"] if int(o["instance_id"]) not in unscored])
# ids of clutter / nothing are FP; unscored mugs dropped from the reports too
rep = [i for i in reported if i not in unscored]
s = score(rep, gt_scored)
clutter = sorted({i for i in rep if i >= 1001})
print(json.dumps({"tp": s.tp, "fp": s.fp, "fn": s.fn, "fp_ids": s.false_positive_ids, "fn_ids": s.false_negative_ids,
                  "clutter_fp": clutter, "objects": [len(objects.filter(pl.col('session') == x)) for x in ("source", "target")]}))
