"""Scenario files: validated config sections for the world, traffic, ego vehicle, LiDAR and episode."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import Field, model_validator

from ssf_common.config import Section, build, parse_overrides, read_yaml
from ssf_common.errors import ConfigError

SpeedRange = tuple[float, float]
MAX_GROUND_CELLS = 4_000_000  # the ground grid spans the route's bounding box: about 2 km x 2 km at 1 m


def _check_range(name: str, value: SpeedRange) -> None:
    low, high = value
    if not 0.0 <= low <= high:
        raise ValueError(f"{name} must be [min, max] with 0 <= min <= max, got {list(value)}")


class RouteConfig(Section):
    """Road centreline through the waypoints (rounded corners) and its cross-section."""

    waypoints: list[tuple[float, float]] = Field(
        default=[(0.0, 0.0), (330.0, 0.0), (330.0, 300.0), (700.0, 300.0)], min_length=2, max_length=64
    )
    corner_radius: float = Field(45.0, ge=20.0, le=500.0)
    extension: float = Field(40.0, ge=20.0, le=500.0)
    lanes_per_direction: int = Field(2, ge=1, le=4)
    lane_width: float = Field(3.5, ge=2.5, le=5.0)
    parking_width: float = Field(2.5, ge=2.2, le=5.0)
    sidewalk_width: float = Field(4.0, ge=2.0, le=10.0)
    crosswalk_spacing: float = Field(60.0, ge=20.0, le=1000.0)


class GroundConfig(Section):
    """Ground surface: gentle slopes plus small-scale roughness (never a perfect plane)."""

    slope_amplitude: float = Field(1.5, ge=0.0, le=20.0)
    slope_wavelength: float = Field(300.0, ge=50.0, le=10000.0)
    roughness: float = Field(0.03, ge=0.005, le=0.5)
    resolution: float = Field(1.0, ge=0.25, le=5.0)
    margin: float = Field(70.0, ge=20.0, le=500.0)


class StructureConfig(Section):
    """Static structure along the road: buildings, poles, trees, parked cars."""

    building_probability: float = Field(0.8, ge=0.0, le=1.0)
    building_length: SpeedRange = (12.0, 35.0)
    building_height: SpeedRange = (6.0, 30.0)
    pole_spacing: float = Field(35.0, ge=5.0, le=1000.0)
    tree_spacing: float = Field(18.0, ge=5.0, le=1000.0)
    parked_car_probability: float = Field(0.35, ge=0.0, le=1.0)

    @model_validator(mode="after")
    def _ranges(self) -> StructureConfig:
        _check_range("building_length", self.building_length)
        _check_range("building_height", self.building_height)
        return self


class AgentsConfig(Section):
    """Moving agents: how many, the vehicle share, speeds and avoidance settings."""

    count: int = Field(100, ge=0, le=5000)
    vehicle_fraction: float = Field(0.5, ge=0.0, le=1.0)
    vehicle_speed: SpeedRange = (3.0, 9.0)
    pedestrian_speed: SpeedRange = (0.8, 1.6)
    horizon: float = Field(1.5, gt=0.1, le=10.0)
    neighbour_radius: float = Field(7.0, ge=3.0, le=50.0)
    keep_clear_of_start: float = Field(25.0, ge=0.0, le=500.0)

    @model_validator(mode="after")
    def _ranges(self) -> AgentsConfig:
        _check_range("vehicle_speed", self.vehicle_speed)
        _check_range("pedestrian_speed", self.pedestrian_speed)
        if self.vehicle_speed[1] > 30.0 or self.pedestrian_speed[1] > 5.0:
            raise ValueError("speeds above 30 m/s (vehicles) or 5 m/s (pedestrians) are not supported")
        return self


class LidarConfig(Section):
    """Spinning LiDAR: beams, columns, vertical field of view, range, noise and dropout."""

    beams: int = Field(64, ge=1, le=256)
    columns: int = Field(1024, ge=16, le=8192)
    fov_down: float = Field(-24.9, ge=-90.0, le=0.0)
    fov_up: float = Field(2.0, ge=-30.0, le=90.0)
    max_range: float = Field(100.0, gt=1.0, le=500.0)
    min_range: float = Field(1.0, ge=0.0, le=10.0)
    range_noise: float = Field(0.01, ge=0.0, le=1.0)
    dropout: float = Field(0.0, ge=0.0, lt=1.0)
    mount_height: float = Field(1.8, ge=0.5, le=5.0)
    frame_id: str = "lidar"

    @model_validator(mode="after")
    def _fov(self) -> LidarConfig:
        if self.fov_up <= self.fov_down:
            raise ValueError(f"fov_up ({self.fov_up}) must be above fov_down ({self.fov_down})")
        return self


class EgoConfig(Section):
    """Ego vehicle: footprint, kinematic model and limits, reference speed for the built-in driver."""

    model: Literal["unicycle", "bicycle"] = "unicycle"
    length: float = Field(4.69, ge=1.0, le=20.0)
    width: float = Field(1.85, ge=0.5, le=4.0)
    height: float = Field(1.6, ge=0.5, le=5.0)
    wheelbase: float = Field(2.87, ge=0.5, le=10.0)
    max_speed: float = Field(12.0, gt=0.0, le=40.0)
    max_reverse_speed: float = Field(0.0, ge=0.0, le=10.0)
    max_accel: float = Field(3.0, gt=0.0, le=20.0)
    max_decel: float = Field(6.0, gt=0.0, le=20.0)
    max_yaw_rate: float = Field(1.0, gt=0.0, le=5.0)
    max_steer: float = Field(0.6, gt=0.0, le=1.2)
    reference_speed: float = Field(10.0, gt=0.0, le=40.0)
    lane: int = Field(0, ge=0, le=3)
    goal_tolerance: float = Field(3.0, gt=0.0, le=50.0)


class EpisodeConfig(Section):
    """Episode timing."""

    dt: float = Field(0.1, gt=0.0, le=1.0)
    time_limit: float = Field(300.0, gt=0.0, le=100000.0)


class Scenario(Section):
    """A complete simulator scenario, as read from one YAML file."""

    name: str = "custom"
    description: str = ""
    seed: int = Field(0, ge=0, le=2**32 - 1)
    route: RouteConfig = RouteConfig()
    ground: GroundConfig = GroundConfig()
    structure: StructureConfig = StructureConfig()
    agents: AgentsConfig = AgentsConfig()
    lidar: LidarConfig = LidarConfig()
    ego: EgoConfig = EgoConfig()
    episode: EpisodeConfig = EpisodeConfig()

    @model_validator(mode="after")
    def _route_fits(self) -> Scenario:
        points = self.route.waypoints
        for a, b in zip(points, points[1:]):
            if abs(a[0] - b[0]) + abs(a[1] - b[1]) < 1e-6:
                raise ValueError(f"route.waypoints has a repeated point {list(a)}")
        if self.ego.lane >= self.route.lanes_per_direction:
            raise ValueError(f"ego.lane {self.ego.lane} must be below route.lanes_per_direction")
        self._ground_fits()
        return self

    def _ground_fits(self) -> None:
        """The world's ground grid covers the route plus margins; refuse one too large to build."""
        route, ground = self.route, self.ground
        margin = ground.margin + route.extension + route.corner_radius + route.lanes_per_direction * route.lane_width
        margin += route.parking_width + route.sidewalk_width
        xs, ys = [p[0] for p in route.waypoints], [p[1] for p in route.waypoints]
        cells = ((max(xs) - min(xs) + 2 * margin) / ground.resolution) * ((max(ys) - min(ys) + 2 * margin) / ground.resolution)
        if cells > MAX_GROUND_CELLS:
            raise ValueError(
                f"route.waypoints span {max(xs) - min(xs):.0f} m x {max(ys) - min(ys):.0f} m: with the margins "
                f"that is a ground grid of {cells:.3g} cells at ground.resolution {ground.resolution:g} m, more than "
                f"{MAX_GROUND_CELLS}"
            )


