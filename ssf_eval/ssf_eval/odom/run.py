"""`ssf odom run`: odometry over anyone's scans (a folder of KITTI .bin, .pcd, .ply or .npy files, or a rosbag with a
PointCloud2 topic), with the project's own flow and segmentation, written as KITTI and TUM trajectories."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ssf_common.config import Section
from ssf_common.errors import DataError
from ssf_eval.pipeline import PerceptionConfig
from ssf_odom_node.core.odometry import OdomConfig, OdomInput, OdomMethod, OdomStep, Odometry

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"


class OdomRunConfig(Section):
    """What `ssf odom run` runs: the odometry and the perception that feeds it."""

    odom: OdomConfig = OdomConfig()
    perception: PerceptionConfig = PerceptionConfig()


@dataclass(frozen=True)
class ScanSource:
    """Scans in order: how many, where from, and an iterator of (stamp_ns, points (N, 3) float32)."""

    description: str
    count: int
    scans: Callable[[], Iterator[tuple[int, np.ndarray]]]


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

    with open_bag(path) as bag:
        clouds = {name: info for name, info in bag.topics.items() if info.type_name == POINTCLOUD2}
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

    return ScanSource(f"{clouds[topic].message_count} scans on {topic} of {path}", clouds[topic].message_count, scans)


class Perceiver:
    """The flow and dynamic probability each method needs for a scan pair (none for points)."""

    def __init__(self, method: OdomMethod, config: PerceptionConfig, device: str = "cpu") -> None:
        self.method = OdomMethod(method)
        self.estimator = self.perception = None
        if self.method is OdomMethod.FLOW:
            from ssf_flow_node.core.estimator import make_estimator

            self.estimator = make_estimator(config=config.flow, device=device)
        elif self.method is OdomMethod.SSF:
            from ssf_eval.pipeline import SsfPerception

            self.perception = SsfPerception(config, device)

    def __call__(self, stamp_ns: int, pc1: np.ndarray, pc2: np.ndarray | None) -> OdomInput:
        """Scan t with its flow towards scan t+1 (and segmentation for ssf); the last scan has neither."""
        if pc2 is None or self.method is OdomMethod.POINTS:
            return OdomInput(stamp_ns, pc1)
        if self.estimator is not None:
            return OdomInput(stamp_ns, pc1, self.estimator.estimate(pc1, pc2).flow)
        fusion = self.perception.perceive(pc1, pc2, follows=True).fusion  # consecutive scans: the last mask carried
        return OdomInput(stamp_ns, pc1, fusion.flow, fusion.segmentation.dynamic_prob)


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


def write_outputs(out: Path, steps: list[OdomStep], config: OdomRunConfig, source: ScanSource) -> list[Path]:
    """poses_kitti.txt, poses_tum.txt, config.yaml and trajectory.png under `out`."""
    from ssf_common.config import dump
    from ssf_common.dataset.kitti import write_poses, write_tum

    poses = np.stack([step.pose for step in steps])
    stamps = np.array([step.stamp_ns for step in steps], dtype=np.float64) * 1e-9
    write_poses(out / "poses_kitti.txt", poses)
    write_tum(out / "poses_tum.txt", stamps, poses)
    try:
        (out / "config.yaml").write_text(f"# ssf odom run on {source.description}\n" + dump(config))
    except OSError as err:
        raise DataError(f"{out}: cannot write config.yaml ({err.strerror})") from None
    plot_path(poses, f"{config.odom.method.value} odometry: {source.description}", out / "trajectory.png")
    return [out / name for name in ("poses_kitti.txt", "poses_tum.txt", "config.yaml", "trajectory.png")]


def plot_path(poses: np.ndarray, title: str, path: Path) -> Path:
    """A bird's-eye picture of the trajectory (first scan's frame)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axis = plt.subplots(figsize=(6, 5))
    axis.plot(poses[:, 0, 3], poses[:, 1, 3], "-", color="tab:green", lw=1.5)
    axis.plot(poses[:1, 0, 3], poses[:1, 1, 3], "o", color="black", label="first scan")
    axis.set_aspect("equal", adjustable="datalim")
    axis.set_xlabel("x (m)")
    axis.set_ylabel("y (m)")
    axis.set_title(title, fontsize=8)
    axis.legend(fontsize=7)
    try:
        figure.savefig(path, dpi=110, bbox_inches="tight")
    except OSError as err:
        raise DataError(f"{path}: cannot write the picture ({err.strerror})") from None
    finally:
        plt.close(figure)
    return path
