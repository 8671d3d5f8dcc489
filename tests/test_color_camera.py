"""The colour camera of a recording whose colour is not registered to its depth (7-Scenes): the
colour carried onto the depth pixels, the meta it is kept in, and the import option that writes it."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from ndfa.cli import app
from ndfa.core.color_camera import ColorCamera
from ndfa.core.errors import OptionError
from ndfa.io.recording import RecordingReader
from ndfa.trajectory.rgbd_config import RgbdOdometryConfig
from ndfa.trajectory.session import rgbd_config_for
from tests.test_tum import make_folder

DEPTH_K = np.array([[585.0, 0.0, 320.0], [0.0, 585.0, 240.0], [0.0, 0.0, 1.0]])
KINECT_COLOUR = ColorCamera(525.0, 525.0, 321.0, 240.0, -0.025)


def pattern(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Grey level of the wall's point (x, y) in the depth camera's frame: smooth stripes, 0-250."""
    return 125.0 + 125.0 * np.sin(40.0 * x) * np.cos(25.0 * y)


def colour_image_of_wall(camera: ColorCamera, distance_m: float) -> np.ndarray:
    """What the colour camera sees of a wall `distance_m` in front of the depth camera."""
    rows, cols = np.indices((480, 640), dtype=np.float64)
    x = (cols - camera.cx) / camera.fx * distance_m - camera.offset_x_m  # back in the depth camera's frame
    y = (rows - camera.cy) / camera.fy * distance_m
    grey = np.round(pattern(x, y)).astype(np.uint8)
    return np.repeat(grey[..., None], 3, axis=2)


def test_registration_puts_each_depth_pixels_colour_on_it():
    distance = 2.0
    rgb = colour_image_of_wall(KINECT_COLOUR, distance)
    depth = np.full((480, 640), distance, np.float32)
    depth[:40] = 0.0  # pixels without depth take the colour at the median depth: the same wall here
    registered = KINECT_COLOUR.register_to_depth(rgb, depth, DEPTH_K)
    rows, cols = np.indices(depth.shape, dtype=np.float64)
    expected = pattern((cols - 320.0) / 585.0 * distance, (rows - 240.0) / 585.0 * distance)
    inner = (slice(20, 460), slice(20, 620))
    assert np.abs(registered[..., 0].astype(float) - expected)[inner].mean() < 2.0
    # As it was, the colour sits up to 30 px from its depth pixel: far from the wall's grey there.
    assert np.abs(rgb[..., 0].astype(float) - expected)[inner].mean() > 20.0


def test_the_colour_camera_is_parsed_and_kept_in_the_meta():
    camera = ColorCamera.parse("525,525,321,240,-0.025")
    assert camera == KINECT_COLOUR and ColorCamera.parse("500,501,3,4").offset_x_m == 0.0
    assert ColorCamera.from_meta({"color_camera": camera.to_meta()}) == camera
    assert ColorCamera.from_meta({}) is None
    for text in ("525,525,321", "a,b,c,d", "0,525,321,240", "525,525,321,nan"):
        with pytest.raises(ValueError):
            ColorCamera.parse(text)
    assert rgbd_config_for({"color_camera": camera.to_meta()}).color_camera == camera
    assert rgbd_config_for({}) == RgbdOdometryConfig()


def test_ingest_tum_keeps_the_colour_camera_and_refuses_a_bad_one(tmp_path):
    folder = make_folder(tmp_path / "tum")
    runner = CliRunner()
    result = runner.invoke(app, ["ingest", "tum", str(folder), "--out", str(tmp_path / "a.mcap"),
                                 "--color-intrinsics", "525,525,321,240,-0.025"])
    assert result.exit_code == 0, result.output
    assert ColorCamera.from_meta(RecordingReader(tmp_path / "a.mcap").meta) == KINECT_COLOUR
    result = runner.invoke(app, ["ingest", "tum", str(folder), "--out", str(tmp_path / "b.mcap"),
                                 "--color-intrinsics", "525,525"])
    assert isinstance(result.exception, OptionError) and "--color-intrinsics" in str(result.exception)  # exit 2
    assert not (tmp_path / "b.mcap").exists()
