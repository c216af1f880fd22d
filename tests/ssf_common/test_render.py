"""Episode pictures and videos from a recording: every layer lands where the world has it (perceived obstacles
carried from the sensor frame by the true pose and the mount, the plan from the odometry frame), frames follow the
scans, and the files are real MP4 / GIF / PNG."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from ssf_common import messages, pose_msgs, topics
from ssf_common.bags.writer import BagWriter, BagWriterConfig
from ssf_common.conversions import obstacles_to_msg, odometry_to_msg, plan_to_msg, semantic_flow_to_cloud
from ssf_common.errors import ConfigError
from ssf_common.geometry.se3 import invert, make_pose
from ssf_common.pointcloud import xyz_to_cloud
from ssf_common.records import ObstacleKind, Obstacles, OdometryEstimate, Plan, Segmentation, SemanticFlow
from ssf_common.render.draw import FrameDrawer, draw_frame
from ssf_common.render.frames import RenderConfig, open_track, recording_frames
from ssf_common.render.video import render_recording, write_video

SCANS = 12
DT_NS = 100_000_000
LAG_NS = 300_000_000  # the segmentation of a scan arrives this much later
MOUNT = make_pose(1.0, 0.0, 1.8, yaw=0.1)  # base_link <- lidar
SPEED = 5.0


def ego_pose(k: int) -> np.ndarray:
    """world <- base_link: driving along a gentle curve."""
    return make_pose(10.0 + SPEED * 0.1 * k, -3.0 + 0.02 * k * k, 0.0, yaw=0.3 + 0.02 * k)


def agents(stamp: int) -> Obstacles:
    """A vehicle crossing and a pedestrian standing, in the world."""
    t = stamp * 1e-9
    return Obstacles(stamp, "world", ids=[4, 9], kinds=[ObstacleKind.VEHICLE, ObstacleKind.PEDESTRIAN],
                     centres=[[25.0, 4.0 + 2.0 * t, 0.8], [18.0, -6.0, 0.9]], sizes=[[4.5, 1.9, 1.6], [0.6, 0.6, 1.8]],
                     yaws=[np.pi / 2, 0.0], velocities=[[0.0, 2.0, 0.0], [0.0, 0.0, 0.0]])


def lidar_points(k: int) -> tuple[np.ndarray, np.ndarray]:
    """Points in the lidar frame: a ground grid and the vehicle's box surface; label 1 on the vehicle."""
    grid = np.stack(np.meshgrid(np.linspace(-30, 30, 40), np.linspace(-30, 30, 40)), -1).reshape(-1, 2)
    ground = np.column_stack([grid, np.zeros(len(grid))])
    vehicle = agents(k * DT_NS)
    box = np.random.default_rng(k).uniform(-0.5, 0.5, (200, 3)) * vehicle.sizes[0]
    box = box @ make_pose(yaw=float(vehicle.yaws[0]))[:3, :3].T + vehicle.centres[0]
    world = np.concatenate([(ground @ ego_pose(k)[:3, :3].T + ego_pose(k)[:3, 3]), box])
    to_lidar = invert(ego_pose(k) @ MOUNT)
    local = world @ to_lidar[:3, :3].T + to_lidar[:3, 3]
    return local.astype(np.float32), np.r_[np.zeros(len(ground)), np.ones(len(box))].astype(np.uint8)


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """A small recording as the demo graph makes one: scans, truth, tf, segmentation (late, every other scan),
    perceived obstacles in the sensor frame, plans and odometry in the odometry frame, fusion states."""
    path = tmp_path_factory.mktemp("render") / "recording"
    writer = BagWriter(path, BagWriterConfig())
    types = {topics.LIDAR_POINTS: "sensor_msgs/msg/PointCloud2", topics.SEMANTIC_FLOW: "sensor_msgs/msg/PointCloud2",
             topics.GT_ODOM: "nav_msgs/msg/Odometry", topics.TF: "tf2_msgs/msg/TFMessage",
             topics.GT_OBSTACLES: "ssf_interfaces/msg/ObstacleArray", topics.OBSTACLES: "ssf_interfaces/msg/ObstacleArray",
             topics.PLAN: "nav_msgs/msg/Path", topics.ODOM: "nav_msgs/msg/Odometry",
             topics.FUSION_STATE: "ssf_interfaces/msg/FusionState"}
    for topic, type_name in types.items():
        writer.add_topic(topic, type_name, ())
    odom_origin = invert(ego_pose(0))
    state = messages.msg_type("ssf_interfaces/msg/FusionState")
    for k in range(SCANS):
        stamp = k * DT_NS
        xyz, labels = lidar_points(k)
        write = lambda topic, msg, at=stamp: writer.write(topic, messages.serialize(msg), at)  # noqa: E731
        write(topics.GT_ODOM, odometry_to_msg(OdometryEstimate(stamp, ego_pose(k), np.zeros((6, 6)), frame_id="world")))
        write(topics.TF, messages.msg_type("tf2_msgs/msg/TFMessage")(transforms=[
            pose_msgs.transform_stamped_msg(ego_pose(k), stamp, "world", "base_link"),
            pose_msgs.transform_stamped_msg(MOUNT, stamp, "base_link", "lidar")]))
        write(topics.GT_OBSTACLES, obstacles_to_msg(agents(stamp)))
        write(topics.LIDAR_POINTS, xyz_to_cloud(xyz, messages.header(stamp, "lidar")))
        write(topics.ODOM, odometry_to_msg(OdometryEstimate(stamp, odom_origin @ ego_pose(k), np.zeros((6, 6)))))
        ahead = odom_origin @ ego_pose(k) @ make_pose(x=1.0)
        line = np.array([odom_origin @ ego_pose(k) @ make_pose(x=2.0 * i) for i in range(6)])[:, :2, 3]
        write(topics.PLAN, plan_to_msg(Plan(stamp, "odom", np.arange(6) * 0.2,
                                            np.column_stack([line, np.full(6, np.arctan2(ahead[1, 0], ahead[0, 0])),
                                                             np.full(6, SPEED)]))))
        if k % 2 == 0:
            late = stamp + LAG_NS
            seen = agents(stamp).take(np.array([0])).transformed(invert(ego_pose(k) @ MOUNT), "lidar")
            segmentation = Segmentation.from_probability(labels.astype(np.float32), labels.astype(np.int32))
            write(topics.SEMANTIC_FLOW, semantic_flow_to_cloud(SemanticFlow(stamp, "lidar", xyz, np.zeros_like(xyz),
                                                                            segmentation)), late)
            write(topics.OBSTACLES, obstacles_to_msg(seen), late)
            for iteration, delta in enumerate((0.5, 0.05, 0.0005)):
                write(topics.FUSION_STATE, state(header=messages.header(stamp, ""), iteration=iteration,
                                                 delta_total=delta, delta_flow=delta, delta_mask=delta,
                                                 converged=iteration == 2, num_points=len(xyz), num_static=1600,
                                                 num_clusters=2), late)
    writer.close()
    return path


