"""Segmentation core: slots to labels, the paper's static selection, the geometric segmenter, obstacles, the loop."""

from __future__ import annotations

import numpy as np
import pytest

from ssf_common.dataset.synthetic import synthetic_pair
from ssf_common.errors import ConfigError
from ssf_common.geometry.se3 import make_pose, transform_points
from ssf_common.records import ObstacleKind, Segmentation
from ssf_seg_node.core.base import one_hot, result_from_slots
from ssf_seg_node.core.fusion import FusionConfig, FusionLoop
from ssf_seg_node.core.obstacles import ObstacleConfig, extract_obstacles, grow_away_from_sensor
from ssf_seg_node.core.segmenter import SegConfig, make_segmenter
from ssf_seg_node.core.selection import StaticRule, StaticSelectionConfig, select_static, slot_speeds


@pytest.fixture(scope="module")
def pair():
    return synthetic_pair(seed=1, agents=4, points=8192)


def test_slots_become_labels_and_instances_largest_first():
    slots = one_hot(np.array([0, 0, 0, 0, 1, 1, 2, 2, 2, -1]), 3)
    result = result_from_slots(slots, np.array([True, False, False, True]))
    seg = result.segmentation
    np.testing.assert_array_equal(seg.label, [0, 0, 0, 0, 1, 1, 1, 1, 1, 0])
    np.testing.assert_array_equal(seg.instance, [0, 0, 0, 0, 2, 2, 1, 1, 1, 0])
    assert seg.num_instances == 2 and seg.dynamic_prob.dtype == np.float32


def test_quantity_selection_takes_the_largest_slot():
    config = StaticSelectionConfig(rule=StaticRule.QUANTITY)
    np.testing.assert_array_equal(select_static(np.array([10, 500, 30]), np.array([9.0, 9.0, 0.0]), 9.0, config),
                                  [False, True, False])


def test_velocity_selection_compares_with_the_ego_speed():
    config = StaticSelectionConfig(rule=StaticRule.VELOCITY, velocity_threshold=1.0)
    static = select_static(np.array([100, 90, 110, 0]), np.array([10.2, 3.0, 9.5, 10.0]), 10.0, config)
    np.testing.assert_array_equal(static, [True, False, True, False])  # the empty slot is never static


def test_auto_selection_switches_on_size_variation():
    config = StaticSelectionConfig(rule=StaticRule.AUTO, size_variation=0.5, velocity_threshold=1.0)
    speeds, ego = np.array([3.0, 10.0, 10.0]), 10.0
    assert select_static(np.array([1000, 20, 30]), speeds, ego, config).tolist() == [True, False, False]
    assert select_static(np.array([100, 90, 110]), speeds, ego, config).tolist() == [False, True, True]


def test_slot_speeds_by_hand():
    flow = np.array([[1.0, 0, 0], [0, 3.0, 0], [0, 0, 0.5]])
    np.testing.assert_allclose(slot_speeds(flow, np.array([0, 0, 1]), 2, dt=0.5), [4.0, 1.0])


def test_geometric_separates_the_static_scene_from_moving_boxes(pair):
    result = make_segmenter("geometric").segment(pair.pc1, pair.flow)
    seg = result.segmentation
    truth = pair.dynamic1
    iou = (truth & seg.dynamic).sum() / (truth | seg.dynamic).sum()
    assert (seg.dynamic == truth).mean() > 0.99 and iou > 0.85
    # every predicted object lies on one true object
    for k in np.unique(seg.instance[seg.instance > 0]):
        owners = pair.instance1[seg.instance == k]
        assert (owners == np.bincount(owners).argmax()).mean() > 0.95


def test_geometric_needs_flow_and_knows_its_prior(pair):
    with pytest.raises(ConfigError, match="needs points and flow"):
        make_segmenter("geometric-points")
    with pytest.raises(ConfigError, match="unknown segmenter"):
        make_segmenter("nothing")
    still = make_segmenter("geometric").segment(pair.pc1, transform_points(pair.ego, pair.pc1) - pair.pc1)
    assert not still.segmentation.dynamic.any()  # pure ego motion: nothing moves


def test_obstacles_recover_box_and_velocity():
    rng = np.random.default_rng(0)
    length, width = 4.4, 1.8
    side = np.column_stack([rng.uniform(-length / 2, length / 2, 300), np.full(300, -width / 2), rng.uniform(0, 1.5, 300)])
    points = side + [12.0, 5.0, 0.0]  # only the side towards the sensor is seen
    ego = make_pose(1.0, 0.0, 0.0, 0.0)  # the sensor moves 1 m forward per frame
    velocity = np.array([5.0, 0.0, 0.0])  # along its length, as vehicles drive
    dt = 0.1
    flow = transform_points(ego, points + velocity * dt) - points
    segmentation = Segmentation(np.ones(300, np.float32), np.ones(300, np.uint8), np.ones(300, np.int32))
    obstacles = extract_obstacles(points, flow, segmentation, ego, dt, 7, "lidar", ObstacleConfig())
    assert len(obstacles) == 1 and obstacles.frame_id == "lidar" and obstacles.stamp_ns == 7
    np.testing.assert_allclose(obstacles.velocities[0], velocity, atol=1e-4)
    np.testing.assert_allclose(obstacles.centres[0, :2], [12.0, 5.0], atol=0.05)  # grown to the hidden side
    np.testing.assert_allclose(obstacles.sizes[0, :2], [length, width], atol=0.05)
    assert obstacles.kinds[0] == ObstacleKind.VEHICLE and obstacles.point_counts[0] == 300
    assert np.all(np.linalg.eigvalsh(obstacles.velocity_covariances[0]) > 0)


