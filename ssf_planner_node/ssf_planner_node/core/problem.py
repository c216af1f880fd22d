"""The primal problem of one tick, built once as a parametric CasADi QP and only re-solved: kinematics linearised
along a nominal trajectory, route tracking at the reference speed (the speed along the route) within a corridor along the route (the road it
runs on), and per obstacle and step a distance bound that
is linear for fixed dual directions (hard at the safety distance, soft up to the comfort distance plus headway)."""

from __future__ import annotations

from typing import NamedTuple

import casadi as ca
import numpy as np

from ssf_common.errors import ConfigError
from ssf_planner_node.core.avoidance import BINDING_CORNERS
from ssf_planner_node.core.config import PlannerConfig
from ssf_planner_node.core.models import CONTROL_SIZE, STATE_SIZE, discrete_step, turn_limit

QP_SOLVERS = ("osqp", "qrqp", "highs", "proxqp", "daqp", "qpoases")
QUIET = {
    # tolerances of 1e-3 m, then polishing on the active set the ADMM iterations found: exact where it succeeds
    "osqp": {"osqp": {"verbose": False, "eps_abs": 1e-3, "eps_rel": 1e-3, "max_iter": 4000, "polish": True}},
    "qrqp": {"print_iter": False, "print_header": False, "print_info": False},
    "highs": {"highs": {"output_flag": False}},
    "proxqp": {"proxqp": {"max_iter": 2000}},
    "daqp": {},
    "qpoases": {"printLevel": "none"},
}


class Reference(NamedTuple):
    """What the plan tracks at steps 1..H: points (H, 2) on the route, moved `offset` (m) along its normals (H, 2) when
    the car passes in the lane beside it, headings (H,), speeds (H,)."""

    points: np.ndarray
    normals: np.ndarray
    headings: np.ndarray
    speeds: np.ndarray
    offset: float = 0.0


class Solution(NamedTuple):
    """A solved primal problem: states (H+1, 4), controls (H, 2), slack (H, K), solver success and its status."""

    states: np.ndarray
    controls: np.ndarray
    slack: np.ndarray
    success: bool
    status: str


def progress(state: ca.SX, nominal: ca.SX, heading: ca.SX) -> ca.SX:
    """Speed along the route, v cos(yaw - route heading), linearised at the nominal state (linear in the state):
    speed the wrong way along the route counts against the reference speed, so turning round never pays."""
    error = nominal[2] - heading
    return ca.cos(error) * state[3] - nominal[3] * ca.sin(error) * (state[2] - nominal[2])


