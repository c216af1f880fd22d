"""The clustering baselines (GMM, DBSCAN) on points, flow and both: a synthetic street with two moving boxes."""

import numpy as np
import pytest

from ssf_common.dataset.synthetic import synthetic_pair
from ssf_common.config import build
from ssf_common.errors import ConfigError
from ssf_common.geometry.se3 import rigid_flow
from ssf_seg_node.core.base import SegInput
from ssf_seg_node.core.features import motion_input, selection_for, standardised
from ssf_seg_node.core.segmenter import SegConfig, make_segmenter
from ssf_seg_node.core.selection import StaticRule, StaticSelectionConfig


@pytest.fixture(scope="module")
def pair():
    """8192 points: rough ground, buildings, poles and two moving boxes (256 points), with exact flow."""
    return synthetic_pair(seed=1, agents=2, points=8192)


def scores(segmentation, truth):
    predicted = segmentation.dynamic
    return float(np.mean(predicted == truth)), np.count_nonzero(predicted & truth) / np.count_nonzero(predicted | truth)


@pytest.mark.parametrize("name", ["gmm-flow", "gmm-both", "dbscan-flow", "dbscan-both"])
@pytest.mark.parametrize("ego_given", [False, True])
def test_methods_that_see_the_flow_separate_the_moving_boxes(pair, name, ego_given):
    result = make_segmenter(name).segment(pair.pc1, pair.flow, None, pair.ego if ego_given else None)
    accuracy, iou = scores(result.segmentation, pair.dynamic1)
    assert accuracy > 0.98 and iou > 0.75, (name, accuracy, iou)
    assert result.slots.shape[0] == len(pair.pc1) and np.allclose(result.slots.sum(axis=1), 1.0, atol=1e-4)
    moving = result.segmentation.instance[pair.dynamic1]
    assert (moving > 0).mean() > 0.75  # the boxes' points carry instance ids


@pytest.mark.parametrize("name", ["gmm-points", "dbscan-points"])
def test_points_only_methods_cannot_see_motion_and_only_count(pair, name):
    """A points-only clustering never looks at the flow: the same clusters and labels whether the boxes move or not,
    and the static selection can only be quantity-based, so every cluster but the largest is called moving."""
    segmenter = make_segmenter(name)
    moving = segmenter.segment(pair.pc1, pair.flow).segmentation
    still = segmenter.segment(pair.pc1, rigid_flow(pair.ego, pair.pc1)).segmentation
    np.testing.assert_array_equal(moving.label, still.label)
    assert segmenter.selection.rule is StaticRule.QUANTITY
    accuracy, iou = scores(moving, pair.dynamic1)
    assert iou < 0.5  # static structure is called moving, or the boxes are not


def test_the_shared_rule_applies_when_a_method_names_none(pair):
    """With the quantity rule only the largest GMM component is static: the mixture splits the static scene, so
    most of it is then called moving (why the clustering methods use the velocity rule by default)."""
    config = SegConfig(selection=StaticSelectionConfig(rule=StaticRule.QUANTITY), gmm={"static_rule": None})
    accuracy, _ = scores(make_segmenter("gmm-flow", config).segment(pair.pc1, pair.flow).segmentation, pair.dynamic1)
    assert accuracy < 0.9
    assert selection_for(StaticSelectionConfig(), None, SegInput.BOTH).rule is StaticRule.AUTO
    assert selection_for(StaticSelectionConfig(), StaticRule.VELOCITY, SegInput.POINTS).rule is StaticRule.QUANTITY


def test_motion_input_removes_the_ego_motion(pair):
    motion = motion_input(pair.pc1, pair.flow, None, None, compensate_ego=True)
    static = ~pair.dynamic1
    assert np.abs(motion.flow[static]).max() < 1e-3  # the static scene stands still once the ego motion is removed
    assert np.linalg.norm(motion.flow[pair.dynamic1], axis=1).min() > 0.1
    np.testing.assert_allclose(motion.ego, pair.ego, atol=1e-3)
    raw = motion_input(pair.pc1, pair.flow, None, None, compensate_ego=False)
    np.testing.assert_array_equal(raw.flow, pair.flow)


def test_standardised_columns():
    features = standardised(np.array([[1.0, 5.0], [3.0, 5.0]]))
    np.testing.assert_allclose(features, [[-1.0, 0.0], [1.0, 0.0]])


def test_bad_method_inputs_are_config_errors():
    with pytest.raises(ConfigError, match="input 'color'"):
        make_segmenter("gmm-color")
    with pytest.raises(ConfigError, match="covariance"):
        build(SegConfig, {"gmm": {"covariance": "round"}})
