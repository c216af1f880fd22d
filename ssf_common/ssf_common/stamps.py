"""Streams that start again: a simulator reset or a looping bag sends stamps back to the beginning (the ROS idiom for
a time jump backwards), and a stateful node starts a new sequence instead of dropping every message as late."""

from __future__ import annotations

RESTART_S = 1.0  # stamps this much older than the newest seen start a new sequence; anything less is a late message


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
