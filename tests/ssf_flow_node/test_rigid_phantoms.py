"""Whole scans: a far wall the sensor's beams slide along is not a moving object, a small far car is, and the lowest
points of moving objects move with them.

The fixture holds three clusters of the rigid estimator's first pass on simulated whole scans (urban_100, tuning
seeds 4 and 1; hdl64e, the ego at 7.5 to 9 m/s): a piece of a building side 64 m away at a grazing angle, whose
columns lie 1.6 m apart so that scan t+1 samples it one ego step further along (the matcher then finds a motion of
one ego step); the end of such a wall 60 m away, where the beams that saw its last column find nothing in scan t+1;
and a moving car 38 m away seen with 24 points (a second fixture holds two cars beside a crawling ego). Each comes with its points (ego-compensated and as the sensor saw
them), its true step over the pair (after the ego motion), and the nearby points of scan t+1 with their normals and
whether they belong to the cluster's joint component."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ssf_common.config import build
from ssf_common.dataset.pairs import PointClass
from ssf_common.dataset.synthetic import synthetic_pair
from ssf_common.geometry.ground import height_above_ground
from ssf_eval.flow.metrics import flow_metrics
from ssf_flow_node.core.estimator import WHOLE_SCAN, FlowConfig, make_estimator
from ssf_flow_node.core.rigid.clusters import Clusters
from ssf_flow_node.core.rigid.config import RigidConfig
from ssf_flow_node.core.rigid.motions import ClusterMotions, cluster_motions

FIXTURE = Path(__file__).resolve().parent / "fixtures" / "far_clusters.npz"


def motion_of(name: str, resampled: bool) -> ClusterMotions:
    """The motion rigid finds for the fixture's cluster (resampled: standing still may be sampled by the moved beams)."""
    data = np.load(FIXTURE)
    assert len(data[f"{name}_points1"]) < 30  # fewer points than the ICP and histogram subsets: all of them count
    points1, sensed, points2, normals2, own2, floor = (
        data[f"{name}_{field}"].astype(np.float64) for field in ("points1", "sensed", "points2", "normals2", "own2", "floor"))
    clusters = Clusters(np.zeros(len(points1), np.int64), np.where(own2 > 0, 0, 1).astype(np.int64), 1, np.array([0]))
    return cluster_motions(points1, points2, clusters, RigidConfig(), None, normals2, np.full(2, float(floor)),
                           sensed=sensed if resampled else None)


@pytest.mark.parametrize("name", ["wall", "wall_end"])
def test_a_far_wall_resampled_one_ego_step_along_is_static(name):
    assert motion_of(name, resampled=False).moving[0]  # the points alone: the wall seems to move one ego step
    still = motion_of(name, resampled=True)
    assert not still.moving[0] and np.all(still.translation == 0.0)


@pytest.mark.parametrize("resampled", [False, True])
def test_a_small_far_car_keeps_its_motion(resampled):
    motion = motion_of("car", resampled)
    assert motion.moving[0]
    step = np.load(FIXTURE)["car_step"]
    assert np.linalg.norm(step[:2]) > 0.25  # the car drives at least 2.5 m/s
    assert np.linalg.norm(motion.translation[0, :2] - step[:2]) < 0.1


QUEUE_FIXTURE = Path(__file__).resolve().parent / "fixtures" / "queue_clusters.npz"


@pytest.mark.parametrize("name", ["overtaking", "oncoming"])
def test_a_car_beside_a_crawling_ego_is_not_taken_for_a_resampled_still_surface(name):
    """Two cars of a queue scenario (stress_queue, tuning seeds 11 and 14; hdl64e, the ego crawling at 1.6-2 m/s): one
    overtaking it 5 m away at 3.4 m/s, one going the other way at 1.9 m/s 17 m away. Their flanks slide along
    themselves and scan t+1 samples them finer than resample_spacing but coarser than half the ego's short step: counted
    as resampled still surfaces they stood still; now they keep their true motion."""
    data = np.load(QUEUE_FIXTURE)
    points1, sensed, points2, normals2, own2, floor, step = (
        data[f"{name}_{field}"].astype(np.float64)
        for field in ("points1", "sensed", "points2", "normals2", "own2", "floor", "step"))
    clusters = Clusters(np.zeros(len(points1), np.int64), np.where(own2 > 0, 0, 1).astype(np.int64), 1, np.array([0]))

    def motion(config: RigidConfig) -> ClusterMotions:
        return cluster_motions(points1, points2, clusters, config, None, normals2, np.full(2, float(floor)),
                               sensed=sensed)

    assert np.linalg.norm(sensed - points1, axis=1).mean() < 0.25  # the ego's step: a crawl
    assert not motion(RigidConfig(resample_spacing=0.0, end_spacings=0.0)).moving[0]  # resampled at any spacing: still
    kept = motion(RigidConfig())
    assert kept.moving[0] and np.linalg.norm(kept.translation[0, :2] - step[:2]) < 0.05
    if name == "overtaking":  # a fitted motion the resampling explains away still moves by its ends where they moved
        rescued = motion(RigidConfig(resample_spacing=0.0))
        assert rescued.moving[0] and np.linalg.norm(rescued.translation[0, :2] - step[:2]) < 0.06


def test_the_lowest_points_of_a_moving_object_move_with_it_and_the_ground_beside_it_stays():
    """Points within ground_clearance of the ground keep the scene's motion, except in a moving object's footprint."""
    pair = synthetic_pair(seed=5, agents=12, ego_step=0.8, points=60000)
    config = build(FlowConfig, WHOLE_SCAN)
    low = height_above_ground(pair.pc1, config.preprocess.ground_cell) < config.rigid.ground_clearance
    movers, ground = low & pair.dynamic1, low & (pair.class1 == PointClass.GROUND)
    assert movers.sum() > 100 and ground.sum() > 10000
    flow = make_estimator("rigid", config).estimate(pair.pc1, pair.pc2).flow
    plain = make_estimator("rigid", build(FlowConfig, WHOLE_SCAN, {"rigid": {"footprint": 0.0}})).estimate(pair.pc1, pair.pc2).flow
    assert flow_metrics(flow[movers], pair.flow[movers]).epe3d < 0.5 * flow_metrics(plain[movers], pair.flow[movers]).epe3d
    assert flow_metrics(flow[ground], pair.flow[ground]).acc_strict > 0.99
