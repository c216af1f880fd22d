"""Torch point operations shared by the networks: neighbour search without N x N matrices, ball grouping, FPS,
interpolation."""

import torch

from ssf_common.geometry.torch_ops import (ball_group, batched_knn, farthest_points, farthest_torch, gather, interpolate,
                                           knn_chunked, knn_kdtree)


def clouds(count=1024, batch=2, seed=0):
    generator = torch.Generator().manual_seed(seed)
    return torch.rand(batch, count, 3, generator=generator) * 20.0


def test_kdtree_and_chunked_knn_agree():
    reference, query = clouds(3000), clouds(1500, seed=1)
    tree = knn_kdtree(query, reference, 6)
    chunked = knn_chunked(query, reference, 6)
    distance = lambda index: (gather(reference, index) - query.unsqueeze(2)).norm(dim=-1)
    assert torch.allclose(distance(tree).sort(-1).values, distance(chunked).sort(-1).values, atol=1e-4)


def test_farthest_points_are_distinct_and_spread():
    points = clouds(2048)
    index = farthest_points(points, 128)
    assert index.shape == (2, 128)
    assert all(len(set(row.tolist())) == 128 for row in index)
    picked = gather(points, index)
    random_pick = points[:, :128]
    spacing = lambda p: torch.cdist(p, p).add(torch.eye(128) * 1e9).min(-1).values.mean()
    assert spacing(picked) > 1.5 * spacing(random_pick)
    torch_index = farthest_torch(points, 128)
    assert spacing(gather(points, torch_index)) > 1.5 * spacing(random_pick)


def test_interpolation_reproduces_values_at_source_points():
    source = clouds(200)
    values = source * 2.0
    assert torch.allclose(interpolate(source, values, source, k=3), values, atol=1e-3)


def test_ball_group_keeps_neighbours_inside_the_radius_nearest_first():
    reference = torch.tensor([[[0.0, 0, 0], [0.5, 0, 0], [3.0, 0, 0], [10.0, 0, 0]]])
    query = torch.tensor([[[0.1, 0, 0], [9.0, 0, 0]]])
    index = ball_group(query, reference, 3, radius=1.0)
    assert index[0, 0].tolist() == [0, 1, 0]  # the point at 3 m is beyond the radius: the nearest repeats
    assert index[0, 1].tolist() == [3, 3, 3]
    assert torch.equal(ball_group(query, reference, 3, radius=100.0), batched_knn(query, reference, 3))
