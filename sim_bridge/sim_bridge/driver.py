"""Built-in route follower: pure pursuit along a right-hand lane, slowing for agents ahead, changing to
the other right-hand lane when it is clearly faster, and stopping at the goal."""

from __future__ import annotations

import numpy as np

from sim_bridge.ego import Outcome, VelocityCommand
from sim_bridge.agents import AgentStates
from sim_bridge.world import World

STOP_GAP = 3.0
COMFORT_DECEL = 2.5
PREDICTION = 1.5
CLEAR_BEHIND = 8.0
LANE_CHANGE_GAIN = 2.0
LOOK_AROUND = 80.0


class RouteFollower:
    """Follows the route at the reference speed and keeps clear of agents in its lane."""

    def __init__(self, world: World, lane_offset: float, reference_speed: float, length: float, width: float,
                 lane_changes: bool = True):
        self.world = world
        self.lane_changes = lane_changes
        self.lanes = [float(offset) for offset in world.section.lane_centres]
        self.lane_offset = lane_offset
        self.reference_speed = reference_speed
        self.length = length
        self.width = width

    def command(self, pose: np.ndarray, speed: float, agents: AgentStates, outcome: Outcome) -> VelocityCommand:
        """The command for the ego at base pose (world <- base_link) and forward speed."""
        if outcome != Outcome.RUNNING or self.reference_speed <= 0.0:
            return VelocityCommand(0.0, 0.0)  # done, or told to hold the ego where it is
        xy, yaw = pose[:2, 3], float(np.arctan2(pose[1, 0], pose[0, 0]))
        s, d = (value[0] for value in self.world.centreline.to_frenet(xy[None]))
        near = agents.take(np.linalg.norm(agents.position[:, :2] - xy, axis=1) < LOOK_AROUND)
        seen = [self._frenet(near, horizon) for horizon in (0.0, PREDICTION)]
        lane_speed = {lane: self._clear_speed(s, lane, near, seen) for lane in self.lanes}
        self._choose_lane(s, d, lane_speed, near, seen[0])
        remaining = self.world.route_length - s
        cap = min(self.reference_speed, np.sqrt(2 * COMFORT_DECEL * max(remaining, 0.0)) + 0.5)
        cap = min(cap, lane_speed[self.lane_offset], self._clear_speed(s, d, near, seen))
        return VelocityCommand(float(max(cap, 0.0)), self._steer(xy, yaw, s, speed))

    def _frenet(self, agents: AgentStates, horizon: float) -> tuple[np.ndarray, np.ndarray]:
        """Frenet coordinates of the agents, now or extrapolated horizon seconds ahead."""
        return self.world.centreline.to_frenet(agents.position[:, :2] + horizon * agents.velocity)

    def _steer(self, xy: np.ndarray, yaw: float, s: float, speed: float) -> float:
        """Pure-pursuit yaw rate toward a point ahead on the chosen lane."""
        lookahead = max(8.0, 0.8 * abs(speed))
        target = self.world.centreline.to_xy(np.array([s + lookahead]), np.array([self.lane_offset]))[0]
        angle = float(np.angle(np.exp(1j * (np.arctan2(target[1] - xy[1], target[0] - xy[0]) - yaw))))
        return float(2.0 * max(abs(speed), 2.0) * np.sin(angle) / lookahead)

    def _choose_lane(
        self,
        s: float,
        d: float,
        lane_speed: dict[float, float],
        agents: AgentStates,
        now: tuple[np.ndarray, np.ndarray],
    ) -> None:
        """Move to a clearly faster right-hand lane when nobody is close behind in it (if lane changes are allowed)."""
        if not self.lane_changes or abs(d - self.lane_offset) > 0.5:
            return  # still changing lanes
        best = max(self.lanes, key=lambda lane: (lane_speed[lane], -abs(lane - self.lanes[0])))
        if best != self.lane_offset and lane_speed[best] > lane_speed[self.lane_offset] + LANE_CHANGE_GAIN:
            if self._clear_behind(s, best, agents, now):
                self.lane_offset = best

    def _in_lane(self, lateral: float, agents: AgentStates, at: np.ndarray) -> np.ndarray:
        """Which agents (at Frenet d values `at`) overlap a lane-wide corridor centred on `lateral`."""
        return np.abs(at - lateral) < self.width / 2 + agents.size[:, 1] / 2 + 0.6

    def _clear_speed(
        self, s: float, lateral: float, agents: AgentStates, seen: list[tuple[np.ndarray, np.ndarray]]
    ) -> float:
        """Highest speed that can still stop before the nearest agent in (or entering) a corridor ahead."""
        if not len(agents):
            return np.inf
        gap = np.inf
        for agent_s, agent_d in seen:
            ahead = agent_s - s
            blocking = (ahead > 0) & self._in_lane(lateral, agents, agent_d)
            if blocking.any():
                gap = min(gap, float((ahead[blocking] - agents.size[blocking, 0] / 2).min()) - self.length / 2)
        if not np.isfinite(gap):
            return np.inf
        return float(np.sqrt(2 * COMFORT_DECEL * max(gap - STOP_GAP, 0.0)))

    def _clear_behind(self, s: float, lateral: float, agents: AgentStates, now: tuple[np.ndarray, np.ndarray]) -> bool:
        """No agent in the corridor just behind or beside the ego."""
        agent_s, agent_d = now
        behind = (agent_s - s > -CLEAR_BEHIND - self.length) & (agent_s - s < self.length)
        return not (behind & self._in_lane(lateral, agents, agent_d)).any()
