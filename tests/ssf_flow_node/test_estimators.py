"""Each estimator on a synthetic pair (street + two moving boxes with known rigid motions)."""

import numpy as np
import pytest

from ssf_common.config import build
from ssf_common.errors import ConfigError
from ssf_common.scans import read_scan
from ssf_flow_node.core.estimator import WHOLE_SCAN, FlowConfig, make_estimator
from ssf_common.geometry.se3 import rigid_flow
from ssf_common.dataset.synthetic import synthetic_pair
from ssf_common.geometry.se3 import make_pose as pose
from ssf_eval.flow.metrics import flow_metrics, score_flow


@pytest.fixture(scope="module")
def pair():
    return synthetic_pair(seed=0, agents=2, ego_step=1.0)


@pytest.fixture(scope="module")
def results(pair):
    return {name: make_estimator(name).estimate(pair.pc1, pair.pc2) for name in ("zero", "ego", "rigid")}


def test_synthetic_pair_has_two_moving_boxes(pair):
    assert set(np.unique(pair.instance1)) == {0, 1, 2}
    static_flow = rigid_flow(pair.ego, pair.pc1)
    for box in (1, 2):
        on = pair.instance1 == box
        assert np.linalg.norm((pair.flow[on] - static_flow[on]).mean(axis=0)) > 0.4


def test_results_cover_every_point(pair, results):
    for result in results.values():
        assert result.flow.shape == pair.pc1.shape and result.flow.dtype == np.float32
        assert result.ego.shape == (4, 4)


def test_zero_baseline_is_zero(results):
    assert not results["zero"].flow.any()


def test_ego_baseline_recovers_ego_motion_only(pair, results):
    scores = score_flow(results["ego"].flow, pair.flow, pair.dynamic1)
    assert scores.static.epe3d < 0.03
    assert np.allclose(results["ego"].ego, pair.ego, atol=0.02)
    assert scores.dynamic.epe3d > 0.5  # it cannot see the boxes move


def test_rigid_recovers_both_box_motions(pair, results):
    scores = score_flow(results["rigid"].flow, pair.flow, pair.dynamic1)
    ego_scores = score_flow(results["ego"].flow, pair.flow, pair.dynamic1)
    assert scores.static.epe3d < 0.03
    assert scores.dynamic.epe3d < 0.5 * ego_scores.dynamic.epe3d
    for box in (1, 2):
        on = pair.instance1 == box
        assert flow_metrics(results["rigid"].flow[on], pair.flow[on]).epe3d < 0.2
        assert np.median(np.linalg.norm(results["rigid"].flow[on] - pair.flow[on], axis=1)) < 0.1


def test_rigid_proves_a_box_sliding_along_its_length_from_its_ends():
    """Box 1 slides along its own length: its sides stay on their planes, but its ends leave them."""
    pair = synthetic_pair(seed=1, agents=2, ego_step=1.0)
    result = make_estimator("rigid").estimate(pair.pc1, pair.pc2).flow
    box1 = pair.instance1 == 1
    assert np.linalg.norm((pair.flow - rigid_flow(pair.ego, pair.pc1))[box1].mean(axis=0)) > 0.9
    assert flow_metrics(result[box1], pair.flow[box1]).epe3d < 0.15


def test_rigid_mask_settles_what_the_points_leave_open():
    """Box 1 has fewer points than a cluster needs to be registered from the points alone (min_cluster_points above
    its size); the mask calling it dynamic is enough."""
    pair = synthetic_pair(seed=1, agents=2, ego_step=1.0)
    box1, box2 = pair.instance1 == 1, pair.instance1 == 2
    estimator = make_estimator("rigid", build(FlowConfig, {"rigid": {"min_cluster_points": 4 * int(box1.sum())}}))
    static_flow = rigid_flow(pair.ego, pair.pc1)
    without = estimator.estimate(pair.pc1, pair.pc2).flow
    assert np.linalg.norm(without[box1] - static_flow[box1], axis=1).mean() < 0.1  # taken for static structure
    assert flow_metrics(without[box1], pair.flow[box1]).epe3d > 0.5
    mask = (pair.instance1 == 1).astype(np.float32)
    with_mask = estimator.estimate(pair.pc1, pair.pc2, mask).flow
    assert flow_metrics(with_mask[box1], pair.flow[box1]).epe3d < 0.15
    assert flow_metrics(with_mask[~box1 & ~box2], pair.flow[~box1 & ~box2]).epe3d < 0.03


def test_estimators_accept_more_points_than_they_sample():
    big = synthetic_pair(seed=3, agents=2, points=20000)
    config = build(FlowConfig, {"preprocess": {"points": 4096}})
    result = make_estimator("rigid", config).estimate(big.pc1, big.pc2)
    assert result.flow.shape == (20000, 3)
    scores = score_flow(result.flow, big.flow, big.dynamic1)
    assert scores.static.epe3d < 0.02


def test_unknown_estimator_and_bad_config_are_config_errors():
    with pytest.raises(ConfigError, match="unknown flow estimator"):
        make_estimator("magic")
    with pytest.raises(ConfigError, match="preprocess.points"):
        build(FlowConfig, {"preprocess.points": -3})


@pytest.mark.parametrize("name", ["vlp16_1673400472138016708.pcd", "vlp32_1713492677464078412.pcd"])
def test_rigid_on_real_scan_geometry_sees_only_the_ego_motion(shared_data, name):
    """A real scan and a re-sampled, noisy copy seen from 0.3 m further on: nothing may look like it moves."""
    scan = read_scan(shared_data / "lidar_scans" / name)[:, :3]
    rng = np.random.default_rng(0)
    ego = np.linalg.inv(pose(0.3, 0.05, 0.01, 0.03))
    pc1 = scan[rng.random(len(scan)) < 0.7]
    second = scan[rng.random(len(scan)) < 0.7]
    pc2 = (second @ ego[:3, :3].T + ego[:3, 3] + rng.normal(0.0, 0.01, second.shape)).astype(np.float32)
    result = make_estimator("rigid", build(FlowConfig, WHOLE_SCAN)).estimate(pc1, pc2)
    error = np.linalg.norm(result.flow - rigid_flow(ego, pc1), axis=1)
    assert error.mean() < 0.02 and np.percentile(error, 99) < 0.05
    assert np.abs(result.ego - ego).max() < 0.02
