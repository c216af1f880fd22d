"""Stamps of a sensor stream: its period as the stamps tell it (a lost scan shows as a gap of more than one period),
and streams that start again: a simulator reset or a looping bag sends stamps back to the beginning (the ROS idiom for
a time jump backwards), and a stateful node starts a new sequence instead of dropping every message as late."""

from __future__ import annotations

RESTART_S = 1.0  # stamps this much older than the newest seen start a new sequence; anything less is a late message
LOST_SCAN_GAP = 1.5  # in shortest gaps: two scans farther apart have a lost scan between them
PERIOD_CONFIRMATIONS = 3  # the shortest gap between answered scans is the sensor's period once seen this often ...
PERIOD_JITTER = 0.05  # ... within this share of it (a driver's stamps jitter)


class SensorPeriod:
    """The sensor's period from the gaps between its scans: the shortest gap seen (what tells a lost scan at once)
    and the period, the shortest gap once it came PERIOD_CONFIRMATIONS times within PERIOD_JITTER (a loaded graph
    answers scans seconds apart at first, and later only some of them)."""

    def __init__(self) -> None:
        self.shortest_ns: int | None = None
        self.period_ns: int | None = None
        self._candidate: tuple[int, int] | None = None  # the shortest answered gap yet, and how often it came

    def consecutive(self, gap_ns: int) -> bool:
        """Take one gap between neighbouring scans; whether those two scans are consecutive sweeps."""
        self.shortest_ns = gap_ns if self.shortest_ns is None else min(self.shortest_ns, gap_ns)
        return not self.spans_lost_scan(gap_ns)

    def spans_lost_scan(self, gap_ns: int) -> bool:
        """Whether two scans this far apart have a lost scan between them (unknown before any gap: assumed so)."""
        return self.shortest_ns is None or gap_ns > LOST_SCAN_GAP * self.shortest_ns

    def learn(self, gap_ns: int) -> int | None:
        """Take one gap between two answered scans; the period once confirmed (None before)."""
        shortest, seen = self._candidate or (gap_ns, 0)
        if gap_ns < (1.0 - PERIOD_JITTER) * shortest:
            shortest, seen = gap_ns, 0
        if gap_ns <= (1.0 + PERIOD_JITTER) * shortest:
            shortest, seen = min(shortest, gap_ns), seen + 1
        self._candidate = (shortest, seen)
        if seen >= PERIOD_CONFIRMATIONS:
            self.period_ns = shortest
        return self.period_ns


class StampSequence:
    """Tells a stream's restart (stamps jumping back by more than `restart_s`) from a message that is merely late."""

    def __init__(self, restart_s: float = RESTART_S) -> None:
        self.restart_ns = int(restart_s * 1e9)
        self.newest_ns: int | None = None
        self.restarts = 0

    def restarted(self, stamp_ns: int) -> bool:
        """Whether this stamp starts a new sequence (then it is the newest), remembering the newest stamp seen."""
        restart = self.newest_ns is not None and stamp_ns < self.newest_ns - self.restart_ns
        if restart or self.newest_ns is None or stamp_ns > self.newest_ns:
            self.newest_ns = int(stamp_ns)
        self.restarts += int(restart)
        return restart
