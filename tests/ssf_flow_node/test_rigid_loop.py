"""The rigid estimator inside the fusion loop: stable ego subsets, work cached per pair, motions proven by surfaces,
whole scans spent at every range with ground points pinning the ego."""

from __future__ import annotations

import numpy as np
import pytest

from ssf_common.config import build
from ssf_common.dataset.synthetic import SyntheticBox, sample_box, sample_ground, synthetic_pair
from ssf_common.geometry.ground import ground_mask
from ssf_common.geometry.se3 import make_pose, rigid_flow, transform_points
from ssf_eval.flow.metrics import flow_metrics, score_flow
from ssf_flow_node.core.estimator import WHOLE_SCAN, FlowConfig, make_estimator
from ssf_flow_node.core.preprocess import PreprocessConfig, downsample
from ssf_flow_node.core.registration import RegistrationConfig, ScanMatcher


@pytest.fixture(scope="module")
def pair():
    return synthetic_pair(seed=5, agents=6, ego_step=0.8)


def test_ordered_icp_uses_the_first_points_so_a_mask_keeps_the_others_subset(pair):
    config = RegistrationConfig(source_points=512, refine_points=2048)
    matcher = ScanMatcher(pair.pc2, config)
    source = pair.pc1[np.random.default_rng(1).permutation(len(pair.pc1))]
    ego = matcher.align(source, ordered=True)
    np.testing.assert_allclose(ego, matcher.align(source[:3000], ordered=True), atol=1e-5)  # beyond the subsets: same
    assert np.abs(ego - pair.ego).max() < 0.03


def test_the_same_pair_and_mask_give_the_same_flow_and_the_moved_set_returns_the_last_estimate(pair):
    estimator = make_estimator("rigid")
    first = estimator.estimate(pair.pc1, pair.pc2)
    moved = np.linalg.norm(first.flow - rigid_flow(first.ego, pair.pc1), axis=1) > 0.0
    again = estimator.estimate(pair.pc1, pair.pc2, moved.astype(np.float32))
    assert again is first  # the mask adds nothing the estimate did not already know
    other = make_estimator("rigid").estimate(pair.pc1, pair.pc2)
    np.testing.assert_allclose(other.flow, first.flow, atol=1e-4)
    mask = (pair.instance1 == pair.instance1.max()).astype(np.float32)
    np.testing.assert_allclose(estimator.estimate(pair.pc1, pair.pc2, mask).flow,
                               estimator.estimate(pair.pc1, pair.pc2, mask).flow, atol=1e-4)


def test_a_walker_is_proven_by_the_surfaces_it_leaves():
    """A pedestrian box walking 1.9 m/s: its points' distances to scan t+1 fall by less than half, the distances to
    its surfaces by three quarters."""
    pair = synthetic_pair(seed=7, agents=8, ego_step=0.8)
    own = transform_points(np.linalg.inv(pair.ego), pair.pc1 + pair.flow) - pair.pc1
    result = make_estimator("rigid").estimate(pair.pc1, pair.pc2)
    walkers = [k for k in np.unique(pair.instance1[pair.dynamic1])
               if np.ptp(pair.pc1[pair.instance1 == k, 0]) < 1.0 and 0.15 < np.linalg.norm(own[pair.instance1 == k].mean(0)) < 0.2]
    assert walkers
    for k in walkers:
        on = pair.instance1 == k
        assert flow_metrics(result.flow[on], pair.flow[on]).epe3d < 0.05
    static = ~pair.dynamic1
    assert flow_metrics(result.flow[static], pair.flow[static]).epe3d < 0.02


def test_range_balanced_sampling_keeps_the_far_points():
    rng = np.random.default_rng(0)
    near = rng.uniform(-10, 10, (20000, 3)) + [0, 0, 1]
    far = rng.uniform(-1, 1, (200, 3)) + [80, 0, 1]
    scan = np.concatenate([near, far]).astype(np.float32)
    config = PreprocessConfig(points=4096, max_range=1000.0, range_balance=True)
    sample = downsample(scan, config, np.random.default_rng(0))
    assert len(sample.indices) == 4096 and np.isin(np.arange(20000, 20200), sample.indices).mean() > 0.95
    plain = downsample(scan, config.model_copy(update={"range_balance": False}), np.random.default_rng(0))
    assert np.isin(np.arange(20000, 20200), plain.indices).mean() < 0.4


