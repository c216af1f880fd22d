"""LiDAR sensor models: datasheet beam layouts, scans per model, rates, rigs, and the sensor effects (range noise,
dropout, mixed points at depth edges) with their ground truth."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sim_bridge.agents import agent_mesh
from sim_bridge.lidar import MIXED_GAP, Lidar, ray_fan, raycasting_scene, soup_distance
from sim_bridge.meshes import TriangleSoup
from sim_bridge.node import SimBridgeNode
from sim_bridge.ros_messages import scan_cloud
from sim_bridge.scenario import load_scenario
from sim_bridge.sensors import SENSOR_MODELS, sensor_names
from sim_bridge.simulator import Simulator
from sim_bridge.sweep import Sweep
from ssf_common.errors import ConfigError
from ssf_common.geometry.se3 import transform_points
from ssf_common.pointcloud import cloud_to_array

# name: beams per sensor, lowest and highest elevation (deg), smallest and largest gap between beams (deg)
DATASHEETS = {
    "vlp16": (16, -15.0, 15.0, 2.0, 2.0),
    "vlp32c": (32, -25.0, 15.0, 0.333, 9.361),  # 0.33 deg around the horizon, -25 to -15.64 at the bottom
    "hdl64e": (64, -24.9, 2.0, 26.9 / 63, 26.9 / 63),
    "os1_128": (128, -22.5, 22.5, 45.0 / 127, 45.0 / 127),
    "roof_2x32": (32, -25.0, 15.0, 0.333, 9.361),
}


def elevations_of(directions: np.ndarray) -> np.ndarray:
    return np.degrees(np.arcsin(np.clip(directions[:, 2], -1.0, 1.0)))


@pytest.mark.parametrize("name", sensor_names())
def test_beam_layout_matches_the_datasheet(name):
    beams, low, high, smallest, largest = DATASHEETS[name]
    spec = load_scenario("empty", {"lidar.model": name}).lidar.spec()
    gaps = np.diff(spec.elevations)
    assert spec.beams == beams and len(np.unique(spec.elevations)) == beams
    assert spec.elevations[0] == pytest.approx(low) and spec.elevations[-1] == pytest.approx(high)
    assert gaps.min() == pytest.approx(smallest, abs=1e-3) and gaps.max() == pytest.approx(largest, abs=1e-3)
    fan = ray_fan(spec)
    assert len(fan.directions) == spec.rays == spec.sensors * beams * spec.columns
    first = fan.directions[: beams * spec.columns]  # the (first) sensor's own beams, ring by ring
    np.testing.assert_allclose(np.unique(np.round(elevations_of(first), 6)), np.round(spec.elevations, 6), atol=1e-4)
    np.testing.assert_array_equal(np.bincount(fan.ring), np.full(beams, spec.sensors * spec.columns))


def test_the_vlp32c_keeps_its_dense_band_around_the_horizon():
    elevations = np.asarray(SENSOR_MODELS["vlp32c"].elevations)
    band = elevations[(elevations >= -4.0) & (elevations <= 1.667)]
    assert len(band) == 18 and np.allclose(np.diff(band), 1 / 3, atol=2e-3)  # 18 of 32 beams 1/3 deg apart
    assert np.diff(elevations).max() > 9.0  # and a few far apart at the bottom


def test_the_roof_rig_has_two_origins_and_fifty_degrees_together():
    spec = load_scenario("empty", {"lidar.model": "roof_2x32"}).lidar.spec()
    fan = ray_fan(spec)
    assert spec.sensors == 2 and fan.sensor is not None and fan.origins is not None
    upper, lower = fan.sensor == 0, fan.sensor == 1
    np.testing.assert_allclose(np.unique(fan.origins[upper], axis=0), [[0.0, 0.0, 0.1]], atol=1e-7)
    np.testing.assert_allclose(np.unique(fan.origins[lower], axis=0), [[0.0, 0.0, -0.1]], atol=1e-7)
    up, down = elevations_of(fan.directions[upper]), elevations_of(fan.directions[lower])
    assert (up.min(), up.max()) == pytest.approx((-25.0, 15.0), abs=1e-4)
    assert (down.min(), down.max()) == pytest.approx((-15.0, 25.0), abs=1e-4)  # mounted upside down
    assert max(up.max(), down.max()) - min(up.min(), down.min()) == pytest.approx(50.0, abs=1e-4)


@pytest.mark.parametrize(("name", "rate", "columns"), [
    ("vlp16", 10, 1800), ("vlp16", 20, 900), ("vlp32c", 20, 900), ("hdl64e", 10, 1024), ("hdl64e", 20, 512),
    ("os1_128", 10, 1024), ("os1_128", 20, 1024), ("roof_2x32", 10, 1800),
])  # fmt: skip
def test_the_rate_sets_columns_sweep_time_and_the_simulator_step(name, rate, columns):
    scenario = load_scenario("empty", {"lidar.model": name, "lidar.rate_hz": rate, "lidar.rolling_shutter": True})
    spec = scenario.lidar.spec()
    assert spec.columns == columns and scenario.episode.dt == pytest.approx(1.0 / rate)
    fan = ray_fan(spec)
    assert fan.time.max() == 0.0 and fan.time.min() == pytest.approx(-(columns - 1) / columns / rate, rel=1e-5)
    steps = np.diff(np.sort(fan.column_time))
    np.testing.assert_allclose(steps, 1.0 / rate / columns, rtol=1e-3)  # one column every period / columns
    assert not ray_fan(load_scenario("empty", {"lidar.model": name, "lidar.rate_hz": rate}).lidar.spec()).time.any()


def test_rates_and_steps_that_do_not_fit_are_refused_in_one_line():
    for overrides, named in [
        ({"lidar.model": "os1_128", "lidar.rate_hz": 15}, "10 or 20 Hz"),
        ({"lidar.rate_hz": 20, "episode.dt": 0.1}, "disagree"),
        ({"lidar.model": "vlp64"}, "lidar.model 'vlp64'"),
        ({"lidar.rate_hz": 40}, "lidar.rate_hz"),
        ({"lidar.min_range": 5.0, "lidar.max_range": 4.0}, "lidar.min_range"),
    ]:
        with pytest.raises(ConfigError, match=named) as err:
            load_scenario("urban_100", overrides)
        assert "\n" not in str(err.value)
    assert load_scenario("empty", {"episode.dt": 0.05}).lidar.rate_hz == pytest.approx(20.0)


@pytest.fixture(scope="module")
def scans(small_scenario):
    """One frame of each sensor model on the short route, with moving agents around."""
    frames = {}
    for name in sensor_names():
        sim = Simulator(small_scenario(agents=40, **{"lidar.model": name, "lidar.columns": None,
                                                     "agents.keep_clear_of_start": 8.0}), seed=1)
        sim.reset()
        frames[name] = (sim, sim.step(sim.follower().command(sim.frame.base_pose, 0.0, sim.frame.agents,
                                                            sim.frame.status.outcome)))
    return frames


@pytest.mark.parametrize("name", sensor_names())
def test_a_scan_has_every_ring_and_a_plausible_point_count(scans, name):
    sim, frame = scans[name]
    spec, scan = sim.lidar.spec, frame.scan
    returned = len(scan) / spec.rays
    assert 0.55 < returned < 1.0  # the sky and the far field return nothing; the rest does
    per_sensor = [scan.ring] if scan.sensor is None else [scan.ring[scan.sensor == k] for k in range(spec.sensors)]
    for rings in per_sensor:
        assert np.array_equal(np.unique(rings), np.arange(spec.beams))
    assert not scan.time.any()  # an instant sweep: every point at the stamp
    assert (scan.instance > 0).sum() > 20  # agents are seen
    cloud = cloud_to_array(scan_cloud(scan, frame.stamp_ns))
    expected = ["x", "y", "z", "intensity", "ring", "time"] + (["sensor"] if spec.sensors > 1 else [])
    assert list(cloud.dtype.names) == expected
    np.testing.assert_array_equal(cloud["ring"], scan.ring)


def test_rig_points_lie_within_range_of_their_own_sensor(scans):
    sim, frame = scans["roof_2x32"]
    scan, spec = frame.scan, sim.lidar.spec
    assert set(np.unique(scan.sensor)) == {0, 1} and 40_000 < len(scan) < 120_000  # ~100 k points, as the real rig
    origins = np.array([mount.position for mount in spec.mounts])[scan.sensor]
    ranges = np.linalg.norm(scan.points - origins, axis=1)
    assert ranges.min() >= spec.min_range - 0.1 and ranges.max() <= spec.max_range + 0.1
    up = scan.points[scan.sensor == 1, 2] - origins[scan.sensor == 1, 2]
    assert (up > 0).mean() > 0.05  # the upside-down sensor sees above itself


@pytest.fixture(scope="module")
def street(small_scenario):
    """A static scene, a pose and a few agents' triangles to cast single sweeps against."""
    sim = Simulator(small_scenario(agents=40, **{"agents.keep_clear_of_start": 8.0, "lidar.columns": 1024}), seed=2)
    frame = sim.reset()
    return sim, frame.pose, agent_mesh(frame.agents, frame.pose[:2, 3], 100.0), frame.agents


