"""Camera trajectories through the room: a route of waypoints, smoothed and resampled at a fixed
step, with the camera at mug height facing the nearest table (the paper's setting).

Routes are built from the table layout, so they work for any grid:

- `perimeter`: a closed loop around all tables, each table seen from its outer side;
- `corridor`: along the corridor between the first two rows (closer to the first row, so it faces
  that row from the inside), then back along the outside of the last row;
- `weave`: a serpentine through the gaps between table columns;
- `circles`: once around each table in turn.

Two sessions on different routes see some tables from opposite sides, which is exactly the low
view overlap the method is built for.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ndfa.core.errors import SimError
from ndfa.core.geometry import look_at
from ndfa.sim.handheld import MOTIONS, HandheldMotion, handheld_poses, walking_arc_lengths
from ndfa.sim.scene import Table

ROUTES = ("perimeter", "corridor", "weave", "circles")
# The gaze limit of a raw (sensor-like) recording: a quick hand-held turn, 100 deg/s at the
# simulator's 5 frames/s; at a 60 deg field of view two frames still share two thirds of the view.
RAW_MAX_TURN_DEG = 20.0
# The most frames one route may take: at the default 8 cm step a route of 800 m, beyond any room;
# past it a tiny step only eats memory (1e-6 m: 3.6 GB in seconds) before any frame is rendered.
MAX_ROUTE_FRAMES = 10_000


@dataclass(frozen=True)
class TrajectoryConfig:
    route: str = "perimeter"
    step_m: float = 0.08            # camera travel between frames (hand-held: its mean)
    clearance_m: float = 0.75       # route distance from table edges
    height_above_table_m: float = 0.25  # camera height over the table top, before the height wobble
    height_wobble_m: float = 0.05   # smooth random height variation (the paper trains on +-0.1 m)
    look_height_m: float = 0.06     # the camera looks at this height above the nearest table's centre
    smoothing_m: float = 0.35       # Gaussian smoothing length of the route's corners and of the gaze
    # Most the gaze turns between two frames, degrees; 0: unlimited. Where the nearest table
    # changes sides, the smoothed gaze target can pass under the camera and the view whips round by
    # over 100 deg in one frame, which no real camera does and no odometry can follow. Off keeps the
    # published scenes' routes (with given poses the whips do not matter); `ingest sim --raw` sets it.
    max_turn_deg: float = 0.0
    # "smooth" (the gaze above) or "handheld" (`ndfa.sim.handheld`: sweeps, pitch towards the desks,
    # shake, at the recording's frame rate; max_turn_deg then plays no part).
    motion: str = "smooth"
    handheld: HandheldMotion = HandheldMotion()

    def __post_init__(self) -> None:
        if self.motion not in MOTIONS:
            raise SimError(f"unknown camera motion {self.motion!r}; expected one of {MOTIONS}")


def camera_poses(tables: list[Table], config: TrajectoryConfig, rng: np.random.Generator,
                 fps: float = 5.0) -> np.ndarray:
    """Camera-to-world poses (N, 4, 4) along `config.route`, one per frame at `fps` (which only
    the hand-held motion's rates depend on)."""
    waypoints, closed = route_waypoints(tables, config.route, config.clearance_m)
    loop = np.vstack([waypoints, waypoints[:1]]) if closed else waypoints
    frames = float(np.linalg.norm(np.diff(loop, axis=0), axis=1).sum()) / config.step_m
    if not 2 <= frames <= MAX_ROUTE_FRAMES:
        raise SimError(f"the {config.route} route is {frames * config.step_m:.1f} m long: a step of "
                       f"{config.step_m:g} m gives {frames:.0f} frames, outside 2-{MAX_ROUTE_FRAMES}; choose a step "
                       f"from {frames * config.step_m / MAX_ROUTE_FRAMES:.3g} to {frames * config.step_m / 2:.3g} m")
    if config.motion == "handheld":  # a person's pace drifts; step_m is its mean
        fine = smooth_resample(waypoints, config.step_m / 8, config.smoothing_m, closed)
        arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(fine, axis=0), axis=1))]
        walked = walking_arc_lengths(float(arc[-1]), config.step_m, fps, config.handheld, rng)
        positions_xy = np.stack([np.interp(walked, arc, fine[:, d]) for d in range(2)], axis=1)
    else:
        positions_xy = smooth_resample(waypoints, config.step_m, config.smoothing_m, closed)
    targets = np.array([_gaze_target(tables, p, config.look_height_m) for p in positions_xy])
    # Smoothing the gaze turns the camera gradually where the nearest table changes.
    targets = _gaussian_smooth(targets, config.smoothing_m / config.step_m, closed)
    table_height = max(t.height for t in tables)
    wobble = _gaussian_smooth(rng.normal(size=(len(positions_xy), 1)), 1.0 / config.step_m, closed)[:, 0]
    wobble *= config.height_wobble_m / max(np.abs(wobble).max(), 1e-9)
    heights = table_height + config.height_above_table_m + wobble
    eyes = np.c_[positions_xy, heights]
    if config.motion == "handheld":
        return handheld_poses(eyes, targets, fps, config.handheld, rng)
    if config.max_turn_deg > 0:
        targets = eyes + limit_turns(targets - eyes, config.max_turn_deg)
    return np.stack([look_at(eye, target) for eye, target in zip(eyes, targets)])


