"""The ego vehicle: unicycle (or kinematic bicycle) with speed, acceleration and turn-rate limits."""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from sim_bridge.footprints import Rectangles
from sim_bridge.scenario import EgoConfig
from sim_bridge.world import Ground


@dataclass(frozen=True)
class VelocityCommand:
    """A /cmd_vel command: forward speed (m/s) and yaw rate (rad/s) in the base frame."""

    linear: float = 0.0
    angular: float = 0.0


class Outcome(IntEnum):
    """How an episode ended, numbered like ssf_interfaces/EpisodeResult OUTCOME_*."""

    RUNNING = 0
    SUCCESS = 1
    COLLISION = 2
    TIMEOUT = 3


@dataclass(frozen=True)
class EgoState:
    """Planar ego state: position, heading, forward speed and yaw rate."""

    x: float
    y: float
    yaw: float
    speed: float
    yaw_rate: float


class EgoVehicle:
    """Integrates velocity commands under the configured limits."""

    def __init__(self, cfg: EgoConfig, ground: Ground, start: EgoState):
        self.cfg = cfg
        self.ground = ground
        self.state = start

    def apply(self, cmd: VelocityCommand, dt: float) -> None:
        """Advance by dt under a command, respecting speed, acceleration and turn limits."""
        cfg, state = self.cfg, self.state
        target = float(np.clip(cmd.linear, -cfg.max_reverse_speed, cfg.max_speed)) if np.isfinite(cmd.linear) else 0.0
        slowing = abs(target) < abs(state.speed) or target * state.speed < 0
        limit = (cfg.max_decel if slowing else cfg.max_accel) * dt
        speed = state.speed + float(np.clip(target - state.speed, -limit, limit))
        requested = float(cmd.angular) if np.isfinite(cmd.angular) else 0.0
        if cfg.model == "bicycle":
            steer = np.arctan2(requested * cfg.wheelbase, max(abs(speed), 1e-3)) * np.sign(speed or 1.0)
            requested = speed * np.tan(np.clip(steer, -cfg.max_steer, cfg.max_steer)) / cfg.wheelbase
        yaw_rate = float(np.clip(requested, -cfg.max_yaw_rate, cfg.max_yaw_rate))
        self.state = _integrate(state, speed, yaw_rate, dt)

    def stop(self) -> None:
        """Stop at once (after a collision or at the end of an episode)."""
        self.state = EgoState(self.state.x, self.state.y, self.state.yaw, 0.0, 0.0)

    def footprint(self) -> Rectangles:
        """The ego's rectangle on the ground."""
        s = self.state
        return Rectangles(
            np.array([[s.x, s.y]]), np.array([s.yaw]), np.array([self.cfg.length]), np.array([self.cfg.width])
        )

    def base_pose(self) -> np.ndarray:
        """World <- base_link: on the ground, pitched and rolled with the smooth slope."""
        s = self.state
        gradient = self.ground.slope_gradient(np.array(s.x), np.array(s.y))
        up = np.array([-gradient[0], -gradient[1], 1.0])
        up /= np.linalg.norm(up)
        heading = np.array([np.cos(s.yaw), np.sin(s.yaw), 0.0])
        forward = heading - (heading @ up) * up
        forward /= np.linalg.norm(forward)
        pose = np.eye(4)
        pose[:3, 0], pose[:3, 1], pose[:3, 2] = forward, np.cross(up, forward), up
        pose[:3, 3] = [s.x, s.y, float(self.ground.height(np.array(s.x), np.array(s.y)))]
        return pose


def _integrate(state: EgoState, speed: float, yaw_rate: float, dt: float) -> EgoState:
    """Exact unicycle motion at constant speed and yaw rate over dt."""
    yaw = state.yaw + yaw_rate * dt
    if abs(yaw_rate) > 1e-9:
        x = state.x + speed / yaw_rate * (np.sin(yaw) - np.sin(state.yaw))
        y = state.y - speed / yaw_rate * (np.cos(yaw) - np.cos(state.yaw))
    else:
        x = state.x + speed * dt * np.cos(state.yaw)
        y = state.y + speed * dt * np.sin(state.yaw)
    return EgoState(float(x), float(y), float(np.angle(np.exp(1j * yaw))), speed, yaw_rate)
