"""A bag's timestamps judged: the span the recording covers, and the messages outside it.

A recording is one stretch of time. A message stamped before 0, or separated from the rest of the bag by a
jump of more than an hour (a clock that was not set, a corrupt stamp), lies outside that stretch: `bag info`
reports it and `bag play` skips it, instead of printing a 50-year duration or sleeping for years.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

MAX_GAP_NS = 3600 * 10**9  # a jump of more than an hour separates the recording from stray stamps


class Timeline(NamedTuple):
    """The stretch of time a bag covers and what lies outside it."""

    start_ns: int  # first plausible timestamp
    end_ns: int  # last plausible timestamp
    messages: int  # all readable messages
    outside: int  # messages whose timestamps lie outside [start_ns, end_ns]
    negative: int  # of those, stamped before 0
    out_of_order: int  # messages stored after one with a later timestamp (replayed in time order)
    outside_examples: tuple[int, ...] = ()  # the earliest and the latest outside stamp

    @property
    def duration_ns(self) -> int:
        """Length of the plausible span."""
        return self.end_ns - self.start_ns if self.messages > self.outside else 0

    def contains(self, timestamp_ns: int) -> bool:
        """Whether a message with this stamp belongs to the recording's span."""
        return self.start_ns <= timestamp_ns <= self.end_ns

    def problem(self) -> str | None:
        """One line about the messages outside the span, None when there are none."""
        if not self.outside:
            return None
        far = self.outside - self.negative
        kinds = [f"{self.negative} stamped before 0"] if self.negative else []
        if far:
            kinds.append(f"{far} more than {MAX_GAP_NS // 3_600_000_000_000} h from the rest")
        examples = " and ".join(f"{stamp} ns" for stamp in self.outside_examples)
        return (
            f"{self.outside} of {self.messages} messages have implausible timestamps ({', '.join(kinds)}; "
            f"{examples}), outside the recording's span {self.start_ns} to {self.end_ns} ns"
        )

    def order_note(self) -> str | None:
        """One line about messages stored out of time order, None when there are none."""
        if not self.out_of_order:
            return None
        return f"{self.out_of_order} messages were stored after a later one; they are read in time order"


def judge(stored: Sequence[np.ndarray], max_gap_ns: int = MAX_GAP_NS) -> Timeline:
    """The timeline of a bag from each storage file's timestamps (int64 ns, in stored order)."""
    out_of_order = sum(int(np.count_nonzero(np.diff(times) < 0)) for times in stored if len(times) > 1)
    times = np.sort(np.concatenate([np.asarray(t, dtype=np.int64) for t in stored])) if stored else np.zeros(0, np.int64)
    if times.size == 0:
        return Timeline(0, 0, 0, 0, 0, out_of_order)
    negative = int(np.count_nonzero(times < 0))
    valid = times[negative:]
    if valid.size == 0:
        return Timeline(0, 0, int(times.size), int(times.size), negative, out_of_order, _examples(times))
    breaks = np.flatnonzero(np.diff(valid) > max_gap_ns) + 1
    starts = np.concatenate([[0], breaks])
    ends = np.concatenate([breaks, [valid.size]])
    largest = int(np.argmax(ends - starts))  # ties: the earliest stretch
    span = valid[starts[largest] : ends[largest]]
    outside = np.concatenate([times[:negative], valid[: starts[largest]], valid[ends[largest] :]])
    return Timeline(
        int(span[0]), int(span[-1]), int(times.size), int(outside.size), negative, out_of_order, _examples(outside)
    )


def _examples(outside: np.ndarray) -> tuple[int, ...]:
    if outside.size == 0:
        return ()
    low, high = int(outside.min()), int(outside.max())
    return (low,) if low == high else (low, high)
