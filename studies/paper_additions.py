"""What each of ndfa's additions to the paper's detector does, by replay over several scenes.

    python studies/paper_additions.py TABLES_DIR [TABLES_DIR ...] [--knobs]

Each TABLES_DIR holds the tables and the JSON summary of one `ndfa detect SRC TGT --tables
TABLES_DIR --json TABLES_DIR/summary.json` run. The detector is replayed on each run's observations
(`ndfa.run.replay`: no re-encoding, about a second a scene) with ndfa's defaults, with each addition
(`ndfa.change.config.ADDITIONS`) switched off alone, with the paper's parameters and every addition
on, and with the paper's parameters and every addition off (`DetectorConfig.paper()`); with
`--knobs`, also each knob of an addition switched off alone. The TP / FP / FN summed over the
scenes are printed per row, with the scenes whose figures moved. The scene-level registration prior
a run offered its detector (its summary's `scene_alignment`, when it held) is offered to the
replay too.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np
import polars as pl

from ndfa.change.config import ADDITIONS, DetectorConfig
from ndfa.change.register import RegistrationPrior
from ndfa.eval.runs import score_replay
from ndfa.run.cloud_align import AlignConfig
from ndfa.run.replay import replay


def prior_of(summary: dict) -> RegistrationPrior | None:
    """The prior a run offered its detector, from its summary (`SceneAlignment.as_dict`)."""
    alignment = summary.get("scene_alignment")
    if not alignment or not alignment["ok"] or alignment["transform"] is None:
        return None
    # A shared world is binding; a scene alignment from a clear overlap (`AlignConfig.binding_fitness`).
    binding = alignment["method"] == "shared world" or (alignment["fitness"] or 0.0) >= AlignConfig().binding_fitness
    return RegistrationPrior(alignment["method"], np.array(alignment["transform"]).reshape(4, 4), binding=binding)


def knob_rows() -> list[tuple[str, DetectorConfig]]:
    """ndfa's defaults with one knob of one addition at its off value, for every knob that has one."""
    default, rows = DetectorConfig(), []
    for name in ADDITIONS:
        on, off = getattr(default, name), getattr(default.without(name), name)
        knobs = [k.name for k in dataclasses.fields(on) if getattr(on, k.name) != getattr(off, k.name)]
        for knob in knobs if len(knobs) > 1 else []:  # one knob: the addition's own row
            one_off = dataclasses.replace(on, **{knob: getattr(off, knob)})
            rows.append((f"  {name}.{knob} = {getattr(off, knob)}", dataclasses.replace(default, **{name: one_off})))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tables", nargs="+", type=Path)
    parser.add_argument("--knobs", action="store_true", help="also each knob of an addition off alone")
    args = parser.parse_args()
    runs = {path.name: (pl.read_parquet(path / "observations.parquet"),
                        json.loads((path / "summary.json").read_text())) for path in args.tables}
    rows = [("ndfa (DetectorConfig())", DetectorConfig())]
    rows += [(f"without {name}", DetectorConfig().without(name)) for name in ADDITIONS]
    if args.knobs:
        rows += knob_rows()
    paper = DetectorConfig.paper()
    rows += [("paper's parameters, additions on", dataclasses.replace(
        DetectorConfig(), association=paper.association, registration=paper.registration, decision=paper.decision))]
    rows += [("paper (DetectorConfig.paper())", paper)]
    detected = {name: (s.get("tp"), s.get("fp"), s.get("fn")) for name, (_, s) in runs.items()}
    print(f"{'config':40} {'TP':>4} {'FP':>4} {'FN':>4}  scenes that differ from ndfa's replay (TP/FP/FN)")
    reference: dict[str, tuple[int, int, int]] = {}
    for label, config in rows:
        totals, per_scene = np.zeros(3, dtype=int), {}
        for name, (observations, summary) in runs.items():
            score = score_replay(replay(observations, config, prior=prior_of(summary)))
            if score is None:
                raise SystemExit(f"{name}: its observations table has no ground-truth labels")
            per_scene[name] = (score.tp, score.fp, score.fn)
            totals += per_scene[name]
        if not reference:
            reference = per_scene
            moved = [f"{n} {'/'.join(map(str, s))} (detect: {'/'.join(map(str, detected[n]))})"
                     for n, s in per_scene.items() if s != detected[n]]
        else:
            moved = [f"{n} {'/'.join(map(str, s))}" for n, s in per_scene.items() if s != reference[n]]
        print(f"{label:40} {totals[0]:4d} {totals[1]:4d} {totals[2]:4d}  {', '.join(moved) or '-'}")


if __name__ == "__main__":
    main()
