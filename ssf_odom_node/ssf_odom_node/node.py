"""ssf_odom_node: odometry from semantic scene flow. /ssf/semantic_flow (or /ssf/flow + /ssf/mask) with the flow's
ego motion (/ssf/ego_motion) in, /cmd_vel as the motion prior across skipped scans, and optionally the vehicle's own
measured motion (wheel speed, yaw rate); /odom, the odom -> base_link transform on /tf, /ssf/path and the static map
on /ssf/map out."""

from __future__ import annotations

import collections
import dataclasses
import time
from typing import Any

import numpy as np
from pydantic import Field

from ssf_common import messages, pose_msgs, topics
from ssf_common.diagnostics import StageStats, advertise, worker_counts
from ssf_common.conversions import (mask_from_cloud, odometry_to_msg, odometry_transform_msg,
                                    scene_flow_from_cloud, semantic_flow_from_cloud)
from ssf_common.errors import ConfigError, SsfError
from ssf_common.matching import ExactMatcher, ego_motion_listener
from ssf_common.middleware import QOS_DEFAULT, Node, run
from ssf_common.pointcloud import xyz_to_cloud
from ssf_common.records import EgoMotion
from ssf_common.stamps import SensorPeriod, StampSequence
from ssf_common.worker import LatestWorker
from ssf_odom_node.core.odometry import OdomConfig, OdomInput, make_odometry
from ssf_common.pose_msgs import mount_from_tf
from ssf_common.vehicle import MountConfig, mount_matrix
from ssf_odom_node.core.vehicle import VehicleMotion, next_scan_estimate, speed_ahead, to_base

PENDING_FLOWS = 8  # flows kept while their mask is on the way (input: flow_mask)


class OdomNodeConfig(MountConfig):
    """How the node is wired: its input, frames, the sensor mount and publishing rates."""

    input: str = Field("semantic_flow", description="semantic_flow (/ssf/semantic_flow) | flow_mask (/ssf/flow + /ssf/mask)")
    odom_frame: str = "odom"
    command_topic: str = Field(topics.CMD_VEL, description="velocity commands (geometry_msgs/Twist) the vehicle "
                               "obeys: across skipped scans, the motion they drove is the odometry's prior (see "
                               "command_yaw_rate); empty: no prior (a vehicle driven by something else)")
    twist_topic: str = Field("", description="the vehicle's own measured motion (geometry_msgs/TwistStamped of "
                             "base_link: wheel speed, yaw-rate gyro), e.g. /vehicle/twist from the simulator: between "
                             "scans it is the odometry's measured motion, which traffic moving with the ego cannot "
                             "fool (`ssf eval odom --methods ssf+twist`); empty: none (the paper's SSF)")
    max_accel: float = Field(3.0, gt=0.0, description="the vehicle follows the commanded speed within this "
                             "acceleration (m/s^2) ...")
    max_decel: float = Field(6.0, gt=0.0, description="... and this deceleration (m/s^2, positive)")
    pose_at: str = Field("next_scan", description="next_scan: /odom and /tf give the pose of the scan the flow "
                         "reaches (the newest scan: the scan before it, refined on the map, moved on by the static "
                         "flow's motion), stamped one sensor period (learnt from the stamps) after the flow, as soon as "
                         "the pair's flow is known; scan: the refined pose of the scan the flow starts from (a scan "
                         "period older). /ssf/path always holds the refined poses")
    map_period_s: float = Field(1.0, gt=0.0, description="how often /ssf/map is published (s)")
    path_length: int = Field(5000, ge=1, description="poses kept on /ssf/path")
    report_period_s: float = Field(5.0, gt=0.0)