JUDGED_SCANS = 5
PHANTOM_XY = (14.0, 8.0)  # where the perception reports a moving obstacle and no agent is


def known_agents(stamp: int) -> Obstacles:
    """In the world: 1 a car driving and scanned, 2 a car driving and scanned, 3 a pedestrian walking behind a wall
    (no point on it), 4 a car parked and scanned, 5 a car driving 60 m away, scanned."""
    t = stamp * 1e-9
    vehicle, walker = [4.5, 1.9, 1.6], [0.6, 0.6, 1.8]
    return Obstacles(stamp, "world", ids=[1, 2, 3, 4, 5], kinds=[1, 1, 2, 1, 1],
                     centres=[[20.0 + 3.0 * t, 2.0, 0.8], [30.0 - 4.0 * t, -6.0, 0.8], [12.0, -12.0 + 1.2 * t, 0.9],
                              [16.0, -4.0, 0.8], [70.0 + 5.0 * t, 3.0, 0.8]],
                     sizes=[vehicle, vehicle, walker, vehicle, vehicle], yaws=[0.0, np.pi, np.pi / 2, 0.0, 0.0],
                     velocities=[[3.0, 0.0, 0.0], [-4.0, 0.0, 0.0], [0.0, 1.2, 0.0], [0.0, 0.0, 0.0], [5.0, 0.0, 0.0]])