def scenario_dir() -> Path:
    """The folder of the scenarios shipped with sim_bridge."""
    return Path(__file__).resolve().parent / "scenarios"


def scenario_names() -> list[str]:
    """Names of the shipped scenarios."""
    return sorted(path.stem for path in scenario_dir().glob("*.yaml"))


def load_scenario(name_or_path: str | Path, overrides: dict[str, Any] | None = None) -> Scenario:
    """Load a shipped scenario by name or a YAML file by path, plus dotted overrides."""
    path = Path(name_or_path)
    if not path.suffix:
        shipped = scenario_dir() / f"{name_or_path}.yaml"
        if not shipped.is_file():
            raise ConfigError(f"unknown scenario '{name_or_path}' (shipped: {', '.join(scenario_names())})")
        path = shipped
    layers = [read_yaml(path)]
    layers[0].setdefault("name", path.stem)
    return build(Scenario, *layers, overrides or {}, source=str(path))


def with_agents(scenario: Scenario, count: int) -> Scenario:
    """A copy of a scenario with another agent count."""
    return build(Scenario, scenario.model_dump(), {"agents.count": count}, source=scenario.name)


def overrides_from_pairs(pairs: list[str], flag: str = "-p") -> dict[str, Any]:
    """Dotted scenario settings from NAME:=VALUE (or NAME=VALUE) items, as `ssf sim -p` and the node take them."""
    return parse_overrides(pairs, flag)
