"""A scene alignment of two sessions with estimated poses against the truth their given poses tell.

For a pair of recordings whose given poses share one world (a dataset's, as `ndfa plant`'s copies of
the kitchen): each session's poses are estimated as `ndfa detect --poses estimate` does
(`prepare_session`), each estimated world is mapped onto the given one by its cameras
(`align_worlds`), and the true T_rel (target's estimated world -> source's) is A_source^-1 A_target.
The scene alignment (`align_scenes`) is then made without and with the turn search
(`AlignConfig.turn_search_deg`), and each is printed with its fitness, its error against the true
T_rel over the target's cloud (mean / max), its own evidence (`own_evidence`) and CPU seconds.
The truth carries the odometry's drift (each session's camera RMSE after the fit is printed) and the
two levellings' difference (a tilt the 4-DoF alignment cannot take): errors of a few centimetres are
at its resolution. docs/registration.md, "The turn search".

    PYTHONPATH=. .venv/bin/python studies/scene_alignment_truth.py DIR   (DIR holds source.mcap and target.mcap)
"""
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

from ndfa.eval.position_match import align_worlds
from ndfa.io.recording import RecordingReader
from ndfa.run.align import align_scenes, scene_cloud
from ndfa.run.cloud_align import AlignConfig, apply_transform
from ndfa.run.scene_evidence import own_evidence
from ndfa.run.world import prepare_session

pair = Path(sys.argv[1])
readers = {s: RecordingReader(pair / f"{s}.mcap") for s in ("source", "target")}
worlds = {s: prepare_session(r, s, poses="estimate") for s, r in readers.items()}
to_given = {}
for session, reader in readers.items():
    frames = list(reader.frames())
    to_given[session], rmse = align_worlds([worlds[session].apply(f).pose_world_camera for f in frames],
                                           [f.pose_world_camera for f in frames])
    print(f"{pair.name} {session}: camera RMSE against the given poses {rmse * 100:.1f} cm")
truth = np.linalg.inv(to_given["source"]) @ to_given["target"]
tilt = np.degrees(np.arccos(np.clip(truth[2, 2], -1.0, 1.0)))
print(f"{pair.name}: true T_rel turns {np.degrees(np.arctan2(truth[1, 0], truth[0, 0])):.2f} deg about up, "
      f"tilt {tilt:.2f} deg (the levellings' difference)")
clouds = {s: scene_cloud(readers[s], worlds[s]) for s in readers}
for turns in ((), AlignConfig().turn_search_deg):
    config = dataclasses.replace(AlignConfig(), turn_search_deg=turns)
    started = time.process_time()
    found = align_scenes(clouds["source"], clouds["target"], config)
    aligned = time.process_time()
    if found.transform is None:
        print(f"{pair.name} turn search {turns}: no alignment ({found.reason})")
        continue
    evidence = own_evidence(clouds["source"], clouds["target"], found.transform, config)
    judged = time.process_time()
    error = np.linalg.norm(apply_transform(found.transform, clouds["target"]) - apply_transform(truth, clouds["target"]),
                           axis=1)
    yaw = np.degrees(np.arctan2(found.transform[1, 0], found.transform[0, 0]))
    print(f"{pair.name} turn search {turns or 'off'}: fitness {found.fitness:.3f} at {yaw:.2f} deg, against the truth "
          f"mean {error.mean() * 100:.1f} / max {error.max() * 100:.1f} cm; {aligned - started:.1f} s CPU to align, "
          f"{judged - aligned:.1f} s CPU to judge; own evidence {evidence.describe()}")
