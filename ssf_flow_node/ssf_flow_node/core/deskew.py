"""Scene flow on sweeps that take their period to turn: both scans moved to their stamps, the flow estimated there, and
each raw point's flow the ego motion plus its own motion.

1. Deskew: every point of a scan is moved into the sensor frame at the scan's stamp by the ego motion along the ground
   (x, y, yaw) interpolated across its sweep at constant velocity: the sweep's own motion where the vehicle measured
   it (wheel speed and gyro, `PairTimes.measured`: as IMU or wheel deskewing on a car; the estimator also starts its
   ego motion from it), else the last pair's ego motion. A scan is deskewed when it first comes, so that scan t+1 of
   one pair is scan t of the next exactly (the estimator carries its motions across that link), and so is a scan t
   that comes after pairs a node skipped to keep up; a stream's first pair is taken as it is (or at the measured
   motion), then deskewed by its own ego motion.
2. Estimate on the deskewed scans: the ego motion and every cluster's own rigid motion between the two stamps; a
   moving cluster is fitted between two deskewed scans in which the same columns fired at the same times, so its
   motion is its own over one period, whatever it did while the sensor turned. Where the ego motion found is not the
   one scan t+1 was deskewed with, that scan is deskewed again with it and the pair estimated again. (Deskewing with
   an alignment of the raw scans instead, once a pair, was 13-17 ms cheaper where the car brakes but locked onto
   traffic moving with the car, 20-35 cm off for pairs on end in dense_500; one estimate at constant velocity alone
   doubled the odometry's rotational error over urban_200's lane change: docs/sensors.md. Deskewed by the measured
   motion, scan t+1 is within the test's 4 cm at 50 m nearly always: 1.01 estimates a pair.)
3. Each raw point's flow is the ego motion between the stamps plus its own motion relative to the scene as the
   estimate between the deskewed scans found it. At constant velocity this is where its surface is when the next sweep
   fires its column (the simulator's truth) exactly; where the car brakes or steers, a still point's flow stays the ego
   motion's, where the column-to-column flow would carry the change of the car's motion between the sweeps (up to
   decimetres a period at 40 m when the yaw rate changes) and every stage downstream would read it as the point's own
   motion: 55 moving objects a scan on the demo's planner-driven drive, where the car meets 4-10.
Flow and ego motion are those between the two header stamps. Without per-point time, or with every time zero (instant
sweeps), the estimator runs on the scans as given: the same result to the bit."""

from __future__ import annotations

import collections
from typing import Any, NamedTuple

import numpy as np

from ssf_common.geometry.se3 import displacement_at, rigid_flow
from ssf_common.geometry.sweep import PairTimes, check_time, deskew, planar, timed
from ssf_flow_node.core.base import FlowEstimator, FlowResult, fingerprint, get_ready, measured_prior
from ssf_flow_node.core.preprocess import check_scan

SWEEP_HISTORY = 3  # deskewed scans kept: a stream's scan t+1 is the next pair's scan t
# a motion over a sweep off by this (m, at this range) moves no point more: steady driving's constant velocity is
# within it, and deskewing again for less chases the estimate's own noise and costs a second estimate (urban_200 seed
# 7: 1.51 estimates per pair at 2 cm, 1.10 at 4 cm; held-out seeds 30-32 at 4 cm against 2 cm: dynamic EPE 0.0453 /
# 0.0516 on urban_200, 0.0527 / 0.0521 on dense_500, moving IoU 0.742 / 0.742 and 0.634 / 0.649)
SETTLED_M, SETTLED_RANGE_M = 0.04, 50.0


class Deskewed(NamedTuple):
    """A scan moved to its stamp, and the sensor motion over one period it was deskewed with."""

    key: bytes  # the raw scan's fingerprint
    points: np.ndarray  # (N, 3) float32, sensor frame at the stamp
    motion: np.ndarray  # (4, 4) the motion over the sweep it was deskewed with (the flow's ego motion convention)
    swept: np.ndarray | None = None  # the motion over its sweep as the pair ending at it measured it, once estimated


