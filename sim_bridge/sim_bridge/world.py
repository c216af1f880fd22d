"""The static world: road centreline with Frenet coordinates, ground surface, structure and their meshes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from sim_bridge.footprints import Rectangles, point_rectangle_distance, rectangles_overlap
from sim_bridge.meshes import BOX, CYLINDER, SPHERE, TriangleSoup, instances
from sim_bridge.scenario import Scenario
from ssf_common.dataset.pairs import PointClass  # noqa: F401  (the simulator labels its points with it)
from ssf_common.errors import ConfigError

SAMPLE_STEP = 0.25
START_CLEARANCE = 3.0  # no structure within this distance (m) of the ego's footprint where it starts


@dataclass(frozen=True)
class CrossSection:
    """Lateral offsets (metres from the centreline, right side negative) of the road's bands."""

    lane_centres: np.ndarray  # offsets of the right-hand lanes (negative), innermost first
    road_edge: float  # |d| where the driving lanes end
    parking_centre: float
    sidewalk_inner: float
    sidewalk_outer: float
    pedestrian_band: tuple[float, float]  # |d| range pedestrians walk in

    @staticmethod
    def of(scenario: Scenario) -> CrossSection:
        """The cross-section described by a scenario's route section."""
        route = scenario.route
        road = route.lanes_per_direction * route.lane_width
        lanes = -(np.arange(route.lanes_per_direction) + 0.5) * route.lane_width
        inner = road + route.parking_width
        outer = inner + route.sidewalk_width
        return CrossSection(lanes, road, road + route.parking_width / 2, inner, outer, (inner + 0.5, outer - 1.6))


