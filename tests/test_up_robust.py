"""World up as a robust mode of plane normals on the sphere (ndfa.trajectory.up.up_from_normals), on
synthetic normals of a handheld office: an upright camera pitched down ~20 deg towards desks,
panning, with some roll; in view a floor, desk tops, a ceiling (seen from below: its normals point
down), walls, monitors tilted back, tilted papers and clutter. The world itself is tilted, so
nothing can lean on its z."""

from __future__ import annotations

import numpy as np
import pytest

from ndfa.core.geometry import axis_angle_to_matrix
from ndfa.trajectory.up import angle_deg, cameras_up, up_from_normals

# The world's up, deliberately not z (as in an odometry world that starts at the first camera).
TILT = axis_angle_to_matrix(np.radians(35.0) * np.array([0.6, 0.8, 0.0]))
UP = TILT @ np.array([0.0, 0.0, 1.0])
# An upright camera looking along +y of a z-up world (OpenCV axes: x right, y down, z forward).
UPRIGHT = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def handheld_rotations(n: int, rng: np.random.Generator, pitch_deg: float = 20.0, pan_deg: float = 40.0,
                       roll_deg: float = 3.0) -> list[np.ndarray]:
    """Camera-to-world rotations of a handheld camera: panning over +-pan_deg, pitched down about
    pitch_deg (+-5), rolled by roll_deg (standard deviation)."""
    rotations = []
    for pan in np.linspace(-pan_deg, pan_deg, n):
        yaw = axis_angle_to_matrix([0.0, 0.0, np.radians(pan)])
        pitch = axis_angle_to_matrix([-np.radians(pitch_deg + rng.normal(0.0, 5.0)), 0.0, 0.0])
        roll = axis_angle_to_matrix([0.0, 0.0, np.radians(rng.normal(0.0, roll_deg))])
        rotations.append(TILT @ yaw @ UPRIGHT @ pitch @ roll)
    return rotations


def around(direction: np.ndarray, spread_deg: float, count: int, rng: np.random.Generator) -> np.ndarray:
    """`count` unit vectors scattered about `direction` by about spread_deg."""
    vectors = direction + np.radians(spread_deg) * rng.normal(size=(count, 3))
    return vectors / np.linalg.norm(vectors, axis=1, keepdims=True)


def tilted_from_up(angle_deg_: float, count: int, rng: np.random.Generator) -> np.ndarray:
    """Unit vectors `angle_deg_` from UP, at random headings."""
    heading = rng.uniform(0.0, 2.0 * np.pi, count)
    horizontal = np.stack([np.cos(heading), np.sin(heading), np.zeros(count)], axis=1) @ TILT.T
    angle = np.radians(angle_deg_)
    return np.cos(angle) * UP + np.sin(angle) * horizontal


def office_frame(rng: np.random.Generator, floor: float = 0.2, desks: float = 0.25, ceiling: float = 0.3,
                 walls: float = 0.5, monitors: float = 0.3, papers: float = 0.15, clutter: float = 0.3,
                 ramp: tuple[np.ndarray, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One frame's world normals and areas: each surface's share of the view given as its area (m^2),
    spread over patches of 0.001 m^2."""
    parts = [
        (around(UP, 1.0, int(floor * 1000), rng)),                                   # floor
        (around(UP, 1.5, int(desks * 1000), rng)),                                   # desk tops
        (around(-UP, 1.0, int(ceiling * 1000), rng)),                                # ceiling from below
        (tilted_from_up(90.0, int(walls * 1000), rng)),                              # walls
        (np.concatenate([around(d, 1.0, int(monitors * 250), rng)                    # monitors tilted back 15 deg
                         for d in tilted_from_up(75.0, 4, rng)])),
        (np.concatenate([around(d, 1.0, int(papers * 200), rng)                      # papers and keyboards, tilted
                         for d in tilted_from_up(rng.uniform(8.0, 35.0), 5, rng)])),
        (around(np.zeros(3), 1e4, int(clutter * 1000), rng)),                        # clutter: every direction
    ]
    if ramp is not None:
        parts.append(around(ramp[0], 1.0, int(ramp[1] * 1000), rng))
    normals = np.concatenate(parts)
    return normals, np.full(len(normals), 0.001)


def test_up_holds_in_a_cluttered_handheld_office():
    rng = np.random.default_rng(7)
    rotations = handheld_rotations(60, rng)
    frames = [office_frame(rng, floor=rng.uniform(0.0, 0.3), desks=rng.uniform(0.05, 0.3)) for _ in rotations]
    estimate = up_from_normals(rotations, [n for n, _ in frames], [a for _, a in frames])
    assert estimate.ok and estimate.method == "planes", estimate.reason
    assert angle_deg(estimate.up_world, UP) < 2.0, estimate.reason
    assert estimate.confidence == "high" and estimate.warning == "" and estimate.uncertainty_deg < 1.0
    # the cameras' mean -y is off by the pitch; the level x axes are not
    assert angle_deg(-np.mean([r[:, 1] for r in rotations], axis=0), UP) > 15.0


def test_scarce_planes_fall_back_to_the_cameras_with_a_warning():
    rng = np.random.default_rng(8)
    rotations = handheld_rotations(40, rng)
    frames = [office_frame(rng, floor=0.0, desks=0.0, papers=0.3) for _ in rotations]  # walls, screens, clutter
    estimate = up_from_normals(rotations, [n for n, _ in frames], [a for _, a in frames])
    assert estimate.ok and estimate.method == "cameras" and estimate.confidence == "low", estimate.reason
    assert "up from the cameras" in estimate.warning
    assert angle_deg(estimate.up_world, UP) < 2.0


def test_split_planes_take_the_mode_near_the_cameras_up_and_say_so():
    # A large sloped surface (a ramp 25 deg off level) as big as the desks: two modes.
    rng = np.random.default_rng(9)
    rotations = handheld_rotations(40, rng)
    ramp = tilted_from_up(25.0, 1, rng)[0]
    frames = [office_frame(rng, floor=0.0, desks=0.3, ramp=(ramp, 0.3)) for _ in rotations]
    estimate = up_from_normals(rotations, [n for n, _ in frames], [a for _, a in frames])
    assert estimate.ok and estimate.confidence == "low", estimate.reason
    assert "split" in estimate.warning
    assert angle_deg(estimate.up_world, UP) < 2.0


def test_a_camera_not_held_upright_is_refused():
    rng = np.random.default_rng(10)
    sideways = [r @ axis_angle_to_matrix([0.0, 0.0, np.radians(60.0)]) for r in handheld_rotations(30, rng)]
    frames = [office_frame(rng) for _ in sideways]
    estimate = up_from_normals(sideways, [n for n, _ in frames], [a for _, a in frames])
    assert not estimate.ok and estimate.up_world is None
    assert "not held upright" in estimate.reason


@pytest.mark.parametrize("pan_deg", [40.0, 0.0])
def test_cameras_up(pan_deg):
    # Panning: the x axes' normal (no pitch bias). Not panning: the mean -y, off by the mean pitch.
    rng = np.random.default_rng(11)
    cameras = cameras_up(np.array(handheld_rotations(50, rng, pan_deg=pan_deg, roll_deg=2.0)))
    assert cameras.up is not None
    if pan_deg:
        assert cameras.method == "level x axes" and angle_deg(cameras.up, UP) < 1.5
    else:
        assert cameras.method == "mean -y" and 15.0 < angle_deg(cameras.up, UP) < 25.0
