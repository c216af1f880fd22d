"""`ssf bench sim`: time one full simulator step (agents, the sweep's rays, ground truth, PointCloud2 + CDR)."""

from __future__ import annotations

import multiprocessing
import resource
import time
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SimBenchRow:
    """Step time and memory for one agent count."""

    agents: int
    step_ms_median: float
    step_ms_p95: float
    peak_rss_mb: float
    points_median: float
    steps: int
    warmup: int


def measure(scenario_name: str, agents: int, steps: int, seed: int | None, warmup: int,
            overrides: dict | None = None) -> SimBenchRow:
    """Run warm-up steps, then time steps of the full loop body in this process (scenario settings overridden)."""
    from sim_bridge.ros_messages import scan_cloud
    from sim_bridge.scenario import load_scenario
    from sim_bridge.simulator import Simulator
    from ssf_common import messages

    scenario = load_scenario(scenario_name, {**(overrides or {}), "agents.count": agents})
    sim = Simulator(scenario, seed)
    frame = sim.reset()
    driver = sim.follower()
    times, points = [], []
    for number in range(warmup + steps):
        start = time.perf_counter()
        frame = sim.step(driver.command(frame.base_pose, frame.ego.speed, frame.agents, frame.status.outcome))
        messages.serialize(scan_cloud(frame.scan, frame.stamp_ns))
        _ = frame.flow  # the exact ground truth is part of the step measured (computed on first use)
        elapsed = time.perf_counter() - start
        if number >= warmup:
            times.append(elapsed * 1e3)
            points.append(len(frame.scan))
    return SimBenchRow(
        agents=agents,
        step_ms_median=round(float(np.median(times)), 2),
        step_ms_p95=round(float(np.percentile(times, 95)), 2),
        peak_rss_mb=round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
        points_median=float(np.median(points)),
        steps=steps,
        warmup=warmup,
    )


def _measure_in_child(queue, scenario_name: str, agents: int, steps: int, seed: int | None, warmup: int,
                      overrides: dict | None = None) -> None:
    try:
        queue.put(measure(scenario_name, agents, steps, seed, warmup, overrides))
    except Exception as err:  # noqa: BLE001 - reported to the parent as one line
        queue.put(f"{type(err).__name__}: {err}")


def run_bench_sim(
    scenario_name: str, agent_counts: list[int], steps: int, seed: int | None, warmup: int = 20, progress=None,
    overrides: dict | None = None,
) -> list[SimBenchRow]:
    """One fresh process per agent count, so each peak RSS is its own."""
    from ssf_common.errors import SsfError

    context = multiprocessing.get_context("spawn")
    rows = []
    for agents in agent_counts:
        queue = context.Queue()
        child = context.Process(target=_measure_in_child, args=(queue, scenario_name, agents, steps, seed, warmup, overrides))
        child.start()
        result = queue.get()
        child.join()
        if isinstance(result, str):
            raise SsfError(f"bench sim with {agents} agents failed: {result}")
        rows.append(result)
        if progress is not None:
            progress(result)
    return rows
