"""The temporal prior: the previous scan's segmentation, carried by its flow, is the next scan's preliminary mask."""

from __future__ import annotations

import numpy as np
import pytest

from ssf_common.records import MotionMask, SceneFlow
from ssf_eval.pipeline import PerceptionConfig, SsfPerception
from ssf_common.dataset.synthetic import synthetic_pair
from ssf_seg_node.core.fusion import Continue, DistributedLoop, Finish, FusionConfig, carry_mask


def test_carry_mask_moves_the_probabilities_with_the_flow():
    points = np.array([[0.0, 0, 0], [5.0, 0, 0], [10.0, 0, 0], [1.6, 0, 0]])
    flow = np.array([[1.0, 0, 0], [0.0, 0, 0], [0.0, 0, 0], [0.0, 0, 0]])
    probability = np.array([0.9, 0.0, 0.6, 0.0], np.float32)
    following = np.array([[1.1, 0, 0], [0.1, 0, 0], [10.2, 0, 0], [30.0, 0, 0], [1.5, 0, 0]])
    prior = carry_mask(points, flow, probability, following, radius=0.5)
    # the mover went to x=1; nothing near x=30; x=1.5 lies nearer the still point at 1.6 than the mover: no dilation
    np.testing.assert_allclose(prior, [0.9, 0.0, 0.6, 0.0, 0.0])
    assert not carry_mask(points, flow, probability, following, radius=0.0).any()


def test_the_distributed_loop_adds_the_prior_to_the_first_hint_of_the_next_scan():
    loop = DistributedLoop(FusionConfig(max_iterations=3), timeout_s=5.0)
    points = np.array([[0.0, 0, 0], [4.0, 0, 0], [8.0, 0, 0]], np.float32)
    moving = np.array([0.0, 0.9, 0.0], np.float32)
    flow = np.zeros((3, 3), np.float32)
    for iteration in range(2):  # scan 1: the middle point moves, twice the same answer
        loop.on_flow(SceneFlow(100, "lidar", points, flow, iteration), 0.0)
        decision = loop.on_mask(MotionMask(100, "lidar", points, moving, (moving > 0.5).astype(np.int32), iteration), 0.0)
    assert isinstance(decision, Finish) and decision.reason == "converged"
    nothing = np.zeros(3, np.float32)
    loop.on_flow(SceneFlow(200, "lidar", points, flow, 0), 1.0)  # scan 2 follows; its first segmentation misses the mover
    hint = loop.on_mask(MotionMask(200, "lidar", points, nothing, np.zeros(3, np.int32), 0), 1.0)
    assert isinstance(hint, Continue) and hint.hint.dynamic_prob.tolist() == [0.0, np.float32(0.9), 0.0]
    assert hint.status.delta_mask == 0.0  # the loop compares segmentations, not hints
    loop.on_flow(SceneFlow(200, "lidar", points, flow, 1), 1.1)
    loop.on_mask(MotionMask(200, "lidar", points, nothing, np.zeros(3, np.int32), 1), 1.1)
    loop.on_flow(SceneFlow(500, "lidar", points, flow, 0), 2.0)  # scans were skipped: its flow points elsewhere
    hint = loop.on_mask(MotionMask(500, "lidar", points, nothing, np.zeros(3, np.int32), 0), 2.0)
    assert isinstance(hint, Continue) and not hint.hint.dynamic_prob.any()


def test_a_restarted_stream_is_not_taken_for_late_answers():
    """After restart() (the fusion node saw stamps jump back) the loop takes the new stream's scans."""
    loop = DistributedLoop(FusionConfig(max_iterations=1), timeout_s=5.0)
    points, flow = np.array([[0.0, 0, 0], [4.0, 0, 0]], np.float32), np.zeros((2, 3), np.float32)
    moving = np.array([0.0, 0.9], np.float32)
    loop.on_flow(SceneFlow(5_000_000_000, "lidar", points, flow, 0), 0.0)  # its segmentation is still on the way
    loop.on_flow(SceneFlow(100_000_000, "lidar", points, flow, 0), 1.0)
    assert loop.on_mask(MotionMask(100_000_000, "lidar", points, moving, np.ones(2, np.int32), 0), 1.0) is None  # late
    loop.restart()
    loop.on_flow(SceneFlow(100_000_000, "lidar", points, flow, 0), 1.1)
    finish = loop.on_mask(MotionMask(100_000_000, "lidar", points, moving, np.ones(2, np.int32), 0), 1.1)
    assert isinstance(finish, Finish) and finish.result.stamp_ns == 100_000_000


def test_an_iteration_that_would_end_after_the_timeout_is_not_started():
    """Once a hint's round trip is known (0.8 s here), a scan whose mask comes 0.3 s into a 1 s timeout is answered at once."""
    loop = DistributedLoop(FusionConfig(max_iterations=3), timeout_s=1.0)
    points, flow = np.array([[0.0, 0, 0], [4.0, 0, 0]], np.float32), np.zeros((2, 3), np.float32)
    masks = [np.array([0.0, 0.9], np.float32), np.array([0.0, 0.6], np.float32)]
    loop.on_flow(SceneFlow(100, "lidar", points, flow, 0), 0.0)
    assert isinstance(loop.on_mask(MotionMask(100, "lidar", points, masks[0], np.ones(2, np.int32), 0), 0.1), Continue)
    loop.on_flow(SceneFlow(100, "lidar", points, flow + 0.5, 1), 0.7)
    second = loop.on_mask(MotionMask(100, "lidar", points, masks[1], np.ones(2, np.int32), 1), 0.9)  # round trip 0.8 s
    assert loop.round_trip_s == pytest.approx(0.8)
    assert isinstance(second, Finish) and second.reason == "deadline"  # a third iteration would end at 1.7 s
    loop.on_flow(SceneFlow(200, "lidar", points, flow, 0), 2.0)
    finish = loop.on_mask(MotionMask(200, "lidar", points, masks[0], np.ones(2, np.int32), 0), 2.3)
    assert isinstance(finish, Finish) and finish.reason == "deadline" and loop.finished["deadline"] == 2


class Recorder:
    """Wraps a flow estimator and remembers the masks it was given."""

    def __init__(self, estimator):
        self.estimator, self.name, self.masks = estimator, estimator.name, []

    def estimate(self, pc1, pc2, mask=None):
        self.masks.append(None if mask is None else np.asarray(mask).copy())
        return self.estimator.estimate(pc1, pc2, mask)


def test_consecutive_scans_start_from_the_carried_segmentation():
    first = synthetic_pair(seed=6, agents=4, points=4096)
    perception = SsfPerception(PerceptionConfig())
    recorder = perception.loop.estimator = Recorder(perception.loop.estimator)
    result = perception.perceive(first.pc1, first.pc2)
    assert recorder.masks[0] is None and result.fusion.segmentation.dynamic.any()
    recorder.masks.clear()
    perception.perceive(first.pc2, first.pc1, follows=True)  # the scan the last pair ended on comes first now
    prior = recorder.masks[0]
    assert prior is not None and prior.shape == (len(first.pc2),) and (prior > 0.5).sum() > 50
    recorder.masks.clear()
    perception.reset()
    perception.perceive(first.pc2, first.pc1, follows=True)
    assert recorder.masks[0] is None