class Centreline:
    """The road centreline sampled densely, with Frenet (s, d) <-> world (x, y) conversions."""

    def __init__(self, waypoints: np.ndarray, corner_radius: float, extension: float):
        points, tangents, curved, length = _sample_rounded_polyline(waypoints, corner_radius, extension)
        self.points = points
        self.tangents = tangents
        self.normals = np.stack([-tangents[:, 1], tangents[:, 0]], axis=1)
        self.curved = curved
        self.start = -extension
        self.route_length = length
        self.end = length + extension
        self.s = self.start + SAMPLE_STEP * np.arange(len(points))
        self._tree = cKDTree(points)

    def _interp(self, values: np.ndarray, s: np.ndarray) -> np.ndarray:
        position = np.clip((np.asarray(s, np.float64) - self.start) / SAMPLE_STEP, 0.0, len(self.s) - 1.000001)
        index = position.astype(np.int64)
        frac = (position - index)[..., None]
        return values[index] * (1.0 - frac) + values[index + 1] * frac

    def to_xy(self, s: np.ndarray, d: np.ndarray) -> np.ndarray:
        """World (x, y) of Frenet coordinates."""
        return self._interp(self.points, s) + np.asarray(d, np.float64)[..., None] * self._interp(self.normals, s)

    def normals_at(self, s: np.ndarray) -> np.ndarray:
        """Unit left normals (..., 2) of the centreline at arc lengths s."""
        normal = self._interp(self.normals, s)
        return normal / np.linalg.norm(normal, axis=-1, keepdims=True)

    def heading(self, s: np.ndarray) -> np.ndarray:
        """Heading (rad) of the centreline at arc length s."""
        tangent = self._interp(self.tangents, s)
        return np.arctan2(tangent[..., 1], tangent[..., 0])

    def to_frenet(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Frenet (s, d) of world points (nearest centreline sample, refined along its tangent)."""
        _, index = self._tree.query(xy)
        offset = xy - self.points[index]
        s = self.s[index] + np.einsum("...i,...i->...", offset, self.tangents[index])
        d = np.einsum("...i,...i->...", offset, self.normals[index])
        return s, d

    def is_straight(self, s_from: float, s_to: float) -> bool:
        """Whether the centreline has no curve between two arc lengths."""
        lo = int(np.clip((s_from - self.start) / SAMPLE_STEP, 0, len(self.s) - 1))
        hi = int(np.clip((s_to - self.start) / SAMPLE_STEP, 0, len(self.s) - 1))
        return not self.curved[lo : hi + 1].any()


def _sample_rounded_polyline(
    waypoints: np.ndarray, radius: float, extension: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Sample a polyline with circular corners (plus straight extensions) every SAMPLE_STEP metres."""
    directions = np.diff(waypoints, axis=0)
    lengths = np.linalg.norm(directions, axis=1)
    directions = directions / lengths[:, None]
    cuts = np.zeros(len(waypoints))
    turns = np.zeros(len(waypoints))
    for i in range(1, len(waypoints) - 1):
        a, b = directions[i - 1], directions[i]
        turns[i] = np.arctan2(a[0] * b[1] - a[1] * b[0], a @ b)
        if abs(turns[i]) > np.radians(170):
            raise ConfigError(f"route.waypoints: the route turns back on itself at waypoint {i}")
        cuts[i] = radius * np.tan(abs(turns[i]) / 2)
    for i, length in enumerate(lengths):
        if cuts[i] + cuts[i + 1] > length + 1e-9:
            raise ConfigError(
                f"route.waypoints: segment {i} ({length:.1f} m) is too short for route.corner_radius {radius:g} m"
            )
    pieces: list[tuple[np.ndarray, float, float, float]] = []  # (start point, heading, length, curvature)
    start = waypoints[0] - extension * directions[0]
    pieces.append((start, np.arctan2(*directions[0][::-1]), extension, 0.0))
    for i, length in enumerate(lengths):
        heading = np.arctan2(directions[i][1], directions[i][0])
        origin = waypoints[i] + cuts[i] * directions[i]
        pieces.append((origin, heading, length - cuts[i] - cuts[i + 1], 0.0))
        if i + 1 < len(waypoints) - 1 and cuts[i + 1] > 0:
            arc_start = waypoints[i + 1] - cuts[i + 1] * directions[i]
            pieces.append((arc_start, heading, radius * abs(turns[i + 1]), np.sign(turns[i + 1]) / radius))
    pieces.append((waypoints[-1], np.arctan2(directions[-1][1], directions[-1][0]), extension, 0.0))
    total = sum(piece[2] for piece in pieces)
    route_length = total - 2 * extension
    s = np.arange(int(np.floor(total / SAMPLE_STEP)) + 1) * SAMPLE_STEP
    piece_ends = np.cumsum([piece[2] for piece in pieces])
    which = np.minimum(np.searchsorted(piece_ends, s, side="right"), len(pieces) - 1)
    points = np.empty((len(s), 2))
    headings = np.empty(len(s))
    curved = np.zeros(len(s), bool)
    for k, (origin, heading, length, curvature) in enumerate(pieces):
        mask = which == k
        local = s[mask] - (piece_ends[k] - length)
        if curvature == 0.0:
            points[mask] = origin + local[:, None] * np.array([np.cos(heading), np.sin(heading)])
            headings[mask] = heading
        else:
            angle = heading + curvature * local
            points[mask, 0] = origin[0] + (np.sin(angle) - np.sin(heading)) / curvature
            points[mask, 1] = origin[1] - (np.cos(angle) - np.cos(heading)) / curvature
            headings[mask] = angle
            curved[mask] = True
    tangents = np.stack([np.cos(headings), np.sin(headings)], axis=1)
    return points, tangents, curved, route_length


class Ground:
    """Ground surface: a triangulated height grid of gentle slopes plus per-vertex roughness."""

    def __init__(self, lower: np.ndarray, upper: np.ndarray, scenario: Scenario, rng: np.random.Generator):
        cfg = scenario.ground
        self.resolution = cfg.resolution
        self.origin = np.floor(lower / cfg.resolution) * cfg.resolution
        self.shape = (np.ceil((upper - self.origin) / cfg.resolution).astype(int) + 2).tolist()
        self.amplitude = cfg.slope_amplitude
        self.wavenumbers = 2 * np.pi / np.array([cfg.slope_wavelength, 0.8 * cfg.slope_wavelength])
        self.phases = rng.uniform(0, 2 * np.pi, 2)
        xs = self.origin[0] + cfg.resolution * np.arange(self.shape[0])
        ys = self.origin[1] + cfg.resolution * np.arange(self.shape[1])
        grid_x, grid_y = np.meshgrid(xs, ys, indexing="ij")
        self.heights = self.slope(grid_x, grid_y) + cfg.roughness * rng.standard_normal(grid_x.shape)

    def slope(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The smooth part of the ground height."""
        kx, ky = self.wavenumbers
        return 0.5 * self.amplitude * (np.sin(kx * x + self.phases[0]) + np.sin(ky * y + self.phases[1]))

    def slope_gradient(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Gradient (dh/dx, dh/dy) of the smooth part."""
        kx, ky = self.wavenumbers
        return (
            0.5
            * self.amplitude
            * np.stack([kx * np.cos(kx * x + self.phases[0]), ky * np.cos(ky * y + self.phases[1])], -1)
        )

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Exact height of the ground mesh at (x, y) (clamped to the grid)."""
        gx = np.clip((np.asarray(x) - self.origin[0]) / self.resolution, 0, self.shape[0] - 1.000001)
        gy = np.clip((np.asarray(y) - self.origin[1]) / self.resolution, 0, self.shape[1] - 1.000001)
        i, j = gx.astype(np.int64), gy.astype(np.int64)
        fx, fy = gx - i, gy - j
        h = self.heights
        h00, h10, h01, h11 = h[i, j], h[i + 1, j], h[i, j + 1], h[i + 1, j + 1]
        lower = h00 + fx * (h10 - h00) + fy * (h01 - h00)
        upper = h11 + (1 - fx) * (h01 - h11) + (1 - fy) * (h10 - h11)
        return np.where(fx + fy <= 1.0, lower, upper)

    def mesh(self) -> TriangleSoup:
        """The ground grid as triangles (split along the same diagonal as height())."""
        nx, ny = self.shape
        xs = self.origin[0] + self.resolution * np.arange(nx)
        ys = self.origin[1] + self.resolution * np.arange(ny)
        grid_x, grid_y = np.meshgrid(xs, ys, indexing="ij")
        vertices = np.stack([grid_x, grid_y, self.heights], -1).reshape(-1, 3)
        index = np.arange(nx * ny).reshape(nx, ny)
        v00, v10, v01, v11 = index[:-1, :-1], index[1:, :-1], index[:-1, 1:], index[1:, 1:]
        triangles = np.concatenate(
            [np.stack([v00, v10, v01], -1).reshape(-1, 3), np.stack([v11, v01, v10], -1).reshape(-1, 3)]
        )
        count = len(triangles)
        return TriangleSoup(
            vertices.astype(np.float32),
            triangles.astype(np.uint32),
            np.full(count, PointClass.GROUND, np.uint8),
            np.full(count, -1, np.int32),
        )


@dataclass(frozen=True)
class EgoStart:
    """Where the ego starts: position (x, y) and heading (rad)."""

    xy: np.ndarray
    yaw: float


@dataclass(frozen=True)
class Structure:
    """Static obstacles: oriented boxes (buildings, walls, parked cars) and upright cylinders (poles, trunks)."""

    boxes: np.ndarray  # (B, 6): x, y, yaw, length, width, height
    box_classes: np.ndarray  # (B,) PointClass
    cylinders: np.ndarray  # (C, 4): x, y, radius, height
    cylinder_classes: np.ndarray  # (C,)
    crowns: np.ndarray  # (K, 4): x, y, z_centre, radius (tree crowns, above head height)


class World:
    """Road, ground and static structure of one scenario, built once from a seed."""

    def __init__(self, scenario: Scenario, seed: int):
        rng = np.random.default_rng([seed, 1])
        self.scenario = scenario
        self.section = CrossSection.of(scenario)
        waypoints = np.asarray(scenario.route.waypoints, np.float64)
        self.centreline = Centreline(waypoints, scenario.route.corner_radius, scenario.route.extension)
        margin = scenario.ground.margin + self.section.sidewalk_outer
        self.ground = Ground(
            self.centreline.points.min(0) - margin, self.centreline.points.max(0) + margin, scenario, rng
        )
        self.crosswalks = self._crosswalks()
        self.start = self._ego_start()
        self.structure = self._clear_of_start(self._structure(rng))
        self._box_tree = cKDTree(self.structure.boxes[:, :2]) if len(self.structure.boxes) else None
        self._box_radius = (
            float(np.hypot(self.structure.boxes[:, 3], self.structure.boxes[:, 4]).max() / 2)
            if len(self.structure.boxes)
            else 0.0
        )
        self._cylinder_tree = cKDTree(self.structure.cylinders[:, :2]) if len(self.structure.cylinders) else None

    @property
    def route_length(self) -> float:
        """Length of the route from start to goal, metres."""
        return self.centreline.route_length

    def lane_offset(self, lane: int) -> float:
        """Lateral offset of a right-hand lane (0 = innermost)."""
        return float(self.section.lane_centres[lane])

    def lane_offset_of_start(self) -> float:
        """Lateral offset the ego starts at: ego.start_offset, else the centre of its lane."""
        ego = self.scenario.ego
        return self.lane_offset(ego.lane) if ego.start_offset is None else ego.start_offset

    def _ego_start(self) -> EgoStart:
        """Where the ego starts: ego.start_s along the route, its offset, its heading relative to the road."""
        ego = self.scenario.ego
        line = self.centreline
        if not line.start + ego.length <= ego.start_s <= line.end - ego.length:
            raise ConfigError(f"ego.start_s {ego.start_s:g} m is off the road (it runs from {line.start:g} to "
                              f"{line.end:.0f} m along the route)")
        xy = line.to_xy(np.array(ego.start_s), np.array(self.lane_offset_of_start()))
        heading = float(line.heading(np.array(ego.start_s))) + np.radians(ego.start_heading)
        return EgoStart(xy.astype(np.float64), float(np.angle(np.exp(1j * heading))))

    def _clear_of_start(self, structure: Structure) -> Structure:
        """The structure without whatever stands within START_CLEARANCE of the ego's footprint at its start."""
        ego = self.scenario.ego
        zone = Rectangles(self.start.xy[None], np.array([self.start.yaw]), np.array([ego.length + 2 * START_CLEARANCE]),
                          np.array([ego.width + 2 * START_CLEARANCE]))
        boxes, cylinders, crowns = structure.boxes, structure.cylinders, structure.crowns
        keep_boxes = ~rectangles_overlap(zone.take(np.zeros(len(boxes), int)), Rectangles(
            boxes[:, :2], boxes[:, 2], boxes[:, 3], boxes[:, 4]))
        keep_cylinders = point_rectangle_distance(cylinders[:, :2], zone.take(np.zeros(len(cylinders), int))) > cylinders[:, 2]
        keep_crowns = point_rectangle_distance(crowns[:, :2], zone.take(np.zeros(len(crowns), int))) > 0.25
        return Structure(boxes[keep_boxes], structure.box_classes[keep_boxes], cylinders[keep_cylinders],
                         structure.cylinder_classes[keep_cylinders], crowns[keep_crowns])

    def _crosswalks(self) -> np.ndarray:
        spacing = self.scenario.route.crosswalk_spacing
        candidates = np.arange(spacing, self.route_length - spacing / 2, spacing)
        return np.array([s for s in candidates if self.centreline.is_straight(s - 8, s + 8)])

    def near_crosswalk(self, s: float, margin: float) -> bool:
        """Whether arc length s is within margin of a crosswalk."""
        return bool(len(self.crosswalks)) and bool(np.abs(self.crosswalks - s).min() < margin)

    def _structure(self, rng: np.random.Generator) -> Structure:
        cfg = self.scenario.structure
        line, section = self.centreline, self.section
        boxes: list[list[float]] = []
        classes: list[int] = []
        cylinders: list[list[float]] = []
        cylinder_classes: list[int] = []
        crowns: list[list[float]] = []

        def place_box(s: float, d: float, length: float, width: float, height: float, cls: PointClass) -> None:
            x, y = line.to_xy(np.array(s), np.array(d))
            boxes.append([x, y, float(line.heading(np.array(s))), length, width, height])
            classes.append(cls)

        for side in (-1.0, 1.0):
            s = line.start
            while s < line.end:
                length = rng.uniform(*cfg.building_length)
                depth, height = rng.uniform(8.0, 20.0), rng.uniform(*cfg.building_height)
                if line.is_straight(s - 5, s + length + 5):
                    front = section.sidewalk_outer + 1.0
                    if rng.random() < cfg.building_probability:
                        place_box(
                            s + length / 2, side * (front + depth / 2), length, depth, height, PointClass.BUILDING
                        )
                    else:
                        place_box(
                            s + length / 2,
                            side * (front + 0.2),
                            length,
                            0.4,
                            rng.uniform(1.2, 2.5),
                            PointClass.BUILDING,
                        )
                s += length + rng.uniform(2.0, 8.0)
            for s in np.arange(line.start + 5, line.end - 5, cfg.pole_spacing):
                x, y = line.to_xy(np.array(s), np.array(side * (section.sidewalk_outer - 0.4)))
                cylinders.append([x, y, 0.12, rng.uniform(6.0, 8.5)])
                cylinder_classes.append(PointClass.POLE)
            for s in np.arange(line.start + 9, line.end - 5, cfg.tree_spacing):
                s_tree = s + rng.uniform(-3, 3)
                x, y = line.to_xy(np.array(s_tree), np.array(side * (section.sidewalk_outer - 0.9)))
                trunk = rng.uniform(3.0, 4.5)
                cylinders.append([x, y, rng.uniform(0.12, 0.22), trunk])
                cylinder_classes.append(PointClass.VEGETATION)
                radius = rng.uniform(1.2, 2.2)
                crowns.append([x, y, trunk + radius * 0.8, radius])
            s = line.start + 3
            while s < line.end - 8:
                length = rng.uniform(4.0, 5.0)
                clear = line.is_straight(s - 3, s + length + 3) and not self.near_crosswalk(s + length / 2, 8.0)
                if clear and rng.random() < cfg.parked_car_probability:
                    place_box(
                        s + length / 2,
                        side * section.parking_centre,
                        length,
                        rng.uniform(1.7, 1.95),
                        rng.uniform(1.4, 1.9),
                        PointClass.PARKED_CAR,
                    )
                s += length + rng.uniform(1.0, 4.0)
        return Structure(
            np.array(boxes, np.float64).reshape(-1, 6),
            np.array(classes, np.uint8),
            np.array(cylinders, np.float64).reshape(-1, 4),
            np.array(cylinder_classes, np.uint8),
            np.array(crowns, np.float64).reshape(-1, 4),
        )

    def static_mesh(self) -> TriangleSoup:
        """Every static surface: ground, buildings, walls, poles, trees and parked cars."""
        st = self.structure
        box_base = self.ground.height(st.boxes[:, 0], st.boxes[:, 1]) - 0.5
        box_scale = np.c_[st.boxes[:, 3], st.boxes[:, 4], st.boxes[:, 5] + 0.5]
        cyl_base = self.ground.height(st.cylinders[:, 0], st.cylinders[:, 1]) - 0.3
        cyl_scale = np.c_[st.cylinders[:, 2], st.cylinders[:, 2], st.cylinders[:, 3] + 0.3]
        crown_z = self.ground.height(st.crowns[:, 0], st.crowns[:, 1]) + st.crowns[:, 2]
        return TriangleSoup.merge(
            [
                self.ground.mesh(),
                instances(BOX, box_scale, st.boxes[:, 2], np.c_[st.boxes[:, :2], box_base], st.box_classes),
                instances(
                    CYLINDER,
                    cyl_scale,
                    np.zeros(len(cyl_base)),
                    np.c_[st.cylinders[:, :2], cyl_base],
                    st.cylinder_classes,
                ),
                instances(
                    SPHERE,
                    np.repeat(st.crowns[:, 3:4], 3, 1),
                    np.zeros(len(crown_z)),
                    np.c_[st.crowns[:, :2], crown_z],
                    PointClass.VEGETATION,
                ),
            ]
        )

    def structure_near(self, xy: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """Indices of structure boxes and cylinders whose footprint may lie within radius of a point."""
        boxes = (
            np.array(self._box_tree.query_ball_point(xy, radius + self._box_radius), np.int64)
            if self._box_tree
            else np.zeros(0, np.int64)
        )
        cylinders = (
            np.array(self._cylinder_tree.query_ball_point(xy, radius + 0.5), np.int64)
            if self._cylinder_tree
            else np.zeros(0, np.int64)
        )
        return np.sort(boxes), np.sort(cylinders)
