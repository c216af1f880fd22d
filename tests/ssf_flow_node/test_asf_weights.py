"""The shipped network weights: they load by default, run on a synthetic pair, and take the mask as input."""

import numpy as np
import pytest
import torch

from ssf_common.config import build
from ssf_common.errors import DataError
from ssf_flow_node.core.asf.checkpoint import shipped_asf_weights
from ssf_flow_node.core.asf.estimator import mask_channels
from ssf_flow_node.core.asf.network import MaskStrategy
from ssf_flow_node.core.estimator import WHOLE_SCAN, FlowConfig, make_estimator
from ssf_common.dataset.synthetic import synthetic_pair
from ssf_eval.flow.metrics import score_flow


@pytest.fixture(scope="module")
def pair():
    return synthetic_pair(seed=0, agents=2, ego_step=1.0)


@pytest.mark.parametrize("strategy", list(MaskStrategy))
def test_shipped_weights_exist_and_load(strategy):
    assert shipped_asf_weights(strategy).stat().st_size < 8_000_000
    assert make_estimator(f"asf-{strategy.value}").name == f"asf-{strategy.value}"


def test_asf_defaults_to_the_explicit_strategy():
    assert make_estimator("asf").name == "asf-explicit"


def test_asf_keeps_the_ego_motion_on_a_synthetic_pair(pair):
    """Whole scans (ground included) go through the whole-scan preprocessing, as in the node: the network was
    trained on ground-free pairs."""
    estimator = make_estimator("asf", build(FlowConfig, WHOLE_SCAN))
    result = estimator.estimate(pair.pc1, pair.pc2, pair.dynamic1.astype(np.float32))
    assert result.flow.shape == pair.pc1.shape and np.isfinite(result.flow).all()
    scores = score_flow(result.flow, pair.flow, pair.dynamic1)
    assert scores.static.epe3d < 0.1
    assert np.allclose(result.ego, pair.ego, atol=0.02)


@torch.no_grad()
@pytest.mark.parametrize("strategy, reads_mask", [("explicit", True), ("implicit", True), ("points", False)])
def test_shipped_networks_read_the_mask_as_their_strategy_says(pair, strategy, reads_mask):
    """Same network inputs but the mask channels: only the points-only network answers the same."""
    estimator = make_estimator(f"asf-{strategy}")
    warped, points2 = estimator.batch(pair.pc1), estimator.batch(pair.pc2)
    count = len(pair.pc1)
    with_mask = estimator.network(warped, points2, estimator.batch(mask_channels(pair.dynamic1, count))).full
    without = estimator.network(warped, points2, estimator.batch(mask_channels(None, count))).full
    assert (not torch.equal(with_mask, without)) is reads_mask


def test_missing_or_wrong_weights_are_data_errors(tmp_path):
    with pytest.raises(DataError, match="no such weights file"):
        make_estimator("asf", build(FlowConfig, {"asf.weights": str(tmp_path / "none.pt")}))
    weights = str(shipped_asf_weights(MaskStrategy.EXPLICIT))
    with pytest.raises(DataError, match="strategy"):
        make_estimator("asf-points", build(FlowConfig, {"asf.weights": weights}))
    with pytest.raises(DataError, match="unknown mask strategy"):
        make_estimator("asf-fancy")