class OdomNode(Node):
    """Converts semantic scene flow messages into odometry steps and publishes the pose, path and static map."""

    def __init__(self, argv: list[str] | None = None) -> None:
        super().__init__("ssf_odom_node", argv=argv)
        self.config = self.declare_config(OdomConfig)
        self.wiring = self.declare_config(OdomNodeConfig)
        if self.wiring.input not in ("semantic_flow", "flow_mask"):
            raise ConfigError(f"parameter input: '{self.wiring.input}' is not semantic_flow or flow_mask")
        if self.wiring.pose_at not in ("next_scan", "scan"):
            raise ConfigError(f"parameter pose_at: '{self.wiring.pose_at}' is not next_scan or scan")
        self.odometry = make_odometry(config=self.config)
        self.mount = mount_matrix(self.wiring.mount)
        self.sensor_frame = ""
        self.path: collections.deque[Any] = collections.deque(maxlen=self.wiring.path_length)
        self.flows: collections.OrderedDict[int, Any] = collections.OrderedDict()
        self.vehicle = VehicleMotion()  # the commands and measurements of the motion priors
        self.said_no_twist = False
        self.speed = 0.0  # base_link's forward speed at the last scan (m/s): where the motion prior starts from
        self.odom_pub = self.create_publisher("nav_msgs/msg/Odometry", topics.ODOM, QOS_DEFAULT)
        self.tf_pub = self.create_publisher("tf2_msgs/msg/TFMessage", topics.TF, QOS_DEFAULT)
        self.path_pub = self.create_publisher("nav_msgs/msg/Path", topics.PATH, QOS_DEFAULT)
        self.map_pub = self.create_publisher("sensor_msgs/msg/PointCloud2", topics.MAP, QOS_DEFAULT)
        self.worker = LatestWorker(self._step, ("scan",), self.get_logger(), "odom")
        self.matcher: ExactMatcher[OdomInput, EgoMotion] = ExactMatcher(self._matched)
        self._compute_ms: list[float] = []
        self.stats = StageStats(self.get_name())
        advertise(self, self.stats, refresh=worker_counts(self.stats, self.worker), inputs=(
            (topics.SEMANTIC_FLOW,) if self.wiring.input == "semantic_flow" else (topics.FLOW, topics.MASK)))
        self._last_stamp: int | None = None
        self.period = SensorPeriod()  # the sensor's period, learnt from the answered scans' stamps
        self._published_ns: int | None = None  # the stamp of the last /odom
        self.sequence = StampSequence()
        self.create_timer(self.wiring.map_period_s, self._publish_map)
        self.create_timer(0.05, lambda: self.matcher.expire(time.monotonic()))
        self.create_timer(self.wiring.report_period_s, self._report)
        self.get_logger().info(f"method '{self.config.method.value}' from {self.wiring.input}")
        if self.wiring.mount_from_tf:
            self.create_subscription("tf2_msgs/msg/TFMessage", topics.TF, self.on_tf, QOS_DEFAULT)
        if self.wiring.command_topic:
            self.create_subscription("geometry_msgs/msg/Twist", self.wiring.command_topic, self.on_command, QOS_DEFAULT)
        if self.wiring.twist_topic:
            self.create_subscription("geometry_msgs/msg/TwistStamped", self.wiring.twist_topic, self.on_twist,
                                     QOS_DEFAULT)
        self.create_subscription("ssf_interfaces/msg/EgoMotion", topics.EGO_MOTION,
                                 ego_motion_listener(self, self.matcher), QOS_DEFAULT)
        if self.wiring.input == "semantic_flow":  # inputs last: the node is whole once they are matched
            self.create_subscription("sensor_msgs/msg/PointCloud2", topics.SEMANTIC_FLOW, self.on_semantic_flow, QOS_DEFAULT)
        else:
            self.create_subscription("sensor_msgs/msg/PointCloud2", topics.FLOW, self.on_flow, QOS_DEFAULT)
            self.create_subscription("sensor_msgs/msg/PointCloud2", topics.MASK, self.on_mask, QOS_DEFAULT)

    def on_semantic_flow(self, msg: Any) -> None:
        """Queue one scan's converged flow and segmentation."""
        result = self.decoded(semantic_flow_from_cloud, msg, topics.SEMANTIC_FLOW, errors=(SsfError,),
                              consequence="; the pose keeps its constant-velocity prediction")
        if result is None:
            return
        self.sensor_frame = result.frame_id
        self.matcher.add_main((result.stamp_ns, result.iterations - 1), OdomInput(
            result.stamp_ns, result.points, result.flow, result.segmentation.dynamic_prob, time=result.time),
            time.monotonic())

    def on_flow(self, msg: Any) -> None:
        """Keep a flow until the mask of its scan arrives."""
        flow = self.decoded(scene_flow_from_cloud, msg, topics.FLOW, errors=(SsfError,))
        if flow is None:
            return
        self.flows[flow.stamp_ns] = flow
        while len(self.flows) > PENDING_FLOWS:
            self.flows.popitem(last=False)

    def on_mask(self, msg: Any) -> None:
        """Pair a mask with the flow of its scan and queue them."""
        stamp = messages.stamp_ns(msg.header.stamp)
        flow = self.flows.get(stamp)
        if flow is None:
            self.get_logger().warning(f"mask for stamp {stamp} matches no recent flow; dropped")
            return
        mask = self.decoded(mask_from_cloud, msg, topics.MASK, len(flow.points), errors=(SsfError,))
        if mask is None:
            return
        self.sensor_frame = flow.frame_id
        self.matcher.add_main((flow.stamp_ns, flow.iteration), OdomInput(flow.stamp_ns, flow.points, flow.flow,
                                                                         mask.dynamic_prob, time=flow.time),
                              time.monotonic())

    def _matched(self, frame: OdomInput, ego: EgoMotion | None) -> None:
        """Queue one scan with its ego motion (without one, the odometry fits it from the static flow: counted)."""
        if ego is None:
            self.stats.count("scans_without_ego_motion")
        self.worker.submit("scan", frame if ego is None else dataclasses.replace(frame, ego=ego.transform))

    def on_command(self, msg: Any) -> None:
        """Remember a velocity command with the time it arrived (a Twist has no stamp)."""
        linear, angular = float(msg.linear.x), float(msg.angular.z)
        if not (np.isfinite(linear) and np.isfinite(angular)):
            self.get_logger().warning(f"dropped a command on {self.wiring.command_topic} that is not finite")
            return
        self.vehicle.add_command(self.get_clock().now_ns(), linear, angular)

    def on_twist(self, msg: Any) -> None:
        """Remember one measurement of the vehicle's speed and yaw rate (over the time since the one before)."""
        stamp = messages.stamp_ns(msg.header.stamp)
        linear, angular = float(msg.twist.linear.x), float(msg.twist.angular.z)
        if not (np.isfinite(linear) and np.isfinite(angular)):
            self.get_logger().warning(f"dropped a measurement on {self.wiring.twist_topic} that is not finite")
            return
        self.vehicle.add_twist(stamp, linear, angular)

    def measured_prior(self, stamp_ns: int) -> np.ndarray | None:
        """The sensor's motion from the last scan to this one as the vehicle's measurements give it; None before the
        first scan, without measurements, or when they stopped."""
        motion, newest_ns = self.vehicle.measured(self._last_stamp, stamp_ns, self.mount)
        if motion is None and self._last_stamp is not None and self.wiring.twist_topic and not self.said_no_twist:
            newest = (f"the newest measurement is {(newest_ns - stamp_ns) * 1e-9:+.1f} s from it (stopped, or "
                      "stamped by another clock)") if newest_ns is not None else "none has come"
            self.get_logger().warning(f"no measured motion on {self.wiring.twist_topic} for the scan at {stamp_ns}: "
                                      f"{newest}; the flow alone decides (said once)")
            self.said_no_twist = True
        return motion

    def motion_prior(self, stamp_ns: int) -> np.ndarray | None:
        """The sensor's motion from the last scan to this one (last scan's sensor frame <- this one's) as the
        commands sent in between drove the vehicle; None before the first scan or without commands."""
        return self.vehicle.commanded(self._last_stamp, stamp_ns, self.speed,
                                      (self.wiring.max_accel, self.wiring.max_decel), self.mount)

    def on_tf(self, msg: Any) -> None:
        """Take the base_link -> sensor mount when /tf carries it."""
        mount = mount_from_tf(msg, self.wiring.base_frame, self.sensor_frame)
        if mount is not None:
            self.mount = mount

    def _step(self, _kind: str, frame: OdomInput) -> None:
        if self.sequence.restarted(frame.stamp_ns):
            self.get_logger().info("stamps jumped back: the stream restarted; odometry, path and map start again")
            self.odometry = make_odometry(config=self.config)
            self.path.clear()
            self._last_stamp = self._published_ns = None
        if self._last_stamp is not None and frame.stamp_ns <= self._last_stamp:
            if frame.stamp_ns < self._last_stamp:  # the same scan again (a later fusion answer) is simply skipped
                self.get_logger().warning(f"stamp {frame.stamp_ns} is older than the last scan's; dropped")
            return
        started = time.perf_counter()
        step = self.odometry.step(dataclasses.replace(frame, motion_prior=self.motion_prior(frame.stamp_ns),
                                                      measured_motion=self.measured_prior(frame.stamp_ns)))
        self._compute_ms.append((time.perf_counter() - started) * 1e3)
        self.stats.record(self._compute_ms[-1], "steps")
        if self._last_stamp is not None:
            self.period.learn(frame.stamp_ns - self._last_stamp)
        self._last_stamp = frame.stamp_ns
        estimate = to_base(step, self.mount, self.wiring.odom_frame, self.wiring.base_frame)
        self.speed = speed_ahead(step, self.config.scan_period, self.mount, without_flow=float(estimate.twist[0]))
        newest = estimate if self.wiring.pose_at != "next_scan" else next_scan_estimate(
            estimate, step, self.odometry.next_pose(), self.mount, self.period.period_ns)
        if self._published_ns is None or newest.stamp_ns > self._published_ns:  # a stamp already given (a shorter
            self._published_ns = newest.stamp_ns  # period learnt since) is not given again
            self.odom_pub.publish(odometry_to_msg(newest))
            self.tf_pub.publish(odometry_transform_msg(newest))
        self.path.append(messages.msg_type("geometry_msgs/msg/PoseStamped")(
            header=messages.header(step.stamp_ns, self.wiring.odom_frame), pose=pose_msgs.pose_msg(estimate.pose)))
        if self.path_pub.get_subscription_count():  # the whole path, for someone watching (thousands of poses late in
            self.path_pub.publish(messages.msg_type("nav_msgs/msg/Path")(  # a drive: milliseconds a scan for nobody)
                header=messages.header(step.stamp_ns, self.wiring.odom_frame), poses=list(self.path)))

    def _publish_map(self) -> None:
        """The static map (odom frame) at a low rate."""
        if self._last_stamp is None or not self.map_pub.get_subscription_count():  # built only for someone who listens
            return
        points = np.asarray(self.odometry.map.points, dtype=np.float64)
        if len(points) == 0:
            return
        base = points @ self.mount[:3, :3].T + self.mount[:3, 3]
        self.map_pub.publish(xyz_to_cloud(base.astype(np.float32), messages.header(self._last_stamp, self.wiring.odom_frame)))

    def _report(self) -> None:
        if not self._compute_ms:
            return
        self.get_logger().info(
            f"odometry: {self.worker.processed['scan']} scans, median {float(np.median(self._compute_ms)):.1f} ms, "
            f"map {len(self.odometry.map)} voxels; dropped {self.worker.dropped['scan']} scans that arrived while busy")
        self._compute_ms.clear()

    def on_shutdown(self) -> None:
        """Stop the worker."""
        self.worker.stop()


def main(argv: list[str] | None = None) -> int:
    """Console script: ros2 run ssf_odom_node ssf_odom_node."""
    return run(OdomNode, argv)
