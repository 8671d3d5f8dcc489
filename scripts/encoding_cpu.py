"""CPU time of the NDF's encoding on a recording's observations, variants alternating in one process.

    python scripts/encoding_cpu.py TARGET.mcap [--repeat 3] [--points 224 --neighbours 10] [--before REV] [--reuse-angle 5]

The observations are perceived once (masks, as `ndfa detect` extracts them); then each variant
runs `NDFEncoder.encode_batch` over all of them, frame by frame as the pipeline calls it (the
reconstruction decoded only as far as decisions need), and prints this process's CPU ms per frame
(`time.process_time`: another job's share of the cores does not count), split into the encoder
network, the occupancy network and the rest. Variants: the shipped encoder; with --points /
--neighbours also that; with --before REV also the encoding as it was at git revision REV (its
`ndfa/ndf/encoder.py` and the encode graph of its `ndfa/ndf/export_onnx.py`); with --reuse-angle
also the shipped encoder behind `ndfa.ndf.reuse.CodeReuse` (one per run: a session's pass). The
first variant is the reference of the codes' agreement printed (the reuse variant's codes are
not compared: they are other views' by design).
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ndfa.io.recording import RecordingReader
from ndfa.ndf.encoder import DEFAULT_WEIGHTS, EncoderConfig, NDFEncoder
from ndfa.ndf.reuse import CodeReuse, ReuseConfig
from ndfa.ndf.runtime import OnnxRuntime
from ndfa.pipeline import ChangeDetectionPipeline, PipelineConfig


class TimedRuntime:
    """A runtime that adds its calls' CPU time to `seconds`."""

    def __init__(self, runtime) -> None:  # noqa: ANN001
        self.runtime, self.name, self.seconds = runtime, runtime.name, {"network": 0.0, "occupancy": 0.0}

    def encode(self, *inputs):  # noqa: ANN002, ANN201
        return self._timed("network", self.runtime.encode, inputs)

    def occupancy(self, *inputs):  # noqa: ANN002, ANN201
        return self._timed("occupancy", self.runtime.occupancy, inputs)

    def _timed(self, part: str, call, inputs: tuple):  # noqa: ANN001, ANN202
        started = time.process_time()
        try:
            return call(*inputs)
        finally:
            self.seconds[part] += time.process_time() - started


def module_at(revision: str, path_in_repo: str, name: str):  # noqa: ANN201
    """The module `path_in_repo` as it was at git `revision` (its imports: this tree's)."""
    source = subprocess.run(["git", "show", f"{revision}:{path_in_repo}"], check=True, capture_output=True, text=True).stdout
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"{name}.py"
        path.write_text(source)
        spec = importlib.util.spec_from_file_location(name, path)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module  # its dataclasses look their module up
        spec.loader.exec_module(module)
    return module


def before_encoder(revision: str) -> NDFEncoder:
    """The shipped weights in `revision`'s encoder.py, with the encode graph of its export_onnx.py."""
    module = module_at(revision, "ndfa/ndf/export_onnx.py", "export_before")
    encoder_module = module_at(revision, "ndfa/ndf/encoder.py", "encoder_before")
    encoder = encoder_module.NDFEncoder(DEFAULT_WEIGHTS, encoder_module.EncoderConfig(runtime="onnxruntime"))
    runtime = encoder.runtime
    assert isinstance(runtime, OnnxRuntime)
    import onnxruntime

    runtime._encode = onnxruntime.InferenceSession(module.export_onnx(encoder.model, encoder.n_points)[0],
                                                   runtime._encode.get_session_options(),
                                                   providers=["CPUExecutionProvider"])
    return encoder


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("target", type=Path)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--points", type=int)
    parser.add_argument("--neighbours", type=int)
    parser.add_argument("--before", help="git revision whose encoding (encoder.py and encode graph) to time too")
    parser.add_argument("--reuse-angle", type=float, help="also the shipped encoder with codes reused within this many degrees")
    args = parser.parse_args()

    perceive = ChangeDetectionPipeline(PipelineConfig(), encoder=NDFEncoder()).perceive
    frames, all_frames, count = [], [], 0
    for frame in RecordingReader(args.target).frames():
        count += 1
        observed = perceive(frame)
        all_frames.append(([o.points_camera for o in observed.observations], frame.pose_world_camera))
        if observed.observations:
            frames.append(all_frames[-1])
    variants = {"shipped": NDFEncoder()}
    if args.before:
        variants = {f"encoding of {args.before}": before_encoder(args.before)} | variants
    if args.points or args.neighbours:
        variants[f"points {args.points}, neighbours {args.neighbours}"] = NDFEncoder(
            config=EncoderConfig(n_points=args.points, knn=args.neighbours))
    if args.reuse_angle:
        variants[f"codes reused within {args.reuse_angle:g} deg"] = NDFEncoder()
    for encoder in variants.values():
        encoder.runtime = TimedRuntime(encoder.runtime)
    print(f"{args.target}: {count} frames, {sum(len(c) for c, _ in frames)} observations")
    codes = {}
    for run in range(args.repeat):
        for name, encoder in variants.items():
            encoder.runtime.seconds = dict.fromkeys(encoder.runtime.seconds, 0.0)
            started = time.process_time()
            if name.startswith("codes reused"):
                reuse = CodeReuse(encoder, ReuseConfig(angle_deg=args.reuse_angle))
                for clouds, pose in all_frames:
                    reuse.encode(clouds, pose, full_reconstruction=False)
                total = (time.process_time() - started) * 1e3 / count
                print(f"run {run + 1}, {name}: encoding {total:.2f} CPU ms per frame ({reuse.encoded} observations "
                      f"encoded, {reuse.reused} reused)", flush=True)
                continue
            codes[name] = [code for clouds, pose in frames
                           for code in encoder.encode_batch(clouds, [pose] * len(clouds), full_reconstruction=False)]
            total = (time.process_time() - started) * 1e3 / count
            network, occupancy = (seconds * 1e3 / count for seconds in encoder.runtime.seconds.values())
            print(f"run {run + 1}, {name}: encoding {total:.2f} CPU ms per frame (network {network:.2f}, "
                  f"occupancy {occupancy:.2f}, the rest {total - network - occupancy:.2f})", flush=True)
    reference = next(iter(codes))
    for name in list(codes)[1:]:
        cosine = [a.shape_code @ b.shape_code / np.linalg.norm(a.shape_code) / np.linalg.norm(b.shape_code)
                  for a, b in zip(codes[reference], codes[name])]
        shift = [np.linalg.norm(a.center_world - b.center_world) * 1e3 for a, b in zip(codes[reference], codes[name])]
        print(f"{name} against {reference}: codes' cosine min {min(cosine):.6f}, median {np.median(cosine):.4f}; "
              f"centers apart median {np.median(shift):.4f} mm, max {max(shift):.4f} mm")


if __name__ == "__main__":
    sys.exit(main())
