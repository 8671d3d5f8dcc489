"""`Frame`: one RGB-D frame in memory, as importers hand it to the writer and the reader yields it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# How far a pose's rotation may be from orthonormal. Loose on purpose: dataset poses are often
# printed with 6 decimals; this only catches matrices that are not rotations at all (scale, shear).
_ROTATION_TOLERANCE = 1e-3


@dataclass
class Frame:
    """One frame of an RGB-D sequence.

    Units and frames: depth in metres, poses in metres, images in the OpenCV camera frame
    (x right, y down, z forward). H, W are the image height and width in pixels.

    index: frame number in the session (>= 0); the recording keeps it (as the MCAP message sequence).
    timestamp: seconds (since the Unix epoch or the start of the session: whatever the source uses), >= 0.
    rgb: (H, W, 3) uint8 colour image, or None when the source has no colour.
    depth: (H, W) float32 depth along the optical axis in metres; 0.0 marks an invalid pixel.
        Recordings store millimetres, so depth comes back rounded to 1 mm.
    K: (3, 3) float64 pinhole intrinsics [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in pixels.
    pose_world_camera: (4, 4) float64 camera-to-world pose (see ndfa.core.geometry), as the method
        should use it (possibly perturbed, e.g. by odometry noise).
    instances: (H, W) uint16 instance id per pixel, 0 = no object, or None.
    pose_world_camera_true: (4, 4) float64 true camera-to-world pose, when `pose_world_camera` is
        perturbed on purpose; None otherwise.

    The constructor checks shapes and dtypes and raises ValueError (the writer and the reader turn it
    into a RecordingError that names the file). Depth of another float dtype is converted to float32,
    K and poses to float64; rgb and instances are not converted, because a silent conversion (float
    colours in [0, 1], int64 ids above 65535) would corrupt them.
    """

    index: int
    timestamp: float
    rgb: np.ndarray | None
    depth: np.ndarray
    K: np.ndarray
    pose_world_camera: np.ndarray
    instances: np.ndarray | None = None
    pose_world_camera_true: np.ndarray | None = None

    def __post_init__(self) -> None:
        if isinstance(self.depth, np.ndarray) and np.issubdtype(self.depth.dtype, np.floating):
            self.depth = self.depth.astype(np.float32, copy=False)
        self.K = np.asarray(self.K, dtype=np.float64)
        self.pose_world_camera = np.asarray(self.pose_world_camera, dtype=np.float64)
        if self.pose_world_camera_true is not None:
            self.pose_world_camera_true = np.asarray(self.pose_world_camera_true, dtype=np.float64)
        self.validate()

    @property
    def image_size(self) -> tuple[int, int]:
        """(height, width) of the frame's images in pixels."""
        return self.depth.shape[0], self.depth.shape[1]

    def validate(self) -> None:
        """Raise ValueError if a field has the wrong type, shape or dtype, or a pose is not rigid."""
        if isinstance(self.index, bool) or not isinstance(self.index, (int, np.integer)) or self.index < 0:
            raise ValueError(f"index must be an integer >= 0, got {self.index!r}")
        if not isinstance(self.timestamp, (int, float, np.number)) or not 0 <= self.timestamp < np.inf:
            raise ValueError(f"timestamp must be a finite number of seconds >= 0, got {self.timestamp!r}")

        _check_array("depth", self.depth, ndim=2, dtype=np.float32)
        height, width = self.depth.shape
        if height == 0 or width == 0:
            raise ValueError(f"depth is empty, shape {self.depth.shape}")
        if self.rgb is not None:
            _check_array("rgb", self.rgb, ndim=3, dtype=np.uint8)
            if self.rgb.shape != (height, width, 3):
                raise ValueError(f"rgb has shape {self.rgb.shape}, expected (H, W, 3) = {(height, width, 3)}")
        if self.instances is not None:
            _check_array("instances", self.instances, ndim=2, dtype=np.uint16)
            if self.instances.shape != (height, width):
                raise ValueError(f"instances has shape {self.instances.shape}, expected (H, W) = {(height, width)}")

        if self.K.shape != (3, 3) or not np.all(np.isfinite(self.K)):
            raise ValueError(f"K must be a finite (3, 3) matrix, got shape {self.K.shape}")
        if not (self.K[0, 0] > 0 and self.K[1, 1] > 0):
            # A zero focal length back-projects every pixel to infinity; the recording reader refuses it too.
            raise ValueError(f"K must have focal lengths fx, fy > 0, got fx {self.K[0, 0]:g}, fy {self.K[1, 1]:g}")
        _check_pose("pose_world_camera", self.pose_world_camera)
        if self.pose_world_camera_true is not None:
            _check_pose("pose_world_camera_true", self.pose_world_camera_true)


def _check_array(name: str, array: object, ndim: int, dtype: type) -> None:
    if not isinstance(array, np.ndarray):
        raise ValueError(f"{name} must be a numpy array, got {type(array).__name__}")
    if array.ndim != ndim:
        raise ValueError(f"{name} must have {ndim} dimensions, got shape {array.shape}")
    if array.dtype != dtype:
        raise ValueError(f"{name} must have dtype {np.dtype(dtype)}, got {array.dtype}")


def _check_pose(name: str, pose: np.ndarray) -> None:
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise ValueError(f"{name} must be a finite (4, 4) matrix, got shape {pose.shape}")
    if not np.allclose(pose[3], [0.0, 0.0, 0.0, 1.0]):
        raise ValueError(f"{name} must have last row [0, 0, 0, 1], got {pose[3]}")
    rotation = pose[:3, :3]
    if not np.allclose(rotation.T @ rotation, np.eye(3), atol=_ROTATION_TOLERANCE) or np.linalg.det(rotation) < 0:
        raise ValueError(f"{name} is not a rigid transform: its 3x3 block is not a rotation")
