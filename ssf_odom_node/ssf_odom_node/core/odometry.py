"""Odometry from semantic scene flow: the paper's static points and their flow give the motion between scans, a few
point-to-plane iterations against a local map of static points refine it, and the motions chain into a pose with a
covariance. The ablation variants (whole scans only, all points' flow, static points' flow) are one switch; the
vehicle's own measured motion (wheel speed, gyro), where given, checks the flow's motion on every scan."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from enum import Enum
from typing import NamedTuple

import numpy as np
from pydantic import Field

from ssf_common.config import Section
from ssf_common.errors import ConfigError, DataError
from ssf_common.geometry.neighbours import PointIndex
from ssf_common.geometry.sampling import voxel_indices
from ssf_common.geometry.se3 import (interpolate_poses, invert, make_pose, rotation_angle, transform_points, yaw_matrix,
                                     yaw_of)
from ssf_common.geometry.sweep import check_time, deskew, planar, timed
from ssf_common.geometry.registration import (Alignment, estimate_normals, exp_se3, flow_transform, log_se3,
                                             normals_among, point_to_plane, steep_support)
from ssf_odom_node.core.static_map import MapConfig, VoxelMap, above_ground

GAP_NOISE = np.diag([0.05, 0.05, 0.05, 0.005, 0.005, 0.005]) ** 2  # per predicted-only scan (m, rad)^2


class OdomMethod(str, Enum):
    """What the motion between scans comes from (the paper's ablation rows)."""

    POINTS = "points"  # robust registration of whole scans (constant-velocity start, no flow, no segmentation)
    FLOW = "flow"  # Kabsch on every point's flow, then the same refinement on every point
    SSF = "ssf"  # Kabsch on the static points' flow, refinement on static points against a static map


GAP_PERIODS = 1.5  # this many scan periods or more since the last scan: scans were skipped
HEADING_TRIAL_POINTS = 512  # points of a scan each heading hypothesis is tried with


class OdomConfig(Section):
    """Everything the odometry needs; the same dotted names in YAML, ROS parameters and CLI flags."""

    method: OdomMethod = Field(OdomMethod.SSF, description="points | flow | ssf")
    min_range: float = Field(2.5, ge=0.0, description="closer points (the ego vehicle) are ignored (m)")
    max_range: float = Field(80.0, gt=0.0, description="farther points are ignored (m)")
    voxel: float = Field(0.8, gt=0.0, description="voxel (m) the scan is reduced with before registration")
    min_points: int = Field(1500, ge=0, description="when the first scan keeps fewer points, scan and map voxels shrink "
                            "(x0.6, at most 3 times) for the whole run: small scenes, sparse sensors")
    static_threshold: float = Field(0.5, ge=0.0, le=1.0, description="points above this dynamic probability are not static")
    refine_gates: tuple[float, ...] = Field((1.0, 0.5, 0.3, 0.3), description="correspondence gate (m) of each "
                                            "point-to-plane iteration after a flow-based start")
    search_gates: tuple[float, ...] = Field((2.0, 1.5, 1.0, 0.8, 0.6, 0.5, 0.4, 0.3, 0.3, 0.3),
                                            description="gates of each iteration from a constant-velocity start (points method, gaps)")
    gap_headings: tuple[float, ...] = Field((3.0, 6.0, 9.0, 12.0, 16.0, 20.0), description="across skipped scans the flow's motion is "
                                            "extrapolated, and a swerve leaves its heading degrees off: these heading "
                                            "offsets (deg, each way) are tried too, and the start that lays most "
                                            "points on steep surfaces is refined")
    gap_yaw_rate: float = Field(40.0, gt=0.0, description="the heading search reaches at least this yaw rate (deg/s) "
                                "over the gap: the offsets above are widened in proportion for longer gaps")
    command_yaw_rate: float = Field(10.0, gt=0.0, description="across a gap with a motion prior (the commands sent, "
                                    "wheel odometry), the prior is searched in heading up to this yaw rate (deg/s) "
                                    "over the gap and competes with the flow's search, instead of constant velocity")
    prior_gate: tuple[float, float] = Field((0.08, 0.02), description="a flow motion farther than this (m, rad) from "
                                            "the constant-velocity prediction is checked: a search from that "
                                            "prediction runs too, and the map keeps whichever fits more points (0.08 m: "
                                            "8 m/s², braking at about 0.8 g, over a 0.1 s scan period; a flow dragged "
                                            "along by traffic creeps away from constant velocity by less than a "
                                            "looser gate)")
    flow_gate: tuple[float, float] = Field((0.2, 0.2), description="a flow motion farther than this (m, rad) from the "
                                           "constant-velocity prediction, per scan period, is not believed at all: "
                                           "0.2 m is 20 m/s² over a 0.1 s period, twice what a car's brakes give; there "
                                           "the flow has taken traffic for the world (a platoon beside a slow ego) and "
                                           "only the search from constant velocity runs. The turn gate is loose: a "
                                           "vehicle's yaw rate can jump where it starts to turn (0.1 rad per scan as the "
                                           "simulator's car starts a lane change) and the flow sees those turns "
                                           "right (0: no gate)")
    measured_gate: tuple[float, float] = Field((0.05, 0.01), description="with the vehicle's measured motion (wheel "
                                               "speed, gyro), a flow motion farther than this (m, rad) from it "
                                               "gives way to it: traffic that moves with the ego can fool the flow, "
                                               "not the wheels")
    ssf_range: float = Field(35.0, gt=0.0, description="ssf maps static points within this range (m) only: the "
                             "segmentation sees moving objects only where the flow is estimated")
    target_range: float = Field(60.0, gt=0.0, description="ssf: static points beyond ssf_range and within this range "
                                "(m) join the registration target for map.confirm_window scans, and the map only once "
                                "scans observe them within ssf_range (nothing checked that they do not move)")
    near_range: float = Field(15.0, ge=0.0, description="points nearer than this (m, horizontally) weigh in proportion "
                              "to their range in the registration: around the ego, traffic that moves with it is "
                              "what the flow and the segmentation take for the world (0: every point alike)")
    near_weight: float = Field(0.3, gt=0.0, le=1.0, description="the least weight of a near point")
    kernel: float = Field(0.2, gt=0.0, description="Geman-McClure scale of the point-to-plane residuals (m)")
    normal_neighbours: int = Field(8, ge=3, description="neighbours for the normals of map points")
    scan_period: float = Field(0.1, gt=0.0, description="time between scans (s); the span one flow covers")
    deskew: bool = Field(True, description="where the scan's points carry time (a sweep that takes its period to "
                         "turn), move each into the sensor frame at the stamp before registering and mapping it, at "
                         "constant velocity along the ground within the sweep (the mean of three pairs' ego motions "
                         "around it, sweep_mean, else the motion the scan's pose is predicted with; on the first scan "
                         "the flow's motion to the next), and fit the sensor's vertical motion "
                         "over the sweep with the pose (sweep_gates), so that the pose is the one at the stamp; scans "
                         "without time, or all of it zero, are taken as given")
    sweep_mean: bool = Field(True, description="deskewed scans: the sweep's motion along the ground is the mean of the "
                             "flow's ego motions of three consecutive pairs (the pair before the sweep's, the sweep's "
                             "own, and this scan's to the next), centred on the sweep: each pair's ego motion is a few mm "
                             "off and its neighbours' errors mostly cancel it (at constant acceleration the mean is the "
                             "middle one); where the three do not change smoothly (sweep_jump) the sweep's own")
    sweep_jump: tuple[float, float] = Field((0.1, 0.005), description="the three pairs' motions are averaged only where "
                                            "their second difference stays within this (m, rad): beyond it the motion "
                                            "changed at once (a turn begins: the simulator's car can take 0.05 rad a "
                                            "period from one period to the next; a crash stops it), and a mean would "
                                            "deskew two sweeps with a turn one of them did not take")
    sweep_gates: tuple[float, ...] = Field((0.3, 0.3), description="deskewed scans: gates (m) of the last "
                                           "point-to-plane iterations, which fit the sensor's rise or fall over the "
                                           "sweep with the pose (a bump of the road moves it within a period, which "
                                           "no constant velocity predicts; empty: not fitted)")
    map: MapConfig = MapConfig()


@dataclass(frozen=True)
class OdomInput:
    """One scan (its sensor frame) with the flow towards the next scan and the dynamic probability of each point."""

    stamp_ns: int
    points: np.ndarray  # (N, 3)
    flow: np.ndarray | None = None  # (N, 3), None when no flow is known
    dynamic_prob: np.ndarray | None = None  # (N,), None when no segmentation is known
    motion_prior: np.ndarray | None = None  # (4, 4) last scan's sensor frame <- this scan's, as the commands sent in
    # between drove the vehicle; None when unknown
    measured_motion: np.ndarray | None = None  # (4, 4) the same, as the vehicle's own sensors (wheel speed, yaw-rate
    # gyro) measured it; None when it has none
    ego: np.ndarray | None = None  # (4, 4) this scan -> the next, as the flow estimator aligned it (scan-t coordinates
    # of static points -> the next scan's frame); ssf takes it as the motion to the next scan instead of fitting one
    time: np.ndarray | None = None  # (N,) each point's time, s relative to the stamp (None or all zero: an instant sweep)


class Prepared(NamedTuple):
    """A scan at its stamp and what the odometry registers and maps of it."""

    scan: np.ndarray  # (N, 3) sensor frame at the stamp (deskewed where its points carry time)
    shares: np.ndarray | None  # (N,) each point's time before the stamp, in scan periods; None: not deskewed
    squared: np.ndarray  # (N,) horizontal range, squared
    keep: np.ndarray  # indices of the points within range, one per voxel
    points: np.ndarray  # (K, 3) float64, the kept points
    flow: np.ndarray | None  # (K, 3) their flow
    dynamic: np.ndarray | None  # (K,) their dynamic probability
    registered: np.ndarray  # the kept points registered (ssf: the static ones)
    weights: np.ndarray  # their weights


@dataclass(frozen=True)
class OdomStep:
    """The pose of one scan in the odometry frame (the first scan's sensor frame) and how it was found."""

    stamp_ns: int
    pose: np.ndarray  # (4, 4) odom <- sensor
    covariance: np.ndarray  # (6, 6) x y z roll pitch yaw, in the odometry frame
    twist: np.ndarray  # (6,) vx vy vz wx wy wz in the sensor frame (per second)
    next_motion: np.ndarray | None  # (4, 4) this scan -> the next (scan-t coordinates of static points), from the flow
    inliers: int  # map points matched on the last refinement iteration
    rmse: float  # point-to-plane RMS residual (m)
    predicted_by: str  # "flow", "velocity" (constant velocity), "prior" (the motion prior, across a gap), "measured"
    # (the vehicle's measured motion) or "start"
    map_voxels: int
    registered_points: int = 0
    extras: dict = field(default_factory=dict)


class Odometry:
    """Scan-by-scan odometry from semantic scene flow (or a variant of it), with its local static map."""

    def __init__(self, config: OdomConfig) -> None:
        self.config = config
        self.method = OdomMethod(config.method)
        self.map = VoxelMap(self.map_config(config.map), config.scan_period)
        self.voxel: float | None = None  # the scan voxel, chosen on the first scan
        self.pose = np.eye(4)
        self.covariance = np.zeros((6, 6))
        self.velocity = np.zeros(6)  # twist per second, sensor frame
        self.next_motion: np.ndarray | None = None
        self.stamp_ns: int | None = None
        self.steps = 0
        self.rejected_flows = 0  # flow motions that constant velocity or the motion prior overruled
        self.pair_motions: deque[np.ndarray] = deque(maxlen=2)  # the flow's ego motions (x, y, yaw) of the last two
        # consecutive pairs, the older first: the sweeps' motions are averaged with them (sweep_mean)

    def step(self, frame: OdomInput) -> OdomStep:
        """One scan: predict its pose, refine it on the static map, chain it, map it, and predict the next motion."""
        raw, flow, dynamic = self.check(frame)
        gap = self.periods(frame.stamp_ns) >= GAP_PERIODS
        # 1. predict: the motion the last scan's static flow gave, and constant velocity; the scan at its stamp, and
        # 2. the points this method registers and maps of it: the static ones (ssf) or all
        by_flow, by_velocity = self.predict(frame.stamp_ns)
        motion = self.sweep_motion(raw, frame, by_velocity if by_flow is None else by_flow, flow, dynamic)
        scan = self.prepared(raw, frame, flow, dynamic, motion)
        # 3. a few point-to-plane iterations against the local static map (a search where the two predictions differ,
        # on a sweep deskewed at constant velocity for that start), then the sensor's rise or fall over a sweep
        by_velocity_scan = self.velocity_deskewed(raw, frame, flow, dynamic, motion, by_flow, by_velocity)
        alignment, source = self.refine(scan.registered, scan.weights, by_flow, by_velocity,
                                        self.periods(frame.stamp_ns), self.prior_pose(frame),
                                        self.prior_pose(frame, measured=True),
                                        None if by_velocity_scan is None else (by_velocity_scan.registered,
                                                                               by_velocity_scan.weights))
        if source == "velocity" and by_velocity_scan is not None:  # the sweep as constant velocity deskewed it
            scan = by_velocity_scan
        if motion is not None and len(self.map) and self.config.sweep_gates:
            alignment, scan = self.fit_sweep(alignment, scan)
        # 4. chain into the pose, its covariance and the velocity
        self.chain(frame.stamp_ns, alignment)
        # 5. the motion to the next scan: the flow estimator's ego motion (else from the static points and their flow)
        self.remember_pair_motion(self.given_ego(frame), gap)
        self.next_motion = self.flow_motion(scan.points, scan.flow, scan.dynamic, self.given_ego(frame))
        # 6. the registered points join the map at the new pose (for ssf: where the segmentation sees, points that do
        # not move on their own, not where it saw moving points lately, and the scan's beams clear what they pass
        # through; static points farther out join only the registration target, for a few scans)
        self.update_map(*self.mapped_points(scan.points, scan.flow, scan.dynamic),
                        np.compress(scan.squared >= self.config.min_range ** 2, scan.scan, axis=0),
                        self.moving_points(scan.points, scan.flow, scan.dynamic))
        return OdomStep(frame.stamp_ns, self.pose.copy(), self.covariance.copy(), self.velocity.copy(),
                        None if self.next_motion is None else self.next_motion.copy(), alignment.inliers,
                        alignment.rmse, source, len(self.map), len(scan.registered),
                        {} if motion is None else {"sweep_lift": alignment.lift})

    def sweep_motion(self, scan: np.ndarray, frame: OdomInput, predicted: np.ndarray, flow: np.ndarray | None = None,
                     dynamic: np.ndarray | None = None) -> np.ndarray | None:
        """The sensor's motion along the ground over the scan's sweep (the flow's convention: the stamp's frame -> a
        period later), at constant velocity: the mean of three pairs' ego motions around the sweep (sweep_mean), else the
        predicted one, per scan period; on the first scan the flow's motion to the next scan (the one its map is built
        from). None: nothing to deskew (no time, deskew off, or a first scan
        without flow)."""
        if not self.config.deskew or not timed(frame.time):
            return None
        if self.stamp_ns is not None:
            centred = self.centred_motion(frame)
            return self.period_motion(predicted, frame.stamp_ns) if centred is None else centred
        motion = self.flow_motion(np.asarray(scan, np.float64), None if flow is None else flow.astype(np.float64),
                                  None if dynamic is None else dynamic.astype(np.float64), self.given_ego(frame))
        return None if motion is None else planar(motion)

    def centred_motion(self, frame: OdomInput) -> np.ndarray | None:
        """ssf: the sweep's motion along the ground as the mean of the flow's ego motions of the pair before it, its own
        and the one after (this scan's to the next), where sweep_mean is on, the three pairs are consecutive periods and
        the frame carries the flow's ego motion; else None."""
        ego = self.given_ego(frame)
        if (not self.config.sweep_mean or self.method is not OdomMethod.SSF or ego is None
                or len(self.pair_motions) < 2 or self.periods(frame.stamp_ns) >= GAP_PERIODS):
            return None
        return centred_mean(np.stack([*self.pair_motions, along_ground(ego)]), self.config.sweep_jump)

    def remember_pair_motion(self, ego: np.ndarray | None, gap: bool) -> None:
        """Keep the flow's ego motion of this scan's pair for the next sweeps' means (after skipped scans the earlier
        pairs are not the next sweeps' neighbours; without an ego motion nothing is averaged until two more came)."""
        if gap or ego is None:
            self.pair_motions.clear()
        if ego is not None:
            self.pair_motions.append(along_ground(ego))

    def velocity_deskewed(self, raw: np.ndarray, frame: OdomInput, flow: np.ndarray | None,
                          dynamic: np.ndarray | None, motion: np.ndarray | None, by_flow: np.ndarray | None,
                          by_velocity: np.ndarray) -> Prepared | None:
        """Where the sweep was deskewed with the flow's motion and constant velocity contradicts it (the search from
        constant velocity will run too), the sweep deskewed at constant velocity: each start registers the sweep as
        its own motion would have swept it (a flow that misjudged a turn-in deskews the sweep wrong as well); else
        None."""
        if motion is None or by_flow is None or self.steps < 2 or not len(self.map):
            return None
        periods = self.periods(frame.stamp_ns)
        if periods >= GAP_PERIODS or self.agree(by_flow, by_velocity, periods):
            return None
        return self.prepared(raw, frame, flow, dynamic, self.period_motion(by_velocity, frame.stamp_ns))

    def period_motion(self, pose: np.ndarray, stamp_ns: int) -> np.ndarray:
        """The motion along the ground over one scan period towards `pose` at `stamp_ns`, from the last scan's."""
        periods = self.elapsed(stamp_ns) / self.config.scan_period
        later = interpolate_poses(self.pose, pose, np.array([1.0 / periods]))[0]  # odom <- a period on
        return planar(invert(later) @ self.pose)  # the flow's convention: a stamp's frame -> a period later

    def prepared(self, raw: np.ndarray, frame: OdomInput, flow: np.ndarray | None, dynamic: np.ndarray | None,
                 motion: np.ndarray | None) -> Prepared:
        """The scan at its stamp (deskewed with `motion`, where not None) and what of it is registered and mapped."""
        scan, shares = raw, None
        if motion is not None:
            time = check_time(frame.time, len(raw), "odometry: the scan's per-point time")
            scan, shares = deskew(raw, time, motion, self.config.scan_period), -time / self.config.scan_period
        squared = scan[:, 0] * scan[:, 0] + scan[:, 1] * scan[:, 1]  # horizontal range, squared
        keep = self.kept(scan, squared)
        points, flow, dynamic = self.taken(scan, flow, dynamic, keep)
        return Prepared(scan, shares, squared, keep, points, flow, dynamic, *self.registered_points(points, dynamic))

    def fit_sweep(self, alignment: Alignment, scan: Prepared) -> tuple[Alignment, Prepared]:
        """A deskewed sweep's pose refined again with the sensor's rise or fall over the sweep (sweep_gates: a bump
        lifts or drops the sensor within a period, which the deskew along the ground leaves in the scan as a ramp
        around it); the alignment and the scan lifted so."""
        static = self.registered_index(scan.dynamic)
        shares = scan.shares[scan.keep] if static is None else scan.shares[scan.keep][static]
        alignment = point_to_plane(scan.registered, scan.weights, self.map.target(), alignment.transform,
                                   self.config.sweep_gates, self.config.kernel, shares=shares)
        return alignment, scan._replace(scan=lifted(scan.scan, scan.shares, alignment.lift),
                                        points=lifted(scan.points, scan.shares[scan.keep], alignment.lift))

    def kept(self, points: np.ndarray, squared: np.ndarray) -> np.ndarray:
        """Indices of the points within range (`squared`: their horizontal range, squared), one per voxel."""
        keep = np.flatnonzero((squared >= self.config.min_range ** 2) & (squared <= self.config.max_range ** 2))
        if self.voxel is None:
            self.voxel = self.choose_voxel(points[keep])
        return keep[voxel_indices(points.take(keep, axis=0), self.voxel)] if len(keep) else keep

    @staticmethod
    def taken(points: np.ndarray, flow: np.ndarray | None, dynamic: np.ndarray | None, keep: np.ndarray):
        """The kept points with their flow and dynamic probability, as float64."""
        return (points.take(keep, axis=0).astype(np.float64),  # take: 3x faster than indexing rows
                None if flow is None else flow.take(keep, axis=0).astype(np.float64),
                None if dynamic is None else dynamic[keep].astype(np.float64))

    def reduce(self, points: np.ndarray, flow: np.ndarray | None, dynamic: np.ndarray | None, squared: np.ndarray):
        """The points within range (`squared`: their horizontal range, squared), one per voxel, with their flow and
        dynamic probability."""
        return self.taken(points, flow, dynamic, self.kept(points, squared))

    def choose_voxel(self, points: np.ndarray) -> float:
        """The configured voxel, shrunk while the first scan would keep fewer than min_points; the map follows."""
        scale = 1.0
        for _ in range(3):
            if len(voxel_indices(points, self.config.voxel * scale)) >= self.config.min_points or len(points) == 0:
                break
            scale *= 0.6
        if scale != 1.0:
            self.map = VoxelMap(self.map_config(self.config.map.model_copy(update={"voxel": self.config.map.voxel * scale})),
                                self.config.scan_period)
        return self.config.voxel * scale

    def map_config(self, config: MapConfig) -> MapConfig:
        """The map's config: as given for ssf; the whole-scan variants map every voxel at once, never cleared."""
        if self.method is OdomMethod.SSF:
            return config
        return config.model_copy(update={"confirm": 1, "clear_cell": 0.0, "max_speed": 0.0, "moving_memory": 0.0})

    def update_map(self, mapped: np.ndarray, observed: np.ndarray | None, scan: np.ndarray,
                   moving: np.ndarray | None = None) -> None:
        """Insert the mapped points (with normals from their neighbours in the scan) at the current pose; for ssf the
        voxels the observed ones (None: all) hit gain evidence (the others only join the target, unconfirmed), the
        voxels of the moving points are remembered, and the beams of the scan (sensor frame, its points beyond the ego)
        clear the voxels they pass through."""
        moved = transform_points(self.pose, mapped)
        if self.method is OdomMethod.SSF:
            seen = np.arange(len(moved)) if observed is None else np.flatnonzero(observed)
            new = seen[self.map.observe(moved[seen], None if moving is None else transform_points(self.pose, moving))]
            if observed is not None:
                unseen = np.flatnonzero(~observed)
                new = np.concatenate([new, unseen[self.map.new_voxels(moved[unseen])]])
            self.map.clear(scan, self.pose)
        else:
            new = self.map.new_voxels(moved)
        self.map.insert(moved[new], self.map_normals(moved, new), self.pose[:3, 3])

    def map_normals(self, moved: np.ndarray, new: np.ndarray) -> np.ndarray:
        """Normals (odometry frame) of the new voxels from their nearest neighbours among the map's points and the
        scan's (`moved`: odometry frame): one scan's voxelised ring far out is nearly a line, whose plane tilts with
        the range noise, and those tilted normals pulled the pitch 0.7 deg off over 100 m of crowd_1000."""
        if len(new) == 0:
            return np.zeros((0, 3))
        if not len(self.map):
            return estimate_normals(moved, self.config.normal_neighbours, new)
        target = self.map.target()
        return normals_among(moved[new], [(target.points, target.tree), (moved, PointIndex(moved))],
                             self.config.normal_neighbours)

    def check(self, frame: OdomInput) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Validate one input (finite points, matching flow and probabilities); DataError names what is wrong."""
        points = np.asarray(frame.points, dtype=np.float32)
        if points.ndim != 2 or points.shape[1] < 3 or len(points) == 0:
            raise DataError(f"odometry: expected an (N, 3) scan, got shape {points.shape}")
        points = points[:, :3]
        if not np.isfinite(points).all():
            raise DataError("odometry: the scan holds NaN/Inf points")
        flow = None if frame.flow is None else np.asarray(frame.flow, dtype=np.float32)
        if flow is not None and (flow.shape != points.shape or not np.isfinite(flow).all()):
            raise DataError(f"odometry: flow of shape {flow.shape} (finite values needed) for {len(points)} points")
        dynamic = None if frame.dynamic_prob is None else np.asarray(frame.dynamic_prob, dtype=np.float32).reshape(-1)
        if dynamic is not None and (dynamic.shape != (len(points),) or not np.isfinite(dynamic).all()):
            raise DataError(f"odometry: {dynamic.size} dynamic probabilities for {len(points)} points")
        if self.method is OdomMethod.SSF and flow is not None and dynamic is None:
            raise ConfigError("odometry method 'ssf' needs the segmentation (dynamic probability) with the flow")
        return points, flow, dynamic

    def predict(self, stamp_ns: int) -> tuple[np.ndarray | None, np.ndarray]:
        """The pose of a new scan by the flow's motion (over one scan period; when scans were skipped, the flow's motion
        rate carried on; None without flow) and by constant velocity alone."""
        if self.stamp_ns is None:
            return None, np.eye(4)
        elapsed = self.elapsed(stamp_ns)
        by_velocity = self.pose @ exp_se3(self.velocity * elapsed)
        if self.method is OdomMethod.POINTS or self.next_motion is None:
            return None, by_velocity
        if elapsed < GAP_PERIODS * self.config.scan_period:
            return self.pose @ invert(self.next_motion), by_velocity
        # scans were skipped: the flow's own motion rate, measured at the last scan, carries on to this one
        per_scan = log_se3(invert(self.next_motion))
        return self.pose @ exp_se3(per_scan * (elapsed / self.config.scan_period)), by_velocity

    def next_pose(self) -> np.ndarray | None:
        """The pose of the scan the last scan's flow reaches: the last pose moved on by its static flow's motion (None
        without a flow). Checked against constant velocity, it came out worse in the real-time graph (turns after
        skipped scans: 6 degrees off against 0.02)."""
        if self.stamp_ns is None or self.next_motion is None:
            return None
        return self.pose @ invert(self.next_motion)

    def prior_pose(self, frame: OdomInput, measured: bool = False) -> np.ndarray | None:
        """The new scan's pose by the motion prior (or by the measured motion), when one is given and a valid 4x4
        rigid transform."""
        prior = frame.measured_motion if measured else frame.motion_prior
        if prior is None or self.stamp_ns is None:
            return None
        prior = np.asarray(prior, dtype=np.float64)
        if prior.shape != (4, 4) or not np.isfinite(prior).all():
            what = "measured motion" if measured else "motion prior"
            raise DataError(f"odometry: the {what} must be a finite 4x4 transform, got shape {prior.shape}")
        return self.pose @ prior

    def agree(self, by_flow: np.ndarray, by_velocity: np.ndarray, periods: float = 1.0,
              gate: tuple[float, float] | None = None) -> bool:
        """Whether the flow's prediction lies within the prior gate (or `gate`: m, rad) of the constant-velocity one;
        over `periods` scan periods (scans skipped by a busy graph) the two drift apart that many times more, and so
        does the gate."""
        distance, angle = self.config.prior_gate if gate is None else gate
        deviation = invert(by_velocity) @ by_flow
        return bool(np.linalg.norm(deviation[:3, 3]) <= distance * periods
                    and rotation_angle(deviation) <= angle * periods)

    def possible(self, by_flow: np.ndarray, by_velocity: np.ndarray, periods: float = 1.0) -> bool:
        """Whether the flow's prediction lies within the flow gate of constant velocity (always, where it is 0)."""
        if min(self.config.flow_gate) <= 0:
            return True
        return self.agree(by_flow, by_velocity, periods, self.config.flow_gate)

    def periods(self, stamp_ns: int) -> float:
        """Scan periods since the last scan (at least one)."""
        return max(1.0, self.elapsed(stamp_ns) / self.config.scan_period)

    def elapsed(self, stamp_ns: int) -> float:
        """Seconds since the last scan (one scan period when stamps do not advance)."""
        if self.stamp_ns is None or stamp_ns <= self.stamp_ns:
            return self.config.scan_period
        return (stamp_ns - self.stamp_ns) * 1e-9

    def registered_points(self, points: np.ndarray, dynamic: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """The points registered, with their weights: for ssf the static ones, weighted by their static probability;
        all of them for the other methods; near ones weigh less (`near_weights`)."""
        weights = np.ones(len(points))
        static = self.registered_index(dynamic)
        if static is not None:
            points, weights = points[static], 1.0 - dynamic[static]
        return points, weights * self.near_weights(points)

    def registered_index(self, dynamic: np.ndarray | None) -> np.ndarray | None:
        """Which points are registered: for ssf with a segmentation the static ones (a mask), else all (None)."""
        if self.method is OdomMethod.SSF and dynamic is not None:
            return dynamic <= self.config.static_threshold
        return None

    def near_weights(self, points: np.ndarray) -> np.ndarray:
        """Weight of each point by its horizontal range: range / near_range, between near_weight and 1. In a queue the
        cars around the ego move with it and fill most of the near voxels; labelled static (the flow's ego motion took
        them for the world) they pulled the registration along with them: on a dense_500 drive (tuning seed 11) the
        odometry went 0.1-0.25 m off per scan for 4 s."""
        if self.config.near_range <= 0:
            return np.ones(len(points))
        reach = np.sqrt(points[:, 0] * points[:, 0] + points[:, 1] * points[:, 1]) / self.config.near_range
        return np.clip(reach, self.config.near_weight, 1.0)

    def mapped_points(self, points: np.ndarray, flow: np.ndarray | None,
                      dynamic: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
        """The points that join the map and which of them are observed (None: all): every point, or for ssf the
        static ones within the target range whose own motion (flow less the ego motion of the static flow) is below
        map.max_speed, observed within the segmentation's range."""
        if self.method is not OdomMethod.SSF:
            return points, None
        squared = np.einsum("ij,ij->i", points[:, :2], points[:, :2])
        keep = squared <= max(self.config.ssf_range, self.config.target_range) ** 2
        if dynamic is not None:
            keep &= dynamic <= self.config.static_threshold
        if flow is not None and self.next_motion is not None and self.config.map.max_speed > 0:
            own = points + flow - (points @ self.next_motion[:3, :3].T + self.next_motion[:3, 3])
            keep &= np.einsum("ij,ij->i", own, own) <= (self.config.map.max_speed * self.config.scan_period) ** 2
        return points[keep], squared[keep] <= self.config.ssf_range ** 2

    def moving_points(self, points: np.ndarray, flow: np.ndarray | None,
                      dynamic: np.ndarray | None) -> np.ndarray | None:
        """ssf: the points the segmentation calls moving within its range, above their local ground (the ground under
        an agent stays mappable), and where their flow takes them by the next scan (this scan's coordinates: where an
        agent that stops will stand); None for the other methods or without a segmentation."""
        if self.method is not OdomMethod.SSF or dynamic is None or self.config.map.moving_memory <= 0:
            return None
        near = np.einsum("ij,ij->i", points[:, :2], points[:, :2]) <= self.config.ssf_range ** 2
        chosen = np.flatnonzero(near & (dynamic > self.config.static_threshold))
        chosen = chosen[above_ground(points[chosen], points[near], self.map.config.voxel)]
        if flow is None or self.next_motion is None:
            return points[chosen]
        ahead = (points[chosen] + flow[chosen] - self.next_motion[:3, 3]) @ self.next_motion[:3, :3]
        return np.concatenate([points[chosen], ahead])

    def refine(self, points: np.ndarray, weights: np.ndarray | None, by_flow: np.ndarray | None,
               by_velocity: np.ndarray, periods: float = 1.0, by_prior: np.ndarray | None = None,
               by_measured: np.ndarray | None = None,
               searched: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[Alignment, str]:
        """Point-to-plane Gauss-Newton of the registered points against the map from the predictions, one scan period
        after the last scan or across a gap; with the vehicle's measured motion, from that or the flow alone (a gyro
        measures the turns a heading search looks for). `searched`: the points (and weights) the search from constant
        velocity registers instead, one scan period on (a sweep deskewed with that motion)."""
        if len(self.map) == 0:
            return Alignment(by_velocity if by_flow is None else by_flow, np.zeros((6, 6)), 0, 0.0, 0), "start"
        target = self.map.target()
        if by_measured is not None:
            return self.refine_measured(points, weights, target, by_flow, by_measured, periods)
        if periods < GAP_PERIODS:
            return self.refine_next(points, weights, target, by_flow, by_velocity, periods, searched)
        return self.refine_across_gap(points, weights, target, by_flow, by_velocity, by_prior, periods)

    def refine_measured(self, points: np.ndarray, weights: np.ndarray | None, target, by_flow: np.ndarray | None,
                        by_measured: np.ndarray, periods: float = 1.0) -> tuple[Alignment, str]:
        """A few iterations from the flow's prediction where it agrees with the vehicle's measured motion (within
        measured_gate, per scan period), else from the measured motion: the wheels and the gyro do not move with the
        traffic, and across skipped scans they saw every turn."""
        gates, kernel = self.config.refine_gates, self.config.kernel
        if by_flow is not None and self.agree(by_flow, by_measured, periods, self.config.measured_gate):
            return point_to_plane(points, weights, target, by_flow, gates, kernel), "flow"
        if by_flow is not None:
            self.rejected_flows += 1
        return point_to_plane(points, weights, target, by_measured, gates, kernel), "measured"

    def refine_next(self, points: np.ndarray, weights: np.ndarray | None, target, by_flow: np.ndarray | None,
                    by_velocity: np.ndarray, periods: float = 1.0,
                    searched: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[Alignment, str]:
        """A few iterations from the flow's prediction; where it contradicts constant velocity (or there is no flow),
        a search from constant velocity too, and the result that matches more points wins; a flow past the flow gate
        is not refined at all."""
        if by_flow is not None and self.steps >= 2 and not self.possible(by_flow, by_velocity, periods):
            self.rejected_flows += 1
            by_flow = None
        if by_flow is not None:
            from_flow = point_to_plane(points, weights, target, by_flow, self.config.refine_gates, self.config.kernel)
            if self.steps < 2 or self.agree(by_flow, by_velocity, periods):
                return from_flow, "flow"
        searched = point_to_plane(*(searched or (points, weights)), target, by_velocity, self.config.search_gates,
                                  self.config.kernel)
        if by_flow is None:
            return searched, "velocity"
        if searched.inliers <= from_flow.inliers:
            return from_flow, "flow"
        self.rejected_flows += 1
        return searched, "velocity"

    def refine_across_gap(self, points: np.ndarray, weights: np.ndarray | None, target, by_flow: np.ndarray | None,
                          by_velocity: np.ndarray, by_prior: np.ndarray | None, periods: float) -> tuple[Alignment, str]:
        """Scans were skipped: the flow's extrapolated motion is searched in heading and refined; so is the motion
        prior (the commands sent meanwhile: a narrow search), or else constant velocity where it contradicts the flow;
        the result that lays most points on steep surfaces wins (the ground fits a wrong heading as well; ties go to
        the prior, then the flow). Where the flow's extrapolated start already is the prior's searched one, that is
        refined without the flow's wide search (most of a step's time across a gap)."""
        candidates: list[tuple[Alignment, str]] = []
        prior_start = None
        if by_prior is not None:
            reach = self.config.command_yaw_rate * periods * self.config.scan_period
            prior_start = self.best_heading(points, weights, target, by_prior, (0.0, reach / 2, -reach / 2, reach, -reach))
            if by_flow is not None and self.same_start(by_flow, prior_start):  # the flow's search would start there
                return point_to_plane(points, weights, target, prior_start, self.config.search_gates,
                                      self.config.kernel), "prior"
        if by_flow is not None:
            start = self.best_heading(points, weights, target, by_flow, self.gap_headings(periods))
            if prior_start is not None and self.same_start(start, prior_start):
                return point_to_plane(points, weights, target, prior_start, self.config.search_gates,
                                      self.config.kernel), "prior"
            from_flow = point_to_plane(points, weights, target, start, self.config.search_gates, self.config.kernel)
            if self.steps < 2 or (by_prior is None and self.agree(start, by_velocity, periods)):
                return from_flow, "flow"
            candidates.append((from_flow, "flow"))
        if prior_start is not None:
            candidates.append((point_to_plane(points, weights, target, prior_start, self.config.search_gates,
                                              self.config.kernel), "prior"))
        else:
            candidates.append((point_to_plane(points, weights, target, by_velocity, self.config.search_gates,
                                              self.config.kernel), "velocity"))
        if len(candidates) == 1:
            return candidates[0]
        (from_flow, _), (other, named) = candidates
        flow_support, other_support = (steep_support(points, found.transform, target) for found in (from_flow, other))
        if other_support < flow_support or (named == "velocity" and other_support == flow_support):
            return from_flow, "flow"
        self.rejected_flows += 1
        return other, named

    @staticmethod
    def same_start(first: np.ndarray, second: np.ndarray) -> bool:
        """Whether two searched starts are one (within a tenth of the refinement's finest gate and a quarter degree):
        refined, they would end alike."""
        deviation = invert(first) @ second
        return bool(np.linalg.norm(deviation[:3, 3]) < 0.1 and rotation_angle(deviation) < np.radians(0.25))

    def gap_headings(self, periods: float) -> tuple[float, ...]:
        """The heading offsets (deg) tried across a gap of `periods` scan periods: straight on and the gap headings
        each way, widened to reach gap_yaw_rate over the gap."""
        headings = np.asarray(self.config.gap_headings, dtype=np.float64)
        if headings.size:
            headings = headings * max(1.0, self.config.gap_yaw_rate * periods * self.config.scan_period / headings.max())
        return (0.0, *headings, *(-headings))

    def best_heading(self, points: np.ndarray, weights: np.ndarray | None, target, start: np.ndarray,
                     offsets: tuple[float, ...]) -> np.ndarray:
        """Of `start` turned by each offset (deg), the one whose first search iterations lay most points on steep
        surfaces (a swerve of 13 degrees in 0.3 s left the extrapolated flow 4 degrees off: metres at range, out of the
        refinement's reach; the ground matches every heading)."""
        best, most = start, -1
        stride = max(1, len(points) // HEADING_TRIAL_POINTS)  # a few hundred points tell the headings apart
        points, weights = points[::stride], None if weights is None else weights[::stride]
        for offset in offsets:
            turned = start.copy()
            turned[:3, :3] = yaw_matrix(np.radians(offset))[:3, :3] @ start[:3, :3]
            found = point_to_plane(points, weights, target, turned, self.config.search_gates[:3], self.config.kernel)
            support = steep_support(points, found.transform, target)
            if support > most:
                best, most = found.transform, support
        return best

    def chain(self, stamp_ns: int, alignment: Alignment) -> None:
        """Take the refined pose; grow the covariance by this step's; update the velocity."""
        elapsed = self.elapsed(stamp_ns)
        if self.stamp_ns is not None:
            self.velocity = log_se3(invert(self.pose) @ alignment.transform) / elapsed
        step_covariance = alignment.covariance if alignment.iterations else (GAP_NOISE if self.stamp_ns is not None else 0)
        self.covariance = self.covariance + step_covariance
        self.pose = alignment.transform
        self.steps += 1
        self.stamp_ns = stamp_ns if self.stamp_ns is None or stamp_ns > self.stamp_ns else self.stamp_ns + int(
            self.config.scan_period * 1e9)

    def given_ego(self, frame: OdomInput) -> np.ndarray | None:
        """The flow estimator's ego motion of this scan, when given (a finite 4x4 transform)."""
        if frame.ego is None:
            return None
        ego = np.asarray(frame.ego, dtype=np.float64)
        if ego.shape != (4, 4) or not np.isfinite(ego).all():
            raise DataError(f"odometry: the ego motion must be a finite 4x4 transform, got shape {ego.shape}")
        return ego

    def flow_motion(self, points: np.ndarray, flow: np.ndarray | None, dynamic: np.ndarray | None,
                    ego: np.ndarray | None = None) -> np.ndarray | None:
        """Scan t -> t+1 from the flow: for ssf the flow estimator's ego motion where given (estimated once, used as
        given), else Kabsch on the static points weighted by their static probability; Kabsch on every point (flow);
        None without flow or for the points method."""
        if flow is None or self.method is OdomMethod.POINTS:
            return None
        if self.method is OdomMethod.SSF and ego is not None:
            return ego.copy()
        weights = np.ones(len(points))
        if self.method is OdomMethod.SSF and dynamic is not None:
            weights = np.where(dynamic > self.config.static_threshold, 0.0, 1.0 - dynamic)
        if np.count_nonzero(weights > 0) < 3:
            return None
        return flow_transform(points, flow, weights)


def along_ground(motion: np.ndarray) -> np.ndarray:
    """A motion's part along the ground as (x, y, yaw)."""
    return np.array([motion[0, 3], motion[1, 3], yaw_of(motion)])


def centred_mean(motions: np.ndarray, jump: tuple[float, float]) -> np.ndarray:
    """The middle of three consecutive periods' motions (3, x y yaw) as a pose along the ground: their mean where their
    second difference stays within `jump` (m, rad; at constant acceleration the mean is the middle motion, and the
    neighbours' errors average out), else the middle motion itself (the motion changed at once)."""
    second = motions[0] - 2.0 * motions[1] + motions[2]
    second[2] = np.angle(np.exp(1j * second[2]))
    smooth = np.hypot(second[0], second[1]) <= jump[0] and abs(second[2]) <= jump[1]
    x, y, yaw = motions.mean(axis=0) if smooth else motions[1]
    return make_pose(x, y, 0.0, yaw)


def lifted(points: np.ndarray, shares: np.ndarray, lift: float) -> np.ndarray:
    """Points raised by their share of the sweep's `lift` along the sensor's z axis (the vertical deskew)."""
    if lift == 0.0:
        return points
    raised = points.copy()
    raised[:, 2] += (shares * lift).astype(points.dtype)
    return raised


def make_odometry(method: str | OdomMethod | None = None, config: OdomConfig | None = None) -> Odometry:
    """The odometry of `method` (default: config.method) built from its config."""
    config = config or OdomConfig()
    if method is not None:
        try:
            config = config.model_copy(update={"method": OdomMethod(method)})
        except ValueError:
            raise ConfigError(f"unknown odometry method '{method}'; choose one of "
                              f"{', '.join(item.value for item in OdomMethod)}") from None
    return Odometry(config)
