"""Repeatable trials: Open3D loaded with a thread pool of one (this module imports nothing heavy, so it runs first).

Open3D's ICP sums over its thread pool (TBB: OMP_NUM_THREADS does not reach it) in an order that changes from run to
run, and a closed loop grows those last bits into another trial. TBB sizes its pool to the CPUs the process may use
when Open3D loads; loaded while the process is held to one CPU (and let go at once), the ICP gives the same answer
every time, so a seeded campaign gives the same table in one worker, on a pool or on Ray."""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ssf_eval.nav.loop import TrialRecord, TrialSpec


@dataclass(frozen=True)
class TrialFailure:
    """A trial that raised instead of finishing: not logged, so a resumed campaign runs it again."""

    key: str
    error: str


def attempt(spec: TrialSpec, trial: Callable[[TrialSpec], TrialRecord] | None = None) -> TrialRecord | TrialFailure:
    """Run one trial (default `run_trial`); an exception becomes a TrialFailure instead of ending the campaign."""
    if trial is None:
        from ssf_eval.nav.loop import run_trial

        trial = run_trial
    try:
        return trial(spec)
    except Exception as err:  # noqa: BLE001 - one broken trial must not lose the others
        return TrialFailure(spec.key, f"{type(err).__name__}: {err}")


def load_open3d_on_one_thread() -> bool:
    """Load Open3D with a one-thread pool; False where it was loaded already or the platform cannot hold CPUs."""
    if "open3d" in sys.modules or not hasattr(os, "sched_setaffinity"):
        return False
    allowed = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {min(allowed)})
    try:
        import open3d  # noqa: F401 - loaded now, its pool sized to one CPU
    finally:
        os.sched_setaffinity(0, allowed)
    return True


def pool_worker() -> None:
    """A campaign pool worker's start: Open3D on one thread, one BLAS/OpenMP thread, Ctrl-C left to the parent."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    load_open3d_on_one_thread()


def ray_attempt(spec_fields: dict[str, Any], trial: Any = None) -> Any:
    """A Ray task: Open3D on one thread (in a fresh worker process), then `attempt` of the trial spec given
    as plain fields (a TrialSpec would load Open3D as it arrives) with `trial` (default `run_trial`)."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    load_open3d_on_one_thread()
    from ssf_eval.nav.loop import TrialSpec

    return attempt(TrialSpec(**spec_fields), trial)