def sweep(street, **overrides):
    sim, pose, _, agents = street
    cfg = sim.scenario.lidar.model_copy(update=overrides)
    return Lidar(cfg, sim.lidar.static).scan(Sweep.still(pose, agents, cfg.spec().period), np.random.default_rng(5))


def test_dropout_loses_that_share_of_returns(street):
    full, dropped = sweep(street, range_noise=0.0), sweep(street, range_noise=0.0, dropout=0.3)
    assert len(dropped) / len(full) == pytest.approx(0.7, abs=0.02)


def test_range_noise_has_the_model_sigma(street):
    clean, noisy = sweep(street, range_noise=0.0), sweep(street, range_noise=0.05)
    assert len(clean) == len(noisy)
    error = np.linalg.norm(noisy.points, axis=1) - np.linalg.norm(clean.points, axis=1)
    assert np.std(error) == pytest.approx(0.05, rel=0.05) and abs(np.mean(error)) < 0.005


def test_mixed_points_lie_between_the_two_surfaces_at_depth_edges(street):
    puck = {"model": "vlp16", "columns": None, "range_noise": 0.0}  # 3 mrad beams 3.5 mrad apart: many straddle
    clean, mixed = sweep(street, **puck), sweep(street, **puck, mixed_points=1.0)
    assert mixed.mixed is not None and clean.mixed is None
    flagged = np.flatnonzero(mixed.mixed)
    assert 0.002 < len(flagged) / len(mixed) < 0.1 and (mixed.instance[flagged] > 0).sum() > 10
    assert sweep(street, **puck, mixed_points=0.5).mixed.sum() == pytest.approx(len(flagged) / 2, rel=0.2)
    sim, pose, dynamic, _ = street
    off_beam = beam_offsets(TriangleSoup.merge([sim.lidar.static, dynamic]), pose, mixed.points)
    assert np.median(off_beam[flagged]) > 0.1  # short of, or beyond, the surface their own beam hits
    assert np.percentile(off_beam[flagged], 99) < MIXED_GAP[1]
    assert np.percentile(off_beam[~mixed.mixed], 99) < 1e-3