def test_whole_scans_pin_the_ego_height_with_ground_points():
    pair = synthetic_pair(seed=3, agents=2, ego_step=1.0)
    lifted = make_pose(0.0, 0.0, 0.06, 0.0) @ pair.pose2  # the sensor also rises 6 cm
    pc2 = transform_points(np.linalg.inv(lifted) @ pair.pose2, pair.pc2)
    ego = np.linalg.inv(lifted) @ pair.pose1
    config = build(FlowConfig, WHOLE_SCAN)
    sample = downsample(pair.pc1, config.preprocess, np.random.default_rng(0))
    assert sample.ground is not None and len(sample.ground) > 100
    result = make_estimator("rigid", config).estimate(pair.pc1, pc2)
    assert abs(result.ego[2, 3] - ego[2, 3]) < 0.01
    truth = transform_points(ego, pair.pc1) - pair.pc1  # the static scene's flow
    assert score_flow(result.flow, truth, pair.dynamic1).static.epe3d < 0.02


def test_scans_without_ground_keep_their_objects_bottoms(pair):
    """The protocol's scans have no ground: the lowest points are the bottoms of objects, and they move with them."""
    cut = pair.class1 != 0
    pc2_cut = pair.pc2[~ground_mask(pair.pc2)]  # scan t+1 without its ground either
    result = make_estimator("rigid").estimate(pair.pc1[cut], pc2_cut)
    estimator = make_estimator("rigid")
    estimator.estimate(pair.pc1[cut], pc2_cut)
    assert estimator.state.above1.all()
    movers = pair.dynamic1[cut]
    assert flow_metrics(result.flow[movers], pair.flow[cut][movers]).epe3d < 0.15


def convoy_scans(step: float = 0.45, seed: int = 0):
    """A street where cars all around the ego move with it (a queue driving along): scan t, scan t+1, the cars'
    points of each, and the true ego motion."""
    rng = np.random.default_rng(seed)
    poles = [SyntheticBox(np.array([x, side * 9.0, 0.0]), np.array([0.4, 0.4, 4.0]), 0.0)
             for x in (-20.0, -5.0, 12.0, 27.0)
             for side in (-1, 1)]
    cars = [SyntheticBox(np.array([x, lane, 0.0]), np.array([4.5, 1.9, 1.6]), 0.0) for x in (-14.0, -7.0, 7.0, 14.0)
            for lane in (-3.5, 3.5)] + [SyntheticBox(np.array([x, 0.0, 0.0]), np.array([4.5, 1.9, 1.6]), 0.0) for x in (-7.5, 7.5)]

    def scan(sensor_x: float) -> tuple[np.ndarray, np.ndarray]:
        eye = np.array([sensor_x, 0.0, 1.8])
        parts = [sample_ground(rng, 3000, eye)] + [sample_box(rng, pole, 150, eye) for pole in poles]
        parts += [sample_box(rng, car._replace(centre=car.centre + [sensor_x, 0.0, 0.0]), 500, eye) for car in cars]
        world = np.concatenate(parts) + rng.normal(0.0, 0.01, (sum(len(part) for part in parts), 3))
        moving = np.repeat([False] * (1 + len(poles)) + [True] * len(cars), [len(part) for part in parts])
        return (world - eye).astype(np.float32), moving

    (pc1, moving1), (pc2, moving2) = scan(0.0), scan(step)
    return pc1, pc2, moving1, moving2, make_pose(-step, 0.0, 0.0, 0.0)


def test_a_queue_moving_with_the_ego_is_kept_out_of_its_motion_by_the_mask():
    """Every point aligned: the cars, half the scan, pull the ego towards standing still; without the mask's cars the
    motion is right, and the previous pair's motion (constant velocity, before the queue closed in) confirms it."""
    pc1, pc2, cars, cars2, truth = convoy_scans()
    estimator = make_estimator("rigid")
    before = estimator.estimate(pc1[~cars], pc2[~cars2])  # the previous pair: the same motion, no queue yet
    assert np.linalg.norm(before.ego[:3, 3] - truth[:3, 3]) < 0.01
    result = estimator.estimate(pc1, pc2, cars.astype(np.float32))
    assert np.linalg.norm(estimator.state.base_ego[:3, 3] - truth[:3, 3]) > 0.1  # all points: pulled by the cars
    assert np.linalg.norm(result.ego[:3, 3] - truth[:3, 3]) < 0.01


@pytest.mark.parametrize("seed", [2, 3, 5])
def test_a_mask_that_calls_the_static_structure_dynamic_does_not_steer_the_ego(seed):
    """A carried mask that calls every building and pole dynamic leaves the ground and the cars, which align far from
    the previous pair's motion: the alignment on every point, near it, is kept."""
    pair = synthetic_pair(seed=seed, agents=8, ego_step=1.0)
    structure = (pair.class1 != 0) & ~pair.dynamic1
    estimator = make_estimator("rigid")
    estimator.estimate(pair.pc1[1:], pair.pc2)  # the previous pair: the same motion
    wrong = estimator.estimate(pair.pc1, pair.pc2, structure.astype(np.float32))
    assert np.linalg.norm(wrong.ego[:3, 3] - pair.ego[:3, 3]) < 0.01
    right = estimator.estimate(pair.pc1, pair.pc2, pair.dynamic1.astype(np.float32))  # the same pair, a true mask
    assert np.linalg.norm(right.ego[:3, 3] - pair.ego[:3, 3]) < 0.01
    assert not np.allclose(right.ego, wrong.ego)  # the true mask's alignment is taken


