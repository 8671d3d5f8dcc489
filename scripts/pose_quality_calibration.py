"""The pose-quality figure against the true error: estimate each session's poses as `ndfa detect`
does, and print (and append to a JSON-lines file) its no-truth evidence, estimated error and
verdict beside its true ATE. docs/pose_quality.md has the table this gives and the commands.

    python scripts/pose_quality_calibration.py REC.mcap [REC.mcap ...] --out calibration.jsonl
        [--given-is-truth]    # score against the given poses when a recording has no true ones (7-Scenes)
        [--frame-step 2]      # every 2nd frame, as `ndfa detect --frame-step 2`
        [--backward]          # and the second estimate from the frames in reverse order (its disagreement)
        [--config '{"velocity_in_world": False}']   # RgbdOdometryConfig fields, a Python dict literal
    python scripts/pose_quality_calibration.py --table calibration.jsonl   # the table and Spearman's rho

A session already in the output file is not estimated again.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import json
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

from ndfa.io.recording import RecordingReader
from ndfa.trajectory.metrics import absolute_trajectory_error
from ndfa.trajectory.quality import judge
from ndfa.trajectory.rgbd import RgbdOdometryConfig
from ndfa.trajectory.session import choose_method, estimate_session_poses, frames_backwards, rgbd_config_for


def measure(path: Path, given_is_truth: bool, frame_step: int, backward: bool = False,
            rgbd_config: RgbdOdometryConfig = RgbdOdometryConfig()) -> dict:
    reader = RecordingReader(path)
    truth: list[np.ndarray | None] = []

    def keep_truth(frame) -> None:
        true = frame.pose_world_camera_true
        truth.append(true if true is not None else (frame.pose_world_camera if given_is_truth else None))

    frames = reader.frames(step=frame_step)
    session = estimate_session_poses(frames, choose_method(next(iter(reader.frames(stop=1)), None)), path,
                                     rgbd_config=rgbd_config_for(reader.meta, rgbd_config), on_frame=keep_truth,
                                     backward_frames=frames_backwards(reader, frame_step) if backward else None)
    row: dict = {"session": str(path), "frame_step": frame_step, "frames": len(session.poses)}
    if all(pose is not None for pose in truth) and len(truth) >= 3:
        ate = absolute_trajectory_error(session.poses, truth)
        row["ate_cm"] = 100.0 * ate.rmse_m
    assert session.evidence is not None
    row["evidence"] = session.evidence.to_dict()
    quality = judge(session.evidence)
    row["estimated_error_cm"], row["verdict"] = quality.error_cm, quality.verdict
    return row


def table(rows: list[dict]) -> None:
    rows = [row for row in rows if "ate_cm" in row]
    rejudged = [judge_row(row) for row in rows]
    print("| session | frames | true ATE (cm) | estimated error (cm) | verdict | revisit pairs | revisit conflict (cm) | "
          "revisit deepest 5 % (cm) | neighbour conflict (cm) | step conflict max (cm) | step bulk max (cm) | jumps | "
          "backward disagreement (cm) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for row, (error, verdict) in sorted(zip(rows, rejudged, strict=True), key=lambda item: item[0]["ate_cm"]):
        e = row["evidence"]
        print(f"| {row['session']} | {row['frames']} | {row['ate_cm']:.1f} | {error:.1f} | {verdict} | {e['revisit_pairs']} | "
              f"{_f(e['revisit_conflict_cm'])} | {_f(e.get('revisit_local_conflict_cm'))} | {_f(e['neighbour_conflict_cm'])} | "
              f"{_f(e['step_conflict_cm'])} | {_f(e.get('step_shared_conflict_cm'))} | {e['jumps']} | {_f(e.get('backward_disagreement_cm'), 2)} |")
    errors = [error if np.isfinite(error) else np.inf for error, _ in rejudged]
    if len(rows) < 3:
        return
    rho = spearmanr([row["ate_cm"] for row in rows], errors).statistic
    print(f"\n{len(rows)} sessions; Spearman rank correlation of the estimated error with the true ATE: {rho:.3f}")
    good = [k for k, (_, verdict) in enumerate(rejudged) if verdict == "good"]
    if len(good) >= 3:
        rho_good = spearmanr([rows[k]["ate_cm"] for k in good], [errors[k] for k in good]).statistic
        print(f"{len(good)} of them good; among those: {rho_good:.3f}")


def judge_row(row: dict) -> tuple[float, str]:
    from ndfa.trajectory.quality import PoseEvidence

    evidence = PoseEvidence(**{key: (float("nan") if value is None else value) for key, value in row["evidence"].items()})
    quality = judge(evidence)
    return quality.error_cm, quality.verdict


def _f(value: float | None, digits: int = 1) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recordings", nargs="*", type=Path)
    parser.add_argument("--out", type=Path)
    parser.add_argument("--table", type=Path, help="print the table of this JSON-lines file and stop")
    parser.add_argument("--given-is-truth", action="store_true")
    parser.add_argument("--frame-step", type=int, default=1)
    parser.add_argument("--backward", action="store_true", help="run the backward estimate too (twice the time)")
    parser.add_argument("--config", default="{}", help="RgbdOdometryConfig fields, a Python dict literal")
    args = parser.parse_args()
    rgbd_config = dataclasses.replace(RgbdOdometryConfig(), **ast.literal_eval(args.config))
    if args.table is not None:
        table([json.loads(line) for line in args.table.read_text().splitlines() if line.strip()])
        return
    done = set()
    if args.out is not None and args.out.exists():
        done = {(json.loads(line)["session"], json.loads(line)["frame_step"])
                for line in args.out.read_text().splitlines() if line.strip()}
    for path in args.recordings:
        if (str(path), args.frame_step) in done:
            continue
        row = measure(path, args.given_is_truth, args.frame_step, args.backward, rgbd_config)
        print(json.dumps(row), flush=True)
        if args.out is not None:
            with args.out.open("a") as file:
                file.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
