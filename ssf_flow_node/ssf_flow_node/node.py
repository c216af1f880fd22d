"""ssf_flow_node: scene flow between consecutive scans on /lidar/points, conditioned on the temporal prior the last
scan left (/ssf/prior), re-estimated for each mask hint; the flow on /ssf/flow and its ego motion on /ssf/ego_motion.
Sweeps that carry per-point time are deskewed, by the vehicle's measured motion where it is given (twist_topic), which
also guides and vets the ego motion."""

from __future__ import annotations

import collections
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import Field

from ssf_common import messages, topics
from ssf_common.diagnostics import StageStats, advertise, worker_counts
from ssf_common.conversions import ego_motion_to_msg, mask_from_cloud, prior_from_cloud, scene_flow_to_cloud
from ssf_common.geometry.sweep import pair_times
from ssf_common.middleware import QOS_DEFAULT, QOS_SENSOR_DATA, Node, run
from ssf_common.pointcloud import decode_cloud
from ssf_common.records import EgoMotion, PriorSource, SceneFlow
from ssf_common.stamps import SensorPeriod
from ssf_common.temporal_prior import carry_prior
from ssf_common.pose_msgs import mount_from_tf
from ssf_common.vehicle import MeasuredTwists, MountConfig, mount_matrix
from ssf_common.worker import LatestWorker
from ssf_flow_node.core.estimator import WHOLE_SCAN, FlowConfig, make_estimator

SCAN_HISTORY = 8  # scans kept so that a mask hint for a recent scan still finds its pair
PRIOR_HISTORY = 4  # temporal priors kept until the pair of the scan after theirs is estimated


class FlowNodeVehicle(MountConfig):
    """The vehicle's own measured motion, which deskews each sweep."""

    twist_topic: str = Field("", description="the vehicle's measured motion (geometry_msgs/TwistStamped of base_link: "
                             "wheel speed, yaw-rate gyro), e.g. /vehicle/twist from the simulator: each sweep is "
                             "deskewed by its own measured motion, as IMU or wheel deskewing does on a car, and "
                             "estimated once, and the ego motion starts from it and is vetted by it (traffic moving "
                             "with the car cannot make it stand still); empty: none, each sweep is deskewed at the "
                             "last pair's motion and estimated again where the car braked or steered")


@dataclass(frozen=True)
class ReceivedScan:
    """One received scan: its stamp, frame and finite points."""

    stamp_ns: int
    frame_id: str
    xyz: np.ndarray
    time: np.ndarray | None = None  # each point's time, s relative to the stamp (None: none, or an instant sweep)


@dataclass(frozen=True)
class FlowJob:
    """Flow of scan t towards scan t+1, optionally conditioned on a mask, answering one iteration."""

    scan: ReceivedScan
    next_scan: ReceivedScan
    mask: np.ndarray | None  # a mask hint; None: the temporal prior, when the scan before left one
    iteration: int


