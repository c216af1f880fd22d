"""`ssf bench faults`: the campaign's cases, its graph, its arithmetic on scripted observations, and one real case."""

from __future__ import annotations

import threading
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from ssf_bringup.bench_graph import Probe
from ssf_common import topics
from ssf_bringup.bench_faults import (Arrival, FaultCase, FaultRecord, StateSample, Timing, TruthSample, campaign,
                                     case_graph, evaluate_fault_case, format_row, run_case, select, verdict)
from ssf_bringup.launcher import load_graph
from ssf_common.diagnostics import Level
from ssf_common.errors import ConfigError

S = 1_000_000_000


def test_the_campaign_covers_every_stage_mode_drive_and_array_fault():
    names = [case.name for case in campaign()]
    assert len(names) == len(set(names)) == 30
    for stage in ("flow", "seg", "fusion", "odom", "planner"):
        for mode in ("lockstep", "realtime"):
            assert {f"kill-{stage}-{mode}-ep1", f"kill-{stage}-{mode}-ep2"} <= set(names)
    assert {f"{kind}-obstacles-realtime-ep1" for kind in ("stale", "nan", "empty", "flood")} <= set(names)
    assert {"kill-sim-lockstep-ep1", "kill-sim-realtime-ep1"} <= set(names)
    assert [case.name for case in select(campaign(), "kill-flow-*, nan-obstacles-realtime-ep1")] == [
        "kill-flow-lockstep-ep1", "kill-flow-lockstep-ep2", "kill-flow-realtime-ep1", "kill-flow-realtime-ep2",
        "nan-obstacles-realtime-ep1"]
    with pytest.raises(ConfigError, match="'kill-radar-\\*' matches no case"):
        select(campaign(), "kill-radar-*")


def test_a_cases_graph_restarts_the_simulator_routes_obstacles_through_the_injector_and_restarts_the_clock():
    def node(graph, executable):
        return next(node for node in graph.nodes if node.executable == executable)

    lockstep = case_graph(FaultCase("kill", "sim", "lockstep", 1), "urban_100")
    sim = node(lockstep, "sim_bridge")
    assert sim.parameters["mode"] == "lockstep" and not sim.required and sim.respawn
    assert sim.parameters["cmd_vel_timeout"] == 0.3 and sim.parameters["episodes"] == 1
    demo = load_graph(Path(str(resources.files("ssf_bringup") / "graphs" / "demo.yaml")))
    assert node(lockstep, "ssf_fusion_node").parameters == node(demo, "ssf_fusion_node").parameters  # as the demo
    arrays = case_graph(FaultCase("nan", "obstacles", "realtime", 1), "urban_100")
    assert node(arrays, "ssf_fusion_node").remappings == {"/ssf/obstacles": "/ssf/obstacles_feed"}
    assert node(arrays, "sim_bridge").parameters["mode"] == "realtime"
    second = node(case_graph(FaultCase("kill", "odom", "realtime", 2), "urban_100", timing=Timing(first_episode_s=2.5)),
                  "sim_bridge")
    assert second.parameters["episodes"] == 2 and second.parameters["first_episode_s"] == 2.5


