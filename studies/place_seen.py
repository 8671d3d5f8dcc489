"""What one session's frames showed of a place, frame by frame, as the detector's place rule judges
it (`ndfa.change.sight`): whole in view, the pixels a large mug there would have given, the share
not hidden, and whether the depth passed through the place (seen empty) or ended in it.

    python studies/place_seen.py RECORDING --at=X,Y,Z [--step 2] [--session source]

X,Y,Z: the place in the run's world (as `ndfa detect` levels the recording with its given poses: the
position column of its decisions table). docs/detector.md, "A change needs its place seen empty".
"""
import argparse

import numpy as np

from ndfa.change.config import EvidenceConfig
from ndfa.change.sight import SessionViews
from ndfa.io.recording import RecordingReader
from ndfa.run.world import prepare_session

parser = argparse.ArgumentParser()
parser.add_argument("recording")
parser.add_argument("--at", required=True, help="X,Y,Z (write --at=X,Y,Z when X is negative)")
parser.add_argument("--step", type=int, default=2)
parser.add_argument("--session", default="source")
args = parser.parse_args()
place = np.array([float(v) for v in args.at.split(",")])
size = (EvidenceConfig().sight_radius_m, EvidenceConfig().sight_height_m)
reader = RecordingReader(args.recording)
world = prepare_session(reader, args.session, poses="given")
print(world.describe())
views = SessionViews()
for frame in reader.frames(step=args.step):
    frame = world.apply(frame)
    views.add(frame.index, frame.depth, frame.K, frame.pose_world_camera)
    alone = SessionViews()
    alone.add(frame.index, frame.depth, frame.K, frame.pose_world_camera)
    seen = alone.sight(place, *size)
    if seen.in_view:
        verdict = "" if not seen.shown else ("  seen empty" if seen.seen_empty else f"  stopped {seen.stopped:.0%}")
        print(f"frame {frame.index}: {seen.distance_m:.2f} m, {seen.pixels:.0f} px, {seen.unhidden:.0%} not hidden{verdict}")
seen = views.sight(place, *size)
print(seen.describe(args.session), f"| well in {seen.well}, empty in {seen.empty}: seen empty {seen.seen_empty}")
