"""Navigation campaigns: seeded trial specs mapped over a local process pool or a Ray cluster, every finished trial
appended to a JSONL file at once (Ctrl-C, a crash or a lost worker loses nothing; resume skips what is done). Trials
run in fresh worker processes with Open3D on one thread (`repeatable`), so a seeded trial gives the same record
anywhere."""

from __future__ import annotations

import json
import multiprocessing
import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Protocol, TextIO

from ssf_common.errors import ConfigError, DataError
from ssf_eval.nav.loop import TrialRecord, TrialSpec, run_trial
from ssf_eval.nav.repeatable import TrialFailure, attempt, pool_worker, ray_attempt


def campaign_specs(perceptions: list[str], agents: list[int], trials: int, seed: int = 100,
                   route_length: float | None = None, time_limit: float | None = None, pose: str = "gt",
                   planner: dict | None = None, scenario: dict | None = None, latency_s: float = 0.0,
                   answer_every: int = 1, loop_iterations: int = 1) -> list[TrialSpec]:
    """Every (perception, agents, trial) with seeds seed .. seed + trials - 1: all cells see the same worlds."""
    if trials < 1:
        raise ConfigError(f"--trials must be at least 1, got {trials}")
    return [TrialSpec(name, count, seed + index, route_length, time_limit, pose, dict(planner or {}), dict(scenario or {}),
                      latency_s=latency_s, answer_every=answer_every, loop_iterations=loop_iterations)
            for count in agents for name in perceptions for index in range(trials)]


