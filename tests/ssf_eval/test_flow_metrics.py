"""Scene flow metrics against hand-computed cases."""

import math

import numpy as np
import pytest

from ssf_eval.flow.metrics import FlowMetrics, flow_metrics, pool_metrics, pool_scores, score_flow


def test_hand_computed_case():
    truth = np.array([[1.0, 0, 0], [0, 2.0, 0], [0, 0, 0.5], [0, 0, 0]])
    predicted = truth + np.array([[0.04, 0, 0], [0, 0.15, 0], [0, 0, 0.4], [0, 0.02, 0]])
    # errors 0.04, 0.15, 0.4, 0.02; relative 0.04/1, 0.15/2=0.075, 0.4/0.5=0.8, 0.02/1e-4=200
    m = flow_metrics(predicted, truth)
    assert m.epe3d == pytest.approx((0.04 + 0.15 + 0.4 + 0.02) / 4)
    assert m.acc_strict == pytest.approx(2 / 4)  # point 1 (e<0.05), point 4 (e<0.05)
    assert m.acc_relax == pytest.approx(3 / 4)  # + point 2 (r=0.075<0.1)
    assert m.outliers == pytest.approx(2 / 4)  # point 3 (e>0.3), point 4 (r>0.1)
    assert m.count == 4


def test_relative_error_rescues_large_flows():
    truth = np.array([[10.0, 0, 0]])
    m = flow_metrics(truth + [[0.4, 0, 0]], truth)  # e = 0.4 > 0.3 but r = 0.04
    assert (m.acc_strict, m.acc_relax, m.outliers) == (1.0, 1.0, 1.0)


def test_split_static_dynamic_and_empty_split():
    truth = np.zeros((3, 3))
    predicted = np.array([[0.0, 0, 0], [0.2, 0, 0], [0.0, 0.6, 0]])
    scores = score_flow(predicted, truth, np.array([False, True, True]))
    assert scores.static.epe3d == pytest.approx(0.0)
    assert scores.dynamic.epe3d == pytest.approx(0.4)
    assert scores.all.epe3d == pytest.approx(0.8 / 3)
    none_dynamic = score_flow(predicted, truth, np.zeros(3, bool))
    assert none_dynamic.dynamic.count == 0 and math.isnan(none_dynamic.dynamic.epe3d)


def test_pooling_weights_by_points():
    a = FlowMetrics(0.1, 1.0, 1.0, 0.0, 1)
    b = FlowMetrics(0.4, 0.0, 0.5, 1.0, 3)
    pooled = pool_metrics([a, b])
    assert pooled.epe3d == pytest.approx((0.1 + 1.2) / 4)
    assert pooled.acc_relax == pytest.approx((1.0 + 1.5) / 4)
    assert pooled.count == 4
    truth = np.zeros((2, 3))
    frames = [score_flow(truth + [[0.1, 0, 0]], truth, np.array([True, False])) for _ in range(2)]
    assert pool_scores(frames).all.count == 4


def test_shape_mismatch_is_an_error():
    with pytest.raises(ValueError):
        flow_metrics(np.zeros((3, 3)), np.zeros((4, 3)))
