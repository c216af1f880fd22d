"""Far clusters on whole scans: a wall the sensor's beams slide along is not a moving object, a small far car is.

The fixture holds two clusters of the rigid estimator's first pass on simulated whole scans (hdl64e, the ego at
7.5 m/s): a piece of a building side 64 m away at a grazing angle, whose columns lie 1.6 m apart so that scan t+1
samples it one ego step further along (the matcher then finds a motion of one ego step), and a moving car 38 m away
seen with 24 points. Each comes with its points (ego-compensated and as the sensor saw them), its true step over
the pair (after the ego motion), and the nearby points of scan t+1 with their normals and whether they belong to the
cluster's joint component."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ssf_flow_node.core.rigid import ClusterMotions, Clusters, RigidConfig, cluster_motions

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
