"""Pairing messages of two topics that belong together (message_filters' exact-time policy, keyed by stamp and
iteration): a cloud and the small message published with it, such as /ssf/flow and its /ssf/ego_motion."""

from __future__ import annotations

import collections
from collections.abc import Callable, Hashable
from typing import Any, Generic, TypeVar

Main = TypeVar("Main")
Companion = TypeVar("Companion")


class ExactMatcher(Generic[Main, Companion]):
    """Hands each main item to `on_match` with the companion of the same key, once both came (in either order). The
    newest `depth` unmatched items of each side are kept; a main item whose companion has not come within
    `patience_s` (by the caller's steady clock) is handed on alone, with None."""

    def __init__(self, on_match: Callable[[Main, Companion | None], None], depth: int = 8,
                 patience_s: float = 0.5) -> None:
        self.on_match = on_match
        self.depth = depth
        self.patience_s = patience_s
        self.waiting: collections.OrderedDict[Hashable, tuple[Main, float]] = collections.OrderedDict()
        self.companions: collections.OrderedDict[Hashable, Companion] = collections.OrderedDict()
        self.alone = 0  # main items handed on without their companion

    def add_main(self, key: Hashable, item: Main, now_s: float) -> None:
        """A main item: handed on at once when its companion is here, else kept until it comes."""
        if key in self.companions:
            self.on_match(item, self.companions.pop(key))
            return
        self.waiting[key] = (item, now_s)
        self.waiting.move_to_end(key)
        while len(self.waiting) > self.depth:
            _, (oldest, _) = self.waiting.popitem(last=False)
            self._alone(oldest)

    def add_companion(self, key: Hashable, item: Companion) -> None:
        """A companion: its main item, when waiting, is handed on with it; else it is kept for it."""
        if key in self.waiting:
            main, _ = self.waiting.pop(key)
            self.on_match(main, item)
            return
        self.companions[key] = item
        self.companions.move_to_end(key)
        while len(self.companions) > self.depth:
            self.companions.popitem(last=False)

    def expire(self, now_s: float) -> None:
        """Hand on alone the main items that waited longer than patience_s."""
        for key in [key for key, (_, since) in self.waiting.items() if now_s - since > self.patience_s]:
            main, _ = self.waiting.pop(key)
            self._alone(main)

    def clear(self) -> None:
        """Forget everything (a restarted stream)."""
        self.waiting.clear()
        self.companions.clear()

    def _alone(self, item: Main) -> None:
        self.alone += 1
        self.on_match(item, None)


def ego_motion_listener(node: Any, matcher: ExactMatcher[Any, Any]) -> Callable[[Any], None]:
    """The /ssf/ego_motion callback of a node that pairs clouds with their ego motion: each one decoded (a bad one
    dropped in one line by the node) and offered to `matcher` under its stamp and iteration."""
    from ssf_common import topics
    from ssf_common.conversions import ego_motion_from_msg

    def on_ego_motion(msg: Any) -> None:
        ego = node.decoded(ego_motion_from_msg, msg, topics.EGO_MOTION)
        if ego is not None:
            matcher.add_companion((ego.stamp_ns, ego.iteration), ego)

    return on_ego_motion
