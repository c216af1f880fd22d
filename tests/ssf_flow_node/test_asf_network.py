"""The ASF-style network: shapes, flow limits, mask strategies (its point operations: tests/ssf_common/test_torch_ops.py)."""

import pytest
import torch

from ssf_flow_node.core.asf.network import FLOW_LIMIT, AsfConfig, AsfNet, MaskStrategy

SMALL = dict(points=(256, 64, 32, 16), neighbours=(8, 8, 8, 4), encoder_width=8, level_widths=(8, 16, 16, 16),
             cost_width=(8, 8, 8, 8), cost_neighbours=8, patch_neighbours=4, upconv_neighbours=4, flow_width=16)


def trained_looking(net: AsfNet) -> AsfNet:
    """Give the (zero-initialised) flow outputs some weight, as training does."""
    for head in net.heads:
        torch.nn.init.normal_(head.out.weight, std=0.1)
    return net


def clouds(count=1024, batch=2, seed=0):
    generator = torch.Generator().manual_seed(seed)
    return torch.rand(batch, count, 3, generator=generator) * 20.0


@pytest.mark.parametrize("strategy", list(MaskStrategy))
def test_forward_shapes_and_limits(strategy):
    torch.manual_seed(0)
    net = AsfNet(AsfConfig(strategy=strategy, **SMALL)).eval()
    points1, points2 = clouds(600), clouds(550, seed=2)  # the scans need not have the same size
    channels = torch.zeros(2, 600, 2)
    channels[:, :100] = torch.tensor([1.0, 1.0])
    with torch.no_grad():
        pyramid = net(points1, points2, channels)
    assert [flow.shape[1] for flow in pyramid.flows] == [256, 64, 32, 16]
    assert pyramid.full.shape == (2, 600, 3)
    assert all(index.max() < 600 for index in pyramid.indices)
    assert torch.isfinite(pyramid.full).all() and pyramid.full.abs().max() <= FLOW_LIMIT


def test_mask_reaches_the_network_only_when_the_strategy_uses_it():
    points1, points2 = clouds(600), clouds(600, seed=2)
    with_mask = torch.zeros(1, 600, 2)
    with_mask[:, :300] = torch.tensor([1.0, 1.0])
    outputs = {}
    for strategy in MaskStrategy:
        torch.manual_seed(0)
        net = trained_looking(AsfNet(AsfConfig(strategy=strategy, **SMALL))).eval()
        with torch.no_grad():
            outputs[strategy] = (net(points1[:1], points2[:1], with_mask).full, net(points1[:1], points2[:1], None).full)
    assert torch.equal(*outputs[MaskStrategy.POINTS])
    assert not torch.allclose(*outputs[MaskStrategy.EXPLICIT])
    assert not torch.allclose(*outputs[MaskStrategy.IMPLICIT])


def test_untrained_network_keeps_the_ego_compensation():
    net = AsfNet(AsfConfig(**SMALL)).eval()
    with torch.no_grad():
        assert net(clouds(600), clouds(600, seed=2)).full.abs().max() < 0.1


def test_gradients_flow_to_every_parameter():
    torch.manual_seed(0)
    net = trained_looking(AsfNet(AsfConfig(**SMALL)))
    pyramid = net(clouds(600), clouds(600, seed=2), torch.rand(2, 600, 2))
    sum(flow.square().mean() for flow in pyramid.flows).backward()
    assert all(parameter.grad is not None and torch.isfinite(parameter.grad).all() for parameter in net.parameters())
