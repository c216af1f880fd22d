"""sim_bridge under `ssf launch` with its route follower, recorded by `ssf record`, read back and checked."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from ssf_common import messages
from ssf_common import pose_msgs
from ssf_common.bags import open_bag
from ssf_common.pointcloud import cloud_to_array

STEPS = 10  # 1 s of sim time at dt 0.1
TOPICS = ["/lidar/points", "/sim/ground_truth/flow", "/sim/ground_truth/odom", "/tf", "/sim/episode", "/clock",
          "/vehicle/twist"]


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("closed_loop")
    bag = folder / "bag"
    graph = {
        "stop_timeout_s": 10.0,
        "nodes": [
            {"executable": "ssf", "name": "recorder", "ros_args": False, "arguments": ["record", "-o", str(bag), *TOPICS], "respawn": False},
            {
                "executable": "sim_bridge",
                "required": True,
                "respawn": False,
                "parameters": {
                    "scenario": "sparse_50", "duration_s": STEPS / 10, "driver": "follow",
                    # the sensor's own rate: flat out, 1.5 MB best-effort scans every few ms can overrun a recorder
                    # that a loaded machine slows (one scan in eleven lost, now and then, in CI)
                    "rate": 10.0,
                    "wait_for_subscribers": 1, "summary": str(folder / "episode.json"),
                },
            },
        ],
    }
    (folder / "graph.yaml").write_text(yaml.safe_dump(graph))
    result = subprocess.run(
        [sys.executable, "-P", "-m", "ssf_bringup.cli", "launch", str(folder / "graph.yaml")],
        capture_output=True, text=True, timeout=240,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "Traceback" not in result.stdout
    return folder


def read_all(bag: Path) -> dict[str, list]:
    found: dict[str, list] = {topic: [] for topic in TOPICS}
    with open_bag(bag) as reader:
        for message in reader.messages():
            found[message.topic].append(reader.decode(message))
    return found


def test_every_step_is_recorded_and_the_episode_summarised(recording):
    found = read_all(recording / "bag")
    assert len(found["/lidar/points"]) == STEPS + 1  # the first scan, then one per step
    assert len(found["/sim/ground_truth/flow"]) == STEPS
    assert len(found["/sim/ground_truth/odom"]) == STEPS + 1
    stamps = [messages.stamp_ns(m.header.stamp) for m in found["/lidar/points"]]
    twists = found["/vehicle/twist"]  # the odometer's measurement of every step, stamped at its end
    assert [messages.stamp_ns(m.header.stamp) for m in twists] == stamps[1:]
    truth = [m.twist.twist.linear.x for m in found["/sim/ground_truth/odom"]]
    assert all(abs(m.twist.linear.x - (before + after) / 2) < 0.5 for m, before, after in zip(twists, truth, truth[1:]))
    assert stamps == [i * 100_000_000 for i in range(STEPS + 1)]
    assert [messages.stamp_ns(m.clock) for m in found["/clock"]] == stamps
    final = found["/sim/episode"][-1]
    assert final.scenario == "sparse_50" and abs(final.time - STEPS / 10) < 1e-9 and final.num_agents == 50
    summary = yaml.safe_load((recording / "episode.json").read_text())
    assert summary["distance"] > 0 and summary["outcome"] in ("running", "success")
    scan = cloud_to_array(found["/lidar/points"][0])
    assert {"x", "y", "z", "intensity", "ring", "time"} <= set(scan.dtype.names) and len(scan) > 10_000


def test_recorded_ground_truth_flow_is_the_recorded_ego_motion_for_static_points(recording):
    found = read_all(recording / "bag")
    base_poses = {messages.stamp_ns(m.header.stamp): pose_msgs.matrix_from_pose(m.pose.pose) for m in found["/sim/ground_truth/odom"]}
    mount_tf = next(t for m in found["/tf"] for t in m.transforms if t.child_frame_id == "lidar").transform
    mount = np.eye(4)
    mount[:3, :3] = pose_msgs.matrix_from_pose(
        messages.msg_type("geometry_msgs/msg/Pose")(
            position=messages.msg_type("geometry_msgs/msg/Point")(x=0.0, y=0.0, z=0.0), orientation=mount_tf.rotation
        )
    )[:3, :3]
    mount[:3, 3] = [mount_tf.translation.x, mount_tf.translation.y, mount_tf.translation.z]
    checked = 0
    for truth in found["/sim/ground_truth/flow"]:
        stamp = messages.stamp_ns(truth.header.stamp)
        pose_t, pose_next = base_poses[stamp] @ mount, base_poses[stamp + 100_000_000] @ mount
        motion = np.linalg.inv(pose_next) @ pose_t
        points = cloud_to_array(truth)
        static = (points["instance"] == 0) & (points["dynamic"] == 0)
        xyz = np.stack([points["x"], points["y"], points["z"]], axis=1)[static].astype(np.float64)
        flow = np.stack([points["flow_x"], points["flow_y"], points["flow_z"]], axis=1)[static]
        expected = xyz @ motion[:3, :3].T + motion[:3, 3] - xyz
        assert np.abs(flow - expected).max() < 2e-4  # float32 on the wire
        checked += int(static.sum())
    assert checked > 10_000
