"""The self-supervised losses against hand-computed cases: weighted Kabsch, L_mot, L_SC, L_CD, smoothness."""

import numpy as np
import pytest
import torch

from ssf_common.geometry.se3 import make_pose
from ssf_seg_node.core.ogc.losses import (chamfer_loss, consistency_loss, motion_loss, narrower, neighbourhood,
                                          rigid_mixture, slot_kabsch, slot_motions, smoothness_loss)


def moved(points: torch.Tensor, pose: np.ndarray) -> torch.Tensor:
    transform = torch.tensor(pose, dtype=torch.float32)
    return points @ transform[:3, :3].T + transform[:3, 3]


@pytest.fixture()
def two_bodies():
    """200 points of one rigid body and 100 of another, each with its own motion, and the true one-hot masks."""
    generator = torch.Generator().manual_seed(0)
    first = torch.rand(1, 200, 3, generator=generator) * 4.0
    second = torch.rand(1, 100, 3, generator=generator) * 2.0 + 10.0
    points = torch.cat([first, second], dim=1)
    target = torch.cat([moved(first, make_pose(1.0, 0.2, 0.0, 0.05)), moved(second, make_pose(-0.5, 1.0, 0.0, -0.2))], dim=1)
    right = torch.zeros(1, 300, 2)
    right[0, :200, 0] = 1.0
    right[0, 200:, 1] = 1.0
    return points, target - points, right


def test_kabsch_recovers_each_slot_motion(two_bodies):
    points, flow, masks = two_bodies
    motions = slot_kabsch(points, points + flow, masks)
    expected = make_pose(-0.5, 1.0, 0.0, -0.2)
    np.testing.assert_allclose(motions.rotation[0, 1].numpy(), expected[:3, :3], atol=1e-5)
    np.testing.assert_allclose(motions.translation[0, 1].numpy(), expected[:3, 3], atol=1e-4)
    assert motions.rotation.dtype == torch.float32


def test_kabsch_fixes_reflections_and_gives_empty_slots_the_identity():
    generator = torch.Generator().manual_seed(1)
    points = torch.rand(1, 50, 3, generator=generator)
    mirrored = points * torch.tensor([1.0, 1.0, -1.0])  # no rotation maps a cloud onto its mirror image
    masks = torch.zeros(1, 50, 2)
    masks[..., 0] = 1.0  # slot 1 holds nothing
    motions = slot_kabsch(points, mirrored, masks)
    assert torch.det(motions.rotation[0, 0]).item() == pytest.approx(1.0, abs=1e-5)
    assert torch.equal(motions.rotation[0, 1], torch.eye(3)) and torch.equal(motions.translation[0, 1], torch.zeros(3))


def test_kabsch_is_differentiable_in_the_weights(two_bodies):
    points, flow, right = two_bodies
    logits = torch.zeros(1, 300, 2, requires_grad=True)
    weights = torch.softmax(logits + 4.0 * right, dim=-1)
    motions = slot_kabsch(points, points + flow, weights)
    (motions.translation.sum() + motions.rotation.sum()).backward()
    assert torch.isfinite(logits.grad).all() and logits.grad.abs().sum() > 0


def test_motion_loss_is_zero_for_the_right_masks_and_clearly_positive_for_a_wrong_split(two_bodies):
    points, flow, right = two_bodies
    wrong = torch.zeros_like(right)
    wrong[0, :100, 0] = 1.0  # half of the first body joins the second one
    wrong[0, 100:, 1] = 1.0
    assert motion_loss(points, flow, right).item() < 1e-5
    assert motion_loss(points, flow, wrong).item() > 0.1


def test_motion_loss_gradient_reaches_the_masks_only_and_fixes_a_wrong_assignment(two_bodies):
    """The slot motions are fitted without gradient (OGC detaches the moved points); a step on the masks lowers L_mot."""
    points, flow, right = two_bodies
    logits = (4.0 * right).clone()
    logits[0, :20] = logits[0, :20].flip(-1)  # 20 points of body one sit in slot 1
    logits.requires_grad_(True)
    masks = torch.softmax(logits, dim=-1)
    motions = slot_motions(points, flow, masks)
    assert not motions.rotation.requires_grad
    loss = motion_loss(points, flow, masks, motions)
    loss.backward()
    with torch.no_grad():
        stepped = torch.softmax(logits - 50.0 * logits.grad, dim=-1)
    assert motion_loss(points, flow, stepped, motions).item() < loss.item()


def test_consistency_loss_by_hand():
    masks = torch.zeros(1, 4, 2)
    masks[0, :2, 0] = 1.0
    masks[0, 2:, 1] = 1.0
    constant = torch.tensor([[[1.0, 0, 0], [1.0, 0, 0], [0, 2.0, 0], [0, 2.0, 0]]])
    assert consistency_loss(constant, masks).item() == pytest.approx(0.0, abs=1e-7)
    spread = torch.tensor([[[1.0, 0, 0], [3.0, 0, 0], [0, 2.0, 0], [0, 2.0, 0]]])
    # slot 0: flows 1 and 3 around 2 -> variance 1; slot 1: 0; mean over the two occupied slots = 0.5
    assert consistency_loss(spread, masks).item() == pytest.approx(0.5, abs=1e-6)
    empty = torch.zeros(1, 4, 3)
    empty[..., :2] = masks
    assert consistency_loss(spread, empty).item() == pytest.approx(0.5, abs=1e-6)  # an empty slot is not averaged


def test_chamfer_of_the_rigid_mixture(two_bodies):
    points, flow, right = two_bodies
    scan2 = points + flow
    motions = slot_motions(points, flow, right)
    assert chamfer_loss(rigid_mixture(points, right, motions), scan2).item() < 1e-4
    single = torch.tensor([[[0.0, 0, 0]]])
    assert chamfer_loss(single, single + torch.tensor([0.3, 0.4, 0.0])).item() == pytest.approx(1.0, abs=1e-6)


def test_smoothness_by_hand():
    points = torch.tensor([[[0.0, 0, 0], [0.5, 0, 0], [5.0, 0, 0]]])
    neighbours = neighbourhood(points, 2, radius=1.0)
    assert neighbours[0].tolist() == [[0, 1], [1, 0], [2, 2]]  # the far point has only itself
    masks = torch.tensor([[[1.0, 0.0], [0.0, 1.0], [0.5, 0.5]]])
    # pairs (0,0) (0,1) (1,1) (1,0) (2,2) (2,2): L1 differences 0 2 0 2 0 0 -> mean 4/6
    assert smoothness_loss(masks, neighbours).item() == pytest.approx(4.0 / 6.0)
    assert smoothness_loss(torch.full((1, 3, 2), 0.5), neighbours).item() == 0.0


def test_narrower_neighbourhood_equals_a_direct_search():
    points = torch.rand(1, 2000, 3, generator=torch.Generator().manual_seed(2)) * 15.0
    assert torch.equal(narrower(points, neighbourhood(points, 64, 2.0), 32, 1.0), neighbourhood(points, 32, 1.0))