def test_a_vehicle_seen_end_on_gets_its_length_along_its_motion():
    rng = np.random.default_rng(1)
    rear = np.column_stack([np.full(200, 20.0), rng.uniform(-0.9, 0.9, 200), rng.uniform(0.0, 1.4, 200)])
    velocity = np.array([4.0, 0.0, 0.0])  # driving away from the sensor: only its rear face is seen
    dt = 0.1
    flow = np.tile(velocity * dt, (200, 1))
    segmentation = Segmentation(np.ones(200, np.float32), np.ones(200, np.uint8), np.ones(200, np.int32))
    obstacles = extract_obstacles(rear, flow, segmentation, np.eye(4), dt, 0, "lidar", ObstacleConfig())
    assert obstacles.kinds[0] == ObstacleKind.VEHICLE  # 1.8 m wide: no pedestrian
    np.testing.assert_allclose(obstacles.sizes[0, :2], [4.4, 1.8], atol=0.05)
    assert abs(np.cos(obstacles.yaws[0])) > 0.99  # length along x, the direction of travel
    np.testing.assert_allclose(obstacles.centres[0, :2], [22.2, 0.0], atol=0.05)  # grown away from the sensor
    np.testing.assert_allclose(obstacles.velocities[0], velocity, atol=1e-6)


def test_growing_keeps_the_seen_side_in_place():
    centre, sides = grow_away_from_sensor(np.array([10.0, 0.0]), np.array([0.6, 0.1]), 0.0, np.array([0.6, 0.6]))
    np.testing.assert_allclose(sides, [0.6, 0.6])
    np.testing.assert_allclose(centre, [10.0, 0.0], atol=1e-12)  # the sensor is within its y extent: grown both ways
    centre, _ = grow_away_from_sensor(np.array([0.0, 10.0]), np.array([0.6, 0.1]), 0.0, np.array([0.6, 0.6]))
    np.testing.assert_allclose(centre, [0.0, 10.25])


class ScriptedEstimator:
    """A flow estimator whose answers are scripted per call (to test the loop's stopping rules)."""

    name = "scripted"

    def __init__(self, flows):
        self.flows, self.calls = flows, 0

    def estimate(self, pc1, pc2, mask=None):
        flow = self.flows[min(self.calls, len(self.flows) - 1)]
        self.calls += 1
        return type("Estimate", (), {"flow": flow, "ego": np.eye(4)})()


def test_loop_stops_on_epsilon(pair):
    still = transform_points(pair.ego, pair.pc1) - pair.pc1
    estimator = ScriptedEstimator([still, pair.flow, pair.flow])
    result = FusionLoop(estimator, make_segmenter("geometric"), FusionConfig(max_iterations=5)).run(pair.pc1, pair.pc2)
    assert result.converged and result.iterations == 3 and estimator.calls == 3
    assert result.steps[1].delta_total > 1e-3 > result.steps[2].delta_total
    assert np.isinf(result.steps[0].delta_flow)


def test_loop_stops_on_n_iter(pair):
    rng = np.random.default_rng(0)
    flows = [pair.flow + rng.normal(0, 0.2, pair.flow.shape) for _ in range(6)]
    estimator = ScriptedEstimator(flows)
    result = FusionLoop(estimator, make_segmenter("geometric"), FusionConfig(max_iterations=4)).run(pair.pc1, pair.pc2)
    assert not result.converged and result.iterations == 4 == estimator.calls


def test_loop_with_the_rigid_estimator_converges_and_finds_the_movers(pair):
    from ssf_flow_node.core.estimator import make_estimator

    loop = FusionLoop(make_estimator("rigid"), make_segmenter("geometric"), FusionConfig(max_iterations=5))
    result = loop.run(pair.pc1, pair.pc2)
    assert result.converged and result.iterations <= 3  # the paper's loop: a fixed point after its first iteration
    own = transform_points(np.linalg.inv(pair.ego), pair.pc1 + pair.flow) - pair.pc1
    for k in np.unique(pair.instance1[pair.dynamic1]):
        on = pair.instance1 == k
        if np.linalg.norm(own[on], axis=1).mean() > 0.3:  # faster than 3 m/s: the rigid flow sees it, so must we
            assert result.segmentation.dynamic[on].mean() > 0.8
    static = ~pair.dynamic1
    assert result.segmentation.dynamic[static].mean() < 0.01
    assert SegConfig().method == "geometric"
