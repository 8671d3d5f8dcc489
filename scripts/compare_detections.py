"""Compare two sets of `ndfa detect --json` summaries, object for object (a refactoring's check).

    python scripts/compare_detections.py BEFORE_DIR AFTER_DIR

Each folder holds NAME.json files (e.g. sample.json, paper.json, random1.json ...); every field is
compared except the ones that measure time (fps, stage_ms, a scene alignment's seconds) and the
poses/up provenance ("world").
Exit code 1 when any pair differs or a file is missing.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

IGNORED = ("fps", "stage_ms", "world")


def load(path: Path) -> dict:
    summary = json.loads(path.read_text())
    return {key: untimed(value) for key, value in summary.items() if key not in IGNORED}


def untimed(value: object) -> object:
    """`value` without the time a scene alignment took (at any depth: the pairs of a many-session run)."""
    if isinstance(value, dict):
        return {k: untimed(v) for k, v in value.items() if not (k == "seconds" and "fitness" in value)}
    if isinstance(value, list):
        return [untimed(v) for v in value]
    return value


def main(before_dir: Path, after_dir: Path) -> int:
    failed = 0
    for before_path in sorted(before_dir.glob("*.json")):
        after_path = after_dir / before_path.name
        if not after_path.is_file():
            print(f"{before_path.name}: missing in {after_dir}")
            failed += 1
            continue
        before, after = load(before_path), load(after_path)
        same = before == after
        print(f"{before_path.name}: {'IDENTICAL' if same else 'DIFFERENT'} "
              f"(TP/FP/FN {after.get('tp')}/{after.get('fp')}/{after.get('fn')})")
        for key in sorted(set(before) | set(after)):
            if before.get(key) != after.get(key):
                print(f"    {key}: before {str(before.get(key))[:160]} / after {str(after.get(key))[:160]}")
        failed += not same
    return 1 if failed else 0


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    sys.exit(main(Path(sys.argv[1]), Path(sys.argv[2])))
