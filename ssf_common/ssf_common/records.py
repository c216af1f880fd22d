"""Typed numpy twins of the graph's topics: what the cores take and return, the nodes convert to and from
messages (`ssf_common.conversions`), and the evaluation compares with ground truth.

| record | topic |
| --- | --- |
| `EgoMotion` | `/ssf/ego_motion` (ssf_interfaces/EgoMotion: the flow estimator's ego motion of each pair) |
| `SceneFlow` | `/ssf/flow` (x y z flow_x flow_y flow_z iteration prior) with its `/ssf/ego_motion` |
| `Segmentation` | per point of a scan: label, instance, dynamic probability (part of `/ssf/semantic_flow`) |
| `MotionMask` | `/ssf/mask`, `/ssf/mask_hint` (x y z mask instance iteration) |
| `SemanticFlow` | `/ssf/semantic_flow` (x y z flow_x flow_y flow_z label instance prob iteration) |
| `PriorSource` | `/ssf/prior` (x y z mask: a scan's points near its moving objects, moved by their flow) |
| `Obstacles` | `/ssf/obstacles`, `/sim/ground_truth/obstacles` (ssf_interfaces/ObstacleArray) |
| `OdometryEstimate` | `/odom` (nav_msgs/Odometry) and the odom -> base_link transform on `/tf` |
| `Plan` | `/ssf/plan` (nav_msgs/Path) |
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from enum import IntEnum

import numpy as np

from ssf_common.geometry.boxes import box_corners
from ssf_common.geometry.se3 import yaw_of


class MotionLabel(IntEnum):
    """Static/dynamic label of a point."""

    STATIC = 0
    DYNAMIC = 1


class ObstacleKind(IntEnum):
    """What an obstacle is (ssf_interfaces/Obstacle KIND_*)."""

    UNKNOWN = 0
    VEHICLE = 1
    PEDESTRIAN = 2


@dataclass(frozen=True)
class EgoMotion:
    """The sensor's motion over one scan pair, as the flow estimator aligned it: estimated once, used as given."""

    stamp_ns: int  # scan t
    next_stamp_ns: int  # scan t+1
    frame_id: str
    transform: np.ndarray  # (4, 4) float64: scan-t coordinates of static points -> scan t+1's sensor frame
    iteration: int = 0  # the fusion iteration of the flow it came with

    @property
    def dt(self) -> float:
        """Seconds between the two scans."""
        return (self.next_stamp_ns - self.stamp_ns) * 1e-9


@dataclass(frozen=True)
class SceneFlow:
    """Flow of every point of scan t (its sensor frame): points + flow lies on the surfaces of scan t+1."""

    stamp_ns: int
    frame_id: str
    points: np.ndarray  # (N, 3) float32
    flow: np.ndarray  # (N, 3) float32
    iteration: int = 0  # the fusion iteration this flow answers
    prior: np.ndarray | None = None  # (N,) float32: the dynamic probability M^(i) the flow was conditioned on (None: none)
    ego: EgoMotion | None = None  # the ego motion found with it (None: not known)
    time: np.ndarray | None = None  # (N,) float32 each point's time, s relative to the stamp (None: an instant sweep)

    def __len__(self) -> int:
        return len(self.points)


@dataclass(frozen=True)
class Segmentation:
    """Per point of a scan: probability of moving, static/dynamic label and object instance (0 = static scene)."""

    dynamic_prob: np.ndarray  # (N,) float32 in [0, 1]
    label: np.ndarray  # (N,) uint8 MotionLabel
    instance: np.ndarray  # (N,) int32, 0 for the static scene, 1..K for moving objects

    def __len__(self) -> int:
        return len(self.label)

    @property
    def dynamic(self) -> np.ndarray:
        """(N,) bool: points labelled dynamic."""
        return self.label == MotionLabel.DYNAMIC

    @property
    def num_instances(self) -> int:
        """How many moving objects carry points."""
        return int(np.unique(self.instance[self.instance > 0]).size)

    @classmethod
    def from_probability(cls, dynamic_prob: np.ndarray, instance: np.ndarray | None = None,
                         threshold: float = 0.5) -> Segmentation:
        """Labels by thresholding the probability; instances only on dynamic points."""
        prob = np.clip(np.asarray(dynamic_prob, dtype=np.float32), 0.0, 1.0)
        label = (prob > threshold).astype(np.uint8)
        ids = np.zeros(len(prob), np.int32) if instance is None else np.asarray(instance, dtype=np.int32)
        return cls(prob, label, np.where(label == MotionLabel.DYNAMIC, ids, 0).astype(np.int32))

    @classmethod
    def static(cls, count: int) -> Segmentation:
        """Everything static."""
        return cls(np.zeros(count, np.float32), np.zeros(count, np.uint8), np.zeros(count, np.int32))


