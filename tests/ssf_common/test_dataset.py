"""One pair format: write -> read gives identical arrays; readers reject bad files in one line; KITTI sequences."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ssf_common.dataset.kitti import KittiSequence, SequenceWriter, read_poses
from ssf_common.dataset.masks import noisy_mask
from ssf_common.dataset.pairs import PAIR_KEYS, PointClass, make_pair, pair_files, read_pair, read_pairs, write_pair
from ssf_common.dataset.synthetic import synthetic_pair
from ssf_common.errors import DataError
from ssf_common.geometry.neighbours import nearest
from ssf_common.geometry.fitting import weighted_kabsch
from ssf_common.geometry.se3 import make_pose, transform_points


@pytest.fixture(scope="module")
def pair():
    return synthetic_pair(seed=3, agents=3, points=4096)


@pytest.mark.parametrize("with_mask", [False, True])
@pytest.mark.parametrize("swept", [False, True])
def test_pair_round_trip_is_exact(tmp_path, pair, with_mask, swept):
    original = pair.with_mask(np.linspace(0, 1, len(pair.pc1))) if with_mask else pair
    if swept:  # a rolling-shutter sweep's per-point time
        original = replace(original, time1=np.linspace(-0.1, 0, len(pair.pc1), dtype=np.float32),
                           time2=np.linspace(-0.1, 0, len(pair.pc2), dtype=np.float32))
    back = read_pair(write_pair(tmp_path / "p.npz", original))
    for key in PAIR_KEYS:
        a, b = getattr(original, key), getattr(back, key)
        if a is None:
            assert b is None
        else:
            assert a.dtype == b.dtype and np.array_equal(a, b), key
    np.testing.assert_allclose(back.ego, np.linalg.inv(pair.pose2) @ pair.pose1)


def test_make_pair_fills_what_is_unlabelled():
    points = np.zeros((4, 3), np.float32)
    made = make_pair(points, points, points)
    assert not made.dynamic1.any() and not made.instance1.any()
    assert (made.class1 == PointClass.UNKNOWN).all() and np.array_equal(made.ego, np.eye(4))


def test_synthetic_ground_truth_lands_on_the_next_scan(pair):
    """pc1 + flow lies on pc2's surfaces, static and moving points alike (the generator's own ground truth)."""
    moving = pair.dynamic1
    gap = nearest(pair.pc2, pair.pc1[moving] + pair.flow[moving]).distance
    ego_only = pair.pc1[moving] @ pair.ego[:3, :3].T + pair.ego[:3, 3]
    gap_ego = nearest(pair.pc2, ego_only).distance
    assert np.median(gap) < np.median(gap_ego)  # the objects' own motion explains scan t+1 better than the ego's
    moved = pair.pc1 + pair.flow
    for instance in np.unique(pair.instance1[moving]):  # each object moves rigidly, and not with the scene
        on = pair.instance1 == instance
        motion = weighted_kabsch(pair.pc1[on], moved[on])
        np.testing.assert_allclose(transform_points(motion, pair.pc1[on]), moved[on], atol=1e-3)
        assert np.abs(motion - pair.ego).max() > 1e-3
    static = ~pair.dynamic1
    expected = pair.pc1[static] @ pair.ego[:3, :3].T + pair.ego[:3, 3]
    np.testing.assert_allclose(moved[static], expected, atol=1e-4)
    assert {PointClass.GROUND, PointClass.BUILDING, PointClass.POLE} <= set(np.unique(pair.class1).tolist())


def test_readers_reject_bad_files_in_one_line(tmp_path, pair):
    with pytest.raises(DataError, match="holds no .npz pairs"):
        pair_files(tmp_path)
    broken = tmp_path / "000000.npz"
    np.savez(broken, pc1=np.zeros((5, 3), np.float32))
    with pytest.raises(DataError, match="missing keys pc2, flow"):
        list(read_pairs(tmp_path))
    np.savez(broken, pc1=np.zeros((5, 3)), pc2=np.zeros((5, 3)), flow=np.zeros((5, 3)), instance1=np.zeros((5, 3), np.int32))
    with pytest.raises(DataError, match="'instance1' has shape"):
        read_pair(broken)
    np.savez(broken, pc1=np.array([["a", "b", "c"]]), pc2=np.zeros((5, 3)), flow=np.zeros((1, 3)))
    with pytest.raises(DataError, match="'pc1' holds <U1 values, expected floats"):
        read_pair(broken)
    np.savez(broken, pc1=np.full((2, 3), np.nan), pc2=np.zeros((5, 3)), flow=np.zeros((2, 3)))
    with pytest.raises(DataError, match="NaN or Inf"):
        read_pair(broken)
    np.savez(broken, pc1=np.zeros((2, 3)), pc2=np.zeros((5, 3)), flow=np.zeros((2, 3)), mask1=np.array([0.5, 2.0]))
    with pytest.raises(DataError, match="mask1"):
        read_pair(broken)
    np.savez(broken, pc1=np.zeros((2, 3)), pc2=np.zeros((5, 3)), flow=np.zeros((2, 3)), time2=np.zeros(4, np.float32))
    with pytest.raises(DataError, match="'time2' has 4 values for 5 points of pc2"):
        read_pair(broken)
    broken.write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(DataError, match="not a readable .npz pair"):
        read_pair(broken)


def test_noisy_mask_drops_objects_and_flips_points(pair):
    mask = noisy_mask(pair, np.random.default_rng(0), flip=0.0, drop=1.0)
    assert not mask.any()  # every moving object dropped
    mask = noisy_mask(pair, np.random.default_rng(0), flip=0.0, drop=0.0)
    assert np.array_equal(mask.astype(bool), pair.dynamic1)
    flipped = noisy_mask(pair, np.random.default_rng(0), flip=0.5, drop=0.0)
    assert 0.4 < (flipped.astype(bool) != pair.dynamic1).mean() < 0.6


def test_sequence_writer_and_reader_round_trip(tmp_path):
    writer = SequenceWriter(tmp_path / "seq")
    poses = [make_pose(10.0 + i, 5.0, 1.8, 0.1 * i) for i in range(3)]
    rng = np.random.default_rng(0)
    scans = [rng.normal(size=(100, 3)).astype(np.float32) for _ in poses]
    for index, (scan, pose) in enumerate(zip(scans, poses)):
        writer.add(index, scan, np.full(len(scan), 0.5, np.float32), pose)
    origin = writer.close()
    np.testing.assert_allclose(origin, poses[0])
    sequence = KittiSequence(tmp_path / "seq")
    assert len(sequence) == 3
    for index, (scan, pose) in enumerate(sequence):
        np.testing.assert_array_equal(scan[:, :3], scans[index])
        np.testing.assert_allclose(pose, np.linalg.inv(poses[0]) @ poses[index], atol=1e-8)


def test_kitti_readers_reject_bad_files(tmp_path):
    poses = tmp_path / "poses.txt"
    poses.write_text("1 0 0 0 0 1 0 0 0 0 1\n")
    with pytest.raises(DataError, match="expected 12"):
        read_poses(poses)
    sequence = tmp_path / "seq"
    (sequence / "velodyne").mkdir(parents=True)
    np.zeros((3, 4), np.float32).tofile(sequence / "velodyne" / "000000.bin")
    (sequence / "poses.txt").write_text("")
    with pytest.raises(DataError, match="1 scans but 0 poses"):
        KittiSequence(sequence)
