"""Scenario files: validated config sections for the world, traffic, ego vehicle, LiDAR and episode."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field, model_validator

from sim_bridge.sensors import SENSOR_MODELS, SensorSpec
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
    lane_speeds: list[SpeedRange] = Field(default_factory=list, max_length=4, description="preferred speed range of "
                                          "the vehicles in each lane (0 = innermost); lanes not listed use vehicle_speed")
    ego_yield: float = Field(1.0, ge=0.0, le=1.0, description="share of the excess closing speed an agent takes "
                             "against the ego: 1 all of it (the ego never has to give way), 0.5 half (as between "
                             "agents: reciprocal), 0 none (agents keep their way and the ego must give way); agents "
                             "never step into the ego whatever the share")
    crossing_share: float = Field(0.25, ge=0.0, le=1.0, description="share of pedestrians whose walk crosses the road")

    @model_validator(mode="after")
    def _ranges(self) -> AgentsConfig:
        _check_range("vehicle_speed", self.vehicle_speed)
        _check_range("pedestrian_speed", self.pedestrian_speed)
        for lane, speeds in enumerate(self.lane_speeds):
            _check_range(f"lane_speeds[{lane}]", speeds)
        if max([self.vehicle_speed[1], *(high for _, high in self.lane_speeds)]) > 30.0 or self.pedestrian_speed[1] > 5.0:
            raise ValueError("speeds above 30 m/s (vehicles) or 5 m/s (pedestrians) are not supported")
        return self


class LidarConfig(Section):
    """The LiDAR: a datasheet model (`model`), its rotation rate, and overrides of any of the model's numbers.

    Fields left null take the model's value. Setting beams, fov_down or fov_up replaces the model's elevation table
    by that many beams spread evenly between fov_down and fov_up (the model's count and limits where not set).
    """

    model: str = Field("hdl64e", description="hdl64e | vlp16 | vlp32c | os1_128 | roof_2x32")
    rate_hz: float = Field(10.0, ge=5.0, le=20.0, description="revolutions per second; one simulator step per sweep")
    beams: int | None = Field(None, ge=1, le=256)
    columns: int | None = Field(None, ge=16, le=8192, description="firings per beam and revolution")
    fov_down: float | None = Field(None, ge=-90.0, le=0.0)
    fov_up: float | None = Field(None, ge=-30.0, le=90.0)
    max_range: float | None = Field(None, gt=1.0, le=500.0)
    min_range: float | None = Field(None, ge=0.0, le=10.0)
    range_noise: float | None = Field(None, ge=0.0, le=1.0, description="Gaussian range error, sigma (m)")
    dropout: float = Field(0.0, ge=0.0, lt=1.0, description="probability of losing a return")
    mixed_points: float = Field(0.0, ge=0.0, le=1.0, description="probability that a beam whose footprint straddles "
                                "a depth edge returns one merged echo: a point between the two surfaces")
    mount_height: float = Field(1.8, ge=0.5, le=5.0)
    rolling_shutter: bool = Field(False, description="each column fires at its own time within the sweep, from where "
                                  "the ego is then, at the agents where they are then (the stamp marks the sweep's "
                                  "end; `time` per point, s, <= 0); false: the whole sweep at the stamp (time 0)")
    frame_id: str = "lidar"

    @model_validator(mode="after")
    def _consistent(self) -> LidarConfig:
        if self.model not in SENSOR_MODELS:
            raise ValueError(f"lidar.model '{self.model}' is not a sensor model; choose one of {', '.join(SENSOR_MODELS)}")
        model = SENSOR_MODELS[self.model]
        if not model.allows_rate(self.rate_hz):
            raise ValueError(f"lidar.rate_hz {self.rate_hz:g}: the {self.model} spins at {model.rates_text()}")
        spec = self.spec()
        if spec.elevations[-1] <= spec.elevations[0] and spec.beams > 1:
            raise ValueError(f"fov_up ({spec.elevations[-1]:g}) must be above fov_down ({spec.elevations[0]:g})")
        if spec.min_range >= spec.max_range:
            raise ValueError(f"lidar.min_range ({spec.min_range:g}) must be below lidar.max_range ({spec.max_range:g})")
        return self

    def spec(self) -> SensorSpec:
        """The effective sensor: the model's datasheet values with this section's overrides."""
        model = SENSOR_MODELS[self.model]
        elevations = np.asarray(model.elevations, np.float64)
        if self.beams is not None or self.fov_down is not None or self.fov_up is not None:
            low = elevations[0] if self.fov_down is None else self.fov_down
            high = elevations[-1] if self.fov_up is None else self.fov_up
            elevations = np.linspace(low, high, len(elevations) if self.beams is None else self.beams)
        return SensorSpec(
            model=self.model,
            elevations=elevations,
            columns=model.columns_at(self.rate_hz) if self.columns is None else self.columns,
            rate_hz=self.rate_hz,
            min_range=model.min_range if self.min_range is None else self.min_range,
            max_range=model.max_range if self.max_range is None else self.max_range,
            range_noise=model.range_noise if self.range_noise is None else self.range_noise,
            dropout=self.dropout,
            mixed_points=self.mixed_points,
            divergence_mrad=model.divergence_mrad,
            mounts=model.mounts,
            rolling_shutter=self.rolling_shutter,
        )


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
    reference_speed: float = Field(10.0, ge=0.0, le=40.0, description="the route follower's speed; 0 holds the ego still")
    lane: int = Field(0, ge=0, le=3)
    lane_changes: bool = Field(True, description="the route follower may change to a faster right-hand lane")
    goal_tolerance: float = Field(3.0, gt=0.0, le=50.0)
    start_s: float = Field(0.0, ge=-400.0, le=5000.0, description="start along the route (m from its first waypoint)")
    start_offset: float | None = Field(None, ge=-50.0, le=50.0, description="start left of the centreline (m); "
                                       "null: the centre of `lane`")
    start_heading: float = Field(0.0, ge=-180.0, le=180.0, description="start heading relative to the road (deg)")


class OdometerConfig(Section):
    """The ego's own motion sensors, as a car's bus reports them once per step: the wheel speed (encoder ticks over
    the step) and a yaw-rate gyro, each with a per-episode error drawn once and noise on every sample."""

    speed_scale: float = Field(0.01, ge=0.0, le=0.2, description="sigma of the per-episode wheel-speed scale error "
                               "(tyre radius, load), relative")
    speed_noise: float = Field(0.05, ge=0.0, le=2.0, description="sigma of each sample's speed noise (m/s)")
    yaw_rate_bias: float = Field(0.002, ge=0.0, le=0.1, description="sigma of the per-episode gyro bias (rad/s)")
    yaw_rate_noise: float = Field(0.003, ge=0.0, le=0.1, description="sigma of each sample's yaw-rate noise (rad/s)")


class EpisodeConfig(Section):
    """Episode timing: one step per LiDAR sweep, so dt is the sweep period (1 / lidar.rate_hz)."""

    dt: float = Field(0.1, ge=0.05, le=0.2, description="seconds per step = per sweep; follows lidar.rate_hz")
    time_limit: float = Field(300.0, gt=0.0, le=100000.0)
    warmup_s: float = Field(2.0, ge=0.0, le=600.0, description="simulated seconds before evaluation pairs are cut "
                            "(the traffic starts from rest)")


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
    odometer: OdometerConfig = OdometerConfig()
    episode: EpisodeConfig = EpisodeConfig()

    @model_validator(mode="before")
    @classmethod
    def _one_step_per_sweep(cls, data: Any) -> Any:
        """The sweep period sets the step: dt follows lidar.rate_hz (or, given alone, sets it); both must agree."""
        if not isinstance(data, dict):
            return data
        lidar, episode = data.get("lidar") or {}, data.get("episode") or {}
        rate, dt = _field(lidar, "rate_hz"), _field(episode, "dt")
        if rate is None and dt is None:
            return data
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0 for v in (rate, dt) if v is not None):
            return data  # the fields' own validation names the bad value
        if dt is None:
            return {**data, "episode": _with_field(episode, "dt", 1.0 / rate)}
        if rate is None:
            return {**data, "lidar": _with_field(lidar, "rate_hz", 1.0 / dt)}
        if abs(rate * dt - 1.0) > 1e-6:
            raise ValueError(f"episode.dt {dt:g} s and lidar.rate_hz {rate:g} disagree: the simulator steps once per "
                             "sweep, so set one of them")
        return data

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


def _field(section: Any, name: str) -> Any:
    """A field of a section given as a dict or a model (None when absent)."""
    return section.get(name) if isinstance(section, dict) else getattr(section, name, None)


def _with_field(section: Any, name: str, value: float) -> Any:
    """A copy of a section (dict or model) with one field set."""
    if isinstance(section, dict):
        return {**section, name: value}
    return {**section.model_dump(), name: value}


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
