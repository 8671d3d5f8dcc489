"""Up error of an `ndfa detect` run, per session: the angle between the estimated up (the run's JSON,
in the estimated world = the first camera's frame for a raw recording) and the true up (world z of
the simulator) seen from the first camera.

    .venv/bin/python studies/up_error.py DIR JSON   (DIR holds source.mcap and target.mcap; JSON: ndfa detect --json)
"""
import json
import sys

import numpy as np

from ndfa.io.recording import RecordingReader

run = json.load(open(sys.argv[2]))
for session in ("source", "target"):
    reader = RecordingReader(f"{sys.argv[1]}/{session}.mcap")
    frame = next(iter(reader.frames(stop=1)))
    given = frame.pose_world_camera
    up_est = np.asarray(run["world"][session]["up_estimate"]["up_world"], float)
    up_cam_est = given[:3, :3].T @ up_est
    up_cam_true = frame.pose_world_camera_true[:3, :3].T @ np.array([0.0, 0.0, 1.0])
    angle = np.degrees(np.arccos(np.clip(up_cam_est @ up_cam_true / np.linalg.norm(up_cam_est), -1, 1)))
    err = run["world"][session]["pose_error"]
    print(f"{sys.argv[1]} {session}: up error {angle:.2f} deg (first frame; given pose is identity: {np.allclose(given, np.eye(4))}), "
          f"ATE {100*err['ate_rmse_m']:.2f} cm (max {100*err['ate_max_m']:.1f}), verdict {run['world'][session]['pose_quality']['verdict']}")
print(f"TP {run['tp']} FP {run['fp']} FN {run['fn']} withheld {len(run['withheld_changes'])}")
