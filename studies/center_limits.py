"""What bounds the NDF's center head: where its error lies, and whether a larger head on the same
frozen latent z, or knowing the table, would do better. The figures the model card's "Tried on top
of v2" quotes for the center.

    python studies/center_limits.py WEIGHTS TRAIN_VIEWS.npz [--held-out-from 900] [--steps 4000]
    # TRAIN_VIEWS: the view cache `ndfa train` wrote under --data-dir (train-*.npz)

1. The model's own head on the views of the held-out mugs (mug index >= --held-out-from) within
   2 m of the camera: the median error and its parts along world up (vertical), along the
   horizontal view ray and across it.
2. Center heads of several sizes fitted on the frozen z of the other mugs' views (the same loss
   and learning rate as `ndfa train --train-only center_refit`), each from one seed: their median
   error on the held-out views and on the views they were fitted on. A head that fits better but
   does no better held-out has run out of what z says about the center.
3. The shipped head's build given the support plane too (how far the mug's base lies below the
   view's centroid along up, exact or with Gaussian noise): what a table-aware head could gain.

The views are the training views (the sensor model when the cache was made with it), all seeds of
one cache; held-out mugs were not fitted by step 2 but were seen in training the weights.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from torch import nn

from ndfa.ndf.checkpoint import load_model
from ndfa.ndf.heads import GatedCenterHead
from ndfa.ndf.vn import VNLeakyReLU, VNLinear, vn_invariant
from ndfa.training.dataset import load_dataset
from ndfa.training.validate import encode_views

BATCH, LR = 512, 6e-4  # as `ndfa train --train-only center_refit --batch-mugs 128` (two views a mug)


class VNMLPHead(nn.Module):
    """Two hidden vector-neuron layers with a linear skip: a deeper equivariant head."""

    def __init__(self, latent: int, hidden: int = 128) -> None:
        super().__init__()
        self.hidden = nn.Sequential(VNLinear(latent, hidden), VNLeakyReLU(hidden), VNLinear(hidden, hidden),
                                    VNLeakyReLU(hidden), VNLinear(hidden, 1))
        self.skip = VNLinear(latent, 1)

    def forward(self, z: torch.Tensor, plane: torch.Tensor, up: torch.Tensor) -> torch.Tensor:
        out: torch.Tensor = self.skip(z) + self.hidden(z)
        return out


class GatedHead(nn.Module):
    """`GatedCenterHead` with a chosen size, optionally told the plane (its invariant input gains
    the base's height; the output a learned multiple of up)."""

    def __init__(self, latent: int, frame: int = 4, width: int = 128, depth: int = 1, plane: bool = False) -> None:
        super().__init__()
        self.plane = plane
        self.linear, self.frame = VNLinear(latent, 1), VNLinear(latent, frame)
        inputs = latent * frame + int(plane)
        layers: list[nn.Module] = [nn.Linear(inputs, width), nn.ReLU()]
        for _ in range(depth - 1):
            layers += [nn.Linear(width, width), nn.ReLU()]
        last = nn.Linear(width, latent)
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)
        self.weights = nn.Sequential(*layers, last)
        self.along_up = nn.Sequential(nn.Linear(inputs, width), nn.ReLU(), nn.Linear(width, 1)) if plane else None

    def forward(self, z: torch.Tensor, plane: torch.Tensor, up: torch.Tensor) -> torch.Tensor:
        invariants = vn_invariant(z, self.frame(z)).flatten(1)
        if self.plane:
            invariants = torch.cat([invariants, plane[:, None]], dim=1)
        out: torch.Tensor = self.linear(z) + z @ self.weights(invariants).unsqueeze(-1)
        if self.along_up is not None:
            out = out + up.unsqueeze(-1) * self.along_up(invariants).unsqueeze(-1)
        return out