def beam_offsets(surfaces: TriangleSoup, pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """|range of each point - range at which the beam through it (from the sensor at pose) first hits a surface|."""
    import open3d as o3d

    ranges = np.linalg.norm(points, axis=1)
    rays = np.concatenate([np.broadcast_to(pose[:3, 3], points.shape), (points / ranges[:, None]) @ pose[:3, :3].T], 1)
    hits = raycasting_scene(surfaces).cast_rays(o3d.core.Tensor(rays.astype(np.float32)))["t_hit"].numpy()
    return np.abs(hits - ranges)


def test_mixed_points_move_rigidly_with_the_surface_nearer_along_their_beam(small_scenario):
    """Ground truth of a mixed point: the class, instance and rigid motion of the nearer surface, so its flow keeps
    its distance to that surface from one sweep to the next."""
    sim = Simulator(small_scenario(agents=60, **{"lidar.range_noise": 0.0, "lidar.mixed_points": 1.0,
                                                 "agents.keep_clear_of_start": 8.0}), seed=3)
    frame = sim.reset()
    driver = sim.follower()
    for _ in range(15):
        frame = sim.step(driver.command(frame.base_pose, frame.ego.speed, frame.agents, frame.status.outcome))
    following = sim.step(driver.command(frame.base_pose, frame.ego.speed, frame.agents, frame.status.outcome))
    mixed = np.flatnonzero(frame.scan.mixed)
    points = frame.scan.points[mixed].astype(np.float64)
    instance = frame.scan.instance[mixed]
    landed = points + following.flow.flow[mixed]
    checked = 0
    for k in np.unique(instance):
        mine = instance == k
        if k == 0:
            before = after = sim.lidar.static
        else:
            before = sim.agent_surfaces(frame.agents.take(np.array([k - 1])))
            after = sim.agent_surfaces(following.agents.take(np.array([k - 1])))
        at_t = soup_distance(before, transform_points(frame.pose, points[mine]))
        at_next = soup_distance(after, transform_points(following.pose, landed[mine]))
        np.testing.assert_allclose(at_next, at_t, atol=2e-3)
        checked += int(mine.sum())
    moving = following.flow.dynamic[mixed]
    assert checked == len(mixed) > 100 and moving.sum() > 5
    labels = frame.scan.label[mixed]
    assert set(np.unique(labels[instance > 0])) <= {5, 6} and not (labels[instance == 0] >= 5).any()


def test_the_default_sensor_is_todays_64_beam_sweep():
    scenario = load_scenario("urban_100")
    spec = scenario.lidar.spec()
    assert (spec.model, spec.beams, spec.columns, spec.max_range, spec.range_noise) == ("hdl64e", 64, 1024, 100.0, 0.01)
    np.testing.assert_array_equal(spec.elevations, np.linspace(-24.9, 2.0, 64))
    assert scenario.episode.dt == 0.1 and spec.dropout == 0.0 and spec.mixed_points == 0.0


def test_the_node_takes_scenario_settings_as_parameters():
    small = ["route.waypoints=[[0,0],[60,0]]", "ground.margin=30", "agents.count=0"]
    node = SimBridgeNode(argv=["--ros-args", "-p", "scenario:=empty", "-p", f"overrides:={json.dumps(small)}",
                               "-p", "lidar.model:=vlp16", "-p", "lidar.rate_hz:=20", "-p", "markers:=false"])
    try:
        assert node.sim.lidar.spec.model == "vlp16" and node.sim.lidar.spec.columns == 900 and node.sim.dt == 0.05
    finally:
        node.destroy_node()


def test_bench_sim_times_the_sensor_it_is_given():
    from sim_bridge.bench import measure

    short = {"route.waypoints": [[0, 0], [60, 0]], "ground.margin": 30}
    row = measure("empty", 0, 2, 0, 0, {**short, "lidar.model": "vlp16"})
    assert row.steps == 2 and row.step_ms_median > 0 and 10_000 < row.points_median <= 16 * 1800
