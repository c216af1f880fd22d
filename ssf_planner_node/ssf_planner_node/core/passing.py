"""Passing slower traffic map-free: the lane beside the route is an offset from it, and the car follows that offset
while the traffic there lets it drive clearly faster than behind what is ahead on the route."""

from __future__ import annotations

import numpy as np

from ssf_common.records import Obstacles
from ssf_planner_node.core.config import PassingConfig, VehicleConfig
from ssf_planner_node.core.route import Route

LANE_MARGIN = 0.5  # m between the car's side and a box's for the box to be in a lane


class LaneChooser:
    """Which lateral offset of the route the car follows: the route, or the passing lane while it is clearly faster."""

    def __init__(self, config: PassingConfig, vehicle: VehicleConfig, reference_speed: float) -> None:
        self.config, self.vehicle, self.reference_speed = config, vehicle, reference_speed
        self.offset = 0.0
        self._chosen_ns: int | None = None

    def choose(self, route: Route, xy: np.ndarray, stamp_ns: int, obstacles: Obstacles) -> float:
        """The offset (m, left of the route) to follow from now: moves to the other lane when it is clear beside and
        behind the car and its traffic is `gain` faster, back to the route when the route is no slower; a choice is
        kept `hold_s`."""
        cfg = self.config
        if cfg.offset == 0.0:
            return 0.0
        if self._chosen_ns is not None and (stamp_ns - self._chosen_ns) * 1e-9 < cfg.hold_s:
            return self.offset
        ego = route.project(np.asarray(xy, dtype=np.float64)[None, :2])
        if len(obstacles):
            where = route.project(obstacles.centres[:, :2])
            ahead = where.s - ego.s[0]
            across = np.einsum("nvi,ni->nv", obstacles.corners() - where.point[:, None, :], where.normal)
            right, left = across.min(axis=1), across.max(axis=1)  # each box's extent across the route
            speed = np.maximum(np.einsum("ni,ni->n", obstacles.velocities[:, :2], where.tangent), 0.0)
        else:
            ahead = right = left = speed = np.zeros(0)
        other = cfg.offset if self.offset == 0.0 else 0.0
        reach = self.vehicle.width / 2 + LANE_MARGIN

        def in_lane(offset: float) -> np.ndarray:
            return (right < offset + reach) & (left > offset - reach)

        def lane_speed(offset: float) -> float:
            """The speed the traffic ahead in that lane allows (the reference where none is)."""
            blocking = in_lane(offset) & (ahead > 0.0) & (ahead < cfg.look_ahead)
            return min(self.reference_speed, float(speed[blocking].min())) if blocking.any() else self.reference_speed

        beside = in_lane(other) & (ahead > -(cfg.clear_behind + self.vehicle.length)) & (ahead < self.vehicle.length)
        gain = 0.0 if other == 0.0 else cfg.gain  # back to the route as soon as it is no slower
        if not beside.any() and lane_speed(other) >= lane_speed(self.offset) + gain:
            self.offset, self._chosen_ns = other, stamp_ns
        return self.offset