def error_parts(error: np.ndarray, up: np.ndarray, centroid: np.ndarray) -> dict[str, float]:
    """Median |error| (mm) in all, along up, along the horizontal view ray and across it."""
    ray = centroid - (centroid * up).sum(1, keepdims=True) * up
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    across = np.cross(up, ray)
    part = {"all": np.linalg.norm(error, axis=1), "vertical": (error * up).sum(1), "along ray": (error * ray).sum(1),
            "across": (error * across).sum(1)}
    return {name: float(np.median(np.abs(values)) * 1e3) for name, values in part.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("weights")
    parser.add_argument("views")
    parser.add_argument("--held-out-from", type=int, default=900)
    parser.add_argument("--steps", type=int, default=4000)
    args = parser.parse_args()
    torch.set_num_threads(2)
    model, _ = load_model(args.weights)
    model.eval()
    views = load_dataset(args.views)
    z = encode_views(model, views)
    scale, latent = model.config.input_scale, model.config.latent
    centroid = views["points"].mean(axis=1)
    up = views["pose_camera_object"][:, :3, 2]  # the mug's axis: it stands on a level table
    base = views["pose_camera_object"][:, :3, 3]  # the mug frame's origin is its base (`ndfa.sim.mug`)
    offset = torch.from_numpy((views["center"] - centroid).astype(np.float32))
    plane = torch.from_numpy((((base - centroid) * up).sum(1) * scale).astype(np.float32))
    up_t = torch.from_numpy(up.astype(np.float32))
    near = np.linalg.norm(centroid, axis=1) <= 2.0
    held_out = np.flatnonzero((views["object_index"] >= args.held_out_from) & near)
    fitted = np.flatnonzero(views["object_index"] < args.held_out_from)
    zt = z.transpose(-1, -2)

    with torch.inference_mode():
        own = model.center_offset(z[held_out]).numpy() - offset[held_out].numpy()
    parts = error_parts(own, up[held_out], centroid[held_out])
    print(f"{args.weights}: {len(held_out)} held-out views within 2 m; median |error| mm: "
          + ", ".join(f"{name} {value:.2f}" for name, value in parts.items()))

    def median_mm(head: nn.Module, rows: np.ndarray, noise_m: float) -> float:
        with torch.inference_mode():
            told = plane[rows] + noise_m * scale * torch.from_numpy(np.random.default_rng(1).standard_normal(len(rows)).astype(np.float32))
            error = head(zt[rows], told, up_t[rows]).squeeze(-1) / scale - offset[rows]
        return float(np.median(np.linalg.norm(error.numpy(), axis=1)) * 1e3)

    heads = {
        "gated (shipped build)": (lambda: _ZOnly(GatedCenterHead(model.config)), 0.0),
        "gated, 8 x 256": (lambda: GatedHead(latent, 8, 256), 0.0),
        "gated, 8 x 256 x 2 layers": (lambda: GatedHead(latent, 8, 256, 2), 0.0),
        "vector-neuron MLP 128 x 2": (lambda: VNMLPHead(latent), 0.0),
        "gated + exact plane": (lambda: GatedHead(latent, plane=True), 0.0),
        "gated + plane +- 2 mm": (lambda: GatedHead(latent, plane=True), 0.002),
        "gated + plane +- 5 mm": (lambda: GatedHead(latent, plane=True), 0.005),
    }
    print(f"{'head':28s} {'params':>8s} {'held-out':>9s} {'fitted':>7s}  (median mm, views within 2 m)")
    for name, (build, noise_m) in heads.items():
        torch.manual_seed(0)
        head = build()
        optimizer = torch.optim.Adam(head.parameters(), lr=LR)
        rng = np.random.default_rng(0)
        for _ in range(args.steps):
            rows = torch.from_numpy(rng.choice(fitted, BATCH))
            told = plane[rows] + noise_m * scale * torch.randn(BATCH)
            predicted = head(zt[rows], told, up_t[rows]).squeeze(-1) / scale
            loss = torch.linalg.vector_norm((predicted - offset[rows]) * scale, dim=1).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        params = sum(p.numel() for p in head.parameters())
        fitted_near = fitted[near[fitted]][:3000]
        print(f"{name:28s} {params:8d} {median_mm(head, held_out, noise_m):9.2f} {median_mm(head, fitted_near, noise_m):7.2f}",
              flush=True)


class _ZOnly(nn.Module):
    """A head that takes z alone (the shipped build) in the study's call."""

    def __init__(self, head: nn.Module) -> None:
        super().__init__()
        self.head = head

    def forward(self, z: torch.Tensor, plane: torch.Tensor, up: torch.Tensor) -> torch.Tensor:
        out: torch.Tensor = self.head(z)
        return out


if __name__ == "__main__":
    main()
