"""Ego kinematics: limits on speed, acceleration and turn rate; unicycle and kinematic bicycle."""

from __future__ import annotations

import numpy as np
import pytest

from sim_bridge.ego import EgoState, EgoVehicle, VelocityCommand
from sim_bridge.world import World


@pytest.fixture(scope="module")
def world(small_scenario):
    return World(small_scenario(agents=0), 0)


def drive(world, commands, model="unicycle", start_speed=0.0):
    cfg = world.scenario.ego.model_copy(update={"model": model})
    ego = EgoVehicle(cfg, world.ground, EgoState(0.0, -1.75, 0.0, start_speed, 0.0))
    for command in commands:
        ego.apply(command, 0.1)
    return ego


def test_acceleration_speed_and_turn_rate_are_limited(world):
    cfg = world.scenario.ego
    assert drive(world, [VelocityCommand(50.0, 0.0)]).state.speed == pytest.approx(cfg.max_accel * 0.1)
    assert drive(world, [VelocityCommand(50.0, 0.0)] * 100).state.speed == pytest.approx(cfg.max_speed)
    braking = drive(world, [VelocityCommand(0.0, 0.0)], start_speed=10.0)
    assert braking.state.speed == pytest.approx(10.0 - cfg.max_decel * 0.1)
    turning = drive(world, [VelocityCommand(5.0, 9.0)] * 5)
    assert turning.state.yaw_rate == pytest.approx(cfg.max_yaw_rate)
    assert drive(world, [VelocityCommand(-3.0, 0.0)] * 5).state.speed == 0.0  # no reverse by default
    assert drive(world, [VelocityCommand(float("nan"), float("inf"))]).state.speed == 0.0


def test_unicycle_turns_in_place_but_bicycle_cannot(world):
    spin = drive(world, [VelocityCommand(0.0, 0.5)] * 10)
    assert spin.state.yaw == pytest.approx(0.5) and spin.state.x == pytest.approx(0.0)
    car = drive(world, [VelocityCommand(0.0, 0.5)] * 10, model="bicycle")
    assert car.state.yaw == pytest.approx(0.0)
    moving = drive(world, [VelocityCommand(8.0, 0.3)] * 20, model="bicycle", start_speed=8.0)
    assert 0.0 < moving.state.yaw <= 20 * 0.1 * 0.3 + 1e-9


def test_circle_is_integrated_exactly(world):
    ego = drive(world, [VelocityCommand(5.0, 0.5)] * 10, start_speed=5.0)
    radius = 5.0 / 0.5
    assert ego.state.x == pytest.approx(radius * np.sin(0.5))
    assert ego.state.y == pytest.approx(-1.75 + radius * (1 - np.cos(0.5)))


def test_base_pose_sits_on_the_ground_and_follows_the_slope(world):
    ego = drive(world, [VelocityCommand(5.0, 0.0)] * 30)
    pose = ego.base_pose()
    assert pose[2, 3] == pytest.approx(float(world.ground.height(np.array(ego.state.x), np.array(ego.state.y))))
    np.testing.assert_allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-12)
    gradient = world.ground.slope_gradient(np.array(ego.state.x), np.array(ego.state.y))
    assert pose[2, 0] == pytest.approx(gradient[0] / np.sqrt(1 + gradient[0] ** 2), abs=1e-3)
