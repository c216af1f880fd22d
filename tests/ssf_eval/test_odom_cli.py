"""`ssf odom run` on folders of scans and on a bag, `ssf eval odom` and `ssf bench odom` end to end, and their
one-line errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ssf_bringup.cli import main
from ssf_common import messages
from ssf_common.bags import BagWriter
from ssf_common.dataset.kitti import read_poses, read_tum
from ssf_common.geometry.se3 import invert, make_pose, transform_points
from ssf_common.pointcloud import xyz_to_cloud
from ssf_common.scans import read_scan, write_bin

POSES = [make_pose(0.6 * index, 0.05 * index, 0.0, np.radians(0.8 * index)) for index in range(4)]


@pytest.fixture(scope="module")
def real_scans(shared_data) -> list[np.ndarray]:
    """Four scans of real VLP-32 geometry taken at known poses (each a different 80 % of the points, 1 cm noise)."""
    scan = read_scan(shared_data / "lidar_scans" / "vlp32_1713492677464078412.pcd")[:, :3].astype(np.float64)
    rng = np.random.default_rng(0)
    scans = [transform_points(invert(pose), scan[rng.random(len(scan)) < 0.8]) for pose in POSES]
    return [(points + rng.normal(0.0, 0.01, points.shape)).astype(np.float32) for points in scans]


def check_poses(out, tolerance: float = 0.05) -> None:
    poses = read_poses(out / "poses_kitti.txt")
    stamps, tum = read_tum(out / "poses_tum.txt")
    assert len(poses) == len(POSES) and len(tum) == len(POSES)
    np.testing.assert_allclose(tum, poses, atol=1e-6)
    assert np.all(np.diff(stamps) > 0)
    for estimate, truth in zip(poses, POSES):
        assert np.linalg.norm(estimate[:3, 3] - truth[:3, 3]) < tolerance
    assert (out / "config.yaml").is_file() and (out / "trajectory.png").stat().st_size > 0


@pytest.mark.parametrize("method", ["points", "ssf"])
def test_odom_run_on_a_folder_of_scans(tmp_path, real_scans, method, capsys):
    folder = tmp_path / "scans"
    folder.mkdir()
    for index, scan in enumerate(real_scans):
        write_bin(folder / f"{index:06d}.bin", np.c_[scan, np.zeros(len(scan), np.float32)])
    out = tmp_path / "out"
    assert main(["odom", "run", str(folder), "--out", str(out), "--method", method]) == 0
    check_poses(out)
    assert f"method: {method}" in (out / "config.yaml").read_text()
    assert "4 poses" in capsys.readouterr().err


def test_odom_run_on_a_bag_draws_the_truth_when_the_simulator_recorded_it(tmp_path, real_scans, capsys):
    """A simulator's recording holds the true base_link poses and the sensor's mount: the run writes the true sensor
    poses beside its own, in the same frame, and says how far its end lies from the true one."""
    from ssf_common import pose_msgs
    from ssf_common.conversions import odometry_to_msg
    from ssf_common.records import OdometryEstimate

    mount, world = make_pose(1.2, 0.0, 1.8, yaw=0.05), make_pose(40.0, -7.0, 0.0, yaw=1.0)  # base_link <- lidar
    bag = tmp_path / "bag"
    with BagWriter(bag) as writer:
        writer.add_topic("/velodyne_points", "sensor_msgs/msg/PointCloud2")
        writer.add_topic("/sim/ground_truth/odom", "nav_msgs/msg/Odometry")
        writer.add_topic("/tf", "tf2_msgs/msg/TFMessage")
        for index, scan in enumerate(real_scans):
            stamp = 1_000_000_000 + index * 100_000_000
            base = world @ POSES[index] @ invert(mount)
            writer.write("/sim/ground_truth/odom", messages.serialize(odometry_to_msg(
                OdometryEstimate(stamp, base, np.zeros((6, 6)), frame_id="world"))), stamp)
            writer.write("/tf", messages.serialize(messages.msg_type("tf2_msgs/msg/TFMessage")(
                transforms=[pose_msgs.transform_stamped_msg(mount, stamp, "base_link", "lidar")])), stamp)
            writer.write("/velodyne_points", messages.serialize(xyz_to_cloud(scan, messages.header(stamp, "lidar"))), stamp)
    out = tmp_path / "out"
    assert main(["odom", "run", str(bag), "--out", str(out), "--method", "points"]) == 0
    check_poses(out)
    stamps, _ = read_tum(out / "poses_tum.txt")
    assert stamps[0] == pytest.approx(1.0)
    _, truth = read_tum(out / "truth_tum.txt")
    np.testing.assert_allclose(truth, POSES, atol=1e-6)  # the sensor's motion, in the first scan's frame
    assert "m from the true end)" in capsys.readouterr().err


def test_odom_run_on_a_bag_without_truth_draws_the_odometry_alone(tmp_path, real_scans):
    bag = tmp_path / "bag"
    with BagWriter(bag) as writer:
        writer.add_topic("/velodyne_points", "sensor_msgs/msg/PointCloud2")
        for index, scan in enumerate(real_scans[:2]):
            stamp = 1_000_000_000 + index * 100_000_000
            writer.write("/velodyne_points", messages.serialize(xyz_to_cloud(scan, messages.header(stamp, "lidar"))), stamp)
    out = tmp_path / "out"
    assert main(["odom", "run", str(bag), "--out", str(out), "--method", "points"]) == 0
    assert (out / "trajectory.png").is_file() and not (out / "truth_tum.txt").exists()


def test_odom_run_errors_are_one_line(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["odom", "run", str(tmp_path / "empty"), "--out", str(tmp_path / "out")]) == 2
    assert "needs at least two scan files" in capsys.readouterr().err
    assert main(["odom", "run", str(tmp_path / "missing"), "--out", str(tmp_path / "out")]) == 2
    assert "no such folder" in capsys.readouterr().err
    assert main(["odom", "run", str(tmp_path / "empty"), "--out", str(tmp_path / "o"), "-p", "odom.voxel:=-1"]) == 2
    assert "voxel" in capsys.readouterr().err


def test_eval_odom_end_to_end(tmp_path, capsys):
    result = tmp_path / "odom.json"
    assert main(["eval", "odom", "--scenario", "sparse_50", "--frames", "4", "--masks", "gt", "--methods", "points",
                 "ssf", "ssf+twist", "kiss-icp", "--json", str(result), "--plot", str(tmp_path / "traj.png"),
                 "--map-plot", str(tmp_path / "maps.png"), "--trail-every", "2", "--poses", str(tmp_path / "poses"),
                 "-p", "map.confirm:=2",  # a 4-scan drive: voxels seen twice are in the map
                 "-p", "perception.flow.rigid.end_whole:=false"]) == 0
    table = capsys.readouterr().out
    assert "RPE t RMSE" in table and "kiss-icp" in table
    document = json.loads(result.read_text())
    methods = document["scenarios"]["sparse_50"]["methods"]
    assert set(methods) == {"points", "ssf", "ssf+twist", "kiss-icp"}
    scenario = document["scenarios"]["sparse_50"]
    assert 0.0 <= scenario["static_world_left_behind_share"] <= scenario["static_world_trail_share"] <= 1.0
    assert "the static world itself" in table and "where the last pose is off" in table
    for figures in methods.values():
        assert {"rmse", "sse", "std"} <= set(figures["rpe_translation"]) and figures["ate"]["rmse"] >= 0
        assert 0.0 <= figures["left_behind_share"] <= figures["trail_share"] <= 1.0
    assert methods["ssf"]["rpe_translation"]["rmse"] < 0.05 and methods["ssf+twist"]["rpe_translation"]["rmse"] < 0.05
    assert document["config"]["odom"]["method"] == "ssf" and (tmp_path / "odom.config.yaml").is_file()
    assert document["config"]["perception"] == {"flow.rigid.end_whole": False}
    assert (tmp_path / "traj.png").stat().st_size > 0 and (tmp_path / "maps.png").stat().st_size > 0
    stamps, truth = read_tum(tmp_path / "poses" / "sparse_50_truth_tum.txt")
    np.testing.assert_allclose(truth[0], np.eye(4), atol=1e-9)
    for method in methods:
        method_stamps, poses = read_tum(tmp_path / "poses" / f"sparse_50_{method}_tum.txt")
        np.testing.assert_array_equal(method_stamps, stamps)
        end_error = np.linalg.norm(poses[-1, :3, 3] - truth[-1, :3, 3])  # the files hold the trajectories scored
        distance = document["scenarios"]["sparse_50"]["distance_m"]
        assert end_error == pytest.approx(methods[method]["endpoint_pct"] * distance / 100.0, abs=1e-6)
        split = methods[method]["end_error"]  # the same end error, along the ground and in height
        assert np.hypot(split["horizontal_m"], split["height_m"]) == pytest.approx(end_error, abs=1e-6)
    assert main(["eval", "odom", "--scenario", "sparse_50", "--methods", "lidar"]) == 2
    assert "unknown odometry method" in capsys.readouterr().err
    assert main(["eval", "odom", "--frames", "3", "-p", "perception.flow.rigid.bogus:=1"]) == 2
    error = capsys.readouterr().err.strip()
    assert "flow.rigid.bogus" in error and len(error.splitlines()) == 1


def test_bench_odom(tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert main(["bench", "odom", "--scenario", "sparse_50", "--frames", "3", "--methods", "ssf", "kiss-icp",
                 "--json", str(out)]) == 0
    figures = json.loads(out.read_text())
    assert set(figures["methods"]) == {"ssf", "kiss-icp"} and figures["peak_rss_mb"] > 0
    assert figures["methods"]["ssf"]["ms_median"] > 0


def test_eval_odom_scores_the_poses_odom_run_gives_on_the_same_scans(tmp_path):
    """`ssf eval odom` runs the graph's perception: its `ssf` trajectory is the one `ssf odom run` writes for the very
    same scans (the maskless flow of the 'flow' row asked for beside it must not touch the loop's stream)."""
    from ssf_eval.odom.sequence import scenario_of, sim_scans

    frames = 8
    folder = tmp_path / "scans"
    folder.mkdir()
    scans = list(sim_scans(scenario_of("urban_200"), 4, frames, 2.0))
    for scan in scans:
        np.save(folder / f"{scan.index:06d}.npy", scan.points)
    np.save(folder / f"{frames:06d}.npy", scans[-1].next_points)
    assert main(["eval", "odom", "--scenario", "urban_200", "--seed", "4", "--frames", str(frames), "--methods", "flow",
                 "ssf", "--poses", str(tmp_path / "poses")]) == 0
    assert main(["odom", "run", str(folder), "--out", str(tmp_path / "run")]) == 0
    _, evaluated = read_tum(tmp_path / "poses" / "urban_200_ssf_tum.txt")
    _, run = read_tum(tmp_path / "run" / "poses_tum.txt")
    np.testing.assert_allclose(evaluated, run[:frames], atol=1e-6)


def test_the_maskless_flow_beside_the_loop_leaves_the_loops_estimator_as_the_graph_leaves_it():
    """What a pair's last estimate moved is what the stream carries to the next pair: in the graph that is the loop's
    own answer, so the 'flow' row's maskless estimate must come from another estimator."""
    from ssf_eval.odom.cli import perception_for
    from ssf_eval.odom.sequence import scenario_of, sim_scans

    perception = perception_for("seg", 0, plain=True)
    for scan in sim_scans(scenario_of("urban_200"), 4, 2, 2.0):
        perceived = perception(scan)
        assert perceived.flow_plain is not None and perceived.flow_plain.shape == perceived.flow.shape
        np.testing.assert_array_equal(perception.estimator.state.result.flow, perceived.flow)
    assert perception_for("seg", 0, plain=False)(scan).flow_plain is None


def test_a_perception_cache_reproduces_the_drive_and_refuses_another(tmp_path, capsys):
    cache = tmp_path / "cache"
    arguments = ["eval", "odom", "--scenario", "sparse_50", "--frames", "4", "--masks", "seg", "--methods", "flow",
                 "ssf", "-p", "map.confirm:=2", "--perception-cache", str(cache)]
    first, second = tmp_path / "first.json", tmp_path / "second.json"
    assert main([*arguments, "--json", str(first)]) == 0
    assert "0 scans read" in capsys.readouterr().err
    stored = sorted(path.name for path in (cache / "sparse_50").iterdir())
    assert stored == ["drive.json", *(f"scan_{index:06d}.npz" for index in range(4))]
    assert main([*arguments, "--json", str(second)]) == 0
    assert "4 scans read" in capsys.readouterr().err
    figures = [json.loads(path.read_text())["scenarios"]["sparse_50"]["methods"] for path in (first, second)]
    for method in ("flow", "ssf"):  # the stored perception gives the very same poses
        assert figures[1][method]["rpe_translation"] == figures[0][method]["rpe_translation"]
        assert figures[1][method]["end_error"] == figures[0][method]["end_error"]
    ssf_only = [*arguments[:9], "ssf", *arguments[11:]]  # the cache holds the maskless flow; ssf alone reads it too
    assert main(ssf_only) == 0 and "4 scans read" in capsys.readouterr().err
    assert main([*arguments[:-2], "--seed", "5", "--perception-cache", str(cache)]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert len(errors) == 1 and "written for another drive (differs in seed)" in errors[0]


def test_the_agents_mask_leaves_every_agent_out_of_the_map(tmp_path):
    from ssf_eval.odom.cli import perception_for
    from ssf_eval.odom.sequence import scenario_of, sim_scans

    scan = next(iter(sim_scans(scenario_of("dense_500"), 0, 2, 2.8)))  # cars standing in a queue
    perceived = perception_for("agents", 0)(scan)
    np.testing.assert_array_equal(perceived.dynamic_prob, (scan.instance > 0).astype(np.float32))
    assert perceived.dynamic_prob.sum() > scan.dynamic.sum()  # standing agents too, not only the moving ones
