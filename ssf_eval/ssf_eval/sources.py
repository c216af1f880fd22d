"""Where labelled scan pairs come from: a simulator scenario and seed, an exported folder, or a recorded bag."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sim_bridge.options import add_protocol_options, protocol_from_args
from sim_bridge.dataset.export import PROTOCOLS, PairProtocol, generate_pairs
from sim_bridge.scenario import Scenario, load_scenario, overrides_from_pairs
from sim_bridge.sensors import sensor_names
from ssf_common import topics
from ssf_common.dataset.pairs import ScanPair, make_pair, read_pairs
from ssf_common.errors import ConfigError, DataError
from ssf_common.geometry.sampling import sample_indices

GT_FLOW_TOPIC, GT_ODOM_TOPIC, TF_TOPIC = topics.GT_FLOW, topics.GT_ODOM, topics.TF


@dataclass(frozen=True)
class PairSet:
    """Labelled pairs and a description of where they came from (for tables and result files)."""

    pairs: list[ScanPair]
    description: str
    source: dict[str, Any]


def add_pair_source_options(parser: argparse.ArgumentParser, default_scenario: str | None = None,
                            default_frames: int = 10) -> None:
    """--scenario | --data | --bag, and how pairs are cut from the simulator (seed, frames, warm-up, protocol)."""
    source = parser.add_mutually_exclusive_group(required=default_scenario is None)
    source.add_argument("--scenario", default=default_scenario, help="simulator scenario to generate pairs from"
                        + (f" (default {default_scenario})" if default_scenario else ""))
    source.add_argument("--data", type=Path, help="folder of exported .npz pairs (`ssf dataset export`)")
    source.add_argument("--bag", type=Path, help=f"recorded bag with {GT_FLOW_TOPIC} (a recorded simulator run)")
    parser.add_argument("--seed", type=int, default=0, help="simulator seed (default 0: never used in training)")
    parser.add_argument("--frames", type=int, default=default_frames, help=f"pairs to use (default {default_frames})")
    parser.add_argument("--warmup", type=float, default=None, metavar="S",
                        help="simulated seconds before the first pair: the traffic starts from rest (default: the "
                        "scenario's episode.warmup_s, 2 s unless it says otherwise)")
    add_sensor_options(parser)
    add_protocol_options(parser)


def add_sensor_options(parser: argparse.ArgumentParser) -> None:
    """--sensor NAME and --sim-param NAME:=VALUE: what the simulator source is changed to."""
    parser.add_argument("--sensor", choices=sensor_names(), metavar="NAME",
                        help=f"LiDAR model of the simulator ({', '.join(sensor_names())}); short for "
                        "--sim-param lidar.model:=NAME (default: the scenario's)")
    parser.add_argument("--sim-param", action="append", default=[], metavar="NAME:=VALUE",
                        help="scenario setting of the simulator source, e.g. --sim-param lidar.rate_hz:=20 (repeatable)")


def sim_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The scenario overrides that --sim-param and --sensor name (--sensor last: it wins)."""
    overrides = overrides_from_pairs(list(getattr(args, "sim_param", None) or []), "--sim-param")
    if getattr(args, "sensor", None):
        overrides["lidar.model"] = args.sensor
    return overrides


def pairs_from_args(args: argparse.Namespace) -> PairSet:
    """The pairs the source flags name."""
    if args.frames < 1:
        raise ConfigError(f"--frames must be at least 1, got {args.frames}")
    overrides = sim_overrides(args)
    if overrides and (args.data is not None or getattr(args, "bag", None) is not None):
        raise ConfigError("--sensor and --sim-param change the simulator: they need --scenario, not --data or --bag")
    if args.data is not None:
        pairs = list(read_pairs(args.data))[: args.frames]
        return PairSet(pairs, f"data {args.data}", {"data": str(args.data), "pairs": len(pairs)})
    protocol = protocol_from_args(args)
    if getattr(args, "bag", None) is not None:
        pairs = bag_pairs(args.bag, protocol, args.frames, args.seed)
        return PairSet(pairs, f"bag {args.bag}", {"bag": str(args.bag), "pairs": len(pairs), "protocol": protocol})
    return simulator_pairs(args.scenario, args.seed, args.frames, protocol, args.warmup, overrides)


def simulator_pairs(scenario: str, seed: int, frames: int, protocol: PairProtocol = PROTOCOLS["paper"],
                    warmup_s: float | None = None, overrides: dict[str, Any] | None = None) -> PairSet:
    """frames pairs of a scenario (with dotted overrides) after warmup_s seconds (None: the scenario's), cut by the
    protocol."""
    loaded = load_scenario(scenario, overrides or {})
    warmup_s = loaded.episode.warmup_s if warmup_s is None else warmup_s
    pairs = list(generate_pairs(loaded, seed, frames, protocol, warmup_s))
    spec = loaded.lidar.spec()
    description = (f"scenario {scenario} seed {seed}, {spec.model} at {spec.rate_hz:g} Hz, {len(pairs)} pairs after "
                   f"{warmup_s:g} s")
    return PairSet(pairs, description, {"scenario": scenario, "seed": seed, "pairs": len(pairs), "warmup_s": warmup_s,
                                        "protocol": protocol, "sensor": spec.model, "dt": loaded.episode.dt,
                                        "overrides": dict(overrides or {})})


