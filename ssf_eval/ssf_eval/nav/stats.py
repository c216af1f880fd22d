"""Small pure functions of the navigation benchmark: Wilson intervals, the BARN-style score, per-cell summaries."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import asdict, dataclass
from typing import Any, Iterable

from ssf_eval.nav.loop import QUEUE_MIN, TrialOutcome, TrialRecord

Z95 = 1.959963984540054


def wilson_interval(successes: int, trials: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval of a success rate (95 % by default); (0, 1) without trials."""
    if trials <= 0:
        return 0.0, 1.0
    if not 0 <= successes <= trials:
        raise ValueError(f"{successes} successes out of {trials} trials")
    p = successes / trials
    denominator = 1.0 + z * z / trials
    centre = (p + z * z / (2 * trials)) / denominator
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / denominator
    return max(0.0, centre - half), min(1.0, centre + half)


def barn_score(success: bool, route_length: float, time_s: float, reference_speed: float) -> float:
    """BARN's score, success * OT / clip(AT, 2 OT, 8 OT), with the optimal time OT = route length / reference speed
    (at most 0.5: full marks for averaging at least half the reference speed)."""
    if not success:
        return 0.0
    optimal = route_length / reference_speed
    return optimal / min(max(time_s, 2 * optimal), 8 * optimal)


def source_name(perception: str, pose: str, late: bool = False) -> str:
    """A table row's name: the perception source ("(real time)": answering as late and as rarely as the real-time
    graph), and the pose source when it is not the ground truth."""
    name = f"{perception} (real time)" if late else perception
    return name if pose == "gt" else f"{name} + {pose} pose"


@dataclass(frozen=True)
class CellSummary:
    """One (perception, agents) cell: the paper's three columns with a Wilson interval, outcomes and costs."""

    perception: str
    agents: int
    trials: int
    successes: int
    success_rate: float
    success_ci95: tuple[float, float]
    navigation_time_s: float | None  # mean over successful trials
    average_speed_mps: float | None  # mean over successful trials
    moving_speed_mps: float | None  # the paper's moving average speed: mean over successful trials that recorded it
    collisions: int
    collisions_by_kind: dict[str, int]
    timeouts: int
    stuck: int
    queued: int  # of the stuck and timed-out trials, those behind vehicles standing in the route's lane
    barn_score: float
    min_clearance_m_median: float
    path_length_m_mean: float
    fallback_rate: float  # fallback ticks / ticks
    solve_ms_p95: float  # median over trials of each trial's p95
    pose: str = "gt"  # where the ego pose came from: the simulator (gt) or SSF odometry (ssf)
    pose_error_max_m: float = 0.0  # with the ssf pose: the median over trials of each trial's largest position error
    latency_s: float = 0.0  # perception answered this long after its scan (0: lockstep)
    answer_every: int = 1  # perception answered one scan in this many

    @property
    def source(self) -> str:
        """The row's name: the perception source, whether it answered as the real-time graph does, and the pose source
        when it is not the ground truth."""
        return source_name(self.perception, self.pose, self.latency_s > 0 or self.answer_every > 1)

    def to_json(self) -> dict[str, Any]:
        """Plain data for the result file."""
        return asdict(self)


def summarise(records: Iterable[TrialRecord], reference_speed: float = 10.0) -> list[CellSummary]:
    """Per (perception, pose, timing, agents) cell: the sources in the order they first appear, each by growing
    density (timing: how late and how rarely perception answered)."""
    cells: dict[tuple, list[TrialRecord]] = {}
    sources: dict[tuple, int] = {}
    for record in records:
        source = (record.perception, record.pose, record.latency_s, record.answer_every)
        sources.setdefault(source, len(sources))
        cells.setdefault((*source, record.agents), []).append(record)
    ordered = sorted(cells.items(), key=lambda item: (sources[item[0][:4]], item[0][4]))
    return [summarise_cell(key[0], key[4], rows, reference_speed) for key, rows in ordered]


def summarise_cell(perception: str, agents: int, rows: list[TrialRecord], reference_speed: float) -> CellSummary:
    """The summary of one cell's trials."""
    outcomes = Counter(row.outcome for row in rows)
    won = [row for row in rows if row.success]
    collisions = {kind.value.removeprefix("collision_"): outcomes[kind.value] for kind in TrialOutcome
                  if kind.value.startswith("collision_")}
    ticks = sum(row.ticks for row in rows)
    return CellSummary(
        perception=perception, agents=agents, trials=len(rows), successes=len(won),
        success_rate=round(len(won) / len(rows), 4), success_ci95=tuple(round(v, 4) for v in wilson_interval(len(won), len(rows))),
        navigation_time_s=_mean([row.navigation_time_s for row in won]),
        average_speed_mps=_mean([row.average_speed_mps for row in won]),
        moving_speed_mps=_mean([row.moving_speed_mps for row in won if row.moving_speed_mps is not None]),
        collisions=sum(collisions.values()), collisions_by_kind=collisions,
        timeouts=outcomes[TrialOutcome.TIMEOUT.value], stuck=outcomes[TrialOutcome.STUCK.value],
        queued=sum(row.standing_ahead is not None and row.standing_ahead >= QUEUE_MIN for row in rows),
        barn_score=round(sum(barn_score(row.success, row.route_length_m, row.navigation_time_s, reference_speed)
                             for row in rows) / len(rows), 4),
        min_clearance_m_median=round(_median([row.min_clearance_m for row in rows]), 3),
        path_length_m_mean=round(sum(row.path_length_m for row in rows) / len(rows), 1),
        fallback_rate=round(sum(row.fallbacks for row in rows) / ticks, 5) if ticks else 0.0,
        solve_ms_p95=round(_median([row.solve_ms_p95 for row in rows]), 2), pose=rows[0].pose,
        pose_error_max_m=round(_median([row.pose_error_max_m for row in rows]), 3), latency_s=rows[0].latency_s,
        answer_every=rows[0].answer_every)


def _mean(values: list[float]) -> float | None:
    return round(sum(values) / len(values), 3) if values else None


def _median(values: list[float]) -> float:
    ordered = sorted(values)
    middle = len(ordered) // 2
    return (ordered[middle] if len(ordered) % 2 else (ordered[middle - 1] + ordered[middle]) / 2) if ordered else 0.0
