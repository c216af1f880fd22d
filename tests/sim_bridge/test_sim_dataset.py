"""Dataset export: deterministic pairs, .npz + KITTI round trip, readers reject bad files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sim_bridge.dataset.export import PAIR_KEYS, export, generate_pairs, load_pairs, pair_protocol, sample_indices
from sim_bridge.world import PointClass
from ssf_common.errors import ConfigError
from sim_bridge.dataset.kitti import KittiSequence, read_poses
from ssf_common.errors import DataError


@pytest.fixture(scope="module")
def exported(tmp_path_factory, small_scenario):
    out = tmp_path_factory.mktemp("export")
    export(small_scenario(agents=30), out, seed=7, frames=3, protocol=pair_protocol(points=2048))
    return out


def test_same_seed_gives_identical_pairs(small_scenario):
    scenario = small_scenario(agents=30)
    one = list(generate_pairs(scenario, seed=7, frames=2, protocol=pair_protocol(points=1024)))
    two = list(generate_pairs(scenario, seed=7, frames=2, protocol=pair_protocol(points=1024)))
    other = list(generate_pairs(scenario, seed=8, frames=2, protocol=pair_protocol(points=1024)))
    for a, b in zip(one, two):
        for key in PAIR_KEYS:
            assert np.array_equal(getattr(a, key), getattr(b, key)), key
    assert not np.array_equal(one[1].pc1, other[1].pc1)


def test_export_round_trip(exported, small_scenario):
    pairs = list(load_pairs(exported))
    assert len(pairs) == 3
    reference = list(generate_pairs(small_scenario(agents=30), seed=7, frames=3, protocol=pair_protocol(points=2048)))
    for pair, expected in zip(pairs, reference):
        assert pair.pc1.shape == (2048, 3) and pair.pc1.dtype == np.float32
        for key in PAIR_KEYS:
            assert np.array_equal(getattr(pair, key), getattr(expected, key)), key
    sequence = KittiSequence(exported / "sequence")
    assert len(sequence) == 4
    np.testing.assert_allclose(sequence.poses[0], np.eye(4), atol=1e-9)
    relative = np.linalg.inv(pairs[0].pose1) @ pairs[2].pose2
    np.testing.assert_allclose(sequence.poses[3], relative, atol=1e-6)
    scan = sequence.scan(1)
    assert scan.shape[1] == 4 and len(scan) > 10 * 2048
    assert np.isin(pairs[1].pc1[:5], scan[:, :3]).all()  # downsampled points come from the full scan
    description = json.loads((exported / "dataset.json").read_text())
    assert description["seed"] == 7 and description["sensor"]["beams"] == 64 and description["pairs"] == 3
    assert description["protocol"] == {"points": 2048, "sampling": "random", "max_range": 35.0, "drop_ground": True}


def test_protocols_cut_pairs_as_named(small_scenario):
    scenario = small_scenario(agents=30)
    paper = next(generate_pairs(scenario, seed=7, frames=1, protocol=pair_protocol("paper", points=1024)))
    raw = next(generate_pairs(scenario, seed=7, frames=1, protocol=pair_protocol("raw", points=1024)))
    assert not (paper.class1 == PointClass.GROUND).any()
    assert np.linalg.norm(paper.pc1[:, :2], axis=1).max() <= 35.0
    assert (raw.class1 == PointClass.GROUND).mean() > 0.2
    assert np.linalg.norm(raw.pc1[:, :2], axis=1).max() > 35.0
    with pytest.raises(ConfigError, match="unknown pair protocol"):
        pair_protocol("kitti")
    with pytest.raises(ConfigError, match="points"):
        pair_protocol(points=0)


def test_readers_reject_bad_files(tmp_path, exported):
    with pytest.raises(DataError, match="no .npz pairs"):
        list(load_pairs(tmp_path))
    broken = tmp_path / "000000.npz"
    np.savez(broken, pc1=np.zeros((5, 3), np.float32))
    with pytest.raises(DataError, match="missing keys"):
        list(load_pairs(tmp_path))
    shapes = {key: np.zeros((5, 3)) for key in PAIR_KEYS}
    np.savez(broken, **shapes)
    with pytest.raises(DataError, match="'instance1' has shape"):
        list(load_pairs(tmp_path))
    poses = tmp_path / "poses.txt"
    poses.write_text("1 0 0 0 0 1 0 0 0 0 1\n")
    with pytest.raises(DataError, match="expected 12"):
        read_poses(poses)
    sequence = tmp_path / "seq"
    (sequence / "velodyne").mkdir(parents=True)
    (sequence / "velodyne" / "000000.bin").write_bytes((exported / "sequence" / "velodyne" / "000000.bin").read_bytes())
    (sequence / "poses.txt").write_text("")
    with pytest.raises(DataError, match="1 scans but 0 poses"):
        KittiSequence(sequence)


def test_sampling_is_seeded_and_farthest_point_spreads_out():
    rng = np.random.default_rng(0)
    points = np.concatenate([rng.normal(0, 0.1, (2000, 3)), rng.normal(10, 0.1, (20, 3))]).astype(np.float32)
    random = sample_indices(points, 64, np.random.default_rng(1), "random")
    assert np.array_equal(random, sample_indices(points, 64, np.random.default_rng(1), "random"))
    assert len(np.unique(random)) == 64
    fps = sample_indices(points, 8, np.random.default_rng(1), "fps")
    assert (np.linalg.norm(points[fps], axis=1) > 5).sum() >= 1  # the far cluster is picked
    few = sample_indices(points[:10], 32, np.random.default_rng(1), "random")
    assert len(few) == 32 and set(few) == set(range(10))
