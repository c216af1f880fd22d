"""The route A -> B: a polyline in the odometry frame with arc length, projection and a speed profile."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ssf_common.errors import ConfigError
from ssf_common.geometry.reductions import vector_lengths

EXTENSION = 200.0  # metres of straight road assumed beyond the goal, so the horizon never runs off the route


@dataclass(frozen=True)
class RoutePoint:
    """Where points lie along the route: arc length, the nearest route point, unit tangent and heading."""

    s: np.ndarray  # (N,)
    point: np.ndarray  # (N, 2)
    tangent: np.ndarray  # (N, 2)
    heading: np.ndarray  # (N,)

    @property
    def normal(self) -> np.ndarray:
        """(N, 2) unit left normals."""
        return np.stack([-self.tangent[:, 1], self.tangent[:, 0]], axis=1)


class Route:
    """A polyline from start to goal (x, y in the odometry frame), extended straight beyond the goal."""

    def __init__(self, waypoints: np.ndarray, frame_id: str = "odom") -> None:
        points = np.asarray(waypoints, dtype=np.float64).reshape(-1, 2)
        if len(points) < 2 or not np.isfinite(points).all():
            raise ConfigError("a route needs at least two finite waypoints (x, y)")
        keep = np.r_[True, np.linalg.norm(np.diff(points, axis=0), axis=1) > 1e-6]
        points = points[keep]
        if len(points) < 2:
            raise ConfigError("a route's waypoints must not all be the same point")
        self.frame_id = frame_id
        self.waypoints = points
        self.length = float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())
        last = points[-1] - points[-2]
        self._points = np.vstack([points, points[-1] + EXTENSION * last / np.linalg.norm(last)])
        segments = np.diff(self._points, axis=0)
        self._lengths = np.linalg.norm(segments, axis=1)
        self._tangents = segments / self._lengths[:, None]
        self._starts = np.r_[0.0, np.cumsum(self._lengths)[:-1]]

    @property
    def goal(self) -> np.ndarray:
        """(2,) the last waypoint."""
        return self.waypoints[-1]

    def project(self, xy: np.ndarray) -> RoutePoint:
        """The nearest point of the route to each of xy (N, 2)."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        offset = xy[:, None, :] - self._points[None, :-1, :]  # (N, S, 2)
        along = np.clip(np.einsum("nsi,si->ns", offset, self._tangents), 0.0, self._lengths[None])
        nearest = self._points[None, :-1, :] + along[..., None] * self._tangents[None]
        segment = np.argmin(vector_lengths(xy[:, None, :] - nearest), axis=1)
        rows = np.arange(len(xy))
        return self._point(self._starts[segment] + along[rows, segment], nearest[rows, segment], segment)

    def at(self, s: np.ndarray) -> RoutePoint:
        """Route points at arc lengths s (clamped to the start and the extension)."""
        s = np.clip(np.asarray(s, dtype=np.float64).reshape(-1), 0.0, self._starts[-1] + self._lengths[-1])
        segment = np.clip(np.searchsorted(self._starts, s, side="right") - 1, 0, len(self._lengths) - 1)
        point = self._points[segment] + (s - self._starts[segment])[:, None] * self._tangents[segment]
        return self._point(s, point, segment)

    def _point(self, s: np.ndarray, point: np.ndarray, segment: np.ndarray) -> RoutePoint:
        tangent = self._tangents[segment]
        return RoutePoint(s, point, tangent, np.arctan2(tangent[:, 1], tangent[:, 0]))

    def speed_limit(self, s: np.ndarray, cruise: float, decel: float) -> np.ndarray:
        """Reference speed at arc lengths s: cruise, braking comfortably to a stop at the goal."""
        remaining = np.maximum(self.length - np.asarray(s, dtype=np.float64), 0.0)
        return np.minimum(cruise, np.sqrt(2.0 * decel * remaining))

    def remaining(self, xy: np.ndarray) -> float:
        """Distance (m) along the route from the point nearest xy to the goal."""
        return float(max(self.length - self.project(np.asarray(xy)[None, :2]).s[0], 0.0))
