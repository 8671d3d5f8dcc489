"""Levers on the NDF's encoding that change what it computes: reusing codes of views that barely
changed, and ONNX Runtime's options and int8 quantisation of the encode graph (docs/speed.md,
"Codes reused while a view barely changes").

    python studies/encoding_levers.py views out/paper/target.mcap      # views' codes against their angle; reuse rates
    python studies/encoding_levers.py graph out/paper/target.mcap      # encode graph: ONNX Runtime options, int8
    python studies/encoding_levers.py decisions BEFORE_DIR AFTER_DIR   # `ndfa detect --json` runs: the same decisions?

`views` and `graph` perceive the recording's masked frames once, as `ndfa detect` does; `graph`
times each variant of the encode graph over all of its observations, variants alternating, by this
process's CPU time (`time.process_time`).
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ndfa.io.recording import RecordingReader
from ndfa.ndf.encoder import EncoderConfig, NDFEncoder
from ndfa.ndf.export_onnx import export_onnx
from ndfa.ndf.reuse import CodeReuse, ReuseConfig
from ndfa.pipeline import ChangeDetectionPipeline, PipelineConfig


def perceived(recording: Path) -> list[tuple[list[np.ndarray], np.ndarray, list[int], int]]:
    """Every frame's observations: (clouds in the camera frame, pose, instance ids, frame index)."""
    perceive = ChangeDetectionPipeline(PipelineConfig(), encoder=NDFEncoder()).perceive
    frames = []
    for frame in RecordingReader(recording).frames():
        observed = perceive(frame)
        frames.append(([o.points_camera for o in observed.observations], np.asarray(frame.pose_world_camera),
                       [o.instance_id for o in observed.observations], frame.index))
    return frames


def cosine(a: np.ndarray, b: np.ndarray) -> float:
    return float(a @ b / np.linalg.norm(a) / np.linalg.norm(b))


def views(recording: Path) -> None:
    frames = perceived(recording)
    seeds = NDFEncoder(), NDFEncoder(config=EncoderConfig(seed=1))
    tracks: dict[int, list] = {}
    same_view = []
    for clouds, pose, ids, index in frames:
        if not clouds:
            continue
        codes = [encoder.encode_batch(clouds, [pose] * len(clouds), full_reconstruction=False) for encoder in seeds]
        for cloud, instance, a, b in zip(clouds, ids, *codes):
            same_view.append((cosine(a.shape_code, b.shape_code), np.linalg.norm(a.center_world - b.center_world) * 1e3))
            centroid = cloud.mean(axis=0) @ pose[:3, :3].T + pose[:3, 3]
            ray = centroid - pose[:3, 3]
            tracks.setdefault(instance, []).append((index, ray / np.linalg.norm(ray), a))
    pairs = []
    for seen in tracks.values():
        for k, (index, ray, code) in enumerate(seen):
            for later_index, later_ray, later in seen[k + 1:k + 4]:
                if later_index - index <= 3:
                    pairs.append((np.degrees(np.arccos(np.clip(ray @ later_ray, -1, 1))), cosine(code.shape_code, later.shape_code),
                                  np.linalg.norm(code.center_world - later.center_world) * 1e3, later_index - index))
    table, rows = np.array(same_view), np.array(pairs)
    steps = rows[rows[:, 3] == 1, 0]
    print(f"one view resampled with seeds 0 and 1: codes' cosine median {np.median(table[:, 0]):.3f}, "
          f"centers apart median {np.median(table[:, 1]):.2f} mm")
    print(f"an object's views in consecutive frames: {np.percentile(steps, [10, 50, 90]).round(1)} degrees apart (p10, p50, p90)")
    print("its views up to 3 frames apart:")
    for low, high in ((0, 2.5), (2.5, 5), (5, 7.5), (7.5, 10), (10, 15)):
        chosen = (rows[:, 0] >= low) & (rows[:, 0] < high)
        if chosen.any():
            print(f"  {low}-{high} degrees apart ({chosen.sum()} pairs): cosine median {np.median(rows[chosen, 1]):.3f}, "
                  f"centers apart median {np.median(rows[chosen, 2]):.2f} mm")

    class Uncounted:  # the reuse's decisions need no network
        def encode_batch(self, clouds, poses, full_reconstruction=True):  # noqa: ANN001, ANN201
            return [object() for _ in clouds]

    for angle in (2, 3, 5, 8, 10):
        reuse = CodeReuse(Uncounted(), ReuseConfig(angle_deg=angle))  # type: ignore[arg-type]
        for clouds, pose, _, _ in frames:
            reuse.encode(clouds, pose, False)
        print(f"reuse within {angle} degrees: {reuse.reused} of {reuse.reused + reuse.encoded} observations take an earlier code")


