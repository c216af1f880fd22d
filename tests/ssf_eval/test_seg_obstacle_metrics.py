"""Obstacle errors of the segmentation table: yaw against the true boxes, modulo the footprint's symmetry."""

from __future__ import annotations

import numpy as np
import pytest

from ssf_common.dataset.pairs import ScanPair, boxes_from_obstacles
from ssf_common.records import ObstacleKind, Obstacles, Segmentation
from ssf_eval.seg.metrics import obstacle_errors, pool, yaw_error


def test_yaw_error_is_modulo_the_footprints_symmetry():
    assert yaw_error(np.radians(10.0), np.radians(190.0), 4.5, 1.8) == pytest.approx(0.0, abs=1e-9)  # a box turned round
    assert yaw_error(np.radians(10.0), np.radians(50.0), 4.5, 1.8) == pytest.approx(40.0)
    assert yaw_error(np.radians(100.0), np.radians(5.0), 4.5, 1.8) == pytest.approx(85.0)
    assert yaw_error(np.radians(100.0), np.radians(5.0), 0.5, 0.5) == pytest.approx(5.0)  # a square: 90 degrees


def test_obstacle_errors_report_yaw_of_vehicles_and_all():
    n = 200
    instance = np.repeat([1, 2], n // 2).astype(np.int32)
    pc1 = np.zeros((n, 3), np.float32)
    truth = Obstacles(0, "sensor", ids=[1, 2], kinds=[ObstacleKind.VEHICLE, ObstacleKind.PEDESTRIAN],
                      centres=[[10.0, 0.0, 0.0], [5.0, 5.0, 0.0]], sizes=[[4.5, 1.8, 1.5], [0.5, 0.5, 1.7]],
                      yaws=[0.0, 0.0], velocities=np.zeros((2, 3)))
    pair = ScanPair(pc1, pc1, np.zeros((n, 3), np.float32), np.ones(n, bool), instance, np.zeros(n, np.uint8),
                    np.eye(4), np.eye(4), boxes1=boxes_from_obstacles(truth))
    found = Obstacles(0, "sensor", ids=[1, 2], kinds=[1, 2], centres=[[10.3, 0.4, 0.0], [5.0, 5.0, 0.0]],
                      sizes=truth.sizes, yaws=[np.radians(40.0), np.radians(80.0)], velocities=np.zeros((2, 3)))
    segmentation = Segmentation(np.ones(n, np.float32), np.ones(n, np.uint8), instance)
    errors = obstacle_errors(found, segmentation, pair, 0.1)
    summary = pool([errors, errors]).summary()
    np.testing.assert_allclose(sorted(errors.yaw), [10.0, 40.0])  # the pedestrian's square: 80 degrees is 10 off
    assert summary["yaw_deg_median_vehicles"] == pytest.approx(40.0)
    assert summary["yaw_over_30deg_ratio_vehicles"] == 1.0 and summary["yaw_over_30deg_ratio"] == 0.5
    assert summary["position_m_median"] == pytest.approx(0.25) and summary["matches"] == 4