@dataclass(frozen=True)
class MotionMask:
    """A segmentation of one scan as it travels the fusion loop: per-point dynamic probability and instance, and
    the iteration it belongs to."""

    stamp_ns: int
    frame_id: str
    points: np.ndarray  # (N, 3) float32
    dynamic_prob: np.ndarray  # (N,) float32 in [0, 1]
    instance: np.ndarray = field(default=None)  # (N,) int32, 0 = static scene
    iteration: int = 0

    def __post_init__(self) -> None:
        if self.instance is None:
            object.__setattr__(self, "instance", np.zeros(len(self.points), np.int32))

    def __len__(self) -> int:
        return len(self.points)


@dataclass(frozen=True)
class SemanticFlow:
    """The fusion loop's converged answer for one scan: flow plus segmentation of every point."""

    stamp_ns: int
    frame_id: str
    points: np.ndarray  # (N, 3) float32
    flow: np.ndarray  # (N, 3) float32
    segmentation: Segmentation
    iterations: int = 1  # flow/segmentation rounds it took
    converged: bool = True  # False when it stopped on N_iter or a timeout
    ego: EgoMotion | None = None  # the flow estimator's ego motion of the flow it answers with (None: not known)
    time: np.ndarray | None = None  # (N,) float32 each point's time, s relative to the stamp (None: an instant sweep)

    def __len__(self) -> int:
        return len(self.points)

    @property
    def static_points(self) -> np.ndarray:
        """(S, 3) points labelled static."""
        return self.points[~self.segmentation.dynamic]


@dataclass(frozen=True)
class PriorSource:
    """What a scan's segmentation leaves for the next scan's temporal prior M^(0): its points near its moving objects,
    moved by their flow into the next scan's frame, with their dynamic probability."""

    stamp_ns: int  # the scan they came from
    frame_id: str
    points: np.ndarray  # (M, 3) float32, the next scan's sensor frame
    probability: np.ndarray  # (M,) float32 in [0, 1]
    radius: float = 1.0  # m: a point of the next scan takes the probability of the nearest of these within it

    def __len__(self) -> int:
        return len(self.points)


def _column(values, count: int, shape: tuple[int, ...], dtype) -> np.ndarray:
    array = np.asarray(values, dtype=dtype) if values is not None else np.zeros((count, *shape), dtype)
    return array.reshape((count, *shape))


OBSTACLE_COLUMNS = ("ids", "kinds", "centres", "sizes", "yaws", "velocities", "velocity_covariances", "yaw_rates",
                    "point_counts", "confidences")  # the per-obstacle columns of Obstacles


