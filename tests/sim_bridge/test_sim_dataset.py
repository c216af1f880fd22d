"""Dataset export: deterministic pairs that start when the traffic moves, .npz + KITTI round trip."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sim_bridge.dataset.export import export, generate_pairs, pair_protocol, warmup_frames
from ssf_common.dataset.kitti import KittiSequence
from ssf_common.dataset.pairs import PAIR_KEYS, PointClass, read_pairs
from ssf_common.errors import ConfigError


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
    pairs = list(read_pairs(exported))
    assert len(pairs) == 3
    reference = list(generate_pairs(small_scenario(agents=30), seed=7, frames=3, protocol=pair_protocol(points=2048)))
    for pair, expected in zip(pairs, reference):
        assert pair.pc1.shape == (2048, 3) and pair.pc1.dtype == np.float32
        for key in PAIR_KEYS:
            if key != "mask1":
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
    assert description["first_frame"] == 20 and description["warmup_s"] == 2.0
    assert description["protocol"] == {"points": 2048, "sampling": "random", "max_range": 35.0, "remove_ground": True}


def test_exports_start_when_the_traffic_moves():
    """Every pair of a scenario with agents has moving points (the traffic starts from rest)."""
    pairs = list(generate_pairs("urban_100", seed=5, frames=6, protocol=pair_protocol(points=4096)))
    moving = [int(pair.dynamic1.sum()) for pair in pairs]
    assert min(moving) > 20, moving
    cold = list(generate_pairs("urban_100", seed=5, frames=2, protocol=pair_protocol(points=4096), warmup_s=0.0))
    assert cold[0].dynamic1.sum() < min(moving)  # what the warm-up is for


def test_warmup_is_validated(small_scenario):
    assert warmup_frames(small_scenario(), 2.0) == 20
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ConfigError, match="warm-up"):
            warmup_frames(small_scenario(), bad)


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
