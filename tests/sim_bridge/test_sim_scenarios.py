"""Scenario files: every shipped one loads, bad ones fail with one line naming the field."""

from __future__ import annotations

import numpy as np
import pytest

from sim_bridge.scenario import load_scenario, scenario_names
from sim_bridge.traffic import Traffic
from sim_bridge.world import World
from ssf_common.errors import ConfigError

SHIPPED = ["empty", "sparse_50", "urban_100", "urban_200", "dense_500", "dense_800", "crowd_1000"]


def test_every_required_scenario_is_shipped_and_valid():
    assert set(SHIPPED) <= set(scenario_names())
    counts = {name: load_scenario(name).agents.count for name in SHIPPED}
    assert counts == {
        "empty": 0,
        "sparse_50": 50,
        "urban_100": 100,
        "urban_200": 200,
        "dense_500": 500,
        "dense_800": 800,
        "crowd_1000": 1000,
    }


def test_default_route_is_about_one_kilometre():
    world = World(load_scenario("empty"), 0)
    assert 900 < world.route_length < 1100


@pytest.mark.parametrize(
    ("overrides", "named"),
    [
        ({"agents.count": -1}, "agents.count"),
        ({"agents.vehicle_speed": [9.0, 3.0]}, "vehicle_speed"),
        ({"lidar.beams": 0}, "lidar.beams"),
        ({"lidar.fov_up": -30.0}, "fov_up"),
        ({"ego.max_speed": "fast"}, "ego.max_speed"),
        ({"agents.colour": "red"}, "agents.colour"),
        ({"route.waypoints": [[0, 0]]}, "route.waypoints"),
        ({"ego.lane": 3}, "ego.lane"),
    ],
)
def test_bad_fields_are_named(overrides, named):
    with pytest.raises(ConfigError) as err:
        load_scenario("urban_100", overrides)
    message = str(err.value)
    assert named in message and "\n" not in message


def test_bad_yaml_and_unknown_names_fail_cleanly(tmp_path):
    broken = tmp_path / "broken.yaml"
    broken.write_text("agents: [1, 2\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_scenario(broken)
    with pytest.raises(ConfigError, match="unknown scenario 'nope'"):
        load_scenario("nope")
    listed = tmp_path / "list.yaml"
    listed.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="expected a mapping"):
        load_scenario(listed)


def test_route_too_tight_for_its_corners_is_reported():
    scenario = load_scenario("empty", {"route.waypoints": [[0, 0], [30, 0], [30, 30]], "route.corner_radius": 45.0})
    with pytest.raises(ConfigError, match="route.corner_radius"):
        World(scenario, 0)


def test_scenario_too_dense_to_spawn_is_reported():
    scenario = load_scenario(
        "empty", {"route.waypoints": [[0, 0], [60, 0]], "agents.count": 400, "agents.vehicle_fraction": 1.0}
    )
    world = World(scenario, 0)
    with pytest.raises(ConfigError, match="agents.count"):
        Traffic(world, scenario.agents, np.random.default_rng(0), np.zeros(2))
