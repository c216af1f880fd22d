"""What a bird's-eye frame shows (`ViewFrame`, in the world frame), and the frames of a recorded episode.

A recording is read in two passes. The first keeps the small topics whole: the true poses
(/sim/ground_truth/odom), the sensor mount (/tf), the true agents, the perceived obstacles, the plans, the
odometry, the fusion loop's states, and the stamps of the clouds. The second streams the clouds and yields one
frame per scan: the points of the newest segmented scan (/ssf/semantic_flow) no older than `max_age_s`, or the raw
scan when there is none, placed in the world by the true pose at their stamp."""

from __future__ import annotations

import bisect
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from pydantic import Field

from ssf_common import topics
from ssf_common.config import Section
from ssf_common.errors import BagError, MessageError
from ssf_common.geometry.se3 import invert
from ssf_common.records import Obstacles, Plan

WORLD_FRAME = "world"
BASE_FRAME = "base_link"
NS = 1_000_000_000


class RenderConfig(Section):
    """How episodes are drawn."""

    view_radius_m: float = Field(40.0, gt=1.0, description="half the width of the bird's-eye window around the ego")
    max_points: int = Field(40_000, ge=100, description="points drawn per frame at most (a random subset)")
    max_age_s: float = Field(1.0, gt=0.0, description="oldest segmentation shown for a scan; older: the raw scan")
    fps: float = Field(10.0, gt=0.0, le=60.0, description="frames per second of the animation")
    stride: int = Field(1, ge=1, description="draw every stride-th scan")
    start_s: float = Field(0.0, ge=0.0, description="first scan drawn, seconds into the recording")
    duration_s: float = Field(0.0, ge=0.0, description="seconds of scans drawn; 0: to the end")
    size_px: int = Field(720, ge=160, le=2160, description="frame height in pixels (even)")
    ego_length: float = Field(4.6, gt=0.0)
    ego_width: float = Field(1.9, gt=0.0)
    seed: int = Field(0, ge=0, description="random subset of points")
    moving_speed: float = Field(0.5, ge=0.0, description="true agents and perceived obstacles at least this fast (m/s) "
                                "are moving; slower ones stand still")
    count_radius_m: float = Field(40.0, gt=0.0, description="agents and obstacles farther from the ego are not counted")
    seen_points: int = Field(10, ge=1, description="a true moving agent counts as seen with this many scan points on it")
    match_margin_m: float = Field(2.0, ge=0.0, description="a perceived obstacle whose centre lies this close to a true "
                                  "agent's box is on that agent")


@dataclass(frozen=True)
class ViewFrame:
    """One moment of an episode, everything in the world frame."""

    stamp_ns: int
    ego_pose: np.ndarray  # (4, 4) world <- base_link
    points: np.ndarray  # (N, 3) float32
    labels: np.ndarray | None = None  # (N,) MotionLabel per point; None for an unsegmented scan
    instances: np.ndarray | None = None  # (N,) int32 object instance (0: static scene)
    agents: Obstacles | None = None  # the true agents
    perceived: Obstacles | None = None  # the obstacles the perception saw
    plan: np.ndarray | None = None  # (H, 2) planned positions
    path: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (K, 2) the ego's true path so far
    odometry_path: np.ndarray | None = None  # (K, 2) the odometry's estimate of it
    judged: Any = None  # counts.Judgement of the perceived obstacles against the true agents, when known


