"""/ssf/semantic_flow and /ssf/flow clouds round-trip through their records; bad clouds are one MessageError line."""

from __future__ import annotations

import numpy as np
import pytest

from ssf_common import messages
from ssf_common.conversions import (scene_flow_from_cloud, scene_flow_to_cloud, semantic_flow_from_cloud,
                                    semantic_flow_to_cloud)
from ssf_common.errors import MessageError
from ssf_common.pointcloud import xyz_to_cloud
from ssf_common.records import SceneFlow, Segmentation, SemanticFlow


def test_semantic_flow_round_trip():
    rng = np.random.default_rng(0)
    points, flow = rng.normal(size=(50, 3)).astype(np.float32), rng.normal(size=(50, 3)).astype(np.float32)
    segmentation = Segmentation.from_probability(rng.random(50).astype(np.float32), rng.integers(1, 4, 50))
    back = semantic_flow_from_cloud(semantic_flow_to_cloud(SemanticFlow(123, "lidar", points, flow, segmentation)))
    assert (back.stamp_ns, back.frame_id) == (123, "lidar")
    np.testing.assert_array_equal(back.points, points)
    np.testing.assert_array_equal(back.flow, flow)
    np.testing.assert_array_equal(back.segmentation.label, segmentation.label)
    np.testing.assert_array_equal(back.segmentation.instance, segmentation.instance)
    np.testing.assert_allclose(back.segmentation.dynamic_prob, segmentation.dynamic_prob)
    scene = scene_flow_from_cloud(scene_flow_to_cloud(SceneFlow(7, "lidar", points, flow, 2)))
    assert scene.iteration == 2 and np.array_equal(scene.flow, flow)


def test_bad_semantic_flow_clouds_are_one_line():
    header = messages.header(1, "lidar")
    with pytest.raises(MessageError, match="flow_x"):
        semantic_flow_from_cloud(xyz_to_cloud(np.zeros((3, 3), np.float32), header, label=np.zeros(3, np.uint8),
                                              instance=np.zeros(3, np.int32), prob=np.zeros(3, np.float32)))
    nan = np.zeros((3, 3), np.float32)
    nan[1] = np.nan
    with pytest.raises(MessageError, match="NaN"):
        semantic_flow_from_cloud(xyz_to_cloud(nan, header, flow_x=np.zeros(3, np.float32), flow_y=np.zeros(3, np.float32),
                                              flow_z=np.zeros(3, np.float32), label=np.zeros(3, np.uint8),
                                              instance=np.zeros(3, np.int32), prob=np.zeros(3, np.float32)))
