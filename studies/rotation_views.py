"""Which views give a reliable handle heading (docs/rotation.md): every `STEP`-th frame of simulated
recordings encoded with the shipped NDF, one row per view with its heading, strength and error
against the ground truth's handle direction, plus what the simulator knows of the view (distance,
mask size, the angle between the handle and the direction to the camera); then the error by
handle view, distance, mask size and strength.

    python studies/rotation_views.py OUT.parquet STEP REC.mcap [REC.mcap ...]
    python studies/rotation_views.py out/views.parquet 2 out/paper/source.mcap out/paper/target.mcap \\
        out/random{1,2,3,4,5}/source.mcap          # the figures of docs/rotation.md, ~3 min

Views that touch the image border are left out of the figures (the detector skips them).
"""

import sys

import numpy as np
import polars as pl
import torch

from ndfa.io.recording.reader import RecordingReader
from ndfa.ndf.encoder import NDFEncoder
from ndfa.perception.observations import extract_observations

STRENGTH = 0.15  # RotationConfig.heading_strength (the study's own)


def views(paths: list[str], step: int) -> pl.DataFrame:
    encoder = NDFEncoder()
    rows = []
    for path in paths:
        reader = RecordingReader(path)
        session = reader.meta["session"]
        truth = {o["instance_id"]: np.array(o[session]["pose_world_object"])
                 for o in (reader.ground_truth or {}).get("objects", []) if o.get(session)}
        for frame in reader.frames(step=step):
            # The object poses are in the true world: encode with the true camera pose.
            pose = frame.pose_world_camera if frame.pose_world_camera_true is None else frame.pose_world_camera_true
            observations = [o for o in extract_observations(frame)[0] if o.instance_id in truth]
            codes = encoder.encode_batch([o.points_camera for o in observations], [pose] * len(observations))
            for observation, code in zip(observations, codes):
                pose_object = truth[observation.instance_id]
                handle = pose_object[:3, 0]  # the mug frame's +x (ndfa.sim.mug)
                to_camera = pose[:2, 3] - pose_object[:2, 3]
                cosine = to_camera @ handle[:2] / np.linalg.norm(to_camera) / np.linalg.norm(handle[:2])
                error = np.degrees(code.heading_rad - np.arctan2(handle[1], handle[0]))
                rows.append({
                    "recording": path, "frame": frame.index, "instance_id": observation.instance_id,
                    "n_pixels": observation.n_pixels, "border": observation.touches_border,
                    "distance_m": float(np.linalg.norm(pose[:3, 3] - pose_object[:3, 3])),
                    "handle_view_deg": float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))),
                    "strength": code.heading_strength, "error_deg": float(abs((error + 180.0) % 360.0 - 180.0))})
    return pl.DataFrame(rows)


def summary(table: pl.DataFrame, by: pl.Expr) -> pl.DataFrame:
    strong = pl.col("strength") >= STRENGTH
    return table.group_by(by.alias("views")).agg(
        pl.len().alias("n"), strong.mean().alias("strong share"),
        pl.col("error_deg").median().alias("median, all"), (pl.col("error_deg") < 20).mean().alias("<20, all"),
        pl.col("error_deg").filter(strong).median().alias("median, strong"),
        (pl.col("error_deg").filter(strong) < 20).mean().alias("<20, strong")).sort("views")


def _bins(value: pl.Expr, edges: tuple[float, float], unit: str) -> pl.Expr:
    low, high = edges
    return (pl.when(value < low).then(pl.lit(f"a: < {low:g} {unit}")).when(value < high)
            .then(pl.lit(f"b: {low:g}-{high:g} {unit}")).otherwise(pl.lit(f"c: >= {high:g} {unit}")))


def main() -> None:
    torch.set_num_threads(1)
    out, step, paths = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
    table = views(paths, step)
    table.write_parquet(out)
    table = table.filter(~pl.col("border"))
    pl.Config.set_tbl_rows(20)
    print(f"{len(table)} views")
    print(summary(table, (pl.col("handle_view_deg") // 45 * 45).cast(pl.Int64)))
    print(summary(table, _bins(pl.col("distance_m"), (1.0, 2.0), "m")))
    print(summary(table, _bins(pl.col("n_pixels"), (1000, 3000), "px")))
    for bar in (0.05, 0.1, 0.15, 0.25):
        chosen = table.filter(pl.col("strength") >= bar)["error_deg"]
        print(f"strength >= {bar}: {len(chosen) / len(table):.0%} of the views, median {chosen.median():.1f} deg, "
              f"within 20 deg {(chosen < 20).mean():.0%}, beyond 45 deg {(chosen > 45).mean():.1%}")


if __name__ == "__main__":
    main()
