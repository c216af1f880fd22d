"""Configuration of the learning-free estimator: clustering, per-cluster registration, the evidence a motion needs, ends
and carried motions (speeds in m/s, turns in rad/s)."""

from __future__ import annotations

from typing import ClassVar

from pydantic import Field

from ssf_common.config import Section


class RigidConfig(Section):
    """Clustering and per-cluster registration of the learning-free estimator (speeds in m/s, turns in rad/s)."""

    renamed: ClassVar[dict[str, str]] = {"dt": "scan_period"}
    scan_period: float = Field(0.1, gt=0.0, description="time between the two scans (s)")
    cluster_voxel: float = Field(0.5, gt=0.0, description="voxel edge (m) of the connected-component clustering")
    split_voxel: float = Field(0.25, ge=0.0, description="a cluster that stays still although parts of it changed is "
                               "clustered again with this voxel (m), so a walker beside a parked car gets its own motion "
                               "(0: never)")
    split_by_mask: bool = Field(False, description="the mask's dynamic points form clusters apart from the rest of "
                                "their component (off: a carried mask misses the parts of an object it has newly shown, "
                                "which then stayed behind)")
    min_cluster_points: int = Field(15, ge=3, description="points needed in each scan to register a cluster")
    min_masked_points: int = Field(3, ge=2, description="points needed in each scan for a cluster the mask calls dynamic")
    max_speed: float = Field(30.0, gt=0.0, description="fastest object (m/s)")
    histogram_bin: float = Field(0.3, gt=0.0, description="bin (m) of the translation histogram")
    histogram_points: int = Field(32, ge=4, description="points per scan and cluster in the translation histogram")
    histogram_peaks: int = Field(4, ge=1, description="histogram peaks tried as initial translations")
    point_weight: float = Field(0.3, ge=0.0, description="weight of point-to-point next to point-to-plane residuals")
    plane: bool = Field(True, description="register objects point-to-plane (normals of scan t+1) instead of point-to-point")
    max_yaw_rate: float = Field(1.0, ge=0.0, description="fastest object turn (rad/s)")
    max_extent: float = Field(12.0, gt=0.0, description="larger clusters (xy extent, m) are static structure unless the mask says otherwise")
    icp_points: int = Field(128, ge=3, description="points per cluster in its ICP (random, for speed on big clusters)")
    icp_iterations: int = Field(5, ge=1, description="iterations of the batched per-cluster ICP")
    screen_still: bool = Field(True, description="clusters that standing still explains within their noise floor are "
                               "not fitted (no fitted motion could be proven for them); their ends and carried motions "
                               "are still tried")
    icp_gates: tuple[float, float] = Field((1.0, 0.3), description="correspondence gate (m), first and last iteration")
    residual_cap: float = Field(1.0, gt=0.0, description="nearest-neighbour residuals are truncated here (m)")
    min_gain: float = Field(0.3, ge=0.0, le=1.0, description="share of the static hypothesis' distance to the surfaces "
                            "of scan t+1 a motion must remove (where the mask does not call the cluster dynamic)")
    min_point_gain: float = Field(0.5, ge=0.0, le=1.0, description="or: share of its distance to the points")
    support_gain: float = Field(0.1, ge=0.0, le=1.0, description="a motion proven by the surfaces must also bring the "
                                "points this share closer (sliding along a wall does not)")
    mask_gain: float = Field(0.1, ge=0.0, le=1.0, description="the same share where the mask calls the cluster dynamic")
    surface_noise: float = Field(2.0, ge=0.0, description="a cluster standing still must miss the surfaces of scan t+1 by "
                                 "more than this many times the scene's median miss, and its surfaces' own roughness, "
                                 "before its motion counts")
    inlier_gate: float = Field(0.3, gt=0.0, description="a point is explained by scan t+1 within this distance (m)")
    resample_spacing: float = Field(0.3, ge=0.0, description="standing still counts the sensor's resampling of a "
                                    "surface it slides along only where scan t+1 samples it along the slide at least "
                                    "this coarsely (m): far walls at grazing angles; the finer-sampled flank of a car "
                                    "moving with the ego (or overtaking it) would pass for still")
    min_explained_gain: float = Field(0.25, ge=0.0, le=1.0, description="or: share of a cluster's points a motion must "
                                      "newly explain")
    max_unexplained: float = Field(0.2, ge=0.0, le=1.0, description="a motion must explain all but this share of a "
                                   "cluster's points")
    min_speed: float = Field(0.5, ge=0.0, description="clusters slower than this (m/s) are static")
    ground_clearance: float = Field(0.08, ge=0.0, description="where the ground is split off, points this close above "
                                    "it (m) are ground and keep the scene's motion; higher ones near a mover share it")
    footprint: float = Field(0.1, ge=0.0, description="points within ground_clearance of the ground still move with a "
                             "moving object where one of its sampled points lies within this horizontal distance (m): "
                             "its wheels and lowest parts, inside its footprint (0: never)")
    attach_distance: float = Field(0.6, ge=0.0, description="points left out of the clusters (low ones) this close to a "
                                   "moving cluster move with it where its motion explains them better (m)")
    mask_threshold: float = Field(0.5, ge=0.0, le=1.0, description="dynamic probability above which a point is dynamic")
    ego_refit: float = Field(0.02, ge=0.0, le=1.0, description="the ego motion is aligned without the mask's dynamic "
                             "points too only where it calls more than this share of them dynamic (the robust kernel "
                             "copes with the rest)")
    ego_tolerance: float = Field(0.1, ge=0.0, description="the ego motions aligned with and without the mask's dynamic "
                                 "points agree within this (m, over a 1 m radius); where they do not, the second must "
                                 "lie this much nearer the previous pair's to be taken")
    ego_max_accel: float = Field(8.0, gt=0.0, description="hardest change of the ego's speed (m/s², braking at about 0.8 "
                                 "g): where only the alignment without the mask's dynamic points is a change from the "
                                 "previous pair's motion a vehicle can make in dt, it is taken (traffic moving with the ego "
                                 "pulls the other towards standing still)")
    measured_gate: float = Field(0.1, gt=0.0, description="where the vehicle measured the pair's motion (wheel speed, "
                                 "gyro: within 2-3 cm and 0.03 deg a period), an ego motion that puts a point "
                                 "measured_range away this far (m) from where the measured motion puts it is not the "
                                 "car's: traffic moving with it, a vehicle close ahead filling the scan, pulls the "
                                 "alignment towards standing still or turns it with them; it is refined again from the "
                                 "measured motion, and where that is as far, the measured motion is taken")
    measured_range: float = Field(20.0, gt=0.0, description="the range (m) at which measured_gate is measured: a "
                                  "rotation of 0.29 deg moves a point there by 0.1 m")
    ego_vouch: bool = Field(True, description="where the mask calls enough points dynamic, the alignment without them is "
                            "taken at once when it is a change of the previous pair's motion a vehicle can make "
                            "(ego_max_accel, ego_mask_share): the alignment on every point is made only to judge one "
                            "that is not")
    ego_judge_restarts: bool = Field(False, description="the alignment on every point, made only to judge one without "
                                     "the mask's dynamic points that is a change of the previous pair's motion a vehicle "
                                     "can make, restarts where it walks away (from the other samples and that motion) as "
                                     "it does where it is the answer (off: judged as it came; where the mask calls most "
                                     "points dynamic the restarts tripled the flow's cost, to 150-230 ms a scan)")
    ego_mask_share: float = Field(0.5, ge=0.0, le=1.0, description="the alignment without the mask's dynamic points "
                                  "is taken for being the only plausible change only while the mask calls at most this "
                                  "share of the points dynamic (a mask that hides the static structure drags an alignment "
                                  "on oncoming traffic along step by step, each step plausible)")
    end_whole: bool = Field(True, description="where the ground is split, the ends of a flank are found among all the "
                            "points of the whole scans within a sampling spacing of its sampled ones, not among the "
                            "sampled ones alone (a near flank thinned by the range-balanced sample)")
    end_spacings: float = Field(2.0, ge=0.0, description="a cluster alone in its component whose two ends moved alike "
                                "along its main horizontal axis, by at least this many times its sampling spacing, moves "
                                "by that shift where it explains scan t+1 no worse than standing still: a flank sliding "
                                "along itself, which the fits cannot tell from still (0: never)")
    end_agreement: float = Field(0.25, ge=0.0, le=1.0, description="the two ends' shifts agree within this share of "
                                 "their mean")
    end_points: int = Field(50, ge=2, description="points a cluster needs in scan t before its ends count")
    end_slack: float = Field(0.25, ge=0.0, description="the ends' shift may fit the sample this share worse than "
                             "standing still: a flank sliding along itself fits either way only within the noise of its "
                             "sampling")
    end_occlusion: float = Field(0.5, gt=0.0, description="an end with points of scan t+1 this much nearer the sensor "
                                 "beside it (within three sampling spacings) is the edge of what hides the cluster, not "
                                 "the cluster's end (m)")
    carry_pairs: int = Field(10, ge=0, description="in a stream of scans, an object seen moving keeps its motion for at "
                             "most this many pairs running in which the pair alone cannot tell it from standing still (a "
                             "flank sliding along itself), while that motion explains scan t+1 no worse (0: never)")
    carry_radius: float = Field(0.5, gt=0.0, description="a point of scan t takes the motion of the previous pair's "
                                "moving point that landed nearest it, within this distance (m)")
    carry_share: float = Field(0.5, gt=0.0, le=1.0, description="share of a cluster's points that must take a motion "
                               "from the previous pair for the cluster to keep it")
    carry_proven: int = Field(2, ge=1, description="pairs that must have shown the object moving on their own evidence "
                              "before its motion is carried (one pair's phantom is not carried on)")
    carry_tolerance: float = Field(0.2, ge=0.0, description="the cluster's own fitted motion replaces the carried one "
                                   "where the two agree within this (m per pair)")
