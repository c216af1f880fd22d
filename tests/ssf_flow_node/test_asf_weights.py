"""The shipped network weights: they load by default, run on a synthetic pair, and take the mask as input."""

import numpy as np
import pytest

from ssf_common.config import build
from ssf_common.errors import DataError
from ssf_flow_node.core.asf.checkpoint import shipped_weights
from ssf_flow_node.core.asf.network import MaskStrategy
from ssf_flow_node.core.estimator import FlowConfig, make_estimator
from ssf_flow_node.core.metrics import score_flow
from ssf_flow_node.core.synthetic import synthetic_pair


@pytest.fixture(scope="module")
def pair():
    return synthetic_pair(seed=0, agents=2, ego_step=1.0)


@pytest.mark.parametrize("strategy", list(MaskStrategy))
def test_shipped_weights_exist_and_load(strategy):
    assert shipped_weights(strategy).stat().st_size < 8_000_000
    assert make_estimator(f"asf-{strategy.value}").name == f"asf-{strategy.value}"


def test_asf_defaults_to_the_explicit_strategy():
    assert make_estimator("asf").name == "asf-explicit"


def test_asf_keeps_the_ego_motion_on_a_synthetic_pair(pair):
    result = make_estimator("asf").estimate(pair.pc1, pair.pc2, pair.dynamic1.astype(np.float32))
    assert result.flow.shape == pair.pc1.shape and np.isfinite(result.flow).all()
    scores = score_flow(result.flow, pair.flow, pair.dynamic1)
    assert scores.static.epe3d < 0.1
    assert np.allclose(result.ego, pair.ego, atol=0.02)


def test_explicit_mask_changes_the_flow_and_points_only_ignores_it(pair):
    mask = pair.dynamic1.astype(np.float32)
    explicit = make_estimator("asf-explicit")
    with_mask = explicit.estimate(pair.pc1, pair.pc2, mask).flow
    without = explicit.estimate(pair.pc1, pair.pc2).flow
    assert np.abs(with_mask - without)[pair.dynamic1].max() > 1e-3
    points = make_estimator("asf-points")
    # the mask still steers the ego registration, so compare with the same registration input
    assert np.allclose(points.estimate(pair.pc1, pair.pc2, np.zeros_like(mask)).flow, points.estimate(pair.pc1, pair.pc2).flow)


def test_missing_or_wrong_weights_are_data_errors(tmp_path):
    with pytest.raises(DataError, match="no such weights file"):
        make_estimator("asf", build(FlowConfig, {"asf.weights": str(tmp_path / "none.pt")}))
    with pytest.raises(DataError, match="strategy"):
        make_estimator("asf-points", build(FlowConfig, {"asf.weights": str(shipped_weights(MaskStrategy.EXPLICIT))}))
    with pytest.raises(DataError, match="unknown mask strategy"):
        make_estimator("asf-fancy")
