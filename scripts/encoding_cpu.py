"""CPU time of the NDF's encoding on a recording's observations, variants alternating in one process.

    python scripts/encoding_cpu.py TARGET.mcap [--repeat 3] [--points 224 --neighbours 10] [--before REV]

The observations are perceived once (masks, as `ndfa detect` extracts them); then each variant
runs `NDFEncoder.encode_batch` over all of them, frame by frame as the pipeline calls it (the
reconstruction decoded only as far as decisions need), and prints this process's CPU ms per frame
(`time.process_time`: another job's share of the cores does not count), split into the encoder
network, the occupancy network and the rest. Variants: the shipped encoder; with --points /
--neighbours also that; with --before REV also the encode graph of `ndfa/ndf/export_onnx.py` as
it was at git revision REV. The first variant is the reference of the codes' agreement printed.
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
from ndfa.ndf.encoder import EncoderConfig, NDFEncoder
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


def before_encoder(revision: str) -> NDFEncoder:
    """The shipped encoder with the encode graph of `revision`'s export_onnx.py."""
    source = subprocess.run(["git", "show", f"{revision}:ndfa/ndf/export_onnx.py"], check=True,
                            capture_output=True, text=True).stdout
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "export_before.py"
        path.write_text(source)
        spec = importlib.util.spec_from_file_location("export_before", path)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    encoder = NDFEncoder(config=EncoderConfig(runtime="onnxruntime"))
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
    parser.add_argument("--before", help="git revision whose encode graph to time too")
    args = parser.parse_args()

    perceive = ChangeDetectionPipeline(PipelineConfig(), encoder=NDFEncoder()).perceive
    frames, count = [], 0
    for frame in RecordingReader(args.target).frames():
        count += 1
        observed = perceive(frame)
        if observed.observations:
            frames.append(([o.points_camera for o in observed.observations], frame.pose_world_camera))
    variants = {"shipped": NDFEncoder()}
    if args.before:
        variants = {f"graph of {args.before}": before_encoder(args.before)} | variants
    if args.points or args.neighbours:
        variants[f"points {args.points}, neighbours {args.neighbours}"] = NDFEncoder(
            config=EncoderConfig(n_points=args.points, knn=args.neighbours))
    for encoder in variants.values():
        encoder.runtime = TimedRuntime(encoder.runtime)
    print(f"{args.target}: {count} frames, {sum(len(c) for c, _ in frames)} observations")
    codes = {}
    for run in range(args.repeat):
        for name, encoder in variants.items():
            encoder.runtime.seconds = dict.fromkeys(encoder.runtime.seconds, 0.0)
            started = time.process_time()
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
