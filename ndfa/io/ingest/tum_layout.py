"""What a TUM RGB-D folder holds: its file names, the published calibrations and calibration.txt.

Shared by the importer (`tum_folder.py`) and the exporter (`ndfa.io.export.tum`), and light (no
image or scipy imports), so that the CLI can quote the defaults in its help.
See https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats.
"""

from __future__ import annotations

from pathlib import Path

from ndfa.core.errors import IngestError

RGB_LIST = "rgb.txt"
DEPTH_LIST = "depth.txt"
GROUNDTRUTH = "groundtruth.txt"
# ndfa's extensions, written by its exporter (see tum_folder.py's docstring).
CALIBRATION = "calibration.txt"
GROUND_TRUTH_JSON = "ndfa_ground_truth.json"
TRUE_POSES = "ndfa_true_poses.txt"
MASKS_DIR = "masks"  # used when no masks folder is given and the TUM folder has one

# Published TUM calibrations (fx, fy, cx, cy) of the colour camera, per Freiburg sensor. fr1 and fr2
# images are distorted; ndfa's pinhole model ignores the distortion coefficients.
INTRINSICS_PRESETS: dict[str, tuple[float, float, float, float]] = {
    "fr1": (517.3, 516.5, 318.6, 255.3),
    "fr2": (520.9, 521.0, 325.1, 249.7),
    "fr3": (535.4, 539.2, 320.1, 247.6),
}
# TUM's "ROS default" calibration, which the dataset recommends when the sensor is unknown.
DEFAULT_INTRINSICS = (525.0, 525.0, 319.5, 239.5)

# Depth PNG units per metre (TUM: 5000, i.e. 0.2 mm).
DEPTH_SCALE = 5000.0

Intrinsics = str | tuple[float, float, float, float] | None


def read_calibration(path: Path) -> tuple[float, float, float, float]:
    """fx fy cx cy from the first non-comment line of a calibration.txt."""
    try:
        lines = [line.split() for line in path.read_text().splitlines() if line.strip() and not line.lstrip().startswith("#")]
        fx, fy, cx, cy = (float(v) for v in lines[0][:4])
    except (OSError, UnicodeDecodeError, IndexError, ValueError):
        raise IngestError(f"{path}: expected a line 'fx fy cx cy' (pixels)") from None
    return fx, fy, cx, cy