class ScriptedProbe:
    """What FaultProbe saw, written by hand: a drive at 8 m/s in real time (simulated second t shown at wall 90 + t)
    whose flow dies at 5.0 s (the last odometry and obstacles arrive at 5.05 s, half a tick after /clock showed 5.0 s);
    the planner brakes from 5.35 s at 6 m/s^2."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        speeds = [8.0] * 54 + [max(8.0 - 0.6 * k, 0.0) for k in range(1, 30)]
        x = np.cumsum([0.0] + [0.1 * speed for speed in speeds[1:]])
        self.drives = [[TruthSample(k * S // 10, float(x[k]), 0.0, speeds[k]) for k in range(len(speeds))]]
        self.clock_wall = {k * S // 10: [90.0 + 0.1 * k] for k in range(len(speeds))}
        self.states = [StateSample(95.35 + 0.1 * k, (53 + k) * S // 10, (53 + k) * S // 10, "brake",
                                   "stale_odometry (odometry 0.30 s old)", 2.0) for k in range(5)]
        self.arrivals = {topics.ODOM: [Arrival(90.05 + 0.1 * k, k * S // 10, 0) for k in range(51)],
                         topics.OBSTACLES: [Arrival(90.05 + 0.1 * k, k * S // 10, 0) for k in range(51)],
                         topics.CMD_VEL: [Arrival(90.05 + 0.1 * k, k * S // 10, 0) for k in range(60)]}
        self.levels = [(96.0, "ssf_seg_node", Level.WARN, "stale"), (97.0, "ssf_seg_node", Level.ERROR, "silent")]
        self.ended: list = []

    shown_at = Probe.shown_at


def test_onset_and_stop_are_measured_from_the_last_fresh_input_on_simulated_time():
    case = FaultCase("kill", "flow", "realtime", 1)
    record = evaluate_fault_case(case, FaultRecord(case.name, "kill", "flow", "realtime", 1), ScriptedProbe(),
                                 {"fault": 95.06, "end": 130.0, "recovered": 134.5}, 1, None)
    assert record.last_fresh_s == 5.05 and record.onset_s == pytest.approx(0.3) and record.onset_by == "planner"
    # from 5.05 s: 0.25 s at 8 m/s, then a step of 0.6 m/s each 0.1 s: 0.1 * (2.5 * 8 + 7.4 + 6.8 + ... + 0.2)
    assert record.stopped and record.stop_distance_m == pytest.approx(0.1 * (20.0 + sum(8.0 - 0.6 * k for k in range(1, 14))))
    assert record.stop_bound_m == pytest.approx(8.0 * 0.3 + 64.0 / 12.0, abs=0.01)
    assert record.brake_reasons == ["stale_odometry"] and record.recovery_wall_s == 4.5
    assert record.diagnostics == {"ssf_seg_node": "ERROR"}
    assert record.passed, record.note
    assert "| kill-flow-realtime-ep1 |" in format_row(record) and "| pass |" in format_row(record)


def test_late_braking_a_long_stop_a_collision_or_no_recovery_fail_the_case():
    case = FaultCase("kill", "flow", "realtime", 1)
    good = FaultRecord(case.name, "kill", "flow", "realtime", 1, onset_s=0.3, stopped=True, stop_distance_m=7.0,
                       stop_bound_m=7.7, recovery_wall_s=3.0)
    assert verdict(case, good) == (True, "")
    late = FaultRecord(**{**good.__dict__, "onset_s": 0.4})
    assert verdict(case, late) == (False, "onset 0.40 s > 0.3 s")
    long = FaultRecord(**{**good.__dict__, "stop_distance_m": 9.0})
    assert verdict(case, long) == (False, "stopped after 9.0 m > 7.7 m")
    crashed = FaultRecord(**{**good.__dict__, "collision": True, "recovery_wall_s": None})
    assert verdict(case, crashed) == (False, "collision; did not recover")
    flood = FaultCase("flood", "obstacles", "realtime", 1)  # inputs stay fresh: the ticks must stay in budget
    assert verdict(flood, FaultRecord(flood.name, "flood", "obstacles", "realtime", 1, tick_ms_p95=140.0,
                                      recovery_wall_s=1.0)) == (False, "ticks p95 140.0 ms over the 100 ms deadline")


def test_one_case_of_the_campaign_in_the_running_graph():
    """The smoke test: a few seconds of real-time driving, the flow node killed, the car braking within 0.3 s of
    simulated time of its last fresh input, standing, and the graph planning again once the node is back."""
    timing = Timing(fault_at_s=3.0, fault_speed_mps=0.0, stood_s=0.5, hold_limit_s=6.0, after_s=1.0)
    lines: list[str] = []
    record = run_case(FaultCase("kill", "flow", "realtime", 1), "urban_100", say=lines.append, timing=timing)
    assert any(line.startswith("  fault at") for line in lines), lines
    assert not record.collision and record.recovery_wall_s is not None, record
    assert record.onset_by == "planner" and record.onset_s is not None and record.onset_s <= 0.3 + 1e-6, record
    assert record.stopped and record.stop_distance_m <= record.stop_bound_m, record
    assert any(reason.startswith("stale_") for reason in record.brake_reasons), record


def test_an_array_fault_counts_from_the_last_array_passed_before_it_not_after_it():
    """The injector passes arrays again once the fault is over: the last fresh input is the one before the fault."""
    from types import SimpleNamespace

    case = FaultCase("nan", "obstacles", "realtime", 1)
    injector = SimpleNamespace(last_before_fault=5_050_000_000, last_passed=40 * S)
    probe = ScriptedProbe()
    probe.states = [StateSample(95.35 + 0.1 * k, (53 + k) * S // 10, (53 + k) * S // 10, "brake",
                                "stale_obstacles (obstacles 0.30 s old)", 2.0) for k in range(5)]
    record = evaluate_fault_case(case, FaultRecord(case.name, "nan", "obstacles", "realtime", 1), probe,
                                 {"fault": 95.06, "end": 130.0, "recovered": 131.0}, 1, injector)
    assert record.last_fresh_s == 5.05 and record.onset_s == pytest.approx(0.3) and record.stopped
    assert record.brake_reasons == ["stale_obstacles"] and record.passed, record.note


def test_a_planner_that_dies_while_the_car_stands_leaves_it_standing():
    case = FaultCase("kill", "planner", "realtime", 1)
    probe = ScriptedProbe()
    probe.drives = [[TruthSample(k * S // 10, 0.0, 0.0, 0.0) for k in range(80)]]
    record = evaluate_fault_case(case, FaultRecord(case.name, "kill", "planner", "realtime", 1), probe,
                                 {"fault": 95.06, "end": 130.0, "recovered": 131.0}, 1, None)
    assert record.onset_by == "standing" and record.onset_s is None and record.stopped
    assert record.stop_distance_m == 0.0 and record.passed, record.note
