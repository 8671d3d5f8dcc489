"""The height tree T_z against the paper's two-dimensional tree on the same scenes, by replay.

    python studies/shelves_tree.py TABLES_DIR [TABLES_DIR ...]

Each TABLES_DIR holds the tables and the JSON summary of one `ndfa detect SRC TGT --tables
TABLES_DIR --json TABLES_DIR/summary.json` run (ndfa's defaults). Its observations are replayed
(`ndfa.run.replay`: the same measurements, no re-encoding) with ndfa's defaults (T_z on), with the
paper's two-dimensional tree and everything else the same (`DetectorConfig().without("levels")`),
and with `DetectorConfig.paper()` for reference; per scene and summed: TP / FP / FN, precision,
recall, and the objects each session's map holds (two mugs standing one above the other that
become one object show here). The false reports and misses are named by mask id.
The result is recorded in docs/shelves.md.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import polars as pl

from ndfa.change.config import DetectorConfig
from ndfa.eval.runs import score_replay
from ndfa.run.replay import replay

sys.path.insert(0, str(Path(__file__).parent))
from paper_additions import prior_of  # noqa: E402  (the prior a run offered, read one way)

CONFIGS = {"T_z (DetectorConfig())": DetectorConfig(), "2-D tree (without levels)": DetectorConfig().without("levels"),
           "DetectorConfig.paper()": DetectorConfig.paper()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tables", nargs="+", type=Path)
    args = parser.parse_args()
    for label, config in CONFIGS.items():
        totals = np.zeros(3, dtype=int)
        print(label)
        for path in args.tables:
            summary = json.loads((path / "summary.json").read_text())
            result = replay(pl.read_parquet(path / "observations.parquet"), config, prior=prior_of(summary))
            score = score_replay(result)
            if score is None:
                raise SystemExit(f"{path}: its observations table has no ground-truth labels")
            totals += (score.tp, score.fp, score.fn)
            maps = f"objects {len(result.detector.source)} / {len(result.detector.target)}"
            print(f"  {path.name:10} {score.tp:3d} / {score.fp:2d} / {score.fn:2d}  {maps}  "
                  f"FP {list(score.false_positive_ids)} FN {list(score.false_negative_ids)}")
        tp, fp, fn = (int(v) for v in totals)
        print(f"  {'all':10} {tp:3d} / {fp:2d} / {fn:2d}  precision {tp / max(tp + fp, 1):.3f}, recall {tp / max(tp + fn, 1):.3f}")


if __name__ == "__main__":
    main()
