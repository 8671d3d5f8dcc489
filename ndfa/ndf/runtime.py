"""Where the NDF runs at detection time: ONNX Runtime when it is installed, torch otherwise.

Both runtimes take and return numpy arrays (float32) and compute the same thing
(`ndfa.ndf.export_onnx` says how the graphs are made; `tests/test_ndf_runtime.py` how close they
agree). Torch stays the runtime of training and of `ndfa ndf-eval`.

Threads and waiting. ONNX Runtime gets `threads` intra-op threads, runs its nodes one after the
other (the graphs are chains: inter-op parallelism has nothing to overlap) and does not spin:
by default its idle workers busy-wait for the next op, which on a machine shared with one busy
process turned every op into a wait for a descheduled spinner (torch's OpenMP pool did the same:
3.2x slower beside one `while True: pass`). `threads=1` (the default) is the steady choice: the
whole pass is then one thread, and another busy process on a 2-core machine takes the other
core. Torch's threads are process-wide (`torch.set_num_threads`); `ndfa detect --threads` and
`ndfa bench detect --threads` set them.
"""

from __future__ import annotations

import importlib.util
from typing import Protocol

import numpy as np
import torch

from ndfa.core.errors import ModelError
from ndfa.ndf.export_onnx import CATEGORY_OUTPUT, ENCODE_OUTPUTS, export_onnx
from ndfa.ndf.model import NDFModel

RUNTIMES = ("auto", "onnxruntime", "torch")
# What `NDFRuntime.encode` returns: z, shape code, center offset, category probabilities (or None).
Encoded = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]


class NDFRuntime(Protocol):
    """The NDF's two detection-time calls, on numpy arrays."""

    name: str

    def encode(self, points: np.ndarray, up: np.ndarray, view_ray: np.ndarray) -> Encoded:
        """Centred points `[B, N, 3]`, up and view ray `[B, 3]` -> z `[B, k, 3]`, shape code
        `[B, D]`, center offset `[B, 3]` (metres), and the category probabilities `[B, C]` of a
        model with a category head (`NDFConfig.categories`; None without one)."""
        ...

    def occupancy(self, z: np.ndarray, queries: np.ndarray, points: np.ndarray) -> np.ndarray:
        """z `[B, k, 3]`, centred queries `[B, Q, 3]` and points `[B, N, 3]` -> occupancy `[B, Q]`."""
        ...


class TorchRuntime:
    """The model itself (`NDFModel`)."""

    name = "torch"

    def __init__(self, model: NDFModel) -> None:
        self.model = model

    @torch.inference_mode()
    def encode(self, points: np.ndarray, up: np.ndarray, view_ray: np.ndarray) -> Encoded:
        z = self.model.encode(torch.from_numpy(points), torch.from_numpy(up), torch.from_numpy(view_ray))
        code = self.model.shape_code(z)
        probabilities = None if self.model.category_head is None else \
            torch.softmax(self.model.category_logits(code), dim=-1).numpy()
        return z.numpy(), code.numpy(), self.model.center_offset(z).numpy(), probabilities

    @torch.inference_mode()
    def occupancy(self, z: np.ndarray, queries: np.ndarray, points: np.ndarray) -> np.ndarray:
        logits = self.model.occupancy_logits(torch.from_numpy(z), torch.from_numpy(queries), torch.from_numpy(points))
        return torch.sigmoid(logits).numpy()


class OnnxRuntime:
    """The model exported to ONNX in memory (`export_onnx`) and run by ONNX Runtime on the CPU."""

    name = "onnxruntime"

    def __init__(self, model: NDFModel, n_points: int, threads: int = 1) -> None:
        import onnxruntime

        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        options.execution_mode = onnxruntime.ExecutionMode.ORT_SEQUENTIAL
        options.graph_optimization_level = onnxruntime.GraphOptimizationLevel.ORT_ENABLE_ALL
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")  # wait passively (module doc)
        options.log_severity_level = 3  # errors only: no notes about the graph on stderr
        encode, occupancy = export_onnx(model, n_points)
        providers = ["CPUExecutionProvider"]
        self._encode = onnxruntime.InferenceSession(encode, options, providers=providers)
        self._occupancy = onnxruntime.InferenceSession(occupancy, options, providers=providers)
        self._outputs = list(ENCODE_OUTPUTS) + [CATEGORY_OUTPUT] * (model.category_head is not None)
        self.threads = threads

    def encode(self, points: np.ndarray, up: np.ndarray, view_ray: np.ndarray) -> Encoded:
        # By name: a model with categories has a fourth output, the category probabilities.
        outputs = self._encode.run(self._outputs, {"points": points, "up": up, "view_ray": view_ray})
        return outputs[0], outputs[1], outputs[2], outputs[3] if len(outputs) > 3 else None

    def occupancy(self, z: np.ndarray, queries: np.ndarray, points: np.ndarray) -> np.ndarray:
        occupancy: np.ndarray = self._occupancy.run(None, {"z": z, "queries": queries, "points": points})[0]
        return occupancy


def onnxruntime_available() -> bool:
    """ONNX Runtime and onnx (which torch's exporter needs to write the graphs) are installed."""
    return all(importlib.util.find_spec(name) is not None for name in ("onnxruntime", "onnx"))


def make_runtime(model: NDFModel, n_points: int, runtime: str = "auto", threads: int = 1) -> NDFRuntime:
    """The runtime named (`RUNTIMES`); "auto": ONNX Runtime when installed, else torch."""
    if runtime not in RUNTIMES:
        raise ModelError(f"unknown NDF runtime {runtime!r}; expected one of {RUNTIMES}")
    if threads < 1:
        raise ModelError(f"NDF runtime threads must be >= 1, got {threads}")
    # The export covers mean pooling (the shipped weights'); a max-pooling model runs in torch.
    exportable = model.config.pooling == "mean"
    if runtime == "torch" or (runtime == "auto" and not (onnxruntime_available() and exportable)):
        return TorchRuntime(model)
    if not exportable:
        raise ModelError("the onnxruntime NDF runtime covers mean-pooling models only; choose the torch runtime")
    if not onnxruntime_available():
        raise ModelError("the NDF runtime onnxruntime needs the packages onnxruntime and onnx "
                         "(pip install onnxruntime onnx), or choose the torch runtime")
    return OnnxRuntime(model, n_points, threads)