def graph(recording: Path, repeat: int = 3) -> None:
    import onnxruntime
    from onnxruntime.quantization import QuantType, quantize_dynamic

    encoder = NDFEncoder()
    inputs = []
    for clouds, pose, _, _ in perceived(recording):
        if clouds:
            centred, up, centroids = encoder._inputs(np.stack([encoder.resample(c) for c in clouds]), [pose] * len(clouds))
            inputs.append({"points": centred, "up": up, "view_ray": centroids[:, 0].astype(np.float32)})
    level = onnxruntime.GraphOptimizationLevel

    def session(model: str, optimisation=level.ORT_ENABLE_ALL, arena: bool = True):  # noqa: ANN001, ANN202
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads, options.inter_op_num_threads = 1, 1
        options.graph_optimization_level, options.log_severity_level = optimisation, 3
        options.enable_cpu_mem_arena = options.enable_mem_pattern = arena
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        return onnxruntime.InferenceSession(model, options, providers=["CPUExecutionProvider"])

    with tempfile.TemporaryDirectory() as folder:
        shipped, int8, matmul_uint8 = (str(Path(folder) / name) for name in ("encode.onnx", "int8.onnx", "uint8.onnx"))
        Path(shipped).write_bytes(export_onnx(encoder.model, encoder.n_points)[0])
        quantize_dynamic(shipped, int8, weight_type=QuantType.QInt8)
        quantize_dynamic(shipped, matmul_uint8, weight_type=QuantType.QUInt8, op_types_to_quantize=["MatMul"])
        variants = {"shipped (all optimisations)": session(shipped), "extended": session(shipped, level.ORT_ENABLE_EXTENDED),
                    "basic": session(shipped, level.ORT_ENABLE_BASIC), "no memory arena": session(shipped, arena=False),
                    "int8 dynamic": session(int8), "uint8 dynamic, MatMul only": session(matmul_uint8)}
    reference = [variants["shipped (all optimisations)"].run(None, x) for x in inputs]
    frames = len(RecordingReader(recording))
    for run in range(repeat):
        for name, variant in variants.items():
            started = time.process_time()
            outputs = [variant.run(None, x) for x in inputs]
            line = f"run {run + 1}, {name}: {(time.process_time() - started) * 1e3 / frames:.2f} CPU ms per frame"
            if run == 0:
                codes = [cosine(a, b) for ours, theirs in zip(reference, outputs) for a, b in zip(ours[1], theirs[1])]
                shift = np.concatenate([np.linalg.norm(ours[2] - theirs[2], axis=1) for ours, theirs in zip(reference, outputs)]) * 1e3
                line += (f"; codes' cosine min {min(codes):.4f}, median {np.median(codes):.4f}; "
                         f"centers apart median {np.median(shift):.2f}, max {shift.max():.2f} mm")
            print(line, flush=True)


def decisions(before_dir: Path, after_dir: Path) -> int:
    """Per run: TP / FP / FN, objects, and whether the changes (session, kind, frame, instance ids) are the same."""
    differ = 0
    for after_path in sorted(after_dir.glob("*.json")):
        before, after = (json.loads(path.read_text()) for path in (before_dir / after_path.name, after_path))
        changes = [sorted((c["session"], c["kind"], c["frame"], tuple(c.get("instance_ids", []))) for c in run["changes"])
                   for run in (before, after)]
        same = changes[0] == changes[1]
        differ += not same
        print(f"{after_path.stem}: TP/FP/FN {'/'.join(str(before.get(k)) for k in ('tp', 'fp', 'fn'))} -> "
              f"{'/'.join(str(after.get(k)) for k in ('tp', 'fp', 'fn'))}; objects {before.get('objects_source')} / "
              f"{before.get('objects_target')} -> {after.get('objects_source')} / {after.get('objects_target')}; "
              f"{len(changes[1])} changes, {'the same decisions' if same else 'OTHER DECISIONS'}")
        if not same:
            print(f"    only before: {[c for c in changes[0] if c not in changes[1]]}\n    only after: {[c for c in changes[1] if c not in changes[0]]}")
    return 1 if differ else 0


if __name__ == "__main__":
    if len(sys.argv) < 3 or sys.argv[1] not in ("views", "graph", "decisions"):
        sys.exit(__doc__)
    if sys.argv[1] == "views":
        views(Path(sys.argv[2]))
    elif sys.argv[1] == "graph":
        graph(Path(sys.argv[2]))
    else:
        sys.exit(decisions(Path(sys.argv[2]), Path(sys.argv[3])))
