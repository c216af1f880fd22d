"""How the perception did, scan by scan: the true moving agents the LiDAR saw matched to the moving obstacles the
perception reported (perceived, missed, phantoms), beside the still obstacles it reported.

A true agent is moving at `moving_speed` or faster, and counted when it lies within `count_radius_m` of the ego and
the scan has at least `seen_points` points on it (an agent hidden behind another cannot be perceived). A perceived
obstacle is moving at `moving_speed` or faster; it is on a true agent when its centre lies within `match_margin_m`
of the agent's box. A counted agent with a moving obstacle on it is perceived, else missed; a moving obstacle on no
moving agent is a phantom."""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from ssf_common import topics
from ssf_common.records import Obstacles
from ssf_common.render.frames import EpisodeTrack, RenderConfig, header_stamp

GROUND_CLEARANCE_M = 0.25  # points lower in an agent's box are the road under it
POINT_MARGIN_M = 0.3  # scan points this far outside an agent's box still lie on it (noise, the sweep's motion)


class FrameCounts(NamedTuple):
    """One scan's tally (within the counting radius)."""

    stamp_ns: int
    true: int  # moving agents the scan saw
    perceived: int  # moving obstacles reported
    matched: int  # true moving agents with a moving obstacle on them
    missed: int  # true moving agents with none
    phantoms: int  # moving obstacles on no moving agent
    still: int  # still obstacles reported


class Judgement(NamedTuple):
    """One scan's tally and what to mark in a picture of it."""

    counts: FrameCounts
    missed_ids: frozenset[int]  # ids of the true agents missed
    phantom_centres: np.ndarray  # (P, 2) world positions of the phantoms


def moving(obstacles: Obstacles, speed: float) -> np.ndarray:
    """(M,) bool: the obstacles at least this fast on the ground plane."""
    return np.hypot(obstacles.velocities[:, 0], obstacles.velocities[:, 1]) >= speed


def near(obstacles: Obstacles, centre: np.ndarray, radius: float) -> np.ndarray:
    """(M,) bool: the obstacles whose centre lies within `radius` of a ground-plane point."""
    return np.hypot(*(obstacles.centres[:, :2] - centre[:2]).T) <= radius


def box_frame(obstacles: Obstacles, index: int, xy: np.ndarray) -> np.ndarray:
    """(N, 2) ground-plane points in one box's axes (along its length, across), from its centre."""
    c, s = np.cos(obstacles.yaws[index]), np.sin(obstacles.yaws[index])
    offset = xy - obstacles.centres[index, :2]
    return np.column_stack([offset @ np.array([c, s]), offset @ np.array([-s, c])])


def points_on(boxes: Obstacles, xyz: np.ndarray, margin: float) -> np.ndarray:
    """(M,) how many points lie in each box grown by `margin` (above the road under it)."""
    counts = np.zeros(len(boxes), np.int64)
    for i in range(len(boxes)):
        length, width, height = boxes.sizes[i]
        reach = 0.5 * np.hypot(length, width) + margin
        close = np.flatnonzero((np.abs(xyz[:, 0] - boxes.centres[i, 0]) <= reach)
                               & (np.abs(xyz[:, 1] - boxes.centres[i, 1]) <= reach))
        uv = box_frame(boxes, i, xyz[close, :2])
        z = xyz[close, 2] - boxes.centres[i, 2]
        inside = ((np.abs(uv[:, 0]) <= length / 2 + margin) & (np.abs(uv[:, 1]) <= width / 2 + margin)
                  & (z >= -height / 2 + GROUND_CLEARANCE_M) & (z <= height / 2 + margin))
        counts[i] = int(inside.sum())
    return counts


