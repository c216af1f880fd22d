"""`ssf eval nav --video-first N`: a trial filmed as it drives, one bird's-eye frame per tick in the world frame (the
scan, coloured by segmentation where the `ssf` source segmented it; the true agents; the obstacles the perception
gave the planner with their velocity arrows; the MPC plan; the true path and, with --pose ssf, the odometry's)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sim_bridge.ros_messages import agent_obstacles
from ssf_common.geometry.se3 import invert, transform_points
from ssf_common.render.frames import RenderConfig, ViewFrame
from ssf_common.render.video import write_video

WORLD_FRAME = "world"


class TrialFilm:
    """The frames of one trial, collected tick by tick and written as a video at its end."""

    def __init__(self, path: str | Path, config: RenderConfig | None = None) -> None:
        self.path = Path(path)
        self.config = config or RenderConfig()
        self.frames: list[ViewFrame] = []
        self.path_xy: list[np.ndarray] = []
        self.odometry_xy: list[np.ndarray] = []
        self.rng = np.random.default_rng(self.config.seed)
        self._previous_lidar: np.ndarray | None = None  # world <- lidar of the previous frame

    def add(self, loop, frame, tick) -> None:
        """One tick of `loop` (a ClosedLoop): `frame` is what it perceived, `tick` what it answered."""
        odom_to_world = invert(loop.world_to_odom)
        self.path_xy.append(frame.base_pose[:2, 3].copy())
        if loop.ssf_pose is not None:
            self.odometry_xy.append((odom_to_world @ tick.pose)[:2, 3])
        points, labels, instances = self._cloud(loop, frame)
        perceived = None if tick.obstacles is None else tick.obstacles.transformed(odom_to_world, WORLD_FRAME)
        plan = None
        if tick.plan is not None and len(tick.plan.states):
            plan = transform_points(odom_to_world, np.c_[tick.plan.states[:, :2], np.zeros(len(tick.plan.states))])[:, :2]
        self.frames.append(ViewFrame(
            frame.stamp_ns, frame.base_pose.copy(), points, labels, instances,
            agent_obstacles(frame.agents, frame.stamp_ns), perceived, plan, np.array(self.path_xy),
            np.array(self.odometry_xy) if self.odometry_xy else None))
        self._previous_lidar = frame.pose.copy()

    def write(self, title: str) -> int:
        """The video (MP4 or GIF by the file name); the frame count."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        return write_video(self.frames, self.path, self.config, title=title)

    def _cloud(self, loop, frame) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """The points to draw in the world frame: the scan the `ssf` source just segmented (the previous one), with
        its labels and instances, or else this frame's raw scan."""
        scans = getattr(loop.perception, "scans", None)
        pair = None if scans is None else scans.latest
        if pair is not None and self._previous_lidar is not None:
            keep = self._subset(len(pair.points))
            segmentation = pair.seen.fusion.segmentation
            return (transform_points(self._previous_lidar, pair.points[keep]),
                    segmentation.label[keep], segmentation.instance[keep])
        keep = self._subset(len(frame.scan.points))
        return transform_points(frame.pose, frame.scan.points[keep, :3]), None, None

    def _subset(self, count: int) -> np.ndarray:
        """Indices of at most `max_points` points (drawing more adds nothing but time)."""
        if count <= self.config.max_points:
            return np.arange(count)
        return np.sort(self.rng.choice(count, self.config.max_points, replace=False))