def perceived_obstacles(stamp: int) -> Obstacles:
    """What the perception reports, in the world: car 1 moving, the parked car still, the hidden walker (its motion
    carried along), and a phantom; car 2 is missed."""
    truth = known_agents(stamp)
    found = truth.take(np.array([0, 3, 2]))
    phantom = Obstacles(stamp, "world", ids=[77], kinds=[1], centres=[[*PHANTOM_XY, 0.8]], sizes=[[4.0, 1.8, 1.5]],
                        yaws=[0.3], velocities=[[2.0, 1.0, 0.0]])
    return replace(found.joined(phantom), ids=np.array([11, 0, 13, 77]))


@pytest.fixture(scope="module")
def judged_recording(tmp_path_factory) -> Path:
    """Scans with points on agents 1, 2, 4 and 5 (not on the hidden walker), their truth, perceived obstacles in the
    sensor frame, and the simulator's last word: still driving when its time was up."""
    path = tmp_path_factory.mktemp("judged") / "recording"
    writer = BagWriter(path, BagWriterConfig())
    for topic, type_name in {topics.LIDAR_POINTS: "sensor_msgs/msg/PointCloud2", topics.GT_ODOM: "nav_msgs/msg/Odometry",
                             topics.TF: "tf2_msgs/msg/TFMessage", topics.GT_OBSTACLES: "ssf_interfaces/msg/ObstacleArray",
                             topics.OBSTACLES: "ssf_interfaces/msg/ObstacleArray",
                             topics.EPISODE: "ssf_interfaces/msg/EpisodeResult"}.items():
        writer.add_topic(topic, type_name, ())
    rng = np.random.default_rng(0)
    result = messages.msg_type("ssf_interfaces/msg/EpisodeResult")
    for k in range(JUDGED_SCANS):
        stamp = k * DT_NS
        write = lambda topic, msg, at=stamp: writer.write(topic, messages.serialize(msg), at)  # noqa: E731
        truth = known_agents(stamp)
        grid = np.stack(np.meshgrid(np.linspace(-10, 80, 90), np.linspace(-30, 30, 60)), -1).reshape(-1, 2)
        world = [np.column_stack([grid, np.zeros(len(grid))])]
        for row in (0, 1, 3, 4):  # the walker, row 2, is hidden
            box = rng.uniform(-0.5, 0.5, (60, 3)) * truth.sizes[row]
            world.append(box @ make_pose(yaw=float(truth.yaws[row]))[:3, :3].T + truth.centres[row])
        to_lidar = invert(ego_pose(k) @ MOUNT)
        local = np.concatenate(world) @ to_lidar[:3, :3].T + to_lidar[:3, 3]
        write(topics.GT_ODOM, odometry_to_msg(OdometryEstimate(stamp, ego_pose(k), np.zeros((6, 6)), frame_id="world")))
        write(topics.TF, messages.msg_type("tf2_msgs/msg/TFMessage")(transforms=[
            pose_msgs.transform_stamped_msg(MOUNT, stamp, "base_link", "lidar")]))
        write(topics.GT_OBSTACLES, obstacles_to_msg(truth))
        write(topics.LIDAR_POINTS, xyz_to_cloud(local.astype(np.float32), messages.header(stamp, "lidar")))
        write(topics.OBSTACLES, obstacles_to_msg(perceived_obstacles(stamp).transformed(to_lidar, "lidar")),
              stamp + LAG_NS)
        write(topics.EPISODE, result(header=messages.header(stamp, "world"), scenario="urban_100", seed=7, outcome=0,
                                     time=stamp * 1e-9, distance=2.0 * k, average_speed=5.0, min_clearance=3.0,
                                     num_agents=5))
    writer.close()
    return path


def test_every_scan_is_judged_perceived_missed_and_made_up_against_the_truth(judged_recording):
    """Of the two cars driving where the LiDAR sees them one is perceived and one missed; the hidden walker and the car
    60 m away do not count, nor does the obstacle on the walker count as a phantom; the one on nothing does; the
    parked car is a still obstacle."""
    from ssf_common.render.counts import FrameCounts, judge_recording

    bag, track = open_track(judged_recording)
    with bag:
        judged = judge_recording(bag, track, RenderConfig())
    assert sorted(judged) == [k * DT_NS for k in range(JUDGED_SCANS)]
    for stamp, judgement in judged.items():
        assert judgement.counts == FrameCounts(stamp, true=2, perceived=3, matched=1, missed=1, phantoms=1, still=1)
        assert judgement.missed_ids == {2}
        np.testing.assert_allclose(judgement.phantom_centres, [PHANTOM_XY], atol=1e-6)
    # a stricter eye: with more points needed to count as seen, the cars (60 points each, some under the
    # ground clearance) are no longer seen, and nothing is missed
    bag, track = open_track(judged_recording)
    with bag:
        strict = judge_recording(bag, track, RenderConfig(seen_points=61))
    assert {j.counts.true for j in strict.values()} == {0} and {j.counts.phantoms for j in strict.values()} == {1}


