"""Names of everything in an ndfa recording: channels (MCAP topics), coordinate frames and encodings.

One recording is one MCAP file per session. Image, calibration and pose channels use Foxglove's
protobuf schemas, so the file opens as it is in Foxglove and Rerun; the two JSON channels carry
what no Foxglove schema describes. Every message of one frame carries the frame's timestamp.

| channel                    | schema                       | content                                     |
|----------------------------|------------------------------|---------------------------------------------|
| /camera/color              | foxglove.RawImage rgb8       | colour image (optional)                     |
| /camera/depth              | foxglove.RawImage 16UC1      | depth in millimetres, 0 = invalid           |
| /camera/calibration        | foxglove.CameraCalibration   | intrinsics K, one message per frame         |
| /camera/instances          | foxglove.RawImage 16UC1      | instance id per pixel, 0 = none (optional)  |
| /tf                        | foxglove.FrameTransform      | camera pose: "camera" in "world"            |
| /ndfa/ground_truth/pose    | foxglove.PoseInFrame         | true camera pose when /tf is perturbed      |
| /ndfa/meta                 | JSON                         | one message: source, session, units, ...    |
| /ndfa/ground_truth         | JSON                         | one message: objects, ids, change labels    |
"""

COLOR = "/camera/color"
DEPTH = "/camera/depth"
CALIBRATION = "/camera/calibration"
INSTANCES = "/camera/instances"
TF = "/tf"
GROUND_TRUTH_POSE = "/ndfa/ground_truth/pose"
META = "/ndfa/meta"
GROUND_TRUTH = "/ndfa/ground_truth"

# A recording without these is refused by the reader; the others are optional.
REQUIRED_CHANNELS = (DEPTH, CALIBRATION, TF, META)

# Channels that carry one message per frame, all stamped with the frame's time.
FRAME_CHANNELS = (COLOR, DEPTH, CALIBRATION, INSTANCES, TF, GROUND_TRUTH_POSE)

# Coordinate frames: images are in "camera" (OpenCV: x right, y down, z forward) and /tf places
# "camera" in "world" (z up, metres), i.e. it carries pose_world_camera.
WORLD_FRAME = "world"
CAMERA_FRAME = "camera"

# Schema name of each channel, as written into the MCAP file (and checked by the reader).
SCHEMA_NAMES = {
    COLOR: "foxglove.RawImage",
    DEPTH: "foxglove.RawImage",
    CALIBRATION: "foxglove.CameraCalibration",
    INSTANCES: "foxglove.RawImage",
    TF: "foxglove.FrameTransform",
    GROUND_TRUTH_POSE: "foxglove.PoseInFrame",
    META: "ndfa.Meta",
    GROUND_TRUTH: "ndfa.GroundTruth",
}
JSON_CHANNELS = (META, GROUND_TRUTH)

# RawImage encodings (names from ROS sensor_msgs/image_encodings, which Foxglove and Rerun use).
RGB8 = "rgb8"  # 3 x uint8 per pixel
MONO16 = "16UC1"  # 1 x uint16 (little-endian) per pixel: depth in millimetres, instance ids
FLOAT32 = "32FC1"  # 1 x float32 per pixel: depth in metres; the reader accepts it, ndfa never writes it

DEPTH_SCALE_M = 0.001  # metres per unit of a 16UC1 depth image