def limit_turns(gazes: np.ndarray, max_turn_deg: float, max_down_deg: float = 30.0) -> np.ndarray:
    """Unit gaze directions (N, 3) that follow `gazes` but turn at most `max_turn_deg` per step in
    heading (about world up) and in pitch, and look at most `max_down_deg` below the horizon. A whip
    becomes a quick pan over a few frames; a turn under the limit is kept as it is. Heading and
    pitch are limited apart because a great-circle turn between two opposite headings passes
    through "straight down", which is the whip again; the pitch bound keeps the camera off the
    floor where the smoothed target passes under it."""
    gazes = np.asarray(gazes, dtype=float)
    limit, lowest = np.radians(max_turn_deg), np.radians(max_down_deg)
    out = np.empty_like(gazes)
    heading = pitch = 0.0
    for i, gaze in enumerate(gazes):
        horizontal = float(np.linalg.norm(gaze[:2]))
        wanted_heading = float(np.arctan2(gaze[1], gaze[0])) if horizontal > 1e-9 else heading
        wanted_pitch = max(float(np.arctan2(gaze[2], horizontal)), -lowest)
        if i == 0:
            heading, pitch = wanted_heading, wanted_pitch
        else:
            turn = (wanted_heading - heading + np.pi) % (2 * np.pi) - np.pi
            heading += float(np.clip(turn, -limit, limit))
            pitch += float(np.clip(wanted_pitch - pitch, -limit, limit))
        out[i] = [np.cos(pitch) * np.cos(heading), np.cos(pitch) * np.sin(heading), np.sin(pitch)]
    return out


def route_waypoints(tables: list[Table], route: str, clearance: float) -> tuple[np.ndarray, bool]:
    """Waypoints (M, 2) of a named route and whether it is closed."""
    corners = np.concatenate([_corners_xy(t) for t in tables])
    lo, hi = corners.min(axis=0) - clearance, corners.max(axis=0) + clearance
    if route == "perimeter":
        return np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]]), True
    rows = _rows(tables)
    if route == "corridor":
        if len(rows) < 2:
            return np.array([[lo[0], hi[1]], [hi[0], hi[1]]]), False
        first_top = max(_corners_xy(t)[:, 1].max() for t in rows[0])
        second_bottom = min(_corners_xy(t)[:, 1].min() for t in rows[1])
        corridor_y = first_top + 0.4 * (second_bottom - first_top)
        return np.array([[lo[0], corridor_y], [hi[0], corridor_y], [hi[0], hi[1]], [lo[0], hi[1]]]), False
    if route == "weave":
        columns = sorted({round(t.center_xy[0], 3) for t in tables})
        gaps = [lo[0]] + [(a + b) / 2 for a, b in zip(columns, columns[1:])] + [hi[0]]
        points = []
        for i, x in enumerate(gaps):
            ys = (lo[1], hi[1]) if i % 2 == 0 else (hi[1], lo[1])
            points += [[x, ys[0]], [x, ys[1]]]
        return np.array(points), False
    if route == "circles":
        # Serpentine table order, so consecutive tables are grid neighbours; each circle starts
        # facing the previous table and ends facing the next, so links run through the gaps.
        order = [t for i, row in enumerate(rows) for t in (row if i % 2 == 0 else row[::-1])]
        centers = np.array([t.center_xy for t in order])
        # Circles pass between neighbouring tables, so they may have to keep closer than corridors.
        gap = min((a.distance_xy(_corners_xy(b)).min() for a in tables for b in tables if a is not b), default=np.inf)
        circle_clearance = min(clearance, 0.4 * gap)
        points = []
        for k, table in enumerate(order):
            toward = lambda j: np.arctan2(*(centers[j] - centers[k])[::-1])  # noqa: E731
            start = toward(k - 1) if k > 0 else -np.pi / 2
            end = toward(k + 1) if k + 1 < len(order) else start
            sweep = 2 * np.pi + (end - start) % (2 * np.pi)
            angles = start + np.linspace(0.0, sweep, int(np.ceil(sweep / (np.pi / 12))) + 1)
            points += list(_around_table(table, angles, circle_clearance))
        return np.array(points), False
    raise SimError(f"unknown camera route {route!r}; expected one of {ROUTES}")


