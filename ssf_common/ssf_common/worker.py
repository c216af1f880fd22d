"""Keep-newest background work: a node's callbacks never wait for a long computation."""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from typing import Any

from ssf_common.errors import SsfError


class LatestWorker:
    """Runs jobs on one thread; per kind of job only the newest pending one is kept, the rest are counted as dropped.

    Kinds are served in the order given (first = most urgent).
    """

    def __init__(self, handle: Callable[[str, Any], None], kinds: Sequence[str], logger: Any, name: str) -> None:
        self._handle = handle
        self._kinds = tuple(kinds)
        self._logger = logger
        self._pending: dict[str, Any] = {}
        self._condition = threading.Condition()
        self._stopped = False
        self.processed = {kind: 0 for kind in self._kinds}
        self.dropped = {kind: 0 for kind in self._kinds}
        self.failed = {kind: 0 for kind in self._kinds}
        self._busy = False
        self._thread = threading.Thread(target=self._loop, name=f"{name}-worker", daemon=True)
        self._thread.start()

    def submit(self, kind: str, job: Any) -> None:
        """Queue a job; an older pending job of the same kind is replaced (and counted as dropped)."""
        with self._condition:
            if kind in self._pending:
                self.dropped[kind] += 1
            self._pending[kind] = job
            self._condition.notify()

    def idle(self) -> bool:
        """Whether nothing is pending or running."""
        with self._condition:
            return not self._pending and not self._busy

    def stop(self, timeout_s: float = 5.0) -> None:
        """Finish the running job, discard pending ones, end the thread."""
        with self._condition:
            self._stopped = True
            self._pending.clear()
            self._condition.notify()
        self._thread.join(timeout_s)

    def _next(self) -> tuple[str, Any] | None:
        with self._condition:
            self._busy = False
            while not self._pending and not self._stopped:
                self._condition.wait()
            if self._stopped:
                return None
            kind = next(kind for kind in self._kinds if kind in self._pending)
            self._busy = True
            return kind, self._pending.pop(kind)

    def _loop(self) -> None:
        while (item := self._next()) is not None:
            kind, job = item
            try:
                self._handle(kind, job)
                self.processed[kind] += 1
            except SsfError as err:
                self.failed[kind] += 1
                self._logger.error(f"dropped a {kind}: {err}")
            except Exception as err:  # noqa: BLE001 - one bad input must not stop the worker
                self.failed[kind] += 1
                self._logger.error(f"{kind} failed ({type(err).__name__}: {err}); dropped it")
