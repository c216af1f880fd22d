"""The planner's one config model: horizon, models, limits, weights, obstacles, solver; the same dotted names in YAML,
ROS parameters (`-p horizon:=12`) and `ssf` flags."""

from __future__ import annotations

from enum import Enum
from typing import ClassVar

from pydantic import Field, model_validator

from ssf_common.config import Section


class Model(str, Enum):
    """Kinematic model of the ego vehicle."""

    UNICYCLE = "unicycle"  # controls: acceleration, yaw rate (a differential-drive or /cmd_vel car)
    BICYCLE = "bicycle"  # controls: acceleration, front-wheel steering angle (Ackermann)


class PlanTrigger(str, Enum):
    """Which message starts a plan."""

    SCAN = "scan"  # each scan's first answer (its obstacles, or its odometry if that comes first): the odometry off
    # the critical path; the pose is the newest odometry carried forward by the commands sent since
    ODOMETRY = "odometry"  # each /odom, with the newest obstacles (a replay's order: the same commands as the loop)


class VehicleConfig(Section):
    """Footprint and limits of the ego vehicle (the simulator's defaults)."""

    length: float = Field(4.69, gt=0.0, le=20.0, description="footprint length (m), centred on the state")
    width: float = Field(1.85, gt=0.0, le=5.0, description="footprint width (m)")
    wheelbase: float = Field(2.87, gt=0.0, le=10.0, description="bicycle model: axle distance (m)")
    max_speed: float = Field(12.0, gt=0.0, le=40.0, description="m/s")
    max_accel: float = Field(3.0, gt=0.0, le=20.0, description="m/s^2")
    max_decel: float = Field(6.0, gt=0.0, le=20.0, description="m/s^2 (positive)")
    max_yaw_rate: float = Field(1.0, gt=0.0, le=5.0, description="unicycle: rad/s")
    max_steer: float = Field(0.6, gt=0.0, le=1.2, description="bicycle: rad")
    max_lateral_accel: float = Field(6.0, gt=0.0, le=20.0, description="|v * yaw rate| bound (m/s^2)")


class WeightsConfig(Section):
    """Cost weights of the tracking problem (per horizon step)."""

    lateral: float = Field(1.0, ge=0.0, description="squared distance across the route (per m^2)")
    heading: float = Field(1.0, ge=0.0, description="squared heading error against the route (per rad^2)")
    speed: float = Field(1.0, ge=0.0, description="squared error of the speed along the route (v cos(heading error)) "
                         "against the reference (per (m/s)^2)")
    accel: float = Field(0.1, ge=0.0, description="squared acceleration")
    turn: float = Field(2.0, ge=0.0, description="squared yaw rate (unicycle) or steering angle (bicycle)")
    accel_rate: float = Field(0.1, ge=0.0, description="squared change of acceleration between steps")
    turn_rate: float = Field(10.0, ge=0.0, description="squared change of yaw rate / steering between steps")
    terminal: float = Field(3.0, ge=0.0, description="factor on the tracking terms of the last step")


class AvoidanceConfig(Section):
    """Which obstacles the problem sees and how far it keeps from them (RDA's min_sd / max_sd / slack_gain)."""

    max_obstacles: int = Field(10, ge=0, le=50, description="K: the obstacles nearest to the planned motion are used")
    max_considered: int = Field(200, ge=1, description="at most this many obstacles, the nearest to the car (a "
                                "linear-time selection), are considered at all; the rest are dropped and the drop said "
                                "in the log: a flood of obstacles cannot stretch a tick")
    range: float = Field(40.0, gt=0.0, description="obstacles farther than this from the ego are ignored (m)")
    safety_distance: float = Field(0.1, ge=0.0, description="hard: the footprints never come closer than this (m)")
    comfort_distance: float = Field(1.0, ge=0.0, description="soft: distance below which slack_gain is paid per metre")
    slack_gain: float = Field(30.0, ge=0.0, description="cost per metre of distance below comfort_distance, per step")
    headway: float = Field(0.8, ge=0.0, description="soft: extra distance (s x own speed towards the obstacle) kept "
                           "from what lies ahead, since it may stop at once")
    headway_band: float | None = Field(0.5, ge=0.0, description="the headway counts only for vehicles within this "
                                       "distance (m) of the strip the car sweeps along its heading, so a car in the "
                                       "next lane can be passed (people and unknown objects: always; null: every "
                                       "obstacle the car closes on)")
    static_speed: float = Field(0.01, ge=0.0, description="obstacles slower than this (m/s) are taken as static")
    latency_margin: float = Field(0.0, ge=0.0, description="each obstacle grows by this much (m) on every side per "
                                  "second of its age when the plan starts: where its constant velocity puts an object "
                                  "seen that long ago is uncertain (0: off; 1.0 delayed the real-time graph's "
                                  "collisions but blocked dense traffic, see the README)")

    @model_validator(mode="after")
    def _distances(self) -> AvoidanceConfig:
        if self.comfort_distance < self.safety_distance:
            raise ValueError(f"comfort_distance ({self.comfort_distance}) must be at least safety_distance "
                             f"({self.safety_distance})")
        return self


class PassingConfig(Section):
    """Passing slower traffic in the lane beside the route (map-free: that lane is an offset from the route)."""

    offset: float = Field(-3.5, description="lateral offset (m, left of the route positive) of the lane the car may pass "
                          "in (default: the outer of two 3.5 m lanes, as the corridor's default); 0: the car keeps to "
                          "the route")
    gain: float = Field(1.5, ge=0.0, description="how much faster (m/s) the traffic in that lane must let the car drive "
                        "than the traffic ahead on its own")
    look_ahead: float = Field(40.0, gt=0.0, description="traffic this far ahead (m along the route) sets a lane's speed")
    clear_behind: float = Field(10.0, ge=0.0, description="the lane moved into is free from beside the car to this far "
                                "behind its rear (m)")
    hold_s: float = Field(3.0, ge=0.0, description="a choice of lane is kept at least this long (s)")