class TrackingProblem:
    """min tracking + effort + smoothness + slack_gain * slack + corridor_gain * outside, s.t. linearised kinematics,
    limits, the corridor widened by outside >= 0 (a car already outside it steers back instead of finding no plan),
    and n . p_k + e_k >= c_k + comfort with 0 <= e_k <= comfort - safety (for each obstacle slot and step: at the
    planned heading, and for each binding footprint corner with its heading term, so that turning may cost distance
    but never buys it)."""

    def __init__(self, config: PlannerConfig) -> None:
        if config.solver.qp not in QP_SOLVERS:
            raise ConfigError(f"solver.qp '{config.solver.qp}' is not one of {', '.join(QP_SOLVERS)}")
        if not ca.has_conic(config.solver.qp):
            raise ConfigError(f"solver.qp '{config.solver.qp}' is not in this CasADi build")
        self.config = config
        self.horizon, self.slots = config.horizon, config.obstacles.max_obstacles
        self.step = discrete_step(config)
        self._build()

    def _build(self) -> None:
        cfg, horizon, slots = self.config, self.horizon, self.slots
        w = cfg.weights
        states = ca.SX.sym("X", STATE_SIZE, horizon + 1)
        controls = ca.SX.sym("U", CONTROL_SIZE, horizon)
        slack = ca.SX.sym("E", slots, horizon)
        outside = ca.SX.sym("O", 1, horizon)  # how far each step lies outside the corridor (soft: never infeasible)
        # parameters: start state, nominal trajectory, reference, previous control, dual directions
        start = ca.SX.sym("x0", STATE_SIZE)
        nominal_x = ca.SX.sym("Xbar", STATE_SIZE, horizon + 1)
        nominal_u = ca.SX.sym("Ubar", CONTROL_SIZE, horizon)
        ref_points = ca.SX.sym("r", 2, horizon)
        ref_normals = ca.SX.sym("rn", 2, horizon)
        ref_headings = ca.SX.sym("rh", 1, horizon)
        ref_speeds = ca.SX.sym("rv", 1, horizon)
        previous = ca.SX.sym("u_prev", CONTROL_SIZE)
        normals_x = ca.SX.sym("nx", slots, horizon)
        normals_y = ca.SX.sym("ny", slots, horizon)
        yaw_gains = [ca.SX.sym(f"g{c}", slots, horizon) for c in range(BINDING_CORNERS)]
        offsets = [ca.SX.sym(f"c{c}", slots, horizon) for c in range(BINDING_CORNERS)]

        x_bar, u_bar = ca.SX.sym("xb", STATE_SIZE), ca.SX.sym("ub", CONTROL_SIZE)
        next_bar = self.step(x_bar, u_bar)
        linear = ca.Function("linear", [x_bar, u_bar], [next_bar, ca.jacobian(next_bar, x_bar), ca.jacobian(next_bar, u_bar)])

        constraints = [states[:, 0] - start]
        corridor = []
        cost = 0
        for k in range(horizon):
            f, a, b = linear(nominal_x[:, k], nominal_u[:, k])
            constraints.append(states[:, k + 1] - (f + a @ (states[:, k] - nominal_x[:, k]) + b @ (controls[:, k] - nominal_u[:, k])))
            factor = w.terminal if k == horizon - 1 else 1.0
            position = states[:2, k + 1]
            lateral = ca.dot(ref_normals[:, k], position - ref_points[:, k])
            corridor += [lateral + outside[0, k], lateral - outside[0, k]]
            cost += factor * (w.lateral * lateral ** 2 + w.heading * (states[2, k + 1] - ref_headings[0, k]) ** 2
                              + w.speed * (progress(states[:, k + 1], nominal_x[:, k + 1], ref_headings[0, k])
                                           - ref_speeds[0, k]) ** 2)
            cost += w.accel * controls[0, k] ** 2 + w.turn * controls[1, k] ** 2
            before = previous if k == 0 else controls[:, k - 1]
            cost += w.accel_rate * (controls[0, k] - before[0]) ** 2 + w.turn_rate * (controls[1, k] - before[1]) ** 2
        distance = []
        for k in range(horizon):
            for m in range(slots):
                position = normals_x[m, k] * states[0, k + 1] + normals_y[m, k] * states[1, k + 1] + slack[m, k]
                # at the planned heading (turning never buys distance) and, per binding corner, turning that costs it
                distance.append(position + yaw_gains[0][m, k] * nominal_x[2, k + 1] - offsets[0][m, k])
                for gain, offset in zip(yaw_gains, offsets):
                    distance.append(position + gain[m, k] * states[2, k + 1] - offset[m, k])
        cost += cfg.obstacles.slack_gain * ca.sum1(ca.vec(slack)) + cfg.corridor_gain * ca.sum2(outside)
        self._equalities = STATE_SIZE * (horizon + 1)
        variables = ca.veccat(states, controls, slack, outside)
        parameters = ca.veccat(start, nominal_x, nominal_u, ref_points, ref_normals, ref_headings, ref_speeds, previous,
                               normals_x, normals_y, *yaw_gains, *offsets)
        self._sizes = (STATE_SIZE * (horizon + 1), CONTROL_SIZE * horizon, slots * horizon)
        problem = {"x": variables, "p": parameters, "f": cost, "g": ca.vertcat(*constraints, *corridor, *distance)}
        options = {"error_on_fail": False, **QUIET[cfg.solver.qp]}
        self.solver = ca.qpsol("rda_primal", cfg.solver.qp, problem, options)
        self._warm: dict[str, np.ndarray] | None = None

    def solve(self, start: np.ndarray, nominal_states: np.ndarray, nominal_controls: np.ndarray, reference: Reference,
              previous_control: np.ndarray, normals: np.ndarray, yaw_gains: np.ndarray, offsets: np.ndarray,
              margins: np.ndarray,
              hard: np.ndarray | None = None) -> Solution:
        """Solve for the plan from `start`, linearised along the nominal trajectory, with the given dual directions
        (normals (H, K, 2), yaw gains and offsets (H, K, C) of the binding corners for steps 1..H), extra soft distances (H, K) on top of comfort and the
        hard distance per obstacle slot (K,) (default: the safety distance)."""
        cfg, horizon, slots = self.config, self.horizon, self.slots
        parameters = np.concatenate([
            start, nominal_states.ravel(), nominal_controls.ravel(), reference.points.ravel(),
            reference.normals.ravel(), reference.headings, reference.speeds, previous_control,
            normals[:, :, 0].ravel(), normals[:, :, 1].ravel(),
            *(yaw_gains[:, :, c].ravel() for c in range(BINDING_CORNERS)), *(offsets[:, :, c].ravel() for c in range(BINDING_CORNERS)),
        ])
        soft = cfg.obstacles.comfort_distance + margins.ravel()
        hard = np.full(slots, cfg.obstacles.safety_distance) if hard is None else np.asarray(hard, dtype=np.float64)
        lbx, ubx = self._bounds(nominal_states, soft, np.tile(hard, horizon))
        # the corridor stays along the route while the tracked points are moved by the reference's offset
        corridor_low = np.tile([-cfg.corridor_right - reference.offset, -np.inf], horizon)  # lateral + outside >= -right
        corridor_high = np.tile([np.inf, cfg.corridor_left - reference.offset], horizon)  # lateral - outside <= left
        rows = 1 + BINDING_CORNERS  # per obstacle slot and step
        lbg = np.r_[np.zeros(self._equalities), corridor_low, np.repeat(soft, rows)]
        ubg = np.r_[np.zeros(self._equalities), corridor_high, np.full(horizon * slots * rows, np.inf)]
        guess = self._warm or {}
        result = self.solver(p=parameters, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg,
                             x0=np.r_[nominal_states.ravel(), nominal_controls.ravel(), np.zeros(horizon * (slots + 1))],
                             **({"lam_x0": guess["lam_x"], "lam_g0": guess["lam_g"]} if guess else {}))
        stats = self.solver.stats()
        solution = np.asarray(result["x"]).reshape(-1)
        success = bool(stats.get("success", False)) and np.isfinite(solution).all()
        if success:
            self._warm = {"lam_x": np.asarray(result["lam_x"]).reshape(-1), "lam_g": np.asarray(result["lam_g"]).reshape(-1)}
        n_x, n_u, _ = self._sizes
        states = solution[:n_x].reshape(horizon + 1, STATE_SIZE)
        controls = solution[n_x:n_x + n_u].reshape(horizon, CONTROL_SIZE)
        slack = solution[n_x + n_u:n_x + n_u + horizon * slots].reshape(horizon, slots)
        return Solution(states, controls, slack, success, str(stats.get("return_status", "")))

    def _bounds(self, nominal_states: np.ndarray, soft: np.ndarray, hard: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Speed, acceleration and turn limits (turn: at the nominal speed), slack within the hard distance bound."""
        cfg, horizon, slots = self.config, self.horizon, self.slots
        state_low = np.tile([-np.inf, -np.inf, -np.inf, 0.0], (horizon + 1, 1))
        state_high = np.tile([np.inf, np.inf, np.inf, cfg.vehicle.max_speed], (horizon + 1, 1))
        state_low[0, 3], state_high[0, 3] = -np.inf, np.inf  # the start is whatever it is
        turn = turn_limit(cfg, nominal_states[:-1, 3])
        control_low = np.stack([np.full(horizon, -cfg.vehicle.max_decel), -turn], axis=1)
        control_high = np.stack([np.full(horizon, cfg.vehicle.max_accel), turn], axis=1)
        slack_high = soft - hard
        return (np.r_[state_low.ravel(), control_low.ravel(), np.zeros(horizon * slots), np.zeros(horizon)],
                np.r_[state_high.ravel(), control_high.ravel(), slack_high, np.full(horizon, np.inf)])
