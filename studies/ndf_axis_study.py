"""How fast an NDF encoder learns a mug's axis and center: train only the frame and center losses
for a few hundred steps and print the validation errors every 50 steps.

    python studies/ndf_axis_study.py STEPS [NDFConfig field=JSON value ...] [lr=...]   (decoder "frame" always)
    python studies/ndf_axis_study.py 200 pooling='"mean"'   # 2026-11-23: axis 67 deg, center 20 mm
    python studies/ndf_axis_study.py 200 pooling='"max"'    #             axis 53 deg, center 17 mm

Uses the views `ndfa train --data-dir out/ndf-data` caches (run that first; the figures above are
from the default 400-mug cache, pass train='"out/ndf-data/train-....npz"' to choose); one thread.
"""

import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from ndfa.ndf.config import NDFConfig
from ndfa.ndf.model import NDFModel
from ndfa.training.batches import sample_batch
from ndfa.training.dataset import load_dataset
from ndfa.training.losses import center_loss, frame_loss


def main() -> None:
    torch.set_num_threads(1)
    torch.manual_seed(0)
    steps = int(sys.argv[1])
    options = {key: json.loads(value) for key, value in (arg.split("=", 1) for arg in sys.argv[2:])}
    lr = options.pop("lr", 6e-4)  # also train="PATH" and val="PATH": dataset files (default: the first cached)
    data = Path("out/ndf-data")
    train = load_dataset(options.pop("train", None) or sorted(data.glob("train-*.npz"))[0])
    val = load_dataset(options.pop("val", None) or sorted(data.glob("val-*.npz"))[0])
    model = NDFModel(NDFConfig(**(options | {"decoder": "frame"})))  # the frame loss needs its frame vectors
    optimizer = torch.optim.Adam(model.parameters(), lr=lr)
    rng = np.random.default_rng(0)
    started = time.time()
    for step in range(1, steps + 1):
        batch = sample_batch(train, 16, rng)
        centroid = batch["points"].mean(1, keepdim=True)
        z = model.encode(batch["points"] - centroid)
        loss = frame_loss(model.frame_vectors(z), batch["rotation"]) + center_loss(
            model.center_offset(z), batch["center"] - centroid[:, 0], model.config.input_scale)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        if step % 50 == 0:
            axis_deg, center_mm = validate(model, val)
            print(f"step {step}: axis {axis_deg:.1f} deg, center {center_mm:.1f} mm (median), {time.time() - started:.0f} s")


@torch.no_grad()
def validate(model: NDFModel, val: dict, views: int = 128) -> tuple[float, float]:
    model.eval()
    points = torch.from_numpy(val["points"][:views])
    centroid = points.mean(1, keepdim=True)
    z = model.encode(points - centroid)
    true_axis = torch.from_numpy(val["pose_camera_object"][:views, :3, 2])
    cosine = torch.cosine_similarity(model.frame_vectors(z)[..., 0], true_axis, dim=-1).clamp(-1, 1)
    center = centroid[:, 0] + model.center_offset(z)
    model.train()
    return (torch.rad2deg(torch.arccos(cosine)).median().item(),
            1e3 * (center - torch.from_numpy(val["center"][:views])).norm(dim=1).median().item())


if __name__ == "__main__":
    main()
