"""The counting rule of messages lost on the way (gimbal_friction/streams/delivery.py): sequence gaps, and for a
publisher that said what it sent, sent - arrived."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from gimbal_friction.streams.delivery import InputCounter, Sent, publisher_values, read_publisher_values


def _info(seq: int, gid: bytes = b'g') -> dict[str, object]:
    return {'publication_sequence_number': seq, 'publisher_gid': {'data': gid}}


@given(sent=st.integers(1, 400), data=st.data())
def test_received_plus_lost_is_what_the_publisher_sent(sent, data):
    """Whatever subset of 1..sent arrives (in order, some twice: the logger's two temperature subscriptions), once
    the publisher says what it sent, received + lost = sent; before, only the gaps between arrivals count."""
    arrived = sorted(data.draw(st.sets(st.integers(1, sent))))
    twice = data.draw(st.sets(st.sampled_from(arrived))) if arrived else set()
    c = InputCounter()
    for seq in arrived:
        assert c.count('/t', _info(seq))
        if seq in twice:
            assert not c.count('/t', _info(seq))  # the same message again: not counted, not handled
    gaps = (arrived[-1] - arrived[0] + 1 - len(arrived)) if arrived else 0
    assert c.lost.get('/t', 0) == gaps
    c.publisher_sent('/t', b'g', sent)
    assert c.received.get('/t', 0) + c.lost.get('/t', 0) == sent
    assert c.sent() == {'/t': sent}


def test_another_publisher_of_the_topic_keeps_its_own_count():
    c = InputCounter()
    for seq in (1, 2, 5):
        c.count('/t', _info(seq, b'a'))
    for seq in (3, 4):
        c.count('/t', _info(seq, b'b'))   # a second publisher, first seen at 3: nothing counted before it
    assert c.lost == {'/t': 2}
    c.publisher_sent('/t', b'a', 6)       # a: 1, 2, 5 of 6 arrived
    assert c.lost == {'/t': 3} and c.values() == {'received: /t': 5, 'lost: /t': 3, 'sent: /t': 6}
    c.count('/t', _info(6, b'a'))         # the last one was only late: the count falls again
    assert c.lost == {'/t': 2}
    assert c.new_losses() == {'/t': 2} and c.new_losses() == {}


def test_nothing_arrived_of_what_a_publisher_sent():
    c = InputCounter()
    c.publisher_sent('/t', b'a', 7)
    assert c.values() == {'received: /t': 0, 'lost: /t': 7, 'sent: /t': 7}


def test_publisher_status_round_trip_and_untrusted_values():
    values = publisher_values('finished', [Sent('/a', bytes.fromhex('010f'), 3), Sent('/b', None, 4)])
    as_text = {k: str(v) for k, v in values.items()}
    assert read_publisher_values(as_text) == ('finished', [Sent('/a', b'\x01\x0f', 3), Sent('/b', None, 4)])
    hostile = {'state': 'finished', 'published: /a': '1e3', 'published: /b': '-2', 'published: /c': '5',
               'publisher_gid: /c': 'zz', 'published: ': '1', 'published: /d': '2', 'publisher_gid: /d': '0a'}
    assert read_publisher_values(hostile) == ('finished', [Sent('/c', None, 5), Sent('/d', b'\n', 2)])
