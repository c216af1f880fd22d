"""A stream's restart (stamps jumping back) told from a merely late message."""

from ssf_common.stamps import StampSequence

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
