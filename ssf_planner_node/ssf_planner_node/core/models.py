"""Kinematic models of the ego vehicle: state (x, y, yaw, v), controls (acceleration, turn), their discretisation
(RK4 over one horizon step) as CasADi expressions, and the /cmd_vel command that realises a control."""

from __future__ import annotations

from typing import NamedTuple

import casadi as ca
import numpy as np

from ssf_planner_node.core.config import Model, PlannerConfig

STATE_SIZE = 4  # x, y, yaw, speed
CONTROL_SIZE = 2  # acceleration, yaw rate (unicycle) or steering angle (bicycle)


class Command(NamedTuple):
    """A /cmd_vel command: forward speed (m/s) and yaw rate (rad/s)."""

    linear: float
    angular: float


def derivative(model: Model, wheelbase: float, state: ca.SX, control: ca.SX) -> ca.SX:
    """d(state)/dt of the model (CasADi expressions)."""
    yaw, speed, accel, turn = state[2], state[3], control[0], control[1]
    yaw_rate = turn if model is Model.UNICYCLE else speed * ca.tan(turn) / wheelbase
    return ca.vertcat(speed * ca.cos(yaw), speed * ca.sin(yaw), yaw_rate, accel)


def discrete_step(config: PlannerConfig) -> ca.Function:
    """F(state, control) -> state after one horizon step dt (RK4, controls held)."""
    state, control = ca.SX.sym("x", STATE_SIZE), ca.SX.sym("u", CONTROL_SIZE)
    f = lambda x: derivative(config.model, config.vehicle.wheelbase, x, control)  # noqa: E731
    h = config.dt
    k1 = f(state)
    k2 = f(state + h / 2 * k1)
    k3 = f(state + h / 2 * k2)
    k4 = f(state + h * k3)
    return ca.Function("step", [state, control], [state + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)], ["x", "u"], ["next"])


def trajectory(step: ca.Function, horizon: int) -> ca.Function:
    """R(state, controls (2, H)) -> states (4, H+1): the step applied H times (one call for the whole horizon)."""
    steps = step.mapaccum("steps", horizon)
    state, controls = ca.SX.sym("x", STATE_SIZE), ca.SX.sym("U", CONTROL_SIZE, horizon)
    return ca.Function("rollout", [state, controls], [ca.horzcat(state, steps(state, controls))])


def rollout(trajectory_fn: ca.Function, state: np.ndarray, controls: np.ndarray) -> np.ndarray:
    """(H+1, 4) states from `state` under (H, 2) controls."""
    return np.asarray(trajectory_fn(np.asarray(state, dtype=np.float64), np.asarray(controls, dtype=np.float64).T)).T


def yaw_rate_of(config: PlannerConfig, speed: float, turn: float) -> float:
    """The yaw rate a control's turn input gives at a speed."""
    if config.model is Model.UNICYCLE:
        return float(turn)
    return float(speed * np.tan(turn) / config.vehicle.wheelbase)


def command_of(config: PlannerConfig, state: np.ndarray, control: np.ndarray) -> Command:
    """The /cmd_vel that applies `control` from `state` for one control period."""
    speed = float(np.clip(state[3] + control[0] * config.control_period, 0.0, config.vehicle.max_speed))
    return Command(speed, yaw_rate_of(config, speed, float(control[1])))


def turn_limit(config: PlannerConfig, speed: np.ndarray) -> np.ndarray:
    """Largest |turn input| per step: the model's limit, and the lateral-acceleration bound at that speed."""
    speed = np.maximum(np.abs(np.asarray(speed, dtype=np.float64)), 1e-3)
    lateral = config.vehicle.max_lateral_accel / speed
    if config.model is Model.UNICYCLE:
        return np.minimum(config.vehicle.max_yaw_rate, lateral)
    return np.minimum(config.vehicle.max_steer, np.arctan(lateral * config.vehicle.wheelbase / speed))