def test_the_episode_picture_shows_the_counts_and_the_outcome_in_words(judged_recording, tmp_path):
    from ssf_common.render.counts import summary_line
    from ssf_common.render.draw import frame_title, outcome_words

    bag, track = open_track(judged_recording)
    with bag:
        frames = list(recording_frames(bag, track, RenderConfig()))
    assert outcome_words(track) == "duration reached at 0.4 s, still driving"
    assert outcome_words(replace(track, outcome_time_s=0.2)) == "stopped from outside at 0.4 s, still driving"
    assert outcome_words(replace(track, outcome="collision", outcome_time_s=0.3)) == "collision after 0.3 s"
    assert frames[-1].judged is None  # the recording_frames of `render_recording` get the judgements
    from ssf_common.render.counts import judge_recording

    bag, track = open_track(judged_recording)
    with bag:
        judged = judge_recording(bag, track, RenderConfig())
        frames = list(recording_frames(bag, track, RenderConfig(), judged=judged))
    assert "true moving agents seen 2: perceived 1, missed 1; phantoms 1; still obstacles 1" in frame_title(frames[-1], 0)
    assert summary_line([j.counts for j in judged.values()]) == (
        "50 % of 10 true moving agents seen by the LiDAR perceived, 5 missed; 1.0 phantoms and 1 still obstacles per "
        "scan (median) over 5 scans")
    summary = render_recording(judged_recording, picture=tmp_path / "episode.png")
    assert summary.picture == tmp_path / "episode.png"
    with Image.open(tmp_path / "episode.png") as picture:
        assert picture.width > picture.height  # the overview, the last moment and the fusion panel over the counts


def frames_of(recording: Path, **settings) -> list:
    bag, track = open_track(recording)
    with bag:
        return list(recording_frames(bag, track, RenderConfig(**settings)))


def test_every_layer_lands_where_the_world_has_it(recording):
    frames = frames_of(recording)
    assert [frame.stamp_ns for frame in frames] == [k * DT_NS for k in range(SCANS)]  # one frame per scan
    for k, frame in enumerate(frames):
        np.testing.assert_allclose(frame.ego_pose, ego_pose(k), atol=1e-9)
        segmented = k - k % 2
        truth = agents(segmented * DT_NS)  # the agents at the time of the points drawn: the newest segmentation's
        np.testing.assert_allclose(frame.agents.centres, truth.centres, atol=1e-9)
        # perceived obstacles: sensor frame -> world by the true pose at their stamp and the mount
        assert frame.labels is not None and len(frame.perceived) == 1
        np.testing.assert_allclose(frame.perceived.centres[0], agents(segmented * DT_NS).centres[0], atol=1e-6)
        np.testing.assert_allclose(frame.perceived.velocities[0], truth.velocities[0], atol=1e-6)
        # the segmented vehicle points lie in the true box of their scan's time
        vehicle = frame.points[frame.labels == 1]
        centre = agents(segmented * DT_NS).centres[0]
        assert len(vehicle) == 200 and np.abs(vehicle[:, :2] - centre[:2]).max() < 2.3
        # the plan and the odometry, odometry frame -> world: the plan starts at the ego, the odometry is the path
        np.testing.assert_allclose(frame.plan[0], ego_pose(k)[:2, 3], atol=1e-6)
        np.testing.assert_allclose(frame.path, np.array([ego_pose(i)[:2, 3] for i in range(k + 1)]), atol=1e-9)
        np.testing.assert_allclose(frame.odometry_path, frame.path, atol=1e-6)


