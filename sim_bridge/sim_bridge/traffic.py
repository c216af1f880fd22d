"""Moving agents: vehicles (boxes) and pedestrians (cylinders) on looping routes with reciprocal avoidance.

Each agent walks a closed loop in road (Frenet) coordinates toward a carrot point ahead on it. Vehicles
keep their lane and follow the vehicle ahead with the intelligent driver model, stopping before busy
crosswalks. Then a vectorised ORCA-like step over disc covers of the footprints: every pair of discs that
would close its gap faster than gap / horizon shares the excess closing speed (by how directly each
approaches; against the ego, which does not cooperate, agents take `ego_yield` of it: all by default), people
sidestepping to their right, everyone kept inside their band of the road. A final hard check undoes the step of any
agent whose new disc cover would overlap another agent or the ego, so agents never overlap.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from sim_bridge.agents import AgentKind, AgentStates, EgoFootprint
from sim_bridge.footprints import DiscCover, rectangle_cover
from sim_bridge.routes import Loops
from sim_bridge.scenario import AgentsConfig
from sim_bridge.world import World
from ssf_common.errors import ConfigError

AVOID_ITERATIONS = 6
SPAWN_ROUNDS = 100
IDM_MIN_GAP = 2.0
CROSSWALK_HALF_WIDTH = 2.5
CROSSWALK_CYCLE = 40.0
CROSSWALK_WALK = 12.0
CROSSWALK_STAGGER = 13.0
IDM_HEADWAY = 1.0
IDM_ACCEL = 1.5
IDM_DECEL = 2.5
CLEARANCE_MARGIN = 0.3
PEOPLE_NEIGHBOUR_RADIUS = 5.5


class Traffic:
    """N agents stepping with reciprocal avoidance; seeded and bit-for-bit deterministic."""

    def __init__(self, world: World, cfg: AgentsConfig, rng: np.random.Generator, ego_start: np.ndarray):
        self.world = world
        self.cfg = cfg
        count = cfg.count
        kinds = np.where(rng.random(count) < cfg.vehicle_fraction, AgentKind.VEHICLE, AgentKind.PEDESTRIAN)
        self.kind = np.sort(kinds).astype(np.uint8)  # vehicles first: stable ordering of ids by kind
        vehicles = self.kind == AgentKind.VEHICLE
        self.size = np.where(
            vehicles[:, None],
            np.c_[rng.uniform(3.8, 5.2, count), rng.uniform(1.7, 2.0, count), rng.uniform(1.4, 2.0, count)],
            np.c_[np.repeat(rng.uniform(0.45, 0.7, count)[:, None], 2, 1), rng.uniform(1.5, 1.9, count)],
        )
        self.speed = np.where(
            vehicles, rng.uniform(*cfg.vehicle_speed, count), rng.uniform(*cfg.pedestrian_speed, count)
        )
        self.lookahead = np.where(vehicles, 6.0, 2.0)
        self.max_yaw_rate = np.where(vehicles, 1.2, 6.0)
        self.sidestep = np.where(vehicles, 0.0, 0.6)
        self.loops = self._loops(rng, vehicles)
        self._lane_speeds(rng, vehicles)
        self.cover = self._cover(vehicles)
        self.ids = np.arange(1, count + 1, dtype=np.int32)
        self.progress = np.zeros(count)
        self.position = np.zeros((count, 2))
        self.yaw = np.zeros(count)
        self.velocity = np.zeros((count, 2))
        self.yaw_rate = np.zeros(count)
        self.cruise = np.zeros(count)
        self.time = 0.0
        self._spawn(rng, ego_start)

    def _loops(self, rng: np.random.Generator, vehicles: np.ndarray) -> Loops:
        section, line = self.world.section, self.world.centreline
        count = len(vehicles)
        lanes = np.abs(section.lane_centres)[rng.integers(0, len(section.lane_centres), count)]
        walk = rng.uniform(*section.pedestrian_band, count)
        crosswalks = self.world.crosswalks
        if len(crosswalks) >= 2:
            first = rng.integers(0, len(crosswalks) - 1, count)
            last = np.minimum(first + rng.integers(1, 3, count), len(crosswalks) - 1)
            ped_a, ped_b = crosswalks[first], crosswalks[last]
        else:
            span = min(30.0, line.end - line.start - 10.0)
            ped_a = line.start + 5.0 + rng.random(count) * (line.end - line.start - 10.0 - span)
            ped_b = ped_a + span
        side = np.where(rng.random(count) < 0.5, -1.0, 1.0)
        crossing = rng.random(count) < self.cfg.crossing_share
        room = line.end - line.start - 10.0
        stroll_length = np.minimum(rng.uniform(40, 200, count), room)
        stroll = line.start + 5.0 + rng.random(count) * (room - stroll_length)
        ped_a = np.where(crossing, ped_a, stroll)
        ped_b = np.where(crossing, ped_b, stroll + stroll_length)
        low, high = section.pedestrian_band
        turn_in = 8.0 + 12.0 * (len(section.lane_centres) - 1 - np.searchsorted(np.abs(section.lane_centres), lanes))
        s_a = np.where(vehicles, line.start + turn_in, ped_a)
        s_b = np.where(vehicles, line.end - turn_in, ped_b)
        d_a = np.where(vehicles, -lanes, side * np.where(crossing, walk, low))
        d_b = np.where(vehicles | crossing, -d_a, side * high)
        return Loops(s_a, s_b, d_a, d_b)

    def _lane_speeds(self, rng: np.random.Generator, vehicles: np.ndarray) -> None:
        """Vehicles in a lane that agents.lane_speeds lists draw their preferred speed from that lane's range."""
        if not self.cfg.lane_speeds:
            return  # no draws: scenarios without lane speeds keep their random sequence
        lanes = np.abs(self.world.section.lane_centres)
        lane = np.abs(np.abs(self.loops.d_a)[:, None] - lanes[None]).argmin(1)
        for index, (low, high) in enumerate(self.cfg.lane_speeds[: len(lanes)]):
            chosen = np.flatnonzero(vehicles & (lane == index))
            self.speed[chosen] = rng.uniform(low, high, len(chosen))

    def _cover(self, vehicles: np.ndarray) -> DiscCover:
        index = np.arange(len(vehicles))
        boxes = rectangle_cover(self.size[vehicles, 0], self.size[vehicles, 1], index[vehicles])
        people = index[~vehicles]
        owner = np.concatenate([boxes.owner, people])
        offset = np.concatenate([boxes.offset, np.zeros(len(people))])
        radius = np.concatenate([boxes.radius, self.size[people, 0] / 2])
        order = np.argsort(owner, kind="stable")
        return DiscCover(owner[order], offset[order], radius[order])

    def _loop_xy(self, u: np.ndarray, index: np.ndarray | slice = slice(None)) -> np.ndarray:
        loops = Loops(self.loops.s_a[index], self.loops.s_b[index], self.loops.d_a[index], self.loops.d_b[index])
        s, d = loops.frenet(u)
        return self.world.centreline.to_xy(s, d)

    def _spawn(self, rng: np.random.Generator, ego_start: np.ndarray) -> None:
        """Draw every agent at a random point of its loop; redraw those that overlap a lower-numbered one."""
        count = len(self.kind)
        self.s, self.d = np.zeros(count), np.zeros(count)
        if not count:
            return
        perimeter = self.loops.perimeter()
        redraw = np.arange(count)
        self.progress = rng.uniform(0, perimeter)
        for _ in range(SPAWN_ROUNDS):
            self.progress[redraw] = rng.uniform(0, perimeter[redraw])
            self.position = self._loop_xy(self.progress)
            ahead = self._loop_xy(self.progress + 0.5) - self.position
            self.yaw = np.arctan2(ahead[:, 1], ahead[:, 0])
            centres = self.cover.centres(self.position, self.yaw)
            pairs = cKDTree(centres).query_pairs(
                2 * float(self.cover.radius.max()) + CLEARANCE_MARGIN, output_type="ndarray"
            )
            a, b = pairs[:, 0], pairs[:, 1]
            owner_a, owner_b = self.cover.owner[a], self.cover.owner[b]
            gap = np.linalg.norm(centres[a] - centres[b], axis=1) - self.cover.radius[a] - self.cover.radius[b]
            clash = (owner_a != owner_b) & (gap < CLEARANCE_MARGIN)
            near_start = (np.linalg.norm(self.position - ego_start, axis=1) < self.cfg.keep_clear_of_start) & (
                self.kind == AgentKind.VEHICLE
            )
            redraw = np.unique(np.concatenate([np.maximum(owner_a, owner_b)[clash], np.flatnonzero(near_start)]))
            if not len(redraw):
                self.s, self.d = self.world.centreline.to_frenet(self.position)
                return
        raise ConfigError(
            f"agents.count: cannot place {count} agents without overlap ({len(redraw)} left); lower the count"
        )

    def states(self) -> AgentStates:
        """Snapshot of every agent."""
        z = self.world.ground.height(self.position[:, 0], self.position[:, 1])
        return AgentStates(
            self.ids.copy(),
            self.kind.copy(),
            np.c_[self.position, z],
            self.yaw.copy(),
            self.velocity.copy(),
            self.yaw_rate.copy(),
            self.size.copy(),
        )

    def step(self, dt: float, ego: EgoFootprint) -> None:
        """Advance every agent by dt: preferred velocity, reciprocal avoidance, move, hard overlap check."""
        if not len(self.kind):
            return
        ego_cover = rectangle_cover(np.array([ego.length]), np.array([ego.width]), np.array([-1]))
        ego_discs = ego.centre + ego_cover.offset[:, None] * np.array([np.cos(ego.yaw), np.sin(ego.yaw)])
        velocity = self._follow_lanes(self._preferred_velocity(), dt)
        velocity = self._avoid(velocity, ego_discs, ego_cover.radius, ego.velocity, dt)
        position, yaw, s, d = self._move(velocity, dt)
        position, yaw, fraction = self._revert_overlaps(position, yaw, ego_discs, ego_cover.radius)
        held_back = fraction < 1.0
        if held_back.any():
            s[held_back], d[held_back] = self.world.centreline.to_frenet(position[held_back])
        self._advance_progress(s, d)
        self.s, self.d = s, d
        moved = fraction > 0.0
        self.velocity = np.where(moved[:, None], (position - self.position) / dt, 0.0)
        self.cruise = np.minimum(self.cruise, np.linalg.norm(self.velocity, axis=1))
        self.yaw_rate = np.angle(np.exp(1j * (yaw - self.yaw))) / dt
        self.position, self.yaw = position, yaw
        self.time += dt

    def _preferred_velocity(self) -> np.ndarray:
        """Toward the carrot ahead on each loop; people wait at the kerb while the crosswalk shows don't-walk."""
        carrot_s, carrot_d = self.loops.frenet(self.progress + self.lookahead)
        direction = self.world.centreline.to_xy(carrot_s, carrot_d) - self.position
        distance = np.maximum(np.linalg.norm(direction, axis=1), 1e-9)
        speed = np.where(self._waiting_at_kerb(carrot_d), 0.0, np.minimum(self.speed, distance / 0.5))
        return direction / distance[:, None] * speed[:, None]

    def _walk_signal(self) -> np.ndarray:
        """Whether each crosswalk shows walk now (fixed cycle, staggered along the road)."""
        offsets = np.arange(len(self.world.crosswalks)) * CROSSWALK_STAGGER
        return np.mod(self.time + offsets, CROSSWALK_CYCLE) < CROSSWALK_WALK

    def _waiting_at_kerb(self, carrot_d: np.ndarray) -> np.ndarray:
        """People on the pavement whose next step is onto a crosswalk that shows don't-walk."""
        crosswalks = self.world.crosswalks
        waiting = np.zeros(len(self.kind), bool)
        if not len(crosswalks):
            return waiting
        kerb = self.world.section.road_edge + 0.5
        nearest = np.abs(self.s[:, None] - crosswalks[None]).argmin(1)
        stepping_out = (np.abs(self.d) >= kerb) & (np.abs(carrot_d) < kerb) & (self.kind == AgentKind.PEDESTRIAN)
        return stepping_out & ~self._walk_signal()[nearest]

    def _follow_lanes(self, velocity: np.ndarray, dt: float) -> np.ndarray:
        """Vehicles keep their lane loop and follow the vehicle ahead on it (intelligent driver model)."""
        order, leader = self._lane_leaders()
        if not len(order):
            return velocity
        gap = np.minimum(self._gap_to_leader(order, leader), self._crosswalk_gap(order))
        speed = _idm_speed(self.cruise[order], self.cruise[leader], self.speed[order], gap, dt)
        self.cruise[order] = speed
        velocity = velocity.copy()
        preferred = np.linalg.norm(velocity[order], axis=1)
        direction = velocity[order] / np.maximum(preferred, 1e-9)[:, None]
        velocity[order] = direction * np.minimum(speed, preferred)[:, None]
        return velocity

    def _lane_leaders(self) -> tuple[np.ndarray, np.ndarray]:
        """Vehicles sorted by loop and progress, and the vehicle ahead of each on the same loop."""
        vehicles = np.flatnonzero(self.kind == AgentKind.VEHICLE)
        key = np.round(self.loops.d_a[vehicles], 3)
        order = vehicles[np.lexsort((self.progress[vehicles], key))]
        key = np.round(self.loops.d_a[order], 3)
        first = np.r_[True, key[1:] != key[:-1]]
        last = np.r_[key[1:] != key[:-1], True]
        group_start = np.maximum.accumulate(np.where(first, np.arange(len(order)), 0))
        return order, order[np.where(last, group_start, np.arange(len(order)) + 1)]

    def _gap_to_leader(self, order: np.ndarray, leader: np.ndarray) -> np.ndarray:
        """Bumper gap to the leader: along the loop, or straight ahead when the leader is in the path (U-turns)."""
        along_loop = np.mod(self.progress[leader] - self.progress[order], self.loops.perimeter()[order])
        offset = self.position[leader] - self.position[order]
        cos, sin = np.cos(self.yaw[order]), np.sin(self.yaw[order])
        ahead = cos * offset[:, 0] + sin * offset[:, 1]
        beside = np.abs(-sin * offset[:, 0] + cos * offset[:, 1])
        turn = self.yaw[leader] - self.yaw[order]
        leader_half_width = (
            np.abs(np.sin(turn)) * self.size[leader, 0] + np.abs(np.cos(turn)) * self.size[leader, 1]
        ) / 2
        in_path = (ahead > 0) & (beside < self.size[order, 1] / 2 + leader_half_width + 0.3)
        centre_gap = np.minimum(along_loop, np.where(in_path, ahead, np.inf))
        return np.where(leader == order, np.inf, centre_gap - (self.size[order, 0] + self.size[leader, 0]) / 2)

    def _crosswalk_gap(self, vehicles: np.ndarray) -> np.ndarray:
        """Distance from each vehicle's front to the next crosswalk stop line showing walk or with people on it."""
        crosswalks = self.world.crosswalks
        gap = np.full(len(vehicles), np.inf)
        people = self.kind == AgentKind.PEDESTRIAN
        if not len(crosswalks) or not people.any():
            return gap
        s, d = self.s[people], self.d[people]
        on_road = np.abs(d) < self.world.section.road_edge + 0.5
        nearest = np.abs(s[:, None] - crosswalks[None]).argmin(1)
        near = np.abs(s - crosswalks[nearest]) < CROSSWALK_HALF_WIDTH + 1.0
        busy = self._walk_signal()
        busy[nearest[near & on_road]] = True
        if not busy.any():
            return gap
        stops = crosswalks[busy]
        s_v, d_v = self.s[vehicles], self.d[vehicles]
        forward = d_v < 0
        half = self.size[vehicles, 0] / 2
        ahead_forward = stops[np.minimum(np.searchsorted(stops, s_v + half - 0.5), len(stops) - 1)]
        ahead_backward = stops[np.maximum(np.searchsorted(stops, s_v - half + 0.5, side="right") - 1, 0)]
        distance = np.where(forward, ahead_forward - s_v, s_v - ahead_backward) - half - CROSSWALK_HALF_WIDTH
        in_lane = np.abs(np.abs(d_v) - np.abs(self.loops.d_a[vehicles])) < 1.0
        return np.where((distance > -0.5) & in_lane, np.maximum(distance, 0.0) + IDM_MIN_GAP, np.inf)

    def _avoid(
        self, velocity: np.ndarray, ego_discs: np.ndarray, ego_radii: np.ndarray, ego_velocity: np.ndarray, dt: float
    ) -> np.ndarray:
        """Share excess closing speeds between disc pairs (against the ego, agents take `ego_yield` of it)."""
        centres = np.concatenate([self.cover.centres(self.position, self.yaw), ego_discs])
        owner = np.concatenate([self.cover.owner, np.full(len(ego_discs), -1)])
        radius = np.concatenate([self.cover.radius, ego_radii])
        pairs = cKDTree(centres).query_pairs(self.cfg.neighbour_radius, output_type="ndarray")
        if not len(pairs):
            return velocity
        pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
        a, b = pairs[:, 0], pairs[:, 1]
        vehicle = np.concatenate([self.kind == AgentKind.VEHICLE, np.zeros(1, bool)])
        people = ~vehicle[owner[a]] & ~vehicle[owner[b]] & (owner[b] >= 0)
        far = np.linalg.norm(centres[a] - centres[b], axis=1) > PEOPLE_NEIGHBOUR_RADIUS
        keep = (owner[a] != owner[b]) & ~(vehicle[owner[a]] & vehicle[owner[b]]) & ~(people & far)
        a, b = a[keep], b[keep]
        oa, ob = owner[a], owner[b]
        ego_pair = ob < 0
        offset = centres[b] - centres[a]
        distance = np.maximum(np.linalg.norm(offset, axis=1), 1e-9)
        normal = offset / distance[:, None]
        right = np.stack([normal[:, 1], -normal[:, 0]], 1)
        heading = velocity / np.maximum(np.linalg.norm(velocity, axis=1), 1e-9)[:, None]
        approach_a = np.maximum(np.einsum("ij,ij->i", heading[oa], normal), 0.0)
        approach_b = np.where(
            ego_pair, 0.0, np.maximum(-np.einsum("ij,ij->i", heading[np.maximum(ob, 0)], normal), 0.0)
        )
        gap = distance - radius[a] - radius[b] - CLEARANCE_MARGIN
        allowed = np.maximum(gap, 0.0) / self.cfg.horizon
        share_a = np.where(ego_pair, self.cfg.ego_yield, (approach_a + 1e-3) / (approach_a + approach_b + 2e-3))
        share_a[self._pedestrian_not_ahead(oa, ob, vehicle)] = 0.0
        other = ~ego_pair
        receiver = np.concatenate([oa, ob[other]])
        pair = np.concatenate([np.arange(len(oa)), np.flatnonzero(other)])
        share = np.concatenate([share_a, 1.0 - share_a[other]])
        direction = np.concatenate(
            [
                -(normal + self.sidestep[oa][:, None] * right),
                normal[other] + self.sidestep[ob[other]][:, None] * right[other],
            ]
        )
        lane_bound = np.flatnonzero(self.kind == AgentKind.VEHICLE)
        lane_direction = velocity[lane_bound] / np.maximum(np.linalg.norm(velocity[lane_bound], axis=1), 1e-9)[:, None]
        velocity = velocity.copy()
        count = len(velocity)
        ob_safe = np.maximum(ob, 0)
        s, d = self.s, self.d
        low, high = self._bands(s, d)
        lateral = self.world.centreline.normals_at(s)
        slowest, fastest = (low - d) / dt, (high - d) / dt
        for _ in range(AVOID_ITERATIONS):
            vb = np.where(ego_pair[:, None], ego_velocity, velocity[ob_safe])
            relative = velocity[oa] - vb
            excess = np.maximum(relative[:, 0] * normal[:, 0] + relative[:, 1] * normal[:, 1] - allowed, 0.0)
            if not excess.any():
                break
            size = share * excess[pair]
            largest = np.zeros(count)
            np.maximum.at(largest, receiver, size)
            winner = (size > 0) & (size == largest[receiver])
            who, push = receiver[winner], size[winner, None] * direction[winner]
            ties = np.maximum(np.bincount(who, minlength=count), 1)
            velocity[:, 0] += np.bincount(who, push[:, 0], count) / ties
            velocity[:, 1] += np.bincount(who, push[:, 1], count) / ties
            along = np.maximum(np.einsum("ij,ij->i", velocity[lane_bound], lane_direction), 0.0)
            velocity[lane_bound] = along[:, None] * lane_direction
            sideways = np.einsum("ij,ij->i", velocity, lateral)
            velocity += (np.clip(sideways, slowest, fastest) - sideways)[:, None] * lateral
        speed = np.linalg.norm(velocity, axis=1)
        limit = 1.2 * self.speed
        return velocity * np.minimum(1.0, limit / np.maximum(speed, 1e-9))[:, None]

    def _pedestrian_not_ahead(self, oa: np.ndarray, ob: np.ndarray, vehicle: np.ndarray) -> np.ndarray:
        """Vehicle-pedestrian pairs where the person is not in front of the vehicle: the person gives way."""
        pairs = vehicle[oa] & (ob >= 0) & ~vehicle[ob]
        heading = np.stack([np.cos(self.yaw[oa]), np.sin(self.yaw[oa])], 1)
        offset = self.position[np.maximum(ob, 0)] - self.position[oa]
        return pairs & (np.einsum("ij,ij->i", offset, heading) < self.size[oa, 0] / 2)

    def _move(self, velocity: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Integrate velocities, turn headings toward the motion and keep agents inside their bands."""
        position = self.position + velocity * dt
        speed = np.linalg.norm(velocity, axis=1)
        target = np.arctan2(velocity[:, 1], velocity[:, 0])
        turn = np.angle(np.exp(1j * (target - self.yaw)))
        turn = np.clip(turn, -self.max_yaw_rate * dt, self.max_yaw_rate * dt)
        yaw = np.where(speed > 0.2, self.yaw + turn, self.yaw)
        yaw = np.angle(np.exp(1j * yaw))
        position, s, d = self._clamp_to_bands(position)
        return position, yaw, s, d

    def _bands(self, s: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The lateral range [low, high] of d each agent (at Frenet s, d) must stay in."""
        section = self.world.section
        vehicles = self.kind == AgentKind.VEHICLE
        crosses = np.sign(self.loops.d_a) != np.sign(self.loops.d_b)
        at_crossing = crosses & (np.minimum(np.abs(s - self.loops.s_a), np.abs(s - self.loops.s_b)) < 4.0)
        inner = np.where(vehicles | at_crossing, 0.0, section.pedestrian_band[0])
        outer = np.where(vehicles, section.road_edge - self.size[:, 1] / 2 - 0.2, section.pedestrian_band[1])
        free = vehicles | at_crossing
        side = np.where(d >= 0, 1.0, -1.0)
        low = np.where(free, -outer, np.where(side > 0, inner, -outer))
        high = np.where(free, outer, np.where(side > 0, outer, -inner))
        return low, high

    def _clamp_to_bands(self, position: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions moved back inside their bands, with their Frenet coordinates."""
        line = self.world.centreline
        s, d = line.to_frenet(position)
        clamped = np.clip(d, *self._bands(s, d))
        s_clamped = np.clip(s, line.start + 2.0, line.end - 2.0)
        change = (clamped != d) | (s_clamped != s)
        if change.any():
            position = position.copy()
            position[change] = line.to_xy(s_clamped[change], clamped[change])
        return position, s_clamped, clamped

    def _revert_overlaps(
        self, position: np.ndarray, yaw: np.ndarray, ego_discs: np.ndarray, ego_radii: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Halve, then undo, the step of every agent whose new footprint would overlap another agent or the ego.

        Returns positions, yaws and the fraction of its step each agent kept (1, 0.5 or 0).
        """
        fraction = np.ones(len(self.kind))
        target, turn = position.copy(), np.angle(np.exp(1j * (yaw - self.yaw)))
        owner = np.concatenate([self.cover.owner, np.full(len(ego_discs), -1)])
        radius = np.concatenate([self.cover.radius, ego_radii])
        old_centres = self.cover.centres(self.position, self.yaw)
        centres = np.concatenate([self.cover.centres(position, yaw), ego_discs])
        travel = np.linalg.norm(centres[: len(old_centres)] - old_centres, axis=1).max(initial=0.0)
        pairs = cKDTree(centres).query_pairs(2 * float(radius.max()) + 2 * travel, output_type="ndarray")
        a, b = pairs[:, 0], pairs[:, 1]
        keep = owner[a] != owner[b]
        a, b = a[keep], b[keep]
        oa, ob = owner[a], owner[b]
        changed = np.ones(len(self.kind), bool)
        while len(a):
            check = np.flatnonzero(changed[oa] | (changed[np.maximum(ob, 0)] & (ob >= 0)))  # others stay apart
            ca, cb = a[check], b[check]
            touching = check[np.linalg.norm(centres[ca] - centres[cb], axis=1) < radius[ca] + radius[cb]]
            culprits = np.concatenate([oa[touching], ob[touching]])
            culprits = culprits[culprits >= 0]
            culprits = np.unique(culprits[fraction[culprits] > 0])
            if not len(culprits):
                break
            fraction[culprits] = np.where(fraction[culprits] == 1.0, 0.5, 0.0)
            position[culprits] = self.position[culprits] + fraction[culprits, None] * (
                target[culprits] - self.position[culprits]
            )
            yaw[culprits] = self.yaw[culprits] + fraction[culprits] * turn[culprits]
            changed[:] = False
            changed[culprits] = True
            discs = np.flatnonzero(changed[self.cover.owner])
            heading = np.stack([np.cos(yaw), np.sin(yaw)], -1)[self.cover.owner[discs]]
            centres[discs] = position[self.cover.owner[discs]] + self.cover.offset[discs, None] * heading
        return position, yaw, fraction

    def _advance_progress(self, s: np.ndarray, d: np.ndarray) -> None:
        """Move each loop parameter to the agent's projection (Frenet s, d) on its loop, never backwards or far."""
        candidates, distances = self.loops.project(s, d)
        perimeter = self.loops.perimeter()
        ahead = np.mod(candidates - self.progress[:, None], perimeter[:, None])
        reachable = ahead <= 2.0 * self.lookahead[:, None]
        distances = np.where(reachable, distances, np.inf)
        best = distances.argmin(1)
        found = np.isfinite(distances[np.arange(len(best)), best])
        step = np.where(found, ahead[np.arange(len(best)), best], 0.0)
        self.progress = np.mod(self.progress + step, perimeter)


def _idm_speed(
    speed: np.ndarray, leader_speed: np.ndarray, desired: np.ndarray, gap: np.ndarray, dt: float
) -> np.ndarray:
    """Intelligent-driver-model speed after dt, never driving into the gap."""
    closing = speed - leader_speed
    wanted_gap = IDM_MIN_GAP + speed * IDM_HEADWAY + speed * closing / (2 * np.sqrt(IDM_ACCEL * IDM_DECEL))
    accel = IDM_ACCEL * (
        1 - (speed / np.maximum(desired, 1e-6)) ** 4 - (np.maximum(wanted_gap, 0.0) / np.maximum(gap, 0.1)) ** 2
    )
    return np.clip(speed + accel * dt, 0.0, np.maximum(gap - 0.5, 0.0) / dt)
