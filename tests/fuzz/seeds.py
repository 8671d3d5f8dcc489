"""The well-formed inputs the generators mutate: a tiny ndfa recording, a tiny TUM folder, and tiny
ROS1 / ROS2 (mcap storage) bags exported from the recording. `corpus/seed/` holds them checked in
(45 KB; the ROS2 sqlite3 flavour, 28 KB, is exported at test time);
`python -m tests.fuzz.seeds` (from the repository root) writes them again."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from ndfa.core.frame import Frame
from ndfa.core.geometry import look_at
from ndfa.io.recording import RecordingWriter

CORPUS = Path(__file__).resolve().parent / "corpus"
SEED = CORPUS / "seed"
H, W = 6, 8
FRAMES = 3
K = np.array([[10.0, 0.0, 3.5], [0.0, 10.0, 2.5], [0.0, 0.0, 1.0]])
_AT = [[1.0, 0.0, 0.0, 1.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.5], [0.0, 0.0, 0.0, 1.0]]
GROUND_TRUTH = {"session": "target", "tables": [], "changes": {"added": 1},
                "objects": [{"instance_id": 1, "change": "added", "source": None, "target": {"pose_world_object": _AT}}]}


def tiny_frames() -> list[Frame]:
    """FRAMES 8x6 frames 0.1 s apart: a plane 1 m ahead, one 'object' (instance 1) in the middle."""
    frames = []
    for i in range(FRAMES):
        depth = np.full((H, W), 1.0 + 0.001 * i, np.float32)
        depth[2:4, 3:5] = 0.8
        instances = np.zeros((H, W), np.uint16)
        instances[2:4, 3:5] = 1
        rgb = np.zeros((H, W, 3), np.uint8)
        rgb[..., 0] = 40 * i
        pose = look_at(np.array([0.05 * i, 0.0, 1.0]), np.array([0.05 * i + 1.0, 0.0, 0.5]))
        frames.append(Frame(index=i, timestamp=1.0 + 0.1 * i, rgb=rgb, depth=depth, K=K,
                            pose_world_camera=pose, instances=instances))
    return frames


def write_tiny_recording(path: Path, chunk_size: int = 512) -> Path:
    """The tiny recording, in small chunks so that a mutation can hit several chunk headers."""
    with RecordingWriter(path, {"source": "fuzz", "session": "target"}, chunk_size=chunk_size) as writer:
        for frame in tiny_frames():
            writer.write_frame(frame)
        writer.write_ground_truth(GROUND_TRUTH)
    return path


def write_seeds(out: Path = SEED) -> None:
    from ndfa.io.export.bag import export_bag
    from ndfa.io.export.tum import export_tum

    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    recording = write_tiny_recording(out / "tiny.mcap")
    export_tum(recording, out / "tum")
    export_bag(recording, out / "tiny.bag", version=1)
    export_bag(recording, out / "ros2-mcap", version=2, storage="mcap")


if __name__ == "__main__":
    write_seeds()
