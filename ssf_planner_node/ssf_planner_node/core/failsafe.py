"""The planner's fail safe: the car stops when its perception stops.

An input the planner needs (odometry, obstacles) is fresh while it keeps coming with newer stamps. Older than
`stale_periods` sensor periods by the node's clock (simulated time: behaviour), or silent for `silent_after_s` of the
steady clock (liveness: a stopped simulator, lockstep with a dead stage), it is stale and the car brakes: from the
lower of the speed last commanded and the speed last measured, each command slower than the last, down to zero, on
the arc of the last command. At most one braking command per control period, paced by the steady clock as well: in
lockstep each command releases a simulator step, and braking faster than real time would outrun the perception it
waits for. An empty obstacle picture right after one with obstacles close to the car is not believed (they cannot all
have gone in one scan): it is dropped, and the obstacles go stale."""

from __future__ import annotations

from enum import Enum
from typing import NamedTuple

import numpy as np

from ssf_common.records import Obstacles
from ssf_planner_node.core.config import FailSafeConfig
from ssf_planner_node.core.models import Command


class Source(str, Enum):
    """The inputs the planner needs; each is stale as `Reason.stale_<name>`."""

    ODOMETRY = "odometry"
    OBSTACLES = "obstacles"


class InputHeard(NamedTuple):
    """When an input was last fresh: the node's clock and the steady clock (ns), and its stamp."""

    clock_ns: int
    steady_ns: int
    stamp_ns: int


class Staleness(NamedTuple):
    """A stale input: which, and one line on why (for the log and PlannerState's reason)."""

    source: Source
    detail: str

    @property
    def reason(self) -> str:
        """PlannerState's reason key: stale_odometry or stale_obstacles."""
        return f"stale_{self.source.value}"


RESTART_NS = 1_000_000_000  # stamps this far behind the newest start a new sequence (ssf_common.stamps' RESTART_S)
PACE = 0.8  # braking commands are at least this share of a control period of steady time apart (timers jitter)


class InputWatch:
    """Freshness of the planner's inputs on two clocks, and when a braking command is due."""

    def __init__(self, config: FailSafeConfig, control_period: float) -> None:
        self.config = config
        self.period_ns = int(round(control_period * 1e9))
        self.heard: dict[Source, InputHeard] = {}
        self._last_brake: tuple[int, int] | None = None  # (node clock, steady clock) of the last braking command

    def take(self, source: Source, stamp_ns: int, clock_ns: int, steady_ns: int) -> bool:
        """A message of `source` arrived: fresh (True) when its stamp is newer than the last one's or jumps back by
        more than a second (a restarted stream); a repeat or a late one (False) does not count."""
        last = self.heard.get(source)
        if last is not None and last.stamp_ns - RESTART_NS <= stamp_ns <= last.stamp_ns:
            return False
        self.heard[source] = InputHeard(int(clock_ns), int(steady_ns), int(stamp_ns))
        return True

    def stale(self, clock_ns: int, steady_ns: int, running: bool = False,
              sources: tuple[Source, ...] = tuple(Source)) -> list[Staleness]:
        """The stale inputs among `sources`: none yet, older than stale_after_s by the node's clock (or from before the
        clock went back), or silent for silent_after_s by the steady clock. While the node's clock runs with the
        steady one (`running`: wall time, a simulator in real time), an input is also stale once older than
        stale_after_s by the steady clock: a simulated clock ticks once per scan, and an age read off it is up to a
        tick late."""
        found = []
        limit = self.config.stale_after_s
        for source in sources:
            heard = self.heard.get(source)
            age = None if heard is None else (clock_ns - heard.clock_ns) * 1e-9
            steady_age = None if heard is None else (steady_ns - heard.steady_ns) * 1e-9
            if heard is None:
                found.append(Staleness(source, f"no {source.value} yet"))
            elif age < 0:
                found.append(Staleness(source, f"{source.value} from before the clock went back"))
            elif max(age, steady_age if running else 0.0) > limit + 1e-9:
                found.append(Staleness(source, f"{source.value} {max(age, steady_age if running else 0.0):.2f} s "
                                               f"old (more than {limit:g} s)"))
            else:
                found += self.silent(steady_ns, (source,))
        return found

    def silent(self, steady_ns: int, sources: tuple[Source, ...] = tuple(Source)) -> list[Staleness]:
        """The inputs among `sources` that came once and have been silent for silent_after_s of the steady clock:
        what the steady watchdog brakes for, whatever the node's clock does."""
        found = []
        for source in sources:
            heard = self.heard.get(source)
            silent = None if heard is None else (steady_ns - heard.steady_ns) * 1e-9
            if silent is not None and silent > self.config.silent_after_s:
                found.append(Staleness(source, f"no {source.value} for {silent:.1f} s of steady time"))
        return found

    def brake_due(self, clock_ns: int, steady_ns: int) -> bool:
        """Whether a braking command is due (then it is taken as sent): the first, or one at least most of a control
        period of steady time after the last (a brake releases a lockstep simulator's step: braking must not race it)
        with the node's clock a control period on, gone back, or standing still."""
        last = self._last_brake
        due = last is None or (steady_ns - last[1] >= PACE * self.period_ns
                               and (clock_ns - last[0] >= self.period_ns or clock_ns <= last[0]))
        if due:
            self._last_brake = (int(clock_ns), int(steady_ns))
        return due

    def braked(self, clock_ns: int, steady_ns: int) -> None:
        """A braking command was sent now (on a tick): the next one is due a control period later."""
        self._last_brake = (int(clock_ns), int(steady_ns))

    def released(self) -> None:
        """The car drives again: the next braking starts at once."""
        self._last_brake = None


def brake_command(last: Command | None, measured_speed: float, decrement: float) -> Command:
    """The next braking command: `decrement` slower than the lower of the last command (None: none yet) and the
    measured speed, never below zero, on the last command's arc (turning straight in a bend would leave the lane)."""
    speeds = [speed for speed in (measured_speed, last.linear if last is not None else np.nan) if np.isfinite(speed)]
    slowed = max(min(speeds, default=0.0) - decrement, 0.0)
    curvature = last.angular / last.linear if last is not None and abs(last.linear) > 1e-3 else 0.0
    return Command(slowed, curvature * slowed)


def implausible_emptiness(previous: Obstacles | None, new: Obstacles, ego_xy: np.ndarray, vanish_range: float) -> str:
    """Why an obstacle array cannot be believed ("" when it can): empty right after one (in the same frame) with an
    obstacle within `vanish_range` of the car at `ego_xy`."""
    if len(new) or previous is None or not len(previous) or vanish_range <= 0 or previous.frame_id != new.frame_id:
        return ""
    nearest = float(np.linalg.norm(previous.centres[:, :2] - np.asarray(ego_xy)[:2], axis=1).min())
    if nearest > vanish_range:
        return ""
    return (f"an empty obstacle array right after one with an obstacle {nearest:.1f} m away (within "
            f"{vanish_range:g} m): they cannot all be gone")
