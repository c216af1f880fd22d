"""/diagnostics that tell: inputs judged on the node's clock and on a steady one, the ROS levels, conditions said once."""

from __future__ import annotations

import collections

import pytest

from ssf_common import messages
from ssf_common.diagnostics import (ConditionLog, DiagnosticsConfig, Level, StageStats, advertise, input_state,
                                    read_levels, read_status, work_condition)
from ssf_common.middleware import Heard, Node
from support import wait_until

SECOND = 1_000_000_000
CONFIG = DiagnosticsConfig()  # stale after 2 x 0.1 s by the node's clock, silent after 2 s of the steady clock


class Lines:
    """A logger that keeps its lines."""

    def __init__(self) -> None:
        self.lines: list[tuple[str, str]] = []

    def info(self, text: str) -> None:
        self.lines.append(("info", text))

    def warning(self, text: str) -> None:
        self.lines.append(("warn", text))

    def error(self, text: str) -> None:
        self.lines.append(("error", text))


def test_an_input_is_fresh_then_stale_by_the_nodes_clock_then_silent_by_the_steady_one():
    heard = Heard(clock_ns=10 * SECOND, steady_ns=500 * SECOND)
    assert input_state("/odom", None, 0, 0, CONFIG).level is Level.WARN  # waiting for its first message
    assert input_state("/odom", heard, 10 * SECOND + 150_000_000, 500 * SECOND, CONFIG).level is Level.OK
    stale = input_state("/odom", heard, 10 * SECOND + 250_000_000, 500 * SECOND, CONFIG)
    assert stale.level is Level.WARN and "/odom stale (0.25 s old)" in stale.text
    # lockstep: simulated time stands still while the stage above is dead, the steady clock does not
    silent = input_state("/odom", heard, 10 * SECOND, 503 * SECOND, CONFIG)
    assert silent.level is Level.ERROR and "silent for 3.0 s" in silent.text


def test_a_clock_gone_back_judges_the_input_by_the_steady_clock():
    heard = Heard(clock_ns=30 * SECOND, steady_ns=500 * SECOND)  # heard in the last episode
    assert input_state("/odom", heard, SECOND, 500 * SECOND + 100_000_000, CONFIG).level is Level.OK
    restarted = input_state("/odom", heard, SECOND, 500 * SECOND + 500_000_000, CONFIG)
    assert restarted.level is Level.WARN and restarted.age_s is None and "before the clock went back" in restarted.text


def test_work_that_only_fails_is_an_error():
    before = collections.Counter({"scan_answered": 5, "scan_failed": 0})
    assert work_condition(before, collections.Counter({"scan_answered": 6, "scan_failed": 2})) is None
    failing = work_condition(before, collections.Counter({"scan_answered": 5, "scan_failed": 3}))
    assert failing is not None and failing.level is Level.ERROR and "3 inputs failed" in failing.text


def test_the_status_carries_the_worst_level_and_says_why():
    stats = StageStats("ssf_planner_node")
    stats.record(4.0, "ticks")
    stats.report("braking", Level.WARN, "braking: stale_odometry")
    msg = messages.deserialize(messages.serialize(stats.message(5, extra={"/odom age_s": 0.4}),
                                                  "diagnostic_msgs/msg/DiagnosticArray"),
                               "diagnostic_msgs/msg/DiagnosticArray")
    level, text = read_levels(msg)["ssf_planner_node"]
    assert level is Level.WARN and text.startswith("braking: stale_odometry; ticks 1")
    assert read_status(msg)["ssf_planner_node"]["/odom age_s"] == pytest.approx(0.4)
    stats.report("braking", Level.OK, "")
    assert read_levels(stats.message(6))["ssf_planner_node"][0] is Level.OK


def test_a_new_condition_is_said_at_once_and_one_that_keeps_coming_back_is_counted():
    now = [100.0]
    logger = Lines()
    log = ConditionLog(logger, repeat_s=10.0, lasting_s=1.0, clock=lambda: now[0])
    log.update("late", True, "odometry is late")
    log.update("stale", True, "obstacles are stale", Level.ERROR)  # another condition: said at once too
    assert logger.lines == [("warn", "odometry is late"), ("error", "obstacles are stale")]
    for _ in range(4):  # latency hovering around a limit: late, fresh, late, ...
        now[0] += 0.1
        log.update("late", False, over="odometry fresh again")
        now[0] += 0.1
        log.update("late", True, "odometry is late")
    assert [line for line in logger.lines if "odometry" in line[1]] == [
        ("warn", "odometry is late"), ("info", "odometry fresh again")]
    assert log.repeats["late"] == 4
    now[0] += 1.5  # ... and this time it lasts: a fault, said at once with the count
    log.update("late", True, "odometry is late")
    assert logger.lines[-1] == ("warn", "odometry is late (it came back 4 times since it was last said)")
    log.update("late", False, over="odometry fresh again")
    assert logger.lines[-1] == ("info", "odometry fresh again")


def test_a_node_reports_its_inputs_on_a_steady_timer_while_its_clock_stands_still(capfd):
    """Simulated time at 5 s (lockstep, or a dead simulator): the diagnostics still come, and an input that stopped is
    first stale, then an error, each said once."""
    node = Node("watched", argv=["--ros-args", "-p", "use_sim_time:=true", "-p", "diagnostics.period_s:=0.05",
                                 "-p", "diagnostics.silent_after_s:=0.5"])
    probe = Node("diagnostics_probe")
    statuses: list = []
    try:
        probe.create_subscription("diagnostic_msgs/msg/DiagnosticArray", "/diagnostics", statuses.append)
        subscription = node.create_subscription("std_msgs/msg/String", "/input", lambda msg: None)
        stats = StageStats("watched")
        config = advertise(node, stats, inputs=("/input",))
        assert config.silent_after_s == 0.5
        probe.spin_in_thread()
        node.spin_in_thread()
        assert wait_until(lambda: any(read_levels(msg).get("watched", (None,))[0] is Level.WARN for msg in list(statuses)))
        node.get_clock().set_sim_time(5 * SECOND)
        subscription.deliver(messages.serialize(messages.msg_type("std_msgs/msg/String")(data="x"), "std_msgs/msg/String"))
        node.get_clock().set_sim_time(5 * SECOND + 300_000_000)  # 0.3 s old by the node's clock: stale
        assert wait_until(lambda: "/input stale (0.30 s old)" in read_levels(statuses[-1])["watched"][1])
        assert wait_until(lambda: read_levels(statuses[-1])["watched"][0] is Level.ERROR)  # silent 0.5 s of steady time
        assert "/input silent for" in read_levels(statuses[-1])["watched"][1]
        assert read_status(statuses[-1])["watched"]["/input age_s"] == pytest.approx(0.3)
    finally:
        node.request_shutdown()
        node.destroy_node()
        probe.request_shutdown()
        probe.destroy_node()
    log = capfd.readouterr().err
    assert log.count("/input stale (0.30 s old)") == 1 and log.count("/input silent for") == 1  # WARN, then ERROR
    assert "/input fresh again" not in log  # silent is worse than stale, not fresh