def smooth_resample(waypoints: np.ndarray, step: float, smoothing: float, closed: bool) -> np.ndarray:
    """Points every `step` metres along the polyline through `waypoints`, corners rounded by a
    Gaussian of `smoothing` metres."""
    dense = _resample_polyline(waypoints, step / 4, closed)
    dense = _gaussian_smooth(dense, smoothing / (step / 4), closed)
    return _resample_polyline(dense, step, closed=False)


def _resample_polyline(points: np.ndarray, spacing: float, closed: bool) -> np.ndarray:
    if closed:
        points = np.vstack([points, points[:1]])
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))]
    samples = np.arange(0.0, arc[-1], spacing)
    return np.stack([np.interp(samples, arc, points[:, d]) for d in range(points.shape[1])], axis=1)


def _gaussian_smooth(values: np.ndarray, sigma_samples: float, closed: bool) -> np.ndarray:
    """Gaussian filter along axis 0; open sequences keep their ends by edge padding."""
    radius = int(np.ceil(3 * sigma_samples))
    if radius < 1:
        return values
    kernel = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma_samples) ** 2)
    kernel /= kernel.sum()
    padded = np.pad(values, ((radius, radius), (0, 0)), mode="wrap" if closed else "edge")
    return np.stack([np.convolve(padded[:, d], kernel, mode="valid") for d in range(values.shape[1])], axis=1)


def _gaze_target(tables: list[Table], position_xy: np.ndarray, look_height: float) -> np.ndarray:
    distances = [t.distance_xy(position_xy[None])[0] for t in tables]
    nearest = tables[int(np.argmin(distances))]
    return np.array([*nearest.center_xy, nearest.height + look_height])


def _around_table(table: Table, angles: np.ndarray, clearance: float) -> np.ndarray:
    """Points at `clearance` from the table's rectangle (a rounded rectangle), by polar angle."""
    half = np.array(table.size_xy) / 2
    far = 100.0 * np.c_[np.cos(angles - table.yaw), np.sin(angles - table.yaw)]
    on_edge = np.clip(far, -half, half)
    away = far - on_edge
    local = on_edge + clearance * away / np.linalg.norm(away, axis=1, keepdims=True)
    c, s = np.cos(table.yaw), np.sin(table.yaw)
    return local @ np.array([[c, s], [-s, c]]) + np.array(table.center_xy)


def _corners_xy(table: Table) -> np.ndarray:
    half = np.array(table.size_xy) / 2
    local = np.array([[sx * half[0], sy * half[1], 0.0, 1.0] for sx in (-1, 1) for sy in (-1, 1)])
    return (local @ table.pose_world_top.T)[:, :2]


def _rows(tables: list[Table]) -> list[list[Table]]:
    """Tables grouped by their centre's y, from low to high y."""
    ys = sorted({round(t.center_xy[1], 3) for t in tables})
    return [[t for t in tables if round(t.center_xy[1], 3) == y] for y in ys]
