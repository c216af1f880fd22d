"""`ssf odom run`: odometry over anyone's scans (a folder of KITTI .bin, .pcd, .ply or .npy files, or a rosbag with a
PointCloud2 topic), with the project's own flow and segmentation, written as KITTI and TUM trajectories."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ssf_common.config import Section
from ssf_common.errors import DataError
from ssf_common.render.figures import save_figure
from ssf_eval.pipeline import PerceptionConfig
from ssf_odom_node.core.odometry import OdomConfig, OdomInput, OdomMethod, OdomStep, Odometry

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"


class OdomRunConfig(Section):
    """What `ssf odom run` runs: the odometry and the perception that feeds it."""

    odom: OdomConfig = OdomConfig()
    perception: PerceptionConfig = PerceptionConfig()


@dataclass(frozen=True)
class ScanSource:
    """Scans in order: how many, where from, an iterator of (stamp_ns, points (N, 3) float32), and the true sensor
    poses at given stamps when the source knows them (a simulator's recording)."""

    description: str
    count: int
    scans: Callable[[], Iterator[tuple[int, np.ndarray]]]
    truth: Callable[[np.ndarray], np.ndarray | None] | None = None


class OdomOutputs(NamedTuple):
    """What `write_outputs` wrote, and how far the last pose lies from the truth (None without one)."""

    paths: list[Path]
    end_error_m: float | None


def open_source(path: Path, topic: str | None = None, period_s: float = 0.1) -> ScanSource:
    """A folder of scan files (name order, stamps one period apart) or a rosbag (header stamps)."""
    if path.is_dir() and not (path / "metadata.yaml").is_file() and not any(path.glob("*.mcap")) and not any(path.glob("*.db3")):
        return folder_source(path, period_s)
    if path.exists():
        return bag_source(path, topic)
    raise DataError(f"{path}: no such folder of scans or bag")


def folder_source(folder: Path, period_s: float) -> ScanSource:
    """Every scan file of a folder (or of its velodyne/ subfolder, as in a KITTI sequence), in name order."""
    from ssf_common import scans as scan_files

    if (folder / "velodyne").is_dir():
        folder = folder / "velodyne"
    files = sorted(path for path in folder.iterdir() if path.suffix.lower() in scan_files.SUFFIXES)
    if len(files) < 2:
        raise DataError(f"{folder}: needs at least two scan files ({', '.join(scan_files.SUFFIXES)}), found {len(files)}")

    def scans() -> Iterator[tuple[int, np.ndarray]]:
        for index, file in enumerate(files):
            yield int(round(index * period_s * 1e9)), scan_files.read_scan(file)[:, :3]

    return ScanSource(f"{len(files)} scans in {folder}", len(files), scans)


def bag_source(path: Path, topic: str | None) -> ScanSource:
    """The PointCloud2 messages of one topic of a bag (default: its only PointCloud2 topic)."""
    from ssf_common import messages
    from ssf_common.bags import open_bag
    from ssf_common.pointcloud import decode_cloud

    from ssf_common import topics

    with open_bag(path) as bag:
        clouds = {name: info for name, info in bag.topics.items() if info.type_name == POINTCLOUD2}
        has_truth = topics.GT_ODOM in bag.topics
    if topic is None:
        if len(clouds) != 1:
            raise DataError(f"{path}: {len(clouds)} PointCloud2 topics ({', '.join(sorted(clouds)) or 'none'}); "
                            "name one with --topic")
        topic = next(iter(clouds))
    if topic not in clouds:
        raise DataError(f"{path}: no PointCloud2 topic {topic} (PointCloud2 topics: {', '.join(sorted(clouds)) or 'none'})")

    def scans() -> Iterator[tuple[int, np.ndarray]]:
        with open_bag(path) as bag:
            for message in bag.messages([topic]):
                msg = bag.decode(message)
                yield messages.stamp_ns(msg.header.stamp), np.ascontiguousarray(decode_cloud(msg).xyz, dtype=np.float32)

    return ScanSource(f"{clouds[topic].message_count} scans on {topic} of {path}", clouds[topic].message_count, scans,
                      truth=(lambda stamps: bag_truth(path, topic, stamps)) if has_truth else None)


def bag_truth(path: Path, topic: str, stamps: np.ndarray) -> np.ndarray | None:
    """(K, 4, 4) the true poses of the scans' sensor at their stamps, relative to the first (the odometry's frame):
    the simulator's base_link poses on /sim/ground_truth/odom and the sensor's mount on /tf; None when a stamp has no
    true pose."""
    from ssf_common import messages, pose_msgs, topics
    from ssf_common.bags import open_bag
    from ssf_common.geometry.se3 import invert
    from ssf_common.render.frames import StampedPoses

    base, mounts, frame = [], {}, None
    with open_bag(path) as bag:
        for message in bag.messages([name for name in (topics.GT_ODOM, topics.TF, topic) if name in bag.topics]):
            if message.topic == topic:
                frame = frame or bag.decode(message).header.frame_id
                continue
            msg = bag.decode(message)
            if message.topic == topics.GT_ODOM:
                base.append((messages.stamp_ns(msg.header.stamp), pose_msgs.matrix_from_pose(msg.pose.pose)))
            else:
                for item in msg.transforms:
                    if item.header.frame_id == "base_link":
                        mounts[item.child_frame_id] = pose_msgs.matrix_from_transform(item.transform)
    poses = StampedPoses.of(base)
    mount = mounts.get(frame or "", np.eye(4))
    found = [poses.at(int(stamp)) for stamp in stamps]
    if not found or any(pose is None for pose in found):
        return None
    sensor = np.array([pose @ mount for pose in found])
    return invert(sensor[0]) @ sensor


class Perceiver:
    """The flow and dynamic probability each method needs for a scan pair (none for points)."""

    def __init__(self, method: OdomMethod, config: PerceptionConfig, device: str = "cpu") -> None:
        self.method = OdomMethod(method)
        self.estimator = self.perception = None
        if self.method is OdomMethod.FLOW:
            from ssf_flow_node.core.estimator import make_estimator

            self.estimator = make_estimator(config=config.flow, device=device)
        elif self.method is OdomMethod.SSF:
            from ssf_eval.pipeline import PerceptionChain

            self.perception = PerceptionChain(config, device)

    def __call__(self, stamp_ns: int, pc1: np.ndarray, pc2: np.ndarray | None) -> OdomInput:
        """Scan t with its flow towards scan t+1 (and segmentation for ssf); the last scan has neither."""
        if pc2 is None or self.method is OdomMethod.POINTS:
            return OdomInput(stamp_ns, pc1)
        if self.estimator is not None:
            return OdomInput(stamp_ns, pc1, self.estimator.estimate(pc1, pc2).flow)
        fusion = self.perception.perceive(pc1, pc2, follows=True).fusion  # consecutive scans: the last mask carried
        return OdomInput(stamp_ns, pc1, fusion.flow, fusion.segmentation.dynamic_prob, ego=fusion.ego)


def run_odometry(source: ScanSource, odometry: Odometry, perceive: Perceiver,
                 progress: Callable[[int, float], None] | None = None) -> list[OdomStep]:
    """Every scan through perception (with the next scan) and the odometry, in order."""
    steps: list[OdomStep] = []
    previous: tuple[int, np.ndarray] | None = None
    started = time.perf_counter()
    for stamp_ns, points in source.scans():
        if previous is not None:
            steps.append(odometry.step(perceive(previous[0], previous[1], points)))
            if progress is not None:
                progress(len(steps), time.perf_counter() - started)
        previous = (stamp_ns, points)
    if previous is not None:
        steps.append(odometry.step(perceive(previous[0], previous[1], None)))
    return steps


def write_outputs(out: Path, steps: list[OdomStep], config: OdomRunConfig, source: ScanSource) -> OdomOutputs:
    """poses_kitti.txt, poses_tum.txt, config.yaml and trajectory.png under `out` (and truth_tum.txt, the true sensor
    poses in the same frame, when the source has them)."""
    from ssf_common.config import dump
    from ssf_common.dataset.kitti import write_poses, write_tum

    poses = np.stack([step.pose for step in steps])
    stamps = np.array([step.stamp_ns for step in steps], dtype=np.int64)
    write_poses(out / "poses_kitti.txt", poses)
    write_tum(out / "poses_tum.txt", stamps * 1e-9, poses)
    try:
        (out / "config.yaml").write_text(f"# ssf odom run on {source.description}\n" + dump(config))
    except OSError as err:
        raise DataError(f"{out}: cannot write config.yaml ({err.strerror})") from None
    truth = source.truth(stamps) if source.truth is not None else None
    written = [out / name for name in ("poses_kitti.txt", "poses_tum.txt", "config.yaml", "trajectory.png")]
    if truth is not None:
        write_tum(out / "truth_tum.txt", stamps * 1e-9, truth)
        written.append(out / "truth_tum.txt")
    plot_path(poses, f"{config.odom.method.value} odometry: {source.description}", out / "trajectory.png", truth)
    end_error = None if truth is None else float(np.linalg.norm(poses[-1, :3, 3] - truth[-1, :3, 3]))
    return OdomOutputs(written, end_error)


def plot_path(poses: np.ndarray, title: str, path: Path, truth: np.ndarray | None = None) -> Path:
    """A bird's-eye picture of the trajectory (first scan's frame): start, end, a scale bar, and the truth beside it
    when there is one."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ssf_common.render.draw import add_scale_bar

    xy = poses[:, :2, 3]
    distance = float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum())
    figure, axis = plt.subplots(figsize=(7, 6))
    if truth is not None:
        axis.plot(truth[:, 0, 3], truth[:, 1, 3], "-", color="0.6", lw=5, alpha=0.6, label="truth (the simulator)")
        axis.plot(truth[-1, 0, 3], truth[-1, 1, 3], "x", color="black", ms=9, mew=2, label="true end")
    axis.plot(xy[:, 0], xy[:, 1], "-", color="tab:green", lw=1.8, label="odometry")
    axis.plot(xy[0, 0], xy[0, 1], "o", color="white", mec="black", ms=9, label="start (first scan)")
    axis.plot(xy[-1, 0], xy[-1, 1], "*", color="gold", mec="black", ms=15, label="end")
    axis.set_aspect("equal", adjustable="datalim")
    axis.margins(0.15)
    axis.grid(alpha=0.3)
    axis.set_xlabel("x (m), along the first scan's forward axis")
    axis.set_ylabel("y (m)")
    figure.canvas.draw()  # the limits the aspect settles on, for the scale bar
    add_scale_bar(axis, float(np.ptp(axis.get_xlim())), colour="black")
    off = "" if truth is None else f", ends {np.linalg.norm(xy[-1] - truth[-1, :2, 3]):.2f} m from the true end"
    axis.set_title(f"{title}\n{len(poses)} poses, {distance:.1f} m{off}", fontsize=8)
    axis.legend(fontsize=7, loc="best")
    return save_figure(figure, path, dpi=110, bbox_inches="tight")
