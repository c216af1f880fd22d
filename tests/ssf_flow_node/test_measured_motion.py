"""The vehicle's measured motion guides and vets the flow's ego motion: a truck close ahead that moves with the car
fills most of the scan, and the alignment on it says the car stood still; the wheels say otherwise."""

from __future__ import annotations

import numpy as np
import pytest

from ssf_common.config import build
from ssf_common.geometry.se3 import make_pose
from ssf_common.geometry.sweep import pair_times
from ssf_flow_node.core.estimator import WHOLE_SCAN, FlowConfig, make_estimator

STEP = 1.0  # m the car drives along x between the scans


def street_behind_a_truck(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Two instant scans of a street (ground, facades, an end wall) from a car that drives STEP along x behind a truck
    4 m ahead that drives as fast: 30 000 of the 37 500 points move with the car."""
    rng = np.random.default_rng(seed)
    street = np.vstack([np.c_[rng.uniform(-30, 30, (3000, 2)), rng.normal(-1.7, 0.02, 3000)],
                        np.c_[rng.uniform(-30, 30, 1500), np.full(1500, 8.0), rng.uniform(-1.7, 3, 1500)],
                        np.c_[np.full(1500, 25.0), rng.uniform(-8, 8, 1500), rng.uniform(-1.7, 3, 1500)],
                        np.c_[rng.uniform(-30, 30, 1500), np.full(1500, -9.0), rng.uniform(-1.7, 3, 1500)]])

    def truck() -> np.ndarray:
        back = np.c_[np.full(20000, 4.0), rng.uniform(-1.2, 1.2, 20000), rng.uniform(-1.2, 2.0, 20000)]
        side = np.c_[rng.uniform(4, 12, 10000), np.full(10000, 1.2), rng.uniform(-1.2, 2.0, 10000)]
        return np.vstack([back, side])

    return (np.vstack([street, truck()]).astype(np.float32),
            np.vstack([street - [STEP, 0.0, 0.0], truck()]).astype(np.float32))


@pytest.mark.parametrize("measured_step", [None, STEP, STEP * 1.02])
def test_the_measured_motion_vetoes_standing_still_behind_a_truck(measured_step):
    """Without a measurement the alignment locks onto the truck (no motion); with one, 2 % off as a worn tyre's scale
    error, the ego motion is the car's within 2 cm, refined on the street."""
    pc1, pc2 = street_behind_a_truck()
    measured = None if measured_step is None else make_pose(-measured_step, 0.0, 0.0, 0.0)
    estimator = make_estimator("rigid", build(FlowConfig, WHOLE_SCAN))
    result = estimator.estimate(pc1, pc2, None, pair_times(None, None, 0.1, measured))
    if measured is None:
        assert abs(result.ego[0, 3]) < 0.05  # the failure the measurement is there for
    else:
        assert abs(result.ego[0, 3] + STEP) < 0.02
        street = np.flatnonzero(np.arange(len(pc1)) < 7500)
        still = np.linalg.norm(result.flow[street] - [-STEP, 0.0, 0.0], axis=1)
        assert np.median(still) < 0.02


def test_an_alignment_the_measurement_agrees_with_is_kept():
    """Where nothing pulls the alignment away, the measured motion changes nothing beyond the alignment's own noise."""
    pc1, pc2 = street_behind_a_truck()
    pc1, pc2 = pc1[:7500], pc2[:7500]  # the street alone
    plain = make_estimator("rigid", build(FlowConfig, WHOLE_SCAN)).estimate(pc1, pc2, None, None)
    measured = make_pose(-STEP * 1.02, 0.0, 0.0, 0.0)
    guided = make_estimator("rigid", build(FlowConfig, WHOLE_SCAN)).estimate(pc1, pc2, None,
                                                                          pair_times(None, None, 0.1, measured))
    assert abs(plain.ego[0, 3] + STEP) < 0.01 and abs(guided.ego[0, 3] + STEP) < 0.01


def test_an_alignment_turned_a_degree_off_the_measurement_is_refined_from_it():
    """Translation right, the heading a degree off (a point 20 m away moves 0.35 m): refined again from the measured
    motion, and where that refinement turns away as far, the measured motion itself."""
    from types import SimpleNamespace

    from ssf_flow_node.core.rigid.config import RigidConfig
    from ssf_flow_node.core.rigid.ego import vetted

    measured = make_pose(-1.0, 0.0, 0.0, np.radians(2.0))
    turned = make_pose(-1.0, 0.0, 0.0, np.radians(3.0))
    refined = make_pose(-1.0, 0.005, 0.0, np.radians(2.05))
    for refinement, expected in ((refined, refined), (turned, measured)):
        state = SimpleNamespace(measured=measured, matcher=SimpleNamespace(refine=lambda source, start, ordered: refinement))
        np.testing.assert_allclose(vetted(state, np.zeros((10, 3)), turned, RigidConfig()), expected)
    close = make_pose(-1.01, 0.0, 0.0, np.radians(2.02))  # within 0.1 m at 20 m: kept as aligned
    state = SimpleNamespace(measured=measured, matcher=None)
    np.testing.assert_allclose(vetted(state, np.zeros((10, 3)), close, RigidConfig()), close)