class FailSafeConfig(Section):
    """When inputs are stale and how the car brakes then (parameters `failsafe.*`)."""

    renamed: ClassVar[dict[str, str]] = {"sensor_period": "scan_period"}
    scan_period: float = Field(0.1, gt=0.0, le=1.0, description="the LiDAR's period (s): odometry and obstacles "
                                 "come once per scan")
    stale_periods: float = Field(2.0, gt=0.0, description="an input older than this many sensor periods by the node's "
                                 "clock brakes the car")
    silent_after_s: float = Field(2.0, gt=0.0, description="an input silent this long by the steady clock brakes the "
                                  "car whatever the node's clock does (a stopped simulator, lockstep with a dead stage)")
    vanish_range: float = Field(20.0, ge=0.0, description="an empty obstacle array right after one holding an "
                                "obstacle within this distance (m) of the car is dropped as implausible (they cannot all "
                                "be gone in one scan; a picture empties only after one with nothing that near); 0: every "
                                "empty array is believed")

    frame_jump_m: float = Field(3.0, ge=0.0, description="odometry this far (m) from where the last pose, carried "
                                "forward by the commands sent since, puts the car started a new frame (a restarted "
                                "odometry node): it is placed there, so that the route keeps its frame; 0: never")

    @property
    def stale_after_s(self) -> float:
        """Age (node clock) past which an input is stale."""
        return self.stale_periods * self.scan_period


class SolverConfig(Section):
    """How each tick is solved: QP solver of the CasADi wheel, primal/dual rounds, deadline."""

    qp: str = Field("osqp", description="CasADi conic plugin: osqp | qrqp | highs | proxqp | daqp | qpoases")
    iterations: int = Field(2, ge=1, le=20, description="primal QP + dual update rounds per tick (RDA's iter_num)")
    tolerance: float = Field(0.2, gt=0.0, description="stop the rounds when the plan moves less than this (m)")
    deadline_ms: float = Field(100.0, ge=0.0, description="a tick slower than this (wall clock) is late: its plan is not "
                               "used; 0 = no deadline (lockstep simulation, where time waits for the planner)")


class PlannerConfig(Section):
    """Everything the MPC needs; the same dotted names in YAML, ROS parameters and CLI flags."""

    model: Model = Model.UNICYCLE
    horizon: int = Field(10, ge=2, le=60, description="steps in the horizon")
    dt: float = Field(0.2, gt=0.0, le=1.0, description="seconds per horizon step")
    control_period: float = Field(0.1, gt=0.0, le=1.0, description="seconds a command is applied (the tick period); "
                                  "while the clock runs, two periods with no plan plan again from the newest inputs "
                                  "carried forward (a scan the chain dropped does not leave the car without a command)")
    plan_on: PlanTrigger = Field(PlanTrigger.SCAN, description="what starts a plan: scan (each scan's first answer, "
                                 "obstacles or odometry, whichever comes first) or odometry (each /odom)")
    reference_speed: float = Field(10.0, gt=0.0, le=40.0, description="cruise speed along the route (m/s)")
    goal_decel: float = Field(1.5, gt=0.0, description="comfortable deceleration (m/s^2) for stopping at the goal")
    goal_tolerance: float = Field(3.0, gt=0.0, description="the route is done within this distance of its end (m)")
    corridor_left: float = Field(0.825, gt=0.0, description="the plan's centre stays within this distance left of the "
                                 "route (m) and ...")
    corridor_right: float = Field(4.325, gt=0.0, description="... right of it (m): the lanes of the route's direction, less "
                                  "half the car (default: the inner lane of two 3.5 m lanes, right-hand traffic, a 1.85 m "
                                  "car: the body keeps right of the centre line, off the oncoming lanes)")
    corridor_gain: float = Field(1000.0, gt=0.0, description="cost per metre and step outside the corridor: it is soft, "
                                 "so a car already outside it (a pose error, a swerve) steers back instead of braking")
    stale_speed: float = Field(2.0, ge=0.0, description="speed cap (m/s) while obstacles are stale")
    stale_after_s: float = Field(0.5, gt=0.0, description="obstacles older than this against the odometry cap the "
                                 "speed (a picture that old lags the pose; obstacles that stop coming brake the car: "
                                 "failsafe.*)")
    max_latency_s: float = Field(1.0, ge=0.0, description="odometry is carried forward to now by the commands sent "
                                 "since (latency compensation); older than this by the clock it caps the speed, and "
                                 "obstacles older than this are stale; 0: plan from its stamp")
    vehicle: VehicleConfig = VehicleConfig()
    weights: WeightsConfig = WeightsConfig()
    obstacles: AvoidanceConfig = AvoidanceConfig()
    passing: PassingConfig = PassingConfig()
    solver: SolverConfig = SolverConfig()
    failsafe: FailSafeConfig = FailSafeConfig()

    @model_validator(mode="after")
    def _speeds(self) -> PlannerConfig:
        if self.reference_speed > self.vehicle.max_speed:
            raise ValueError(f"reference_speed ({self.reference_speed}) is above vehicle.max_speed "
                             f"({self.vehicle.max_speed})")
        if self.control_period > self.dt * self.horizon:
            raise ValueError("control_period must be shorter than the horizon (dt * horizon)")
        return self
