"""Deskew: a sweep's geometry straightened, results unchanged to the bit without per-point time, and the flow of a
swept pair (the flow node's: test_flow_node_graph.py)."""

from __future__ import annotations

import numpy as np
import pytest

from ssf_common.config import build
from ssf_common.errors import DataError
from ssf_common.geometry.se3 import make_pose
from ssf_common.geometry.sweep import deskew, pair_times, reskew
from support import SWEEP_PERIOD as PERIOD, SWEEP_SPEED as SPEED, swept, swept_pair, swept_stream

def test_a_static_wall_is_bent_by_the_sweep_and_straight_after_deskew():
    wall = np.c_[np.full(400, 15.0), np.linspace(-10, 10, 400), np.zeros(400)]
    raw, times = swept(wall, 0.0)
    motion = make_pose(-SPEED * PERIOD)  # static points come 1 m nearer each period
    straight = deskew(raw, times, motion, PERIOD)
    assert np.ptp(raw[:, 0]) > 0.15 and raw[:, 0].min() > 15.3  # bent, and half a metre off: taken 0.4-0.6 m back
    assert np.abs(straight[:, 0] - 15.0).max() < 1e-3  # straight, where it is at the stamp
    np.testing.assert_allclose(reskew(straight, times, motion, PERIOD), raw, atol=1e-4)
    with pytest.raises(DataError, match="per-point times"):
        deskew(raw, times[:10], motion, PERIOD)


class Answers:
    """An estimator that keeps every answer of the one it wraps."""

    def __init__(self, estimator) -> None:
        self.estimator = estimator
        self.name = estimator.name
        self.answers: list = []

    def estimate(self, *args):
        """The wrapped estimator's answer, kept."""
        self.answers.append(self.estimator.estimate(*args))
        return self.answers[-1]


def test_no_time_or_all_zero_leaves_flow_masks_and_odometry_bit_identical():
    from ssf_eval.pipeline import PerceptionChain, PerceptionConfig
    from ssf_eval.sources import simulator_pairs
    from sim_bridge.dataset.export import PROTOCOLS
    from ssf_flow_node.core.estimator import WHOLE_SCAN
    from ssf_odom_node.core.odometry import OdomConfig, OdomInput, make_odometry

    pairs = simulator_pairs("urban_200", 5, 2, PROTOCOLS["whole"], 1.0).pairs
    assert pairs[0].time1 is None  # instant sweeps carry no time
    zeros = [(np.zeros(len(pair.pc1), np.float32), np.zeros(len(pair.pc2), np.float32)) for pair in pairs]
    runs = {}
    for deskew_on, timed_scans in ((False, False), (True, False), (True, True)):  # off, no time: as it always ran
        chain = PerceptionChain(build(PerceptionConfig, {"flow": {**WHOLE_SCAN, "deskew": deskew_on}}))
        spy = chain.loop.estimator.estimator = Answers(chain.loop.estimator.estimator)
        answers = spy.answers
        seen = [chain.perceive(pair.pc1, pair.pc2, follows=index > 0, stamp_ns=index * 10 ** 8,
                               time1=zeros[index][0] if timed_scans else None, time2=zeros[index][1] if timed_scans else None)
                for index, pair in enumerate(pairs)]
        assert [step.fusion.final.flow is answer.flow for step, answer in zip(seen, answers)] == [True, True]  # as given
        runs[deskew_on, timed_scans] = seen
    reference = runs[False, False]
    for seen in runs.values():
        for got, want in zip(seen, reference):
            assert np.array_equal(got.fusion.flow, want.fusion.flow)
            assert np.array_equal(got.fusion.segmentation.dynamic_prob, want.fusion.segmentation.dynamic_prob)
            # Open3D's ICP sums on several threads: the last bits of an ego motion vary from run to run, as before
            np.testing.assert_allclose(got.fusion.ego, want.fusion.ego, rtol=0, atol=1e-9)
    poses = {}
    for deskew_on, timed_scans in ((False, False), (True, False), (True, True)):
        odometry = make_odometry(config=OdomConfig(deskew=deskew_on))
        poses[deskew_on, timed_scans] = [odometry.step(OdomInput(
            index * 10 ** 8, pair.pc1, seen.fusion.flow, seen.fusion.segmentation.dynamic_prob, ego=seen.fusion.ego,
            time=zeros[index][0] if timed_scans else None)).pose for index, (pair, seen) in enumerate(zip(pairs, reference))]
    for got in poses.values():
        assert all(np.array_equal(a, b) for a, b in zip(got, poses[False, False]))


