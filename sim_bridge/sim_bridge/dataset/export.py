"""Frame pairs with exact scene-flow ground truth from the simulator, written as .npz plus a KITTI sequence."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from pydantic import Field

from sim_bridge.ros_messages import agent_obstacles
from sim_bridge.scenario import Scenario, load_scenario
from sim_bridge.simulator import Frame, Simulator
from ssf_common.config import Section, build, dump
from ssf_common.dataset.kitti import SequenceWriter
from ssf_common.dataset.pairs import PointClass, ScanPair, boxes_from_obstacles, make_pair, write_pair
from ssf_common.errors import ConfigError, DataError
from ssf_common.geometry.sampling import Sampling, sample_indices
from ssf_common.geometry.se3 import invert
from ssf_common.geometry.sweep import timed

class PairProtocol(Section):
    """How a pair is cut from two full scans: range crop, ground removal, then N points per scan."""

    points: int | None = Field(8192, ge=1, description="points per scan; null keeps every point (no sampling)")
    sampling: Sampling = Field(Sampling.RANDOM, description="random | voxel | fps")
    max_range: float | None = Field(35.0, gt=0.0, description="points farther from the sensor are dropped (m); null keeps all")
    remove_ground: bool = Field(True, description="drop points on the ground (ground-truth class) before sampling")


PROTOCOLS = {
    # the scene-flow benchmarks' KITTI protocol (FlowNet3D onwards): ground removed, 35 m, 8192 points
    "paper": PairProtocol(),
    # whole scans, ground and all, sampled to N points
    "raw": PairProtocol(max_range=None, remove_ground=False),
    # every point of every scan, as the nodes see them
    "whole": PairProtocol(points=None, max_range=None, remove_ground=False),
}

DEFAULT_WARMUP_S = 2.0  # the traffic starts from rest: before this, few agents move (a scenario's episode.warmup_s)


def pair_protocol(name: str = "paper", **overrides) -> PairProtocol:
    """A named protocol with some fields replaced (None values are ignored)."""
    if name not in PROTOCOLS:
        raise ConfigError(f"unknown pair protocol '{name}'; choose one of {', '.join(PROTOCOLS)}")
    changes = {key: value for key, value in overrides.items() if value is not None}
    return build(PairProtocol, {**PROTOCOLS[name].model_dump(), **changes})


def warmup_frames(scenario: Scenario, warmup_s: float | None) -> int:
    """Frames simulated before the first pair, so that the traffic is moving (None: the scenario's warm-up)."""
    warmup_s = scenario.episode.warmup_s if warmup_s is None else warmup_s
    if not np.isfinite(warmup_s) or warmup_s < 0:
        raise ConfigError(f"warm-up must be a finite number of seconds >= 0, got {warmup_s}")
    return int(round(warmup_s / scenario.episode.dt))


def simulate(scenario: Scenario, seed: int | None, frames: int, skip: int = 0) -> Iterator[Frame]:
    """frames + 1 consecutive frames of the scenario driven by the built-in route follower, after `skip` frames
    that are simulated but not yielded."""
    sim = Simulator(scenario, seed)
    frame = sim.reset()
    driver = sim.follower()
    for index in range(skip + frames + 1):
        if index >= skip:
            yield frame
        if index < skip + frames:
            frame = sim.step(driver.command(frame.base_pose, frame.ego.speed, frame.agents, frame.status.outcome))


def kept_points(frame: Frame, protocol: PairProtocol) -> np.ndarray:
    """Indices of the scan points the protocol keeps before sampling."""
    keep = np.ones(len(frame.scan.points), dtype=bool)
    if protocol.max_range is not None:
        keep &= np.linalg.norm(frame.scan.points[:, :2], axis=1) <= protocol.max_range
    if protocol.remove_ground:
        keep &= frame.scan.label != PointClass.GROUND
    return np.flatnonzero(keep)


def cut_points(frame: Frame, protocol: PairProtocol, rng: np.random.Generator) -> np.ndarray:
    """Indices of the protocol's N points of a frame's scan (repeated when the scan has fewer)."""
    kept = kept_points(frame, protocol)
    if kept.size == 0:
        raise DataError(f"frame {frame.index}: no point left after the protocol's range and ground cut")
    if protocol.points is None:
        return kept
    return kept[sample_indices(frame.scan.points[kept], protocol.points, rng, protocol.sampling, pad=True)]


def visible_boxes(frame: Frame) -> np.ndarray:
    """boxes1 rows of the agents the frame's scan hits, in its sensor frame."""
    seen = np.isin(frame.agents.ids, np.unique(frame.scan.instance[frame.scan.instance > 0]))
    world = agent_obstacles(frame.agents.take(seen), frame.stamp_ns)
    return boxes_from_obstacles(world.transformed(invert(frame.pose), "sensor"))


def _pairs_of(frames: Iterator[Frame], seed: int, protocol: PairProtocol) -> Iterator[tuple[ScanPair, Frame, Frame]]:
    previous = next(frames)
    for frame in frames:
        rng = np.random.default_rng([seed, 4, previous.index])
        first, second = cut_points(previous, protocol, rng), cut_points(frame, protocol, rng)
        swept = timed(previous.scan.time) or timed(frame.scan.time)  # instant sweeps' pairs carry no time
        pair = make_pair(
            pc1=previous.scan.points[first],
            pc2=frame.scan.points[second],
            flow=frame.flow.flow[first],
            dynamic1=frame.flow.dynamic[first],
            instance1=previous.scan.instance[first],
            class1=previous.scan.label[first],
            pose1=previous.pose.copy(),
            pose2=frame.pose.copy(),
            boxes1=visible_boxes(previous),
            time1=previous.scan.time[first] if swept else None,
            time2=frame.scan.time[second] if swept else None,
            measured=frame.measured_sweep(previous.stamp_ns),
        )
        yield pair, previous, frame
        previous = frame


def _scenario(scenario: Scenario | str) -> Scenario:
    return scenario if isinstance(scenario, Scenario) else load_scenario(scenario)


def generate_pairs(
    scenario: Scenario | str, seed: int | None = None, frames: int = 10, protocol: PairProtocol = PROTOCOLS["paper"],
    warmup_s: float | None = None,
) -> Iterator[ScanPair]:
    """frames consecutive pairs of the scenario (seeded, deterministic) after warmup_s seconds (None: the scenario's
    episode.warmup_s), cut by the protocol."""
    scenario = _scenario(scenario)
    seed = scenario.seed if seed is None else seed
    skip = warmup_frames(scenario, warmup_s)
    for pair, _, _ in _pairs_of(simulate(scenario, seed, frames, skip), seed, protocol):
        yield pair


def export(
    scenario: Scenario | str,
    out: str | Path,
    seed: int | None = None,
    frames: int = 10,
    protocol: PairProtocol = PROTOCOLS["paper"],
    progress=None,
    warmup_s: float | None = None,
) -> Path:
    """Write pairs/NNNNNN.npz, sequence/velodyne/NNNNNN.bin + sequence/poses.txt and dataset.json under out."""
    scenario = _scenario(scenario)
    seed = scenario.seed if seed is None else seed
    out = Path(out)
    pair_dir = out / "pairs"
    try:
        pair_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise DataError(f"{out}: cannot create the output folders ({err.strerror})") from None
    sequence = SequenceWriter(out / "sequence")
    skip = warmup_frames(scenario, warmup_s)
    for number, (pair, previous, frame) in enumerate(_pairs_of(simulate(scenario, seed, frames, skip), seed, protocol)):
        write_pair(pair_dir / f"{number:06d}.npz", pair)
        if number == 0:
            sequence.add(previous.index, previous.scan.points, previous.scan.intensity, previous.pose)
        sequence.add(frame.index, frame.scan.points, frame.scan.intensity, frame.pose)
        if progress is not None:
            progress(number + 1, frames)
    origin = sequence.close()
    description = {
        "scenario": scenario.model_dump(mode="json"),
        "seed": seed,
        "pairs": frames,
        "warmup_s": scenario.episode.warmup_s if warmup_s is None else warmup_s,
        "first_frame": skip,
        "protocol": protocol.model_dump(mode="json"),
        "dt": scenario.episode.dt,
        "sensor": {**scenario.lidar.spec().summary(), "mount_height": scenario.lidar.mount_height},
        "pair_keys": {
            "pc1": "float32 (N,3) scan t in its sensor frame",
            "pc2": "float32 (N,3) scan t+1 in its sensor frame",
            "flow": "float32 (N,3) pc1 + flow lies on the surfaces of scan t+1 "
            "(sensor frame t+1 coordinates minus pc1)",
            "instance1": "int32 agent id, 0 static",
            "class1": "uint8 class (0 ground, 1 building, 2 pole, 3 vegetation, "
            "4 parked car, 5 vehicle, 6 pedestrian)",
            "dynamic1": "bool point on a moving agent",
            "pose1": "float64 4x4 world <- sensor at t",
            "pose2": "float64 4x4 world <- sensor at t+1",
            "boxes1": "float64 (M,12) agents the scan at t hits, in its sensor frame: id kind x y z length width "
            "height yaw vx vy vz (centre at half height, velocity in m/s)",
            "time1": "float32 (N,) each point's time, s relative to scan t's stamp (rolling-shutter sweeps only)",
            "time2": "float32 (M,) the same for scan t+1",
        },
        "sequence": "velodyne/NNNNNN.bin float32 x,y,z,intensity (full scans); poses.txt: KITTI 3x4 rows, "
        "sensor poses relative to the first scan",
        "world_from_first_scan": origin.tolist(),
    }
    (out / "dataset.json").write_text(json.dumps(description, indent=2))
    (out / "scenario.yaml").write_text(dump(scenario))
    return out
