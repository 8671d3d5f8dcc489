"""`ndfa.ndf.reuse`: an observation takes an earlier view's code only while its view has barely
changed, and a pass with reuse off encodes every observation."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ndfa.ndf.encoder import ObjectCode
from ndfa.ndf.reuse import CodeReuse, ReuseConfig


class CountingEncoder:
    """`encode_batch` as the reuse sees it: one fresh code per observation, the calls counted."""

    categories: tuple[str, ...] = ()  # a model without a category head

    def __init__(self) -> None:
        self.encoded: list[int] = []  # observations per call

    def encode_batch(self, clouds, poses, full_reconstruction=True):
        self.encoded.append(len(clouds))
        return [ObjectCode(np.ones(4), np.asarray(pose)[:3, 3] + cloud.mean(axis=0), np.zeros((2, 3)), 0.7, np.zeros((0, 3)))
                for cloud, pose in zip(clouds, poses)]


def mug(center, count=300, seed=0):
    return np.random.default_rng(seed).normal(scale=0.03, size=(count, 3)) + center


def camera_at(x):
    pose = np.eye(4)
    pose[0, 3] = x
    return pose


CONFIG = ReuseConfig(angle_deg=5.0)


def test_a_view_seen_again_from_nearly_the_same_side_takes_its_code():
    encoder = CountingEncoder()
    reuse = CodeReuse(encoder, CONFIG)
    first = reuse.encode([mug([0, 0, 1.0])], camera_at(0.0), False)
    # the camera 5 cm to the side: the view turns by 2.9 degrees; the cloud is the same in the world
    second = reuse.encode([mug([-0.05, 0, 1.0], seed=1)], camera_at(0.05), False)
    assert second[0] is first[0]
    assert (reuse.encoded, reuse.reused) == (1, 1) and encoder.encoded == [1, 0]


@pytest.mark.parametrize("camera_x, cloud_offset, count, why", [
    (0.12, [-0.12, 0, 1.0], 300, "the view turned by 6.8 degrees"),
    (0.0, [0.02, 0, 1.0], 300, "the centroid moved 2 cm"),
    (0.0, [0, 0, 1.0], 200, "a third of the points gone"),
])
def test_a_view_that_changed_is_encoded_again(camera_x, cloud_offset, count, why):
    encoder = CountingEncoder()
    reuse = CodeReuse(encoder, CONFIG)
    first = reuse.encode([mug([0, 0, 1.0])], camera_at(0.0), False)
    second = reuse.encode([mug(cloud_offset, count=count, seed=1)], camera_at(camera_x), False)
    assert second[0] is not first[0], why
    assert reuse.encoded == 2


def test_the_comparison_is_with_the_view_encoded_so_a_slow_drift_is_encoded_again():
    encoder = CountingEncoder()
    reuse = CodeReuse(encoder, CONFIG)
    for step in range(4):  # 2.9 degrees per frame: within 5 of the encoded view every other frame only
        x = 0.05 * step
        reuse.encode([mug([-x, 0, 1.0], seed=step)], camera_at(x), False)
    assert encoder.encoded == [1, 0, 1, 0]


def test_codes_are_forgotten_after_the_gap_and_partial_ones_serve_no_full_reconstruction():
    encoder = CountingEncoder()
    reuse = CodeReuse(encoder, ReuseConfig(angle_deg=5.0, max_gap_frames=2))
    reuse.encode([mug([0, 0, 1.0])], camera_at(0.0), False)
    reuse.encode([mug([0, 0, 1.0])], camera_at(0.0), True)  # needs the full reconstruction: encoded
    for _ in range(2):
        reuse.encode([], camera_at(0.0), True)
    reuse.encode([mug([0, 0, 1.0])], camera_at(0.0), True)  # three calls later: forgotten
    assert encoder.encoded == [1, 1, 0, 0, 1]


def test_two_observations_of_one_frame_do_not_share_a_code():
    encoder = CountingEncoder()
    reuse = CodeReuse(encoder, CONFIG)
    reuse.encode([mug([0, 0, 1.0])], camera_at(0.0), False)
    codes = reuse.encode([mug([0, 0, 1.0]), mug([0.001, 0, 1.0], seed=2)], camera_at(0.0), False)
    assert codes[0] is not codes[1] and encoder.encoded == [1, 1]


def test_reuse_is_off_by_default():
    assert not ReuseConfig().enabled


def test_a_pipeline_reuses_only_when_configured_and_only_in_masked_frames():
    from ndfa.core.frame import Frame
    from ndfa.perception.observations import Observation
    from ndfa.pipeline import ChangeDetectionPipeline, ObservedFrame, PipelineConfig

    def observed(index):
        frame = Frame(index, float(index), None, np.zeros((4, 4), np.float32), np.eye(3), camera_at(0.0), None)
        return ObservedFrame(frame, False, [Observation(index, 1, mug([0, 0, 1.0]), 300, False)], [], {})

    assert ChangeDetectionPipeline(PipelineConfig(), encoder=CountingEncoder()).new_code_reuse() is None
    encoder = CountingEncoder()
    pipeline = ChangeDetectionPipeline(PipelineConfig(reuse=CONFIG), encoder=encoder)
    reuse = pipeline.new_code_reuse()
    codes = [pipeline.encode(observed(index), False, reuse).codes[0] for index in range(2)]
    assert codes[1] is codes[0] and encoder.encoded == [1, 0]
    pipeline.encode(observed(2), False)  # no reuse handed over: encoded
    assert encoder.encoded == [1, 0, 1]
    segmented = replace(observed(3), segmented=True)  # its segments change with the clustering: always encoded
    assert pipeline.encode(segmented, False, reuse).codes[0] is not codes[0] and encoder.encoded == [1, 0, 1, 1]
