"""Progress of long runs on stderr: a bar, how much of how much is done, and how long the rest will take."""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from typing import IO

BAR_WIDTH = 30


def bar(fraction: float, width: int = BAR_WIDTH) -> str:
    """`[#########.....................]` for a fraction in [0, 1]."""
    filled = int(width * min(max(fraction, 0.0), 1.0)) if math.isfinite(fraction) else 0
    return f"[{'#' * filled}{'.' * (width - filled)}]"


def duration_text(seconds: float) -> str:
    """`45 s`, `3 min 05 s` or `1 h 02 min`."""
    seconds = int(round(max(seconds, 0.0)))
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds // 3600} h {seconds % 3600 // 60:02d} min"


def progress_bar(total: int, unit: str = "scans", out: IO[str] | None = None) -> Callable[[int, float], None]:
    """A one-line bar redrawn in place: call it with the count done and the seconds elapsed."""
    def show(done: int, elapsed: float) -> None:
        rate = elapsed / max(done, 1)
        print(f"\r  {bar(done / max(total, 1))} {done}/{total} {unit}, {rate:.2f} s per {unit.rstrip('s')}, "
              f"{rate * (total - done):.0f} s left", end="" if done < total else "\n", file=out or sys.stderr,
              flush=True)
    return show


def sim_time_line(sim_s: float, total_s: float, wall_s: float) -> str:
    """Simulated time against wall time: `t 5.0 / 20 s [#######...] 6.1× slower than real time, about 46 s left`."""
    line = f"t {sim_s:.1f} / {total_s:g} s {bar(sim_s / total_s if total_s > 0 else 0.0)}"
    if sim_s <= 0.0 or wall_s <= 0.0:
        return f"{line} (waiting for the first simulated step)"
    pace = wall_s / sim_s
    speed = f"{pace:.1f}× slower than real time" if pace >= 1.0 else f"{1.0 / pace:.1f}× faster than real time"
    return f"{line} {speed}, about {duration_text(pace * max(total_s - sim_s, 0.0))} left"