class FlowNode(Node):
    """Translates scans and mask hints into estimator calls, and flow into PointCloud2."""

    def __init__(self, argv: list[str] | None = None) -> None:
        super().__init__("ssf_flow_node", argv=argv)
        self.config = self.declare_config(FlowConfig, defaults=WHOLE_SCAN)
        device = self.declare_parameter("device", "cpu").value
        report_period = self.declare_parameter("report_period_s", 5.0).value
        self.prior_wait_s = float(self.declare_parameter("prior_wait_s", 0.0).value)  # see wait_for_prior
        self.vehicle = self.declare_config(FlowNodeVehicle)
        self.mount = mount_matrix(self.vehicle.mount)
        self.twists = MeasuredTwists()
        self.sensor_frame = ""
        self.estimator = make_estimator(config=self.config, device=device)
        self.scans: collections.deque[ReceivedScan] = collections.deque(maxlen=SCAN_HISTORY)
        self.priors: collections.OrderedDict[int, PriorSource] = collections.OrderedDict()  # by the stamp they came from
        self.prior_came = threading.Condition()  # the worker waits on it for a prior on its way
        self.answered: int | None = None  # the stamp of the newest scan whose flow went out: its prior is on its way
        self.period = SensorPeriod()  # the shortest time between consecutive scans seen: the sweep period
        self.ego_pub = self.create_publisher("ssf_interfaces/msg/EgoMotion", topics.EGO_MOTION, QOS_DEFAULT)
        self.flow_pub = self.create_publisher("sensor_msgs/msg/PointCloud2", topics.FLOW, QOS_DEFAULT)
        self.worker = LatestWorker(self._estimate, ("hint", "scan"), self.get_logger(), "flow")
        self.create_subscription("sensor_msgs/msg/PointCloud2", topics.PRIOR, self.on_prior, QOS_DEFAULT)
        if self.vehicle.twist_topic:
            self.create_subscription("geometry_msgs/msg/TwistStamped", self.vehicle.twist_topic, self.on_twist,
                                     QOS_DEFAULT)
            if self.vehicle.mount_from_tf:
                self.create_subscription("tf2_msgs/msg/TFMessage", topics.TF, self.on_tf, QOS_DEFAULT)
        self.create_subscription("sensor_msgs/msg/PointCloud2", topics.LIDAR_POINTS, self.on_scan, QOS_SENSOR_DATA)
        self.create_subscription("sensor_msgs/msg/PointCloud2", topics.MASK_HINT, self.on_mask_hint, QOS_DEFAULT)
        self.create_timer(report_period, self._report)
        self._compute_ms: list[float] = []
        self.stats = StageStats(self.get_name())
        advertise(self, self.stats, refresh=worker_counts(self.stats, self.worker), inputs=(topics.LIDAR_POINTS,))
        self.get_logger().info(f"estimator '{self.config.estimator}' on {device}")

    def on_scan(self, msg: Any) -> None:
        """Remember the scan and ask for the flow of the previous one towards it."""
        decoded = self.decoded(decode_cloud, msg, topics.LIDAR_POINTS)
        if decoded is None:
            return
        if decoded.time_problem:  # said once: every scan of a driver writes its time alike
            self.stats.count("scans_with_unusable_time")
            if self.stats.counts["scans_with_unusable_time"] == 1:
                self.get_logger().warning(f"{topics.LIDAR_POINTS}: {decoded.time_problem}; scans are not deskewed")
        scan = ReceivedScan(messages.stamp_ns(msg.header.stamp), msg.header.frame_id, np.ascontiguousarray(decoded.xyz),
                            decoded.time)
        self.sensor_frame = scan.frame_id
        if self.scans and scan.stamp_ns <= self.scans[-1].stamp_ns:
            self.get_logger().warning("scan stamps went backwards: starting a new sequence")
            self.scans.clear()
            with self.prior_came:
                self.priors.clear()
                self.answered = None
        if self.scans and self._consecutive(self.scans[-1], scan):
            self.worker.submit("scan", FlowJob(self.scans[-1], scan, None, 0))
        self.scans.append(scan)

    def _consecutive(self, previous: ReceivedScan, scan: ReceivedScan) -> bool:
        """Whether two scans are consecutive sweeps: a flow across a lost scan would cover twice the time every stage
        after this one assumes (velocities, odometry), so such a pair is skipped and counted."""
        if self.period.consecutive(scan.stamp_ns - previous.stamp_ns):
            return True
        self.stats.count("pairs_skipped_after_a_lost_scan")
        return False

    def on_twist(self, msg: Any) -> None:
        """Keep one measurement of the vehicle's speed and yaw rate."""
        linear, angular = float(msg.twist.linear.x), float(msg.twist.angular.z)
        if not (np.isfinite(linear) and np.isfinite(angular)):
            self.get_logger().warning(f"dropped a measurement on {self.vehicle.twist_topic} that is not finite")
            return
        self.twists.add(messages.stamp_ns(msg.header.stamp), linear, angular)

    def on_tf(self, msg: Any) -> None:
        """Take the base_link -> sensor mount when /tf carries it."""
        mount = mount_from_tf(msg, self.vehicle.base_frame, self.sensor_frame)
        if mount is not None:
            self.mount = mount

    def measured_sweep(self, scan: ReceivedScan, next_scan: ReceivedScan) -> np.ndarray | None:
        """The sensor's motion over the next scan's sweep as the vehicle measured it (None: not asked for, or none
        came in time for it: then the sweep is deskewed at the last pair's motion, counted)."""
        if not self.vehicle.twist_topic:
            return None
        motion = self.twists.sweep(scan.stamp_ns, next_scan.stamp_ns, self.mount)
        if motion is None:
            self.stats.count("sweeps_without_measured_motion")
            if self.stats.counts["sweeps_without_measured_motion"] == 1:
                self.get_logger().warning(f"no measured motion on {self.vehicle.twist_topic} for the sweep of the scan "
                                          f"at {next_scan.stamp_ns}: deskewed at the last pair's motion (said once)")
        return motion

    def on_prior(self, msg: Any) -> None:
        """Keep what a finished scan left for the next scan's temporal prior."""
        source = self.decoded(prior_from_cloud, msg, topics.PRIOR)
        if source is None:
            return
        with self.prior_came:
            self.priors[source.stamp_ns] = source
            while len(self.priors) > PRIOR_HISTORY:
                self.priors.popitem(last=False)
            self.prior_came.notify_all()

    def temporal_prior(self, scan: ReceivedScan) -> np.ndarray | None:
        """M^(0) of a scan: the segmentation of the scan right before it, carried onto it (None: none has come)."""
        scans = list(self.scans)  # the worker's snapshot of what the subscriptions append
        before = next((earlier for earlier, later in zip(scans, scans[1:]) if later.stamp_ns == scan.stamp_ns), None)
        if before is None or self.period.spans_lost_scan(scan.stamp_ns - before.stamp_ns):
            return None  # the first scan of a sequence, or one after a lost scan: nothing points onto it
        source = self.wait_for_prior(before.stamp_ns)
        if source is None:
            self.stats.count("pairs_without_their_prior")  # the scan before was not finished in time
            return None
        return carry_prior(source, scan.xyz)

    def wait_for_prior(self, stamp_ns: int) -> PriorSource | None:
        """The prior the scan at `stamp_ns` left; where its flow went out and its answer is still on its way, waited
        for at most prior_wait_s (in real time the chain answers a scan a little after the next pair begins: the pair's
        work that needs no mask is done first, and the prior usually comes meanwhile)."""
        with self.prior_came:
            if stamp_ns not in self.priors and self.answered == stamp_ns and self.prior_wait_s > 0:
                self.prior_came.wait_for(lambda: stamp_ns in self.priors, timeout=self.prior_wait_s)
            return self.priors.get(stamp_ns)

    def on_mask_hint(self, msg: Any) -> None:
        """Re-estimate the flow of the scan the hint refers to, conditioned on its mask."""
        stamp = messages.stamp_ns(msg.header.stamp)
        pair = self._pair_of(stamp)
        if pair is None:
            self.get_logger().warning(f"mask hint for stamp {stamp} matches no recent scan pair; dropped")
            return
        hint = self.decoded(mask_from_cloud, msg, topics.MASK_HINT, len(pair[0].xyz))
        if hint is None:
            return
        self.worker.submit("hint", FlowJob(pair[0], pair[1], hint.dynamic_prob, hint.iteration))

    def _pair_of(self, stamp_ns: int) -> tuple[ReceivedScan, ReceivedScan] | None:
        scans = list(self.scans)
        for scan, next_scan in zip(scans, scans[1:]):
            if scan.stamp_ns == stamp_ns:
                return scan, next_scan
        return None

    def _estimate(self, _kind: str, job: FlowJob) -> None:
        start = time.perf_counter()
        sweeps = pair_times(job.scan.time, job.next_scan.time, (job.next_scan.stamp_ns - job.scan.stamp_ns) * 1e-9,
                            self.measured_sweep(job.scan, job.next_scan))
        follows = self.answered is not None and job.scan.stamp_ns > self.answered  # pairs skipped to keep up, if any
        if job.iteration == 0:  # the work that needs no mask first: meanwhile the scan before may finish
            self.estimator.get_ready(job.scan.xyz, job.next_scan.xyz, sweeps, follows)
        mask = self.temporal_prior(job.scan) if job.iteration == 0 else job.mask
        result = self.estimator.estimate(job.scan.xyz, job.next_scan.xyz, mask, sweeps, follows)
        self._compute_ms.append((time.perf_counter() - start) * 1e3)
        self.stats.record(self._compute_ms[-1], "estimates")
        self.stats.set("sweeps_estimated_again", getattr(self.estimator, "estimated_again", 0))
        ego = EgoMotion(job.scan.stamp_ns, job.next_scan.stamp_ns, job.scan.frame_id, result.ego, job.iteration)
        self.ego_pub.publish(ego_motion_to_msg(ego))  # first: it is small, and the flow's readers wait for it
        self.flow_pub.publish(scene_flow_to_cloud(SceneFlow(job.scan.stamp_ns, job.scan.frame_id, job.scan.xyz,
                                                            result.flow, job.iteration, mask, ego,
                                                            job.scan.time if sweeps is not None else None)))
        if job.iteration == 0:
            with self.prior_came:
                self.answered = job.scan.stamp_ns

    def _report(self) -> None:
        if not self._compute_ms:
            return
        median = float(np.median(self._compute_ms))
        self.get_logger().info(
            f"flow: {self.worker.processed['scan']} scans, {self.worker.processed['hint']} mask hints, "
            f"median {median:.1f} ms; dropped {self.worker.dropped['scan']} scans that arrived while busy, "
            f"{self.stats.counts['pairs_skipped_after_a_lost_scan']} pairs across a lost scan"
        )
        self._compute_ms.clear()

    def on_shutdown(self) -> None:
        """Stop the worker."""
        self.worker.stop()


def main(argv: list[str] | None = None) -> int:
    """Console script: ros2 run ssf_flow_node ssf_flow_node."""
    return run(FlowNode, argv)
