"""Ego registration on a sparse scan pair whose identity start stays at no motion."""

import numpy as np
import pytest

from ssf_common.geometry.se3 import make_pose
from ssf_common.errors import ConfigError
from ssf_flow_node.core.registration import IcpBackend, RegistrationConfig, ScanMatcher, same_motion

STEP = 0.6  # the sensor's forward motion between the scans (m)


def street(rng: np.random.Generator) -> np.ndarray:
    """Poles every 1.2 m on both sides of the drive (twice the step: a point lies halfway between two of them) and a
    wall along it."""
    poles = [np.column_stack([np.full(8, x), np.full(8, y), np.linspace(-1.5, 1.5, 8)])
             for x in np.arange(-24.0, 24.1, 1.2) for y in (-4.0, 4.0)]
    wall = np.column_stack([rng.uniform(-30, 30, 600), np.full(600, 9.0), rng.uniform(-1.5, 3.0, 600)])
    return np.concatenate(poles + [wall])


def rings(per_ring: int = 120) -> np.ndarray:
    """Ground rings of a sparse sensor: the same in the sensor's frame wherever it drives."""
    angles = np.linspace(0.0, 2.0 * np.pi, per_ring, endpoint=False)
    return np.concatenate([np.column_stack([r * np.cos(angles), r * np.sin(angles), np.full(per_ring, -1.7)])
                           for r in (5.0, 7.0, 10.0, 14.0, 20.0)])


@pytest.fixture(scope="module")
def sparse_pair():
    rng = np.random.default_rng(0)
    static = street(rng)
    source = np.concatenate([static, rings()])
    target = np.concatenate([static - [STEP, 0.0, 0.0], rings()])
    return source[rng.permutation(len(source))], target, make_pose(-STEP)


def test_a_single_identity_start_stays_at_no_motion(sparse_pair):
    source, target, truth = sparse_pair
    matcher = ScanMatcher(target, RegistrationConfig())
    single = matcher.refine(source, matcher.coarse(source))
    assert np.linalg.norm(single[:3, 3]) < 0.1  # the trap the robust registration must get out of


def test_the_previous_motion_as_a_start_finds_the_true_motion(sparse_pair):
    source, target, truth = sparse_pair
    matcher = ScanMatcher(target, RegistrationConfig())
    previous = make_pose(-0.55)  # a stream's constant velocity, a little off
    found = matcher.align(source, prior=previous)
    assert np.linalg.norm(found[:3, 3] - truth[:3, 3]) < 0.03
    assert same_motion(matcher.align(source, prior=np.eye(4)), np.eye(4), 0.1)  # no better start: no change



@pytest.mark.parametrize("backend", list(IcpBackend))
def test_each_icp_backend_finds_a_known_motion_from_a_close_start(sparse_pair, backend):
    source, target, truth = sparse_pair
    matcher = ScanMatcher(target, RegistrationConfig(backend=backend))
    assert np.allclose(np.linalg.norm(matcher.normals(), axis=1)[:100], 1.0, atol=1e-6)  # the target's normals
    found = matcher.refine(source, make_pose(-0.5))
    assert np.linalg.norm(found[:3, 3] - truth[:3, 3]) < 0.02
    assert matcher.refined(source, found).fitness > 0.6  # all but the ground rings, which drive with the sensor



def corner(rng: np.random.Generator, count: int) -> np.ndarray:
    """Points on a street corner: the ground, two walls at an angle and a box (no two points alike)."""
    ground = np.column_stack([rng.uniform(-20, 20, count), rng.uniform(-20, 20, count), rng.normal(-1.7, 0.01, count)])
    wall = np.column_stack([rng.uniform(-20, 20, count), rng.normal(6.0, 0.01, count), rng.uniform(-1.7, 2.0, count)])
    side = np.column_stack([rng.normal(12.0, 0.01, count), rng.uniform(-20, 6, count), rng.uniform(-1.7, 2.0, count)])
    box = rng.uniform([3.0, -3.0, -1.7], [5.0, -1.0, -0.2], (count, 3))
    return np.concatenate([ground, wall, side, box])


@pytest.mark.parametrize("distance", [2.0, 0.2])
def test_the_shared_layers_icp_gives_open3ds_answers(distance):
    """`plane` runs Open3D's algorithm on a KD-tree built once: the same transform and matched share, step by step."""
    rng = np.random.default_rng(3)
    target = corner(rng, 1500)
    motion = make_pose(-0.45, 0.05, 0.0, 0.02)
    source = corner(rng, 500) @ motion[:3, :3].T + motion[:3, 3]  # other samples of the same surfaces, moved
    config = RegistrationConfig(tolerance=1e-6)
    plane = ScanMatcher(target, config.model_copy(update={"backend": IcpBackend.PLANE}))
    open3d = ScanMatcher(target, config.model_copy(update={"backend": IcpBackend.OPEN3D}))
    for start, iterations in ((make_pose(0.4, -0.05, 0.0, -0.02), 30), (np.eye(4), 30), (np.eye(4), 2)):
        ours = plane.fit(source, start, len(source), distance, iterations)
        theirs = open3d.fit(source, start, len(source), distance, iterations)
        np.testing.assert_allclose(ours.transform, theirs.transform, atol=1e-9)
        assert ours.fitness == pytest.approx(theirs.fitness, abs=1e-12)
        assert ours.inliers == theirs.inliers and ours.rmse == pytest.approx(theirs.rmse, rel=1e-9)
        if start[0, 3] > 0:  # from near the truth: onto it
            assert np.abs(ours.transform @ motion - np.eye(4)).max() < 0.01