def test_the_alignment_without_movers_wins_where_only_it_is_a_change_a_vehicle_can_make():
    """Accelerating in a queue, traffic moving with the ego pulls the alignment on every point to standing still: 0.1 m
    from the previous pair's motion in one scan (10 m/s²), just beyond the tolerance that would compare the two."""
    from ssf_flow_node.core.rigid import RigidConfig
    from ssf_flow_node.core.rigid.ego import nearer_prior

    def forward(metres: float) -> np.ndarray:
        return make_pose(-metres, 0.0, 0.0, 0.0)  # scan t into scan t+1 as the sensor drives forward

    config = RigidConfig()
    prior, base = forward(0.087), forward(-0.014)
    assert nearer_prior(forward(0.090), base, prior, config)  # the masked alignment: 3 mm from constant velocity
    assert not nearer_prior(forward(0.0), base, prior, config)  # 8.7 cm off in 0.1 s: beyond a vehicle as well
    assert not nearer_prior(forward(0.090), forward(0.030), prior, config)  # 5.7 cm: a hard brake, and it agrees
    faster = RigidConfig(scan_period=0.05)  # at 20 Hz a vehicle changes 4 times less
    assert not nearer_prior(forward(0.060), base, prior, faster)
    assert not nearer_prior(forward(0.090), base, prior, config, dynamic_share=0.6)  # a mask hiding most of the scan


def test_an_alignment_without_restarts_is_its_first_refinement_trusted_or_not(pair):
    """Far from the `prior`, an alignment restarts from the other samples and the prior; without restarts it is the
    refinement from its coarse start, as that start's alignment with restarts would be near the prior."""
    matcher = ScanMatcher(pair.pc2, RegistrationConfig(source_points=512, refine_points=2048))
    source = pair.pc1[np.random.default_rng(1).permutation(len(pair.pc1))]
    calls = []
    refined = matcher.refined
    matcher.refined = lambda *args, **kwargs: calls.append(1) or refined(*args, **kwargs)
    far = make_pose(5.0, 0.0, 0.0, 0.0)
    once = matcher.align(source, ordered=True, prior=far, restarts=False)
    assert len(calls) == 1
    np.testing.assert_allclose(once, matcher.align(source, ordered=True), atol=1e-9)
    matcher.align(source, ordered=True, prior=far)
    assert len(calls) > 3  # 1 + the first again, the other samples' and the prior's


def test_the_alignment_that_only_judges_a_steady_masked_one_is_not_restarted():
    """Where the mask calls most points dynamic, the alignment without them is judged against the one on every point;
    that one restarts only where the masked one is no change of the previous pair's motion a vehicle can make."""
    from types import SimpleNamespace

    from ssf_flow_node.core.rigid import RigidConfig
    from ssf_flow_node.core.rigid.ego import pair_ego_motion

    prior = make_pose(-0.5, 0.0, 0.0, 0.0)

    def restarts_of_the_judge(masked: np.ndarray, config: RigidConfig) -> bool:
        asked = []

        def align(source, initial=None, ordered=False, prior=None, restarts=True):
            asked.append(restarts)
            return masked if len(asked) == 1 else make_pose(0.0, 0.0, 0.0, 0.0)  # the judge: pulled to standing still

        state = SimpleNamespace(source=np.zeros((100, 3)), order=np.arange(100), prior=prior, measured=None, base_ego=None, ego=None,
                                matcher=SimpleNamespace(align=align))
        dynamic = np.arange(100) < 60  # most points: beyond ego_mask_share, so the masked one is never taken at once
        pair_ego_motion(state, dynamic, config)
        assert len(asked) == 2
        return asked[1]

    config = RigidConfig()
    assert not restarts_of_the_judge(make_pose(-0.51, 0.0, 0.0, 0.0), config)  # 1 cm from constant velocity
    assert restarts_of_the_judge(make_pose(-0.2, 0.0, 0.0, 0.0), config)  # 30 cm in 0.1 s: no vehicle does that
    assert restarts_of_the_judge(make_pose(-0.51, 0.0, 0.0, 0.0), RigidConfig(ego_judge_restarts=True))
