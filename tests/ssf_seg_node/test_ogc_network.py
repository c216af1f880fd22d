"""The OGC-style network and the PointNet++ classifier: shapes, inputs, GroupNorm, no N x N matrices, checkpoints."""

import pytest
import torch

from ssf_common.errors import DataError
from ssf_seg_node.core.base import SegInput
from ssf_seg_node.core.ogc import checkpoint
from ssf_seg_node.core.ogc.checkpoint import NetworkKind
from ssf_seg_node.core.ogc.network import GroupNorm, OgcConfig, OgcNet, PointNetClassifier

SMALL = dict(input_width=8, widths=(16, 16, 32), embedding=16, decoder_width=16, heads=2, slots=4)


def clouds(count=600, batch=2, seed=0):
    generator = torch.Generator().manual_seed(seed)
    return torch.rand(batch, count, 3, generator=generator) * 20.0, torch.rand(batch, count, 3, generator=generator)


def test_group_norm_matches_torch_on_channels_last():
    x = torch.randn(2, 50, 7, 16) * 3.0 + 1.0
    ours = GroupNorm(4, 16)(x)
    reference = torch.nn.functional.group_norm(x.permute(0, 3, 1, 2), 4).permute(0, 2, 3, 1)
    assert torch.allclose(ours, reference, atol=1e-4)


@pytest.mark.parametrize("kind", list(SegInput))
def test_slot_masks_are_soft_assignments_of_every_point(kind):
    torch.manual_seed(0)
    net = OgcNet(OgcConfig(input=kind, **SMALL)).eval()
    points, flow = clouds()
    masks = net.predict(points, flow)
    assert masks.shape == (2, 600, 4)
    assert torch.allclose(masks.sum(dim=-1), torch.ones(2, 600), atol=1e-5) and (masks >= 0).all()


def test_the_input_decides_what_the_network_sees():
    points, flow = clouds()
    other_flow = torch.rand_like(flow) * 3.0
    for kind, sees_flow in ((SegInput.POINTS, False), (SegInput.FLOW, True), (SegInput.BOTH, True)):
        torch.manual_seed(0)
        net = OgcNet(OgcConfig(input=kind, **SMALL)).eval()
        changed = not torch.allclose(net.predict(points, flow), net.predict(points, other_flow))
        assert changed == sees_flow, kind


def test_pointnet_gives_a_probability_per_point():
    torch.manual_seed(0)
    net = PointNetClassifier(OgcConfig(**SMALL))
    points, flow = clouds()
    assert net(points, flow).shape == (2, 600)
    probability = net.predict(points, flow)
    assert ((probability > 0) & (probability < 1)).all()


def test_a_whole_scan_runs_without_any_n_by_n_distance_matrix(monkeypatch):
    """On the CPU every neighbour search is a KD-tree; torch.cdist (an N x M matrix) is never called."""
    def refuse(*args, **kwargs):
        raise AssertionError("torch.cdist called")

    monkeypatch.setattr(torch, "cdist", refuse)
    net = OgcNet(OgcConfig()).eval()
    points, flow = clouds(8192, batch=1)
    assert net.predict(points, flow).shape == (1, 8192, 10)


def test_checkpoint_round_trip_and_bad_files(tmp_path):
    torch.manual_seed(0)
    net = OgcNet(OgcConfig(input=SegInput.FLOW, **SMALL))
    path = tmp_path / "net.pt"
    checkpoint.save_seg_checkpoint(path, NetworkKind.OGC, net, {"steps": 3}, {"step": 3})
    loaded = checkpoint.load_seg_checkpoint(path)
    assert loaded.kind is NetworkKind.OGC and loaded.config == net.config and loaded.training == {"steps": 3}
    points, flow = clouds()
    assert torch.allclose(loaded.network.predict(points, flow), net.eval()(points, flow))
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    for bad, message in ((tmp_path / "missing.pt", "no such weights file"), (tmp_path / "junk.pt", "not a readable")):
        with pytest.raises(DataError, match=message):
            checkpoint.load_seg_checkpoint(bad)
    torch.save({"format": "something else"}, tmp_path / "foreign.pt")
    with pytest.raises(DataError, match="not an ssf segmentation network"):
        checkpoint.load_seg_checkpoint(tmp_path / "foreign.pt")
