"""Small scenarios that keep the simulator tests fast."""

from __future__ import annotations

import pytest

from sim_bridge.scenario import Scenario, load_scenario

SHORT_ROUTE = {
    "route.waypoints": [[0.0, 0.0], [90.0, 0.0], [90.0, 70.0]],
    "route.corner_radius": 25.0,
    "route.crosswalk_spacing": 30.0,
    "ground.margin": 30.0,
}


def small(agents: int = 30, **overrides) -> Scenario:
    """A ~140 m route with a corner, agents as asked and a lighter LiDAR."""
    return load_scenario("urban_100", {**SHORT_ROUTE, "agents.count": agents, "lidar.columns": 512, **overrides})


@pytest.fixture(scope="session")
def small_scenario():
    """Factory of short-route scenarios: small_scenario(agents=30, **dotted_overrides)."""
    return small
