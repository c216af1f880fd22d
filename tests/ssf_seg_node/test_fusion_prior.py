"""The temporal prior: the previous scan's segmentation, carried by its flow, is the next scan's preliminary mask."""

from __future__ import annotations

import numpy as np
import pytest

from ssf_common.conversions import prior_from_cloud, prior_to_cloud
from ssf_common.records import MotionMask, SceneFlow
from ssf_common.temporal_prior import carry_prior, prior_source
from ssf_eval.pipeline import PerceptionConfig, PerceptionChain
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


def test_the_prior_crosses_processes_in_two_halves_with_the_same_answer():
    """What the fusion node keeps of a finished scan (/ssf/prior), carried by the flow node onto the next scan, is the
    prior the in-process chain carries: only the points near the movers travel."""
    rng = np.random.default_rng(3)
    points = rng.uniform(-20, 20, (2000, 3)).astype(np.float32)
    flow = np.zeros_like(points)
    probability = np.zeros(len(points), np.float32)
    near = np.linalg.norm(points[:, :2] - [5.0, 5.0], axis=1) < 1.5
    probability[near], flow[near] = 0.8, [1.0, 0.0, 0.0]
    following = (points + flow + rng.normal(0, 0.02, points.shape)).astype(np.float32)
    source = prior_source(7, "lidar", points, flow, probability, radius=1.0)
    assert 0 < len(source) < len(points) and source.radius == 1.0
    travelled = prior_from_cloud(prior_to_cloud(source))  # over the wire and back
    np.testing.assert_array_equal(carry_prior(travelled, following), carry_mask(points, flow, probability, following, 1.0))
    assert (carry_prior(travelled, following)[near] == np.float32(0.8)).all()


def test_the_distributed_loop_hints_the_segmentation_and_compares_it_with_the_flow_s_mask():
    """As in process: the next iteration's mask is the segmentation, and Delta_mask compares it with the mask M^(i)
    the flow was conditioned on (the /ssf/flow prior field)."""
    loop = DistributedLoop(FusionConfig(max_iterations=3), timeout_s=5.0)
    points = np.array([[0.0, 0, 0], [4.0, 0, 0], [8.0, 0, 0]], np.float32)
    prior = np.array([0.0, 0.9, 0.0], np.float32)  # the temporal prior the flow started from
    flow = np.zeros((3, 3), np.float32)
    loop.on_flow(SceneFlow(200, "lidar", points, flow, 0, prior), 1.0)
    nothing = np.zeros(3, np.float32)  # its segmentation misses the mover
    hint = loop.on_mask(MotionMask(200, "lidar", points, nothing, np.zeros(3, np.int32), 0), 1.0)
    assert isinstance(hint, Continue) and not hint.hint.dynamic_prob.any()
    assert hint.status.delta_mask == pytest.approx(0.3)  # |0 - 0.9| / 3
    loop.on_flow(SceneFlow(200, "lidar", points, flow, 1, hint.hint.dynamic_prob), 1.1)
    done = loop.on_mask(MotionMask(200, "lidar", points, nothing, np.zeros(3, np.int32), 1), 1.1)
    assert isinstance(done, Finish) and done.reason == "converged"


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
    perception = PerceptionChain(PerceptionConfig())
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
