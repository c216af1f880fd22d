"""A stream's restart (stamps jumping back) told from a merely late message."""

from ssf_common.stamps import SensorPeriod, StampSequence

SECOND = 1_000_000_000


def test_late_messages_are_not_restarts_but_a_jump_back_is():
    sequence = StampSequence(restart_s=1.0)
    assert not sequence.restarted(5 * SECOND)
    assert not sequence.restarted(6 * SECOND)
    assert not sequence.restarted(5 * SECOND + SECOND // 2)  # late by 0.5 s: the same stream
    assert sequence.newest_ns == 6 * SECOND
    assert sequence.restarted(0)  # back to zero: a simulator reset, a looping bag
    assert sequence.newest_ns == 0 and sequence.restarts == 1
    assert not sequence.restarted(SECOND // 10)


def test_a_lost_scan_is_a_gap_of_more_than_one_and_a_half_shortest_gaps():
    period = SensorPeriod()
    assert period.spans_lost_scan(SECOND // 10)  # nothing seen yet
    assert period.consecutive(2 * SECOND // 10) and period.shortest_ns == 2 * SECOND // 10  # the first gap is its own
    assert period.consecutive(SECOND // 10) and period.shortest_ns == SECOND // 10
    assert period.consecutive(SECOND * 15 // 100) and not period.consecutive(SECOND * 16 // 100)
    assert period.spans_lost_scan(2 * SECOND // 10) and period.period_ns is None  # learnt only by `learn`


def test_the_period_is_the_shortest_gap_once_confirmed_and_jitter_does_not_unlearn_it():
    period = SensorPeriod()
    tenth = SECOND // 10
    assert period.learn(2 * tenth) is None and period.learn(2 * tenth) is None  # a busy start: every other scan
    assert period.learn(tenth) is None and period.learn(tenth + 1_000_000) is None  # shorter: counting starts again
    assert period.learn(tenth) == tenth
    assert period.learn(tenth + 2_000_000) == tenth and period.learn(3 * tenth) == tenth
    assert period.learn(tenth // 2) == tenth  # a shorter gap is a candidate, not the period, until it came 3 times