def on_boxes(centres: np.ndarray, boxes: Obstacles, margin: float) -> np.ndarray:
    """(K, M) bool: which ground-plane points lie within `margin` of which box's footprint."""
    found = np.zeros((len(centres), len(boxes)), bool)
    for i in range(len(boxes)):
        uv = box_frame(boxes, i, centres[:, :2])
        found[:, i] = (np.abs(uv[:, 0]) <= boxes.sizes[i, 0] / 2 + margin) & \
                      (np.abs(uv[:, 1]) <= boxes.sizes[i, 1] / 2 + margin)
    return found


def judge_frame(stamp_ns: int, ego_xy: np.ndarray, agents: Obstacles, perceived: Obstacles, scan: np.ndarray | None,
                config: RenderConfig) -> Judgement:
    """Match one scan's perceived obstacles to the true agents, everything in the world frame; `scan` (N, 3) is the
    scan's points (None: every moving agent in range counts as seen)."""
    agents = agents.take(near(agents, ego_xy, config.count_radius_m + 5.0))  # a box's centre may lie a little out
    perceived = perceived.take(near(perceived, ego_xy, config.count_radius_m))
    agents_moving, perceived_moving = moving(agents, config.moving_speed), moving(perceived, config.moving_speed)
    movers, reported = agents.take(agents_moving), perceived.take(perceived_moving)
    seen = near(movers, ego_xy, config.count_radius_m)
    if scan is not None:
        seen &= points_on(movers, scan, POINT_MARGIN_M) >= config.seen_points
    on = on_boxes(reported.centres, movers, config.match_margin_m)
    found = on.any(axis=0) & seen
    phantom = ~on.any(axis=1)
    counts = FrameCounts(stamp_ns, int(seen.sum()), len(reported), int(found.sum()), int((seen & ~found).sum()),
                         int(phantom.sum()), int((~perceived_moving).sum()))
    return Judgement(counts, frozenset(int(k) for k in movers.ids[seen & ~found]), reported.centres[phantom, :2])


def judge_recording(bag: Any, track: EpisodeTrack, config: RenderConfig) -> dict[int, Judgement]:
    """Every scan with perceived obstacles and true agents at its stamp, judged (keyed by the scan's stamp): the
    scans (or, without them, the segmented clouds) streamed once to see which agents they hit."""
    from ssf_common.errors import BagError, MessageError
    from ssf_common.pointcloud import decode_cloud

    wanted = set(track.perceived) & set(track.agents)
    if not wanted:
        return {}
    topic = next((name for name in (topics.LIDAR_POINTS, topics.SEMANTIC_FLOW) if name in bag.topics), None)
    judged: dict[int, Judgement] = {}
    for message in bag.messages([topic] if topic else []):
        stamp = header_stamp(message.data)
        if stamp not in wanted or stamp in judged:
            continue
        ego = track.truth.at(stamp)
        agents, perceived = track.in_world(track.agents[stamp]), track.in_world(track.perceived[stamp])
        if ego is None or agents is None or perceived is None:
            continue
        try:
            msg = bag.decode(message)
            xyz = decode_cloud(msg).xyz.astype(np.float64)
        except (BagError, MessageError):
            continue
        to_world = track.world_from(msg.header.frame_id, stamp)
        if to_world is None:
            continue
        world = xyz @ to_world[:3, :3].T + to_world[:3, 3]
        judged[stamp] = judge_frame(stamp, ego[:2, 3], agents, perceived, world, config)
    return judged


def summary_line(counts: list[FrameCounts]) -> str:
    """The whole run in one line: how many sightings of true moving agents were perceived, missed, and phantoms."""
    if not counts:
        return "no scan with both perceived obstacles and true agents"
    true, matched = sum(c.true for c in counts), sum(c.matched for c in counts)
    share = f"{100 * matched / true:.0f} % of {true}" if true else "none of 0"
    return (f"{share} true moving agents seen by the LiDAR perceived, {true - matched} missed; "
            f"{sum(c.phantoms for c in counts) / len(counts):.1f} phantoms and "
            f"{float(np.median([c.still for c in counts])):.0f} still obstacles per scan (median) over {len(counts)} scans")
