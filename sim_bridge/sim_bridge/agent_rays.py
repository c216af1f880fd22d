"""Rays against agents that move while the sweep turns: each ray meets each agent where that agent is when it fires.

Casting in the agent's own frame makes this exact without rebuilding geometry per column: a ray fired at time t is
moved into the frame of agent k at t and scaled into k's template (a unit box or cylinder, one scene each, built
once), where Open3D's hit parameter is the metric distance along the world ray. Only pairs that can meet are cast:
rays whose azimuth passes within the agent's circle (grown by how far the agent and the sensor move during the
sweep), and of those the rays that pass through the agent's bounding cylinder where the agent is at their time.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from sim_bridge.agents import AgentKind, template_scales
from sim_bridge.meshes import BOX, CYLINDER, Template, TriangleSoup, import_open3d, raycasting_scene
from sim_bridge.sweep import Sweep
from ssf_common.dataset.pairs import PointClass
from ssf_common.geometry.labels import ragged_arange

AZIMUTH_BINS = 4096  # rays are bucketed by world azimuth (a counting sort) to find those near each agent
MARGIN = 0.05  # m added to every bound: the tests are conservative, the cast decides
REACH_BEYOND_RANGE = 3.0  # m: agents this far beyond the range are still cast (as agent_mesh keeps them)


class AgentHits(NamedTuple):
    """The nearest agent along each ray."""

    distance: np.ndarray  # (R,) float32, inf where the ray hits no agent
    owner: np.ndarray  # (R,) int32 agent index, -1 where none
    label: np.ndarray  # (R,) uint8 PointClass of the agent hit
    normal: np.ndarray  # (R, 3) float32 world normal of the face hit

    @staticmethod
    def none(rays: int) -> AgentHits:
        """No ray hits an agent."""
        return AgentHits(np.full(rays, np.inf, np.float32), np.full(rays, -1, np.int32), np.zeros(rays, np.uint8),
                         np.zeros((rays, 3), np.float32))


class Pairs(NamedTuple):
    """Rays and the agents they may meet, one row per (ray, agent)."""

    ray: np.ndarray  # (P,) ray index
    agent: np.ndarray  # (P,) agent index


class MovingAgentCaster:
    """Casts a sweep's rays against agents that move while it turns, exactly per ray."""

    def __init__(self, max_range: float, columns: int, mount_radius: float = 0.0) -> None:
        self.max_range = max_range
        self.columns = columns  # rays come row by row (sensor, beam), a row's columns in turn
        self.mount_radius = mount_radius  # the farthest a rig's sensor sits from the rig's origin (m)
        self.scenes = {kind: raycasting_scene(_unit(template)) for kind, template in
                       ((AgentKind.VEHICLE, BOX), (AgentKind.PEDESTRIAN, CYLINDER))}

    def cast(self, sweep: Sweep, rays: np.ndarray, times: np.ndarray) -> AgentHits:
        """Nearest agent along each world ray (R, 6: origin, unit direction) fired at times (R,) s from the stamp."""
        hits = AgentHits.none(len(rays))
        pairs, origin, yaw = self._meeting(sweep, rays, times, self.candidates(sweep, rays))
        if not len(pairs.ray):
            return hits
        distance, normal = self._cast_pairs(sweep, rays, pairs, origin, yaw)
        met = np.flatnonzero(np.isfinite(distance))
        order = met[np.lexsort((distance[met], pairs.ray[met]))]
        ray = pairs.ray[order]
        nearest = order[np.r_[True, ray[1:] != ray[:-1]]]  # the first (nearest) pair of each ray
        ray, agent = pairs.ray[nearest], pairs.agent[nearest]
        hits.distance[ray] = distance[nearest]
        hits.owner[ray] = agent
        hits.label[ray] = np.where(sweep.agents.kind[agent] == AgentKind.PEDESTRIAN, PointClass.PEDESTRIAN,
                                   PointClass.VEHICLE)
        hits.normal[ray] = _world_normals(normal[nearest], template_scales(sweep.agents)[agent], yaw[nearest])
        return hits

    def candidates(self, sweep: Sweep, rays: np.ndarray) -> Pairs:
        """Every (ray, agent) that may meet during the sweep, seen from any of the rays' origins: the ray's azimuth
        within the agent's circle, its row's elevations within the agent's height band at that distance."""
        start, end = sweep.agents_start, sweep.agents
        if not len(end) or not len(rays):
            return Pairs(np.zeros(0, np.int64), np.zeros(0, np.int64))
        sensor = (sweep.pose_start[:2, 3] + sweep.pose[:2, 3]) / 2
        # every ray starts within this of the sweep's middle: the sensor moves along an arc of less than a turn
        spread = float(np.linalg.norm(sweep.pose[:2, 3] - sweep.pose_start[:2, 3])) / 2 + self.mount_radius + MARGIN
        centre = (start.position[:, :2] + end.position[:, :2]) / 2
        radius = (_footprint_radius(end) + np.linalg.norm(end.position[:, :2] - start.position[:, :2], axis=1) / 2
                  + MARGIN)  # the agent stays inside this circle during the sweep
        offset = centre - sensor
        distance = np.linalg.norm(offset, axis=1)
        reach = radius + spread  # seen from the sweep's middle, whichever origin a ray has
        near = np.flatnonzero(distance - reach <= self.max_range + REACH_BEYOND_RANGE)
        if not len(near):
            return Pairs(np.zeros(0, np.int64), np.zeros(0, np.int64))
        outside = distance[near] > reach[near]  # else the sensor may be inside the circle: every azimuth
        half_width = np.where(outside, np.arcsin(np.minimum(reach[near] / np.maximum(distance[near], 1e-9), 1.0)), np.pi)
        low = np.minimum(start.position[near, 2], end.position[near, 2]) - MARGIN
        high = np.maximum(start.position[near, 2], end.position[near, 2]) + end.size[near, 2] + MARGIN
        climbs = _climbs(low, high, distance[near] - reach[near], distance[near] + reach[near], rays[:, 2].min(),
                         rays[:, 2].max())
        return _pairs_by_row(rays[:, 3:], self.columns, near, np.arctan2(offset[near, 1], offset[near, 0]), half_width,
                             climbs)

    @staticmethod
    def _meeting(sweep: Sweep, rays: np.ndarray, times: np.ndarray,
                 pairs: Pairs) -> tuple[Pairs, np.ndarray, np.ndarray]:
        """The pairs whose ray passes through the agent's bounding cylinder where the agent is when the ray fires,
        with the ray's origin relative to the agent (P, 3) and the agent's heading (P,) then."""
        position, yaw = sweep.agent_states(pairs.agent, times[pairs.ray].astype(np.float64))
        ray = rays[pairs.ray]
        origin = ray[:, :3] - position  # float64: relative to the agent where it is when the ray fires
        radius = (_footprint_radius(sweep.agents) + MARGIN)[pairs.agent]
        keep = np.flatnonzero(_meets_cylinder(origin, ray[:, 3:], radius,
                                              (sweep.agents.size[:, 2] + MARGIN)[pairs.agent]))
        return Pairs(pairs.ray[keep], pairs.agent[keep]), origin[keep], yaw[keep]

    def _cast_pairs(self, sweep: Sweep, rays: np.ndarray, pairs: Pairs, origin: np.ndarray,
                    yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Hit distance (P,) (inf: a miss) and the normal of the face hit in the unit template (P, 3) of each pair,
        its ray's origin given relative to the agent (P, 3), the agent turned by yaw (P,)."""
        o3d = import_open3d()
        direction = rays[pairs.ray, 3:]
        cos, sin = np.cos(yaw), np.sin(yaw)
        inverse_scale = 1.0 / template_scales(sweep.agents)[pairs.agent]
        local = np.empty((len(pairs.ray), 6), np.float32)
        for column, vector in ((0, origin), (3, direction)):  # rotate by -yaw, then into the unit template
            local[:, column] = (cos * vector[:, 0] + sin * vector[:, 1]) * inverse_scale[:, 0]
            local[:, column + 1] = (cos * vector[:, 1] - sin * vector[:, 0]) * inverse_scale[:, 1]
            local[:, column + 2] = vector[:, 2] * inverse_scale[:, 2]
        distance = np.full(len(pairs.ray), np.inf, np.float32)
        normal = np.zeros((len(pairs.ray), 3), np.float32)
        kinds = sweep.agents.kind[pairs.agent]
        for kind, scene in self.scenes.items():
            mine = np.flatnonzero(kinds == kind)
            if len(mine):
                hit = scene.cast_rays(o3d.core.Tensor(local[mine]))
                distance[mine] = hit["t_hit"].numpy()
                normal[mine] = hit["primitive_normals"].numpy()
        return distance, normal


def _world_normals(normal: np.ndarray, scale: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Unit world normals (K, 3) of faces with normals (K, 3) in unit templates scaled by scale (K, 3), turned by yaw."""
    normal = normal / scale  # a normal scales by the inverse of its surface
    cos, sin = np.cos(yaw), np.sin(yaw)
    world = np.stack([cos * normal[:, 0] - sin * normal[:, 1], sin * normal[:, 0] + cos * normal[:, 1], normal[:, 2]],
                     axis=1)
    length = np.linalg.norm(world, axis=1, keepdims=True)
    return (world / np.where(length > 0, length, 1.0)).astype(np.float32)


def _unit(template: Template) -> TriangleSoup:
    """A template as a soup, unscaled at the origin."""
    count = len(template.triangles)
    return TriangleSoup(template.vertices.astype(np.float32), template.triangles.astype(np.uint32),
                        np.zeros(count, np.uint8), np.full(count, -1, np.int32))


def _footprint_radius(states) -> np.ndarray:
    """(N,) radius of the circle around each agent's footprint: half a box's diagonal, a cylinder's radius."""
    scale = template_scales(states)
    return np.where(states.kind == AgentKind.PEDESTRIAN, scale[:, 0], np.hypot(scale[:, 0], scale[:, 1]) / 2)


def _climbs(low: np.ndarray, high: np.ndarray, nearest: np.ndarray, farthest: np.ndarray, origin_low: float,
            origin_high: float) -> tuple[np.ndarray, np.ndarray]:
    """The least and the most height per horizontal metre (K,) of a ray from a height in [origin_low, origin_high]
    that is within [low, high] somewhere between nearest and farthest horizontally (K,); +-inf when an agent may be
    right at the origin."""
    nearest = np.maximum(nearest, 0.0)
    close = nearest < 0.01
    down, up = low - origin_high, high - origin_low
    least = np.where(close, -np.inf, down / np.where(down < 0, np.maximum(nearest, 0.01), farthest))
    most = np.where(close, np.inf, up / np.where(up > 0, np.maximum(nearest, 0.01), farthest))
    return least, most


def _pairs_by_row(directions: np.ndarray, columns: int, agents: np.ndarray, azimuth: np.ndarray,
                  half_width: np.ndarray, climbs: tuple[np.ndarray, np.ndarray]) -> Pairs:
    """(ray, agent) for every ray whose world azimuth lies within half_width of each agent's azimuth (one bin wider
    on each side), in each row whose rays climb within the agent's climbs (least, most)."""
    rows = len(directions) // columns
    bins = ((np.arctan2(directions[:, 1], directions[:, 0]) + np.pi) * (AZIMUTH_BINS / (2 * np.pi))).astype(np.int64)
    key = np.repeat(np.arange(rows) * AZIMUTH_BINS, columns) + np.minimum(bins, AZIMUTH_BINS - 1)
    order = np.argsort(key, kind="stable")  # fast: each row's azimuths already run round in at most two runs
    sorted_key = key[order]
    climb = (directions[:, 2] / np.maximum(np.hypot(directions[:, 0], directions[:, 1]), 1e-9)).reshape(rows, columns)
    meets = (climb.max(axis=1)[None, :] >= climbs[0][:, None]) & (climb.min(axis=1)[None, :] <= climbs[1][:, None])
    which, row = np.nonzero(meets)  # (agent, row) whose heights can meet
    first = np.floor((azimuth - half_width + np.pi) * (AZIMUTH_BINS / (2 * np.pi))).astype(np.int64)[which] - 1
    last = np.floor((azimuth + half_width + np.pi) * (AZIMUTH_BINS / (2 * np.pi))).astype(np.int64)[which] + 1
    whole = last - first + 1 >= AZIMUTH_BINS
    first, last = np.where(whole, 0, first), np.where(whole, AZIMUTH_BINS - 1, last)
    wraps = (first < 0) | (last >= AZIMUTH_BINS)  # split into [first, end of circle] and [0, rest]
    first_bins = np.r_[np.where(wraps, np.mod(first, AZIMUTH_BINS), first), np.zeros(wraps.sum(), np.int64)]
    last_bins = np.r_[np.where(wraps, AZIMUTH_BINS - 1, last), np.mod(last[wraps], AZIMUTH_BINS)]
    row_start = np.r_[row, row[wraps]] * AZIMUTH_BINS
    owners = agents[np.r_[which, which[wraps]]]
    begin = np.searchsorted(sorted_key, row_start + first_bins, "left")
    lengths = np.searchsorted(sorted_key, row_start + last_bins, "right") - begin
    return Pairs(order[np.repeat(begin, lengths) + ragged_arange(lengths)], np.repeat(owners, lengths))


def _meets_cylinder(origin: np.ndarray, direction: np.ndarray, radius: np.ndarray, height: np.ndarray) -> np.ndarray:
    """Whether each ray (origin relative to the bottom centre of an upright cylinder, unit direction) passes through
    the cylinder of that radius, from MARGIN below its bottom to height."""
    horizontal = np.maximum(np.hypot(direction[:, 0], direction[:, 1]), 1e-9)
    across = np.abs(origin[:, 0] * direction[:, 1] - origin[:, 1] * direction[:, 0]) / horizontal
    closest = -(origin[:, 0] * direction[:, 0] + origin[:, 1] * direction[:, 1]) / horizontal**2  # along the ray
    half_chord = np.sqrt(np.maximum(radius**2 - across**2, 0.0)) / horizontal
    enter, leave = np.maximum(closest - half_chord, 0.0), closest + half_chord  # inside the circle between these
    z_enter, z_leave = origin[:, 2] + enter * direction[:, 2], origin[:, 2] + leave * direction[:, 2]
    return ((across <= radius) & (leave >= 0.0) & (np.maximum(z_enter, z_leave) >= -MARGIN)
            & (np.minimum(z_enter, z_leave) <= height))


__all__ = ["AgentHits", "MovingAgentCaster", "Pairs"]