class DeskewingEstimator:
    """Any flow estimator, on scans first moved to their stamps where their points carry time."""

    def __init__(self, estimator: FlowEstimator, enabled: bool = True) -> None:
        self.estimator = estimator
        self.enabled = enabled
        self.name = estimator.name
        self.motion: np.ndarray | None = None  # the last pair's ego motion: the next sweep's, at constant velocity
        self.scans: collections.OrderedDict[bytes, Deskewed] = collections.OrderedDict()
        self.estimated_again = 0  # pairs whose scan t+1 was deskewed and estimated again (their ego motion was not it)

    def __getattr__(self, name: str) -> Any:
        """The wrapped estimator's own attributes (its state, its config) show through."""
        if name == "estimator":
            raise AttributeError(name)
        return getattr(self.estimator, name)

    def estimate(self, pc1: np.ndarray, pc2: np.ndarray, mask: np.ndarray | None = None,
                 sweeps: PairTimes | None = None, follows: bool = False) -> FlowResult:
        """Flow for every point of pc1 between the two stamps; deskewed where `sweeps` carries time. follows: pc1 comes
        later in the stream than the last pair's scan t+1 (the caller skipped the pairs between to keep up)."""
        measured = {} if sweeps is None else measured_prior(self.estimator, sweeps.measured)
        if not self.deskews(sweeps):
            return self.estimator.estimate(pc1, pc2, mask, **measured)
        # 1. both scans at their stamps
        scan1, scan2, xyz1 = self.deskewed(pc1, pc2, sweeps, follows)
        # 2. flow and ego motion between the stamps; where the ego motion found is not the one scan t+1 was deskewed
        #    with (the vehicle braked or turned in), scan t+1 is deskewed again with it and the estimate taken again
        #    (and so is scan t in a stream's first pair, whose sweep no pair has measured)
        result = self.estimator.estimate(scan1.points, scan2.points, mask, **measured)
        ego = planar(result.ego)
        if not settled(ego, scan2.motion):
            if scan1.swept is None:  # no pair measured scan t's sweep: both at this pair's motion
                scan1 = self.store(scan1.key, xyz1, sweeps.time1, ego, sweeps.period)
            scan2 = self.store(scan2.key, check_scan(pc2, "scan t+1"), sweeps.time2, ego, sweeps.period)
            result = self.estimator.estimate(scan1.points, scan2.points, mask, **measured)
            ego = planar(result.ego)
            self.estimated_again += 1
        self.motion = ego
        self.scans[scan2.key] = scan2._replace(swept=ego)
        # 3. each raw point moves with the ego motion, plus its own motion relative to the scene
        own = result.flow - rigid_flow(result.ego, scan1.points)
        return FlowResult(flow=rigid_flow(result.ego, xyz1) + own, ego=result.ego)

    def get_ready(self, pc1: np.ndarray, pc2: np.ndarray, sweeps: PairTimes | None = None,
                  follows: bool = False) -> None:
        """The pair's work that needs no mask, on the scans it will be asked about."""
        measured = None if sweeps is None else sweeps.measured
        if not self.deskews(sweeps):
            get_ready(self.estimator, pc1, pc2, measured)
            return
        scan1, scan2, _ = self.deskewed(pc1, pc2, sweeps, follows)
        get_ready(self.estimator, scan1.points, scan2.points, measured)

    def deskews(self, sweeps: PairTimes | None) -> bool:
        """Whether this pair is deskewed: on, and either scan took its period to turn."""
        return self.enabled and sweeps is not None and (timed(sweeps.time1) or timed(sweeps.time2))

    def deskewed(self, pc1: np.ndarray, pc2: np.ndarray, sweeps: PairTimes,
                 follows: bool = False) -> tuple[Deskewed, Deskewed, np.ndarray]:
        """Both scans at their stamps (each deskewed once, when it first comes) and scan t's raw xyz."""
        xyz1, xyz2 = check_scan(pc1, "scan t"), check_scan(pc2, "scan t+1")
        time1 = check_time(sweeps.time1, len(xyz1), "scan t's per-point time")
        time2 = check_time(sweeps.time2, len(xyz2), "scan t+1's per-point time")
        key1, key2 = fingerprint(xyz1, time1), fingerprint(xyz2, time2)
        # a stream goes on at constant velocity, also past pairs the caller skipped (`follows`: a node that cannot keep
        # up answers the newest pair); a first pair is taken as it is, then deskewed by its own ego motion
        # scan t+1's own sweep as the vehicle measured it, where it did: no pair has to have driven alike before (and
        # a first pair's scan t at that motion too, not as it is: both scans of a pair are deskewed alike)
        measured = None if sweeps.measured is None else planar(sweeps.measured)
        going_on = (key1 in self.scans or follows) and self.motion is not None
        motion = self.motion if going_on else np.eye(4) if measured is None else measured
        motions = (motion, motion if measured is None else measured)
        scans = [self.scans[key] if key in self.scans else self.store(key, xyz, time, moved, sweeps.period)
                 for key, xyz, time, moved in ((key1, xyz1, time1, motions[0]), (key2, xyz2, time2, motions[1]))]
        for key in (key1, key2):
            self.scans.move_to_end(key)
        while len(self.scans) > SWEEP_HISTORY:
            self.scans.popitem(last=False)
        return scans[0], scans[1], xyz1

    def store(self, key: bytes, xyz: np.ndarray, time: np.ndarray, motion: np.ndarray, period: float) -> Deskewed:
        """Deskew a scan with the motion over its sweep and keep it (in place of what was kept for it)."""
        self.scans[key] = Deskewed(key, deskew(xyz, check_time(time, len(xyz), "per-point time"), motion, period),
                                   motion)
        return self.scans[key]


def settled(ego: np.ndarray, motion: np.ndarray) -> bool:
    """Whether the ego motion found is the one a scan was deskewed with, within what moves its points by less than
    SETTLED_M at SETTLED_RANGE_M."""
    return displacement_at(motion, ego, SETTLED_RANGE_M) < SETTLED_M