class TrialLog:
    """The JSONL file of finished trials: read what is done, append each new record durably."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)

    def records(self) -> list[TrialRecord]:
        """Every complete record in the file (a torn last line from an interrupted write is ignored)."""
        if not self.path.is_file():
            return []
        records = []
        for number, line in enumerate(self.path.read_text().splitlines(), 1):
            if not line.strip():
                continue
            try:
                records.append(TrialRecord.from_json(json.loads(line)))
            except (json.JSONDecodeError, KeyError, TypeError) as err:
                if number < len(self.path.read_text().splitlines()):
                    raise DataError(f"{self.path}: line {number} is not a trial record ({err})") from None
        return records

    def append(self, record: TrialRecord) -> None:
        """Write one record and make it durable before returning."""
        with self.path.open("a") as handle:
            handle.write(json.dumps(record.to_json(), allow_nan=False) + "\n")
            handle.flush()
            os.fsync(handle.fileno())


class Runner(Protocol):
    """Maps `attempt` over specs, yielding records (or failures) as trials finish, in any order."""

    def map(self, specs: list[TrialSpec]) -> Iterator[TrialRecord | TrialFailure]:
        """Run every spec; yield each record when it is done."""


@dataclass
class LocalRunner:
    """A pool of `workers` fresh processes, Open3D on one thread in each (`in_process`: in this process instead, for
    trial functions a fresh process cannot import; Open3D's answers may then differ in the last bits from run to run)."""

    workers: int = 1
    trial: Callable[[TrialSpec], TrialRecord] = run_trial
    in_process: bool = False

    def map(self, specs: list[TrialSpec]) -> Iterator[TrialRecord | TrialFailure]:
        """Trials on the pool, at most `workers` at a time; pending ones are cancelled on Ctrl-C."""
        if self.in_process:
            for spec in specs:
                yield attempt(spec, self.trial)
            return
        fresh = multiprocessing.get_context("spawn")  # a forked worker would have Open3D loaded already
        with ProcessPoolExecutor(max_workers=max(self.workers, 1), mp_context=fresh, initializer=pool_worker) as pool:
            pending: set[Future] = set()
            queue = list(reversed(specs))
            try:
                while queue or pending:
                    while queue and len(pending) < 2 * self.workers:
                        pending.add(pool.submit(attempt, queue.pop(), self.trial))
                    done, pending = wait(pending, return_when=FIRST_COMPLETED)
                    for future in done:
                        yield future.result()
            finally:
                for future in pending:
                    future.cancel()


@dataclass
class RayRunner:
    """Trials as Ray tasks on a cluster (`address`: 'auto', 'ray://host:port') or a local Ray ('local')."""

    address: str = "local"
    local_mode: bool = False
    trial: Callable[[TrialSpec], TrialRecord] = run_trial
    options: dict = field(default_factory=dict)

    def map(self, specs: list[TrialSpec]) -> Iterator[TrialRecord | TrialFailure]:
        """One task per trial (trials take seconds to minutes, far above Ray's per-task cost)."""
        try:
            import ray
        except ImportError:
            raise ConfigError("--ray needs the ray extra: pip install '.[ray]'") from None
        started_here = not ray.is_initialized()
        if started_here:
            address = None if self.address == "local" else self.address
            ray.init(address=address, include_dashboard=False, log_to_driver=False, **self.options)
        if self.local_mode:  # in this process, as it is
            remote = ray.remote(num_cpus=1)(attempt)
            pending = [remote.remote(spec, self.trial) for spec in specs]
        else:
            remote = ray.remote(num_cpus=1)(ray_attempt)
            trial = None if self.trial is run_trial else self.trial
            pending = [remote.remote(asdict(spec), trial) for spec in specs]
        try:
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                for ref in done:
                    yield ray.get(ref)
        finally:
            for ref in pending:
                ray.cancel(ref, force=True)
            if started_here:
                ray.shutdown()


@dataclass
class CampaignProgress:
    """One stderr line per finished trial: count, elapsed, ETA, and the running success rate of its cell."""

    total: int
    out: TextIO = sys.stderr
    started: float = field(default_factory=time.monotonic)
    done: int = 0
    cells: dict[tuple[str, int], list[int]] = field(default_factory=dict)

    def seed_cells(self, records: Iterable[TrialRecord]) -> None:
        """Count trials finished before this run (resume)."""
        for record in records:
            self._count(record)

    def update(self, record: TrialRecord) -> None:
        """Report one more finished trial."""
        self.done += 1
        wins, runs = self._count(record)
        elapsed = time.monotonic() - self.started
        eta = elapsed / self.done * (self.total - self.done)
        print(f"[{self.done}/{self.total} {100 * self.done / self.total:3.0f}%] {_clock(elapsed)} elapsed, ETA "
              f"{_clock(eta)} | {record.perception}/{record.agents} seed {record.seed}: {record.outcome} "
              f"{record.navigation_time_s:.1f} s | cell {record.perception}/{record.agents}: {wins}/{runs} "
              f"success ({wins / runs:.2f})", file=self.out, flush=True)

    def _count(self, record: TrialRecord) -> tuple[int, int]:
        cell = self.cells.setdefault((record.perception, record.agents), [0, 0])
        cell[0] += int(record.success)
        cell[1] += 1
        return cell[0], cell[1]


def run_campaign(specs: list[TrialSpec], log: TrialLog, runner: Runner, out: TextIO | None = None) -> list[TrialRecord]:
    """Run the specs not yet in the log; every record is in the log as soon as its trial ends. Returns the log's
    records for these specs (old and new). Progress goes to `out` (default stderr)."""
    out = out or sys.stderr
    finished = {record.key: record for record in log.records()}
    todo = [spec for spec in specs if spec.key not in finished]
    if finished:
        print(f"resuming {log.path}: {len(specs) - len(todo)} of {len(specs)} trials already done", file=out)
    progress = CampaignProgress(len(todo), out)
    progress.seed_cells(finished[spec.key] for spec in specs if spec.key in finished)
    for record in runner.map(todo):
        if isinstance(record, TrialFailure):
            print(f"trial {record.key} failed ({record.error}); not logged, a resumed run retries it", file=out,
                  flush=True)
            continue
        log.append(record)
        finished[record.key] = record
        progress.update(record)
    return [finished[spec.key] for spec in specs if spec.key in finished]


def _clock(seconds: float) -> str:
    seconds = int(seconds)
    return f"{seconds // 3600:d}:{seconds % 3600 // 60:02d}:{seconds % 60:02d}"