@dataclass(frozen=True)
class StampedPoses:
    """4x4 poses at sorted stamps."""

    stamps: np.ndarray  # (K,) int64
    matrices: np.ndarray  # (K, 4, 4)

    @classmethod
    def of(cls, items: Iterable[tuple[int, np.ndarray]]) -> StampedPoses:
        """From (stamp, pose) pairs in any order (the last pose of a repeated stamp wins)."""
        by_stamp = dict(items)
        stamps = np.array(sorted(by_stamp), dtype=np.int64)
        matrices = np.array([by_stamp[s] for s in stamps]).reshape(-1, 4, 4)
        return cls(stamps, matrices)

    def __len__(self) -> int:
        return len(self.stamps)

    def at(self, stamp_ns: int, tolerance_ns: int = NS // 20) -> np.ndarray | None:
        """The pose nearest to `stamp_ns`, when one lies within the tolerance."""
        if not len(self):
            return None
        i = int(np.clip(np.searchsorted(self.stamps, stamp_ns), 1, len(self) - 1)) if len(self) > 1 else 0
        nearest = min((i - 1, i), key=lambda j: abs(int(self.stamps[j]) - stamp_ns)) if len(self) > 1 else 0
        return self.matrices[nearest] if abs(int(self.stamps[nearest]) - stamp_ns) <= tolerance_ns else None

    def xy_until(self, stamp_ns: int) -> np.ndarray:
        """(k, 2) positions up to and including `stamp_ns`."""
        return self.matrices[: int(np.searchsorted(self.stamps, stamp_ns, side="right")), :2, 3]


@dataclass(frozen=True)
class FusionLog:
    """The fusion loop's state per iteration (/ssf/fusion_state)."""

    stamps: np.ndarray  # (M,) int64 scan stamps
    iterations: np.ndarray  # (M,) int
    delta_total: np.ndarray  # (M,)
    converged: np.ndarray  # (M,) bool
    delta_mask: np.ndarray | None = None  # (M,) mean change of the mask: the segmentation against the mask it started from


@dataclass
class EpisodeTrack:
    """The small topics of a recording, whole, and the stamps of its clouds."""

    truth: StampedPoses  # world <- base_link
    mounts: dict[str, np.ndarray]  # base_link <- sensor frame
    agents: dict[int, Obstacles]
    perceived: dict[int, Obstacles]
    plans: list[Plan]
    odometry: StampedPoses  # odometry frame <- base_link
    odometry_frame: str
    fusion: FusionLog
    scan_stamps: np.ndarray
    segmented_stamps: np.ndarray
    outcome: str = ""
    outcome_time_s: float = 0.0  # the simulated time of the last episode result
    scenario: str = ""  # of the last episode result
    seed: int = 0
    agent_count: int = 0

    def world_from(self, frame_id: str, stamp_ns: int) -> np.ndarray | None:
        """world <- frame_id at a stamp, from the true pose (None when it cannot be placed)."""
        if frame_id in (WORLD_FRAME, ""):
            return np.eye(4)
        if frame_id == self.odometry_frame or (not len(self.odometry) and frame_id == "odom"):
            return self.world_from_odometry()
        pose = self.truth.at(stamp_ns)
        if pose is None:
            return None
        if frame_id == BASE_FRAME:
            return pose
        mount = self.mounts.get(frame_id)
        return None if mount is None else pose @ mount

    def world_from_odometry(self) -> np.ndarray | None:
        """world <- odometry frame: the odometry's first pose laid on the true pose at its stamp (without odometry,
        the odometry frame is the first true pose, as a planner anchored on it has it)."""
        if len(self.odometry):
            pose = self.truth.at(int(self.odometry.stamps[0]))
            return None if pose is None else pose @ invert(self.odometry.matrices[0])
        return self.truth.matrices[0] if len(self.truth) else None

    def plan_at(self, stamp_ns: int, max_age_ns: int) -> Plan | None:
        """The newest plan stamped at or before `stamp_ns`, when it is not too old."""
        stamps = [plan.stamp_ns for plan in self.plans]
        i = bisect.bisect_right(stamps, stamp_ns) - 1
        return self.plans[i] if i >= 0 and stamp_ns - stamps[i] <= max_age_ns else None

    def in_world(self, obstacles: Obstacles | None) -> Obstacles | None:
        """Obstacles moved into the world frame (None when they cannot be placed)."""
        if obstacles is None:
            return None
        transform = self.world_from(obstacles.frame_id, obstacles.stamp_ns)
        return None if transform is None else obstacles.transformed(transform, WORLD_FRAME)


SMALL_TOPICS = (topics.GT_ODOM, topics.TF, topics.GT_OBSTACLES, topics.OBSTACLES, topics.PLAN, topics.ODOM,
                topics.FUSION_STATE, topics.EPISODE)
CLOUD_TOPICS = (topics.LIDAR_POINTS, topics.SEMANTIC_FLOW)


def header_stamp(cdr: bytes) -> int:
    """The header stamp of a CDR message that starts with std_msgs/Header (read without decoding the rest)."""
    if len(cdr) < 12 or cdr[1] != 1:  # encapsulation: CDR little-endian
        raise MessageError(f"not a little-endian CDR message with a header ({len(cdr)} bytes)")
    sec, nanosec = struct.unpack_from("<iI", cdr, 4)
    return sec * NS + nanosec


def read_track(bag: Any) -> EpisodeTrack:
    """The first pass over an open bag (`ssf_common.bags.open_bag`)."""
    from ssf_common import messages, pose_msgs
    from ssf_common.conversions import obstacles_from_msg, odometry_from_msg, plan_from_msg

    present = [name for name in (*SMALL_TOPICS, *CLOUD_TOPICS) if name in bag.topics]
    if topics.GT_ODOM not in present:
        raise BagError(f"{bag.path}: no {topics.GT_ODOM} (the true poses place everything in the world)")
    truth, odometry, mounts, agents, perceived, plans = [], [], {}, {}, {}, []
    fusion: list[tuple[int, int, float, bool]] = []
    clouds: dict[str, list[int]] = {name: [] for name in CLOUD_TOPICS}
    odometry_frame, episode = "odom", None
    for message in bag.messages(present):
        if message.topic in CLOUD_TOPICS:
            clouds[message.topic].append(header_stamp(message.data))
            continue
        msg = bag.decode(message)
        if message.topic == topics.GT_ODOM:
            truth.append((messages.stamp_ns(msg.header.stamp), pose_msgs.matrix_from_pose(msg.pose.pose)))
        elif message.topic == topics.TF:
            for item in msg.transforms:
                if item.header.frame_id == BASE_FRAME:
                    mounts[item.child_frame_id] = pose_msgs.matrix_from_transform(item.transform)
        elif message.topic == topics.GT_OBSTACLES:
            agents[messages.stamp_ns(msg.header.stamp)] = obstacles_from_msg(msg)
        elif message.topic == topics.OBSTACLES:
            perceived[messages.stamp_ns(msg.header.stamp)] = obstacles_from_msg(msg)
        elif message.topic == topics.PLAN and msg.poses:
            plans.append(plan_from_msg(msg))
        elif message.topic == topics.ODOM:
            estimate = odometry_from_msg(msg)
            odometry.append((estimate.stamp_ns, estimate.pose))
            odometry_frame = estimate.frame_id
        elif message.topic == topics.FUSION_STATE:
            fusion.append((messages.stamp_ns(msg.header.stamp), msg.iteration, msg.delta_total, msg.converged,
                           msg.delta_mask))
        elif message.topic == topics.EPISODE:
            episode = msg
    rows = np.array(fusion, dtype=np.float64).reshape(-1, 5)
    return EpisodeTrack(
        truth=StampedPoses.of(truth), mounts=mounts, agents=agents, perceived=perceived,
        plans=sorted(plans, key=lambda plan: plan.stamp_ns), odometry=StampedPoses.of(odometry),
        odometry_frame=odometry_frame,
        fusion=FusionLog(rows[:, 0].astype(np.int64), rows[:, 1].astype(int), rows[:, 2], rows[:, 3].astype(bool),
                         rows[:, 4]),
        scan_stamps=np.unique(clouds[topics.LIDAR_POINTS]).astype(np.int64),
        segmented_stamps=np.unique(clouds[topics.SEMANTIC_FLOW]).astype(np.int64),
        **({} if episode is None else {"outcome": _outcome_name(episode.outcome), "outcome_time_s": float(episode.time),
                                       "scenario": episode.scenario, "seed": int(episode.seed),
                                       "agent_count": int(episode.num_agents)}),
    )


def _outcome_name(code: int) -> str:
    """ssf_interfaces/EpisodeResult OUTCOME_* as a word."""
    from ssf_common import messages

    result = messages.msg_type("ssf_interfaces/msg/EpisodeResult")
    names = {getattr(result, name): name.removeprefix("OUTCOME_").lower()
             for name in dir(result) if name.startswith("OUTCOME_")}
    return names.get(int(code), str(code))


class FrameInput(NamedTuple):
    """Which cloud a frame draws: the scan time it shows, and the topic and stamp of its points."""

    stamp_ns: int
    topic: str
    cloud_stamp_ns: int


def schedule(track: EpisodeTrack, config: RenderConfig) -> list[FrameInput]:
    """One frame per scan (every stride-th, within the time window): its newest segmentation, else the raw scan."""
    scans = track.scan_stamps if len(track.scan_stamps) else track.segmented_stamps
    if not len(scans):
        return []
    start = int(scans[0] + config.start_s * NS)
    end = start + int(config.duration_s * NS) if config.duration_s else int(scans[-1])
    chosen = scans[(scans >= start) & (scans <= end)][:: config.stride]
    frames = []
    for stamp in chosen:
        newest = _newest(track.segmented_stamps, int(stamp), int(config.max_age_s * NS))
        frames.append(FrameInput(int(stamp), topics.SEMANTIC_FLOW, newest) if newest is not None
                      else FrameInput(int(stamp), topics.LIDAR_POINTS, int(stamp)))
    return frames


def recording_frames(bag: Any, track: EpisodeTrack, config: RenderConfig, frames: list[FrameInput] | None = None,
                     judged: dict[int, Any] | None = None) -> Iterator[ViewFrame]:
    """The second pass: stream the clouds, yield the scheduled frames in order (each cloud decoded once), each with
    the judgement of its perceived obstacles when `judged` (by scan stamp, see `counts.judge_recording`) has one."""
    frames = schedule(track, config) if frames is None else frames
    uses: dict[tuple[str, int], int] = {}
    for item in frames:
        key = (item.topic, item.cloud_stamp_ns)
        uses[key] = uses.get(key, 0) + 1
    present = [name for name in CLOUD_TOPICS if name in bag.topics and any(key[0] == name for key in uses)]
    ready: dict[tuple[str, int], tuple[np.ndarray, np.ndarray | None, np.ndarray | None] | None] = {}
    rng = np.random.default_rng(config.seed)
    position = 0
    for message in bag.messages(present):
        key = (message.topic, header_stamp(message.data))
        if key not in uses or key in ready:
            continue
        ready[key] = _cloud_in_world(bag, message, track, config, rng)
        while position < len(frames) and (frames[position].topic, frames[position].cloud_stamp_ns) in ready:
            item = frames[position]
            position += 1
            frame = _frame(item, ready, uses, track, config, judged or {})
            if frame is not None:
                yield frame
    for item in frames[position:]:  # inputs that never decoded: skipped
        if (item.topic, item.cloud_stamp_ns) in ready and (frame := _frame(item, ready, uses, track, config,
                                                                            judged or {})):
            yield frame


def _frame(item: FrameInput, ready: dict, uses: dict, track: EpisodeTrack, config: RenderConfig,
           judged: dict[int, Any]) -> ViewFrame | None:
    """The frame of one scheduled scan: the ego at the scan's time; the points, the true agents and the perceived
    obstacles at the time of the cloud drawn (the newest segmentation)."""
    key = (item.topic, item.cloud_stamp_ns)
    cloud = ready[key]
    uses[key] -= 1
    if not uses[key]:
        ready[key] = None  # decoded once, not needed again
    ego = track.truth.at(item.stamp_ns)
    if cloud is None or ego is None:
        return None
    points, labels, instances = cloud
    max_age = int(config.max_age_s * NS)
    perceived_stamp = _newest(np.array(sorted(track.perceived), dtype=np.int64), item.cloud_stamp_ns, max_age)
    plan = track.plan_at(item.stamp_ns, max_age)
    plan_world = track.world_from(plan.frame_id, plan.stamp_ns) if plan is not None else None
    to_world = track.world_from_odometry()
    odometry = track.odometry.matrices[: int(np.searchsorted(track.odometry.stamps, item.stamp_ns, side="right"))]
    return ViewFrame(
        stamp_ns=item.stamp_ns, ego_pose=ego, points=points, labels=labels, instances=instances,
        agents=track.in_world(_at_or_before(track.agents, item.cloud_stamp_ns, max_age)),
        perceived=track.in_world(track.perceived.get(perceived_stamp)) if perceived_stamp is not None else None,
        plan=None if plan_world is None else (plan.states[:, :2] @ plan_world[:2, :2].T + plan_world[:2, 3]),
        path=track.truth.xy_until(item.stamp_ns),
        odometry_path=None if to_world is None or not len(odometry) else (to_world @ odometry)[:, :2, 3],
        judged=judged.get(perceived_stamp) if perceived_stamp is not None else None,
    )


def _cloud_in_world(bag: Any, message: Any, track: EpisodeTrack, config: RenderConfig,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None] | None:
    """A cloud's points in the world (near the sensor, at most max_points), with labels when it is segmented."""
    from ssf_common.conversions import semantic_flow_from_cloud
    from ssf_common.pointcloud import decode_cloud

    try:
        msg = bag.decode(message)
        if message.topic == topics.SEMANTIC_FLOW:
            result = semantic_flow_from_cloud(msg)
            xyz, labels, instances = result.points, result.segmentation.label, result.segmentation.instance
        else:
            xyz, labels, instances = decode_cloud(msg).xyz, None, None
    except (BagError, MessageError):
        return None
    transform = track.world_from(msg.header.frame_id, header_stamp(message.data))
    if transform is None:
        return None
    near = np.flatnonzero(np.einsum("ij,ij->i", xyz[:, :2], xyz[:, :2]) <= (1.5 * config.view_radius_m) ** 2)
    if len(near) > config.max_points:
        near = np.sort(rng.choice(near, config.max_points, replace=False))
    world = (xyz[near].astype(np.float64) @ transform[:3, :3].T + transform[:3, 3]).astype(np.float32)
    pick = (lambda values: None if values is None else np.asarray(values)[near])
    return world, pick(labels), pick(instances)


def _newest(stamps: np.ndarray, stamp_ns: int, max_age_ns: int) -> int | None:
    """The newest of sorted stamps at or before `stamp_ns`, within max_age_ns."""
    i = int(np.searchsorted(stamps, stamp_ns, side="right")) - 1
    return int(stamps[i]) if i >= 0 and stamp_ns - int(stamps[i]) <= max_age_ns else None


def _at_or_before(by_stamp: dict[int, Obstacles], stamp_ns: int, max_age_ns: int) -> Obstacles | None:
    newest = _newest(np.array(sorted(by_stamp), dtype=np.int64), stamp_ns, max_age_ns)
    return None if newest is None else by_stamp[newest]


def open_track(path: str | Path) -> tuple[Any, EpisodeTrack]:
    """Open a recording and read its first pass (the caller closes the bag)."""
    from ssf_common.bags.reader import open_bag

    bag = open_bag(path)
    try:
        return bag, read_track(bag)
    except BaseException:
        bag.close()
        raise