def test_deskew_is_off_without_time_and_changes_the_flow_with_it():
    from ssf_flow_node.core.estimator import WHOLE_SCAN, FlowConfig, make_estimator

    (pc1, time1), (pc2, time2) = swept_pair(3)
    config = build(FlowConfig, WHOLE_SCAN)
    plain = make_estimator("rigid", build(FlowConfig, WHOLE_SCAN, {"deskew": False}))
    deskewing = make_estimator("rigid", config)
    without = deskewing.estimate(pc1, pc2)
    assert np.array_equal(without.flow, plain.estimate(pc1, pc2).flow)  # no time: the estimator as given
    sweeps = pair_times(time1, time2, PERIOD)
    with_time = make_estimator("rigid", config).estimate(pc1, pc2, None, sweeps)
    assert not np.array_equal(with_time.flow, without.flow)
    truth = np.array([-SPEED * PERIOD, 0.0, 0.0], np.float32)  # constant velocity: every raw point's flow
    assert np.median(np.linalg.norm(with_time.flow - truth, axis=1)) < 0.02
    assert abs(with_time.ego[0, 3] + SPEED * PERIOD) < 0.02


def test_a_pair_after_skipped_pairs_goes_on_at_constant_velocity():
    """A node that cannot keep up answers the newest pair: its scan t, which no pair brought, is deskewed with the last
    pair's motion (one estimate, as in a stream); a scan t that does not follow starts a stream: taken as swept first
    (two estimates, as a stream's first pair)."""
    from ssf_flow_node.core.estimator import WHOLE_SCAN, FlowConfig, make_estimator

    sweeps = swept_stream(4, 4)
    estimates = {}
    for follows in (False, True):
        estimator = make_estimator("rigid", build(FlowConfig, WHOLE_SCAN))
        spy = estimator.estimator = Answers(estimator.estimator)
        estimator.estimate(sweeps[0][0], sweeps[1][0], None, pair_times(sweeps[0][1], sweeps[1][1], PERIOD))
        first = len(spy.answers)  # a stream's first pair: as swept for its motion, then deskewed
        result = estimator.estimate(sweeps[2][0], sweeps[3][0], None, pair_times(sweeps[2][1], sweeps[3][1], PERIOD),
                                    follows)
        estimates[follows] = len(spy.answers) - first
        assert first == 2 and abs(result.ego[0, 3] + SPEED * PERIOD) < 0.02
    assert estimates == {False: 2, True: 1}


def test_a_braking_sensor_sees_a_still_street_still():
    """The sensor brakes at 8 m/s^2 (1 m during one sweep, 0.92 m during the next): the second pair's scans are
    deskewed at the last pair's motion, its ego motion is found within 5 cm (half the change), and no point of the still
    street gets a motion of its own (the column-to-column flow would carry the change of speed, read downstream as
    movers)."""
    from ssf_common.geometry.se3 import rigid_flow
    from ssf_flow_node.core.estimator import WHOLE_SCAN, FlowConfig, make_estimator

    speeds = [SPEED, SPEED, SPEED - 0.8]
    sweeps = swept_stream(5, 3, speeds)
    estimator = make_estimator("rigid", build(FlowConfig, WHOLE_SCAN))
    estimator.estimate(sweeps[0][0], sweeps[1][0], None, pair_times(sweeps[0][1], sweeps[1][1], PERIOD))
    (pc1, time1), (pc2, time2) = sweeps[1], sweeps[2]
    result = estimator.estimate(pc1, pc2, None, pair_times(time1, time2, PERIOD))
    assert abs(result.ego[0, 3] + speeds[2] * PERIOD) < 0.05
    own = np.linalg.norm(result.flow - rigid_flow(result.ego, pc1), axis=1)
    assert own.max() < 1e-4


def test_a_braking_sensor_deskewed_by_its_measured_motion_is_estimated_once():
    """Where the vehicle measured its motion over the sweep (wheel speed, gyro), scan t+1 is deskewed by it: the braking
    pair is estimated once (at the last pair's motion it is deskewed and estimated again), its ego motion is found
    closer, and the still street stays still."""
    from ssf_common.geometry.se3 import rigid_flow
    from ssf_flow_node.core.estimator import WHOLE_SCAN, FlowConfig, make_estimator

    speeds = [SPEED, SPEED, SPEED - 0.8]
    sweeps = swept_stream(5, 3, speeds)
    found = {}
    for measured in (False, True):
        estimator = make_estimator("rigid", build(FlowConfig, WHOLE_SCAN))
        for (pc1, time1), (pc2, time2), speed in zip(sweeps, sweeps[1:], speeds[1:]):
            motion = make_pose(-speed * PERIOD, 0.0, 0.0, 0.0) if measured else None  # the sensor drives along x
            result = estimator.estimate(pc1, pc2, None, pair_times(time1, time2, PERIOD, motion))
        found[measured] = (estimator.estimated_again, abs(result.ego[0, 3] + speeds[2] * PERIOD))
        own = np.linalg.norm(result.flow - rigid_flow(result.ego, sweeps[1][0]), axis=1)
        assert own.max() < 1e-4
    assert found[False][0] >= 1 and found[True][0] == 0
    assert found[True][1] < 0.01 and found[True][1] <= found[False][1]