def test_a_scan_without_a_recent_segmentation_is_drawn_raw(recording):
    frames = frames_of(recording, max_age_s=0.05, stride=1)
    assert [frame.labels is None for frame in frames] == [k % 2 == 1 for k in range(SCANS)]
    assert all(frame.perceived is None for frame in frames[1::2])
    windowed = frames_of(recording, start_s=0.3, duration_s=0.4, stride=2)
    assert [frame.stamp_ns for frame in windowed] == [3 * DT_NS, 5 * DT_NS, 7 * DT_NS]


def test_perceived_obstacles_are_drawn_only_when_seen(recording):
    import matplotlib.pyplot as plt

    frames = frames_of(recording)
    config = RenderConfig()

    def pixels(frame) -> np.ndarray:
        figure = plt.figure(figsize=(3.2, 3.2), dpi=100)
        draw_frame(figure.add_axes((0, 0, 1, 1)), frame, config, legend=False)
        figure.canvas.draw()
        image = np.asarray(figure.canvas.buffer_rgba())[..., :3].astype(int)
        plt.close(figure)
        return image

    plain = replace(frames[2], labels=np.zeros_like(frames[2].labels))  # no dynamic points drawn over the box
    with_obstacle, without = pixels(plain), pixels(replace(plain, perceived=None))
    changed = (with_obstacle != without).any(axis=-1)
    assert changed.sum() > 30  # the box and its arrow
    red, green, blue = (with_obstacle[changed] - without[changed]).T
    assert ((red > 20) & (red > blue)).mean() > 0.5  # a red box laid over the scene (the arrow is yellow)
    frame = FrameDrawer(RenderConfig(size_px=320))
    assert frame.draw(frames[2]).shape == (320, 320, 3)
    frame.close()


def test_recording_renders_a_gif_an_mp4_and_the_episode_picture(recording, tmp_path):
    summary = render_recording(recording, picture=tmp_path / "episode.png", video=tmp_path / "episode.gif",
                               config=RenderConfig(size_px=256))
    assert summary.frames == SCANS and abs(summary.seconds - (SCANS - 1) * 0.1) < 1e-9
    with Image.open(tmp_path / "episode.gif") as gif:
        assert gif.n_frames == SCANS and gif.size == (256, 256) and gif.info["duration"] == 100
    with Image.open(tmp_path / "episode.png") as picture:
        assert picture.width > picture.height  # overview, last moment and the fusion plot over the counts
    import imageio_ffmpeg

    render_recording(recording, video=tmp_path / "episode.mp4", config=RenderConfig(size_px=256, fps=5))
    reader = imageio_ffmpeg.read_frames(str(tmp_path / "episode.mp4"))
    meta = next(reader)
    assert meta["size"] == (256, 256) and meta["fps"] == 5 and sum(1 for _ in reader) == SCANS


def test_frames_held_in_memory_animate_too(recording, tmp_path):
    frames = frames_of(recording)[:4]
    assert write_video(iter(frames), tmp_path / "trial.gif", RenderConfig(size_px=192)) == 4
    with Image.open(tmp_path / "trial.gif") as gif:
        assert gif.n_frames == 4


@pytest.mark.parametrize("name", ["episode.avi", "episode"])
def test_a_video_name_that_says_no_format_is_refused_first(tmp_path, name):
    with pytest.raises(ConfigError, match="must end in .mp4 or .gif"):
        render_recording(tmp_path / "nothing", video=tmp_path / name)


def test_demo_refuses_a_video_it_cannot_write_before_starting(tmp_path, capsys):
    from ssf_bringup.cli import main

    assert main(["demo", "--out", str(tmp_path / "out"), "--video", str(tmp_path / "episode.avi")]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("ssf: error: --video ") and "must end in .mp4 or .gif" in line
    assert not (tmp_path / "out" / "recording").exists()


def test_render_command_draws_any_recording_with_settings(recording, tmp_path, capsys):
    import json

    from ssf_bringup.cli import main

    assert main(["render", str(recording), "--video", str(tmp_path / "a.gif"), "-p", "stride:=3",
                 "-p", "size_px:=160"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["frames"] == 4 and printed["video"] == str(tmp_path / "a.gif") and printed["picture"] is None
    assert main(["render", str(recording)]) == 2
    assert "nothing to draw" in capsys.readouterr().err
    assert main(["render", str(recording), "--picture", str(tmp_path / "p.png"), "-p", "stride:=0"]) == 2
    assert "stride" in capsys.readouterr().err