def source_scenario(args: argparse.Namespace) -> Scenario | None:
    """The scenario the source flags simulate (None for --data and --bag): checked before any work starts."""
    if getattr(args, "scenario", None) is None:
        return None
    return load_scenario(args.scenario, sim_overrides(args))


def sweep_period_layer(scenario: Scenario) -> dict[str, Any]:
    """Perception config values that follow the simulated sensor: the time between scans (scan_period, flow.rigid.scan_period,
    seg.selection.scan_period)."""
    dt = scenario.episode.dt
    return {"scan_period": dt, "flow": {"rigid": {"scan_period": dt}}, "seg": {"selection": {"scan_period": dt}}}


def bag_pairs(path: Path, protocol: PairProtocol, limit: int, seed: int = 0) -> list[ScanPair]:
    """Pairs of consecutive ground-truth flow clouds of a recorded simulator run, cut by the protocol; sensor
    poses from the recorded ground-truth odometry and the base_link -> sensor transform on /tf."""
    from ssf_common import messages, pose_msgs
    from ssf_common.bags import open_bag
    from ssf_common.pointcloud import cloud_to_array

    clouds: list[tuple[int, str, np.ndarray]] = []
    base_poses: dict[int, np.ndarray] = {}
    mounts: dict[str, np.ndarray] = {}
    with open_bag(path) as bag:
        if GT_FLOW_TOPIC not in bag.topics:
            raise DataError(f"{path}: no {GT_FLOW_TOPIC} topic (record a simulator run with `ssf demo --record-all`, "
                            f"`ssf demo --record {GT_FLOW_TOPIC}` or `ssf record`)")
        wanted = [topic for topic in (GT_FLOW_TOPIC, GT_ODOM_TOPIC, TF_TOPIC) if topic in bag.topics]
        for message in bag.messages(wanted):
            msg = bag.decode(message)
            if message.topic == TF_TOPIC:
                for item in msg.transforms:
                    mounts.setdefault(item.child_frame_id, pose_msgs.matrix_from_transform(item.transform))
            elif message.topic == GT_ODOM_TOPIC:
                base_poses[messages.stamp_ns(msg.header.stamp)] = pose_msgs.matrix_from_pose(msg.pose.pose)
            elif len(clouds) <= limit:
                clouds.append((messages.stamp_ns(msg.header.stamp), msg.header.frame_id, cloud_to_array(msg).copy()))
    if len(clouds) < 2:
        raise DataError(f"{path}: fewer than two {GT_FLOW_TOPIC} clouds")

    def sensor_pose(stamp: int, frame: str) -> np.ndarray | None:
        base = base_poses.get(stamp)
        return None if base is None else base @ mounts.get(frame, np.eye(4))

    pairs = []
    for (stamp1, frame1, cloud1), (stamp2, frame2, cloud2) in zip(clouds, clouds[1:]):
        rng = np.random.default_rng([seed, 4, len(pairs)])
        pick1, pick2 = _cut(cloud1, protocol, rng), _cut(cloud2, protocol, rng)
        flow = np.stack([cloud1[name][pick1] for name in ("flow_x", "flow_y", "flow_z")], axis=1)
        pairs.append(make_pair(_xyz(cloud1[pick1]), _xyz(cloud2[pick2]), flow, cloud1["dynamic"][pick1],
                               cloud1["instance"][pick1], cloud1["label"][pick1], sensor_pose(stamp1, frame1),
                               sensor_pose(stamp2, frame2)))
    return pairs[:limit]


def _xyz(cloud: np.ndarray) -> np.ndarray:
    return np.stack([cloud[name] for name in ("x", "y", "z")], axis=1).astype(np.float32)


def _cut(cloud: np.ndarray, protocol: PairProtocol, rng: np.random.Generator) -> np.ndarray:
    keep = np.ones(len(cloud), bool)
    if protocol.max_range is not None:
        keep &= np.hypot(cloud["x"], cloud["y"]) <= protocol.max_range
    if protocol.remove_ground:
        keep &= cloud["label"] != 0
    kept = np.flatnonzero(keep)
    if kept.size == 0:
        raise DataError("a recorded scan has no point left after the protocol's range and ground cut")
    if protocol.points is None:
        return kept
    return kept[sample_indices(_xyz(cloud[kept]), protocol.points, rng, protocol.sampling, pad=True)]