@dataclass(frozen=True)
class Obstacles:
    """Oriented boxes with constant-velocity motion, one row per obstacle (columnar arrays), in `frame_id`."""

    stamp_ns: int
    frame_id: str
    ids: np.ndarray  # (M,) int64 track / instance id, 0 when unknown
    kinds: np.ndarray  # (M,) uint8 ObstacleKind
    centres: np.ndarray  # (M, 3) box centre
    sizes: np.ndarray  # (M, 3) length (along yaw), width, height
    yaws: np.ndarray  # (M,) heading of the length axis
    velocities: np.ndarray  # (M, 3) m/s
    velocity_covariances: np.ndarray = field(default=None)  # (M, 3, 3) (m/s)^2
    yaw_rates: np.ndarray = field(default=None)  # (M,) rad/s
    point_counts: np.ndarray = field(default=None)  # (M,) LiDAR points supporting each (0 for ground truth)
    confidences: np.ndarray = field(default=None)  # (M,) in [0, 1]

    def __post_init__(self) -> None:
        count = len(np.asarray(self.ids).reshape(-1))
        set_ = object.__setattr__
        set_(self, "ids", _column(self.ids, count, (), np.int64))
        set_(self, "kinds", _column(self.kinds, count, (), np.uint8))
        set_(self, "centres", _column(self.centres, count, (3,), np.float64))
        set_(self, "sizes", _column(self.sizes, count, (3,), np.float64))
        set_(self, "yaws", _column(self.yaws, count, (), np.float64))
        set_(self, "velocities", _column(self.velocities, count, (3,), np.float64))
        set_(self, "velocity_covariances", _column(self.velocity_covariances, count, (3, 3), np.float64))
        set_(self, "yaw_rates", _column(self.yaw_rates, count, (), np.float64))
        set_(self, "point_counts", _column(self.point_counts, count, (), np.int64))
        confidences = np.ones(count) if self.confidences is None else self.confidences
        set_(self, "confidences", _column(confidences, count, (), np.float32))

    def __len__(self) -> int:
        return len(self.ids)

    @classmethod
    def empty(cls, stamp_ns: int = 0, frame_id: str = "") -> Obstacles:
        """No obstacles."""
        return cls(stamp_ns, frame_id, np.zeros(0, np.int64), None, None, None, None, None)

    def take(self, selection: np.ndarray) -> Obstacles:
        """The obstacles at an index or boolean selection."""
        return replace(self, **{name: getattr(self, name)[selection] for name in OBSTACLE_COLUMNS})

    def joined(self, other: Obstacles) -> Obstacles:
        """These obstacles and another set in the same frame, at this set's stamp."""
        if other.frame_id != self.frame_id:
            raise ValueError(f"cannot join obstacles in '{other.frame_id}' to obstacles in '{self.frame_id}'")
        return replace(self, **{name: np.concatenate([getattr(self, name), getattr(other, name)])
                                for name in OBSTACLE_COLUMNS})

    def transformed(self, transform: np.ndarray, frame_id: str) -> Obstacles:
        """The same obstacles expressed in another frame (transform: new frame <- this frame)."""
        rotation = np.asarray(transform, dtype=np.float64)[:3, :3]
        centres = self.centres @ rotation.T + transform[:3, 3]
        covariances = rotation @ self.velocity_covariances @ rotation.T
        return replace(self, frame_id=frame_id, centres=centres, yaws=self.yaws + yaw_of(transform),
                       velocities=self.velocities @ rotation.T, velocity_covariances=covariances)

    def corners(self) -> np.ndarray:
        """(M, 4, 2) footprint corners, counter-clockwise."""
        return np.array([box_corners(c, s[0], s[1], y) for c, s, y in zip(self.centres, self.sizes, self.yaws)]).reshape(-1, 4, 2)

    def predicted_corners(self, times: np.ndarray) -> np.ndarray:
        """(T, M, 4, 2) footprint corners moved with each obstacle's constant velocity at each time (s)."""
        shift = np.asarray(times, dtype=np.float64)[:, None, None, None] * self.velocities[None, :, None, :2]
        return self.corners()[None] + shift


@dataclass(frozen=True)
class OdometryEstimate:
    """Pose of base_link in the odometry frame with covariance, and its twist (in base_link)."""

    stamp_ns: int
    pose: np.ndarray  # (4, 4) odom <- base_link
    pose_covariance: np.ndarray  # (6, 6): x y z roll pitch yaw
    twist: np.ndarray = field(default_factory=lambda: np.zeros(6))  # vx vy vz wx wy wz in base_link
    twist_covariance: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))
    frame_id: str = "odom"
    child_frame_id: str = "base_link"

    @property
    def position(self) -> np.ndarray:
        """(3,) translation."""
        return self.pose[:3, 3]

    @property
    def yaw(self) -> float:
        """Heading (rad)."""
        return yaw_of(self.pose)


@dataclass(frozen=True)
class Plan:
    """A planned trajectory: states at times from the stamp, in `frame_id`, and the controls between them."""

    stamp_ns: int
    frame_id: str
    times: np.ndarray  # (H,) seconds from stamp_ns
    states: np.ndarray  # (H, 4) x, y, yaw, speed
    controls: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (H-1, 2) speed, yaw rate (or accel, steer)

    def __len__(self) -> int:
        return len(self.times)
