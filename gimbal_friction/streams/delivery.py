"""What a publisher sent and what arrived: the one rule of counting messages lost on the way (no I/O).

Every subscription of the nodes counts, per topic, the messages it received and the messages lost on the way
(:class:`InputCounter`). Two sources tell what was lost:

- **sequence gaps**: DDS numbers the messages of each publisher (``publication_sequence_number`` 1, 2, ...), so a
  jump from n to n + k means k − 1 messages that publisher sent never arrived;
- **what the publisher says it sent**: a gap shows only between two messages that arrived, so the messages lost
  before the first one and after the last one are invisible to it (at a 2000× replay, up to the last few thousand
  of a run). A publisher that announces how many messages it sent in all (``chamber_replay`` does on
  ``/diagnostics`` when it has played its bag: :func:`publisher_values`) closes that hole: for that publisher, lost
  = sent − arrived.

The ``/diagnostics`` keys users read are made here: ``received: <topic>``, ``lost: <topic>``, ``sent: <topic>``
(:func:`received_key`, :func:`lost_key`, :func:`sent_key`), and the publisher's ``published: <topic>``,
``publisher_gid: <topic>``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any, NamedTuple

#: name of the status in which chamber_replay says what it published (``/diagnostics``)
PUBLISHER_STATUS = 'gimbal_friction/chamber_replay'
#: ``state`` of that status once the bag has been played to its end: the counts are final
STATE_FINISHED = 'finished'
#: ``state`` while it plays (the counts so far)
STATE_PLAYING = 'playing'
#: the largest count of sent messages believed (a publisher's DDS sequence numbers are 64-bit) [-]
MAX_SENT = 2**63 - 1


def received_key(topic: str) -> str:
    """``/diagnostics`` key of the messages a node received on ``topic``."""
    return f'received: {topic}'


def lost_key(topic: str) -> str:
    """``/diagnostics`` key of the messages lost on the way to a node on ``topic``."""
    return f'lost: {topic}'


def sent_key(topic: str) -> str:
    """``/diagnostics`` key of the messages the publishers of ``topic`` said they sent (where one did)."""
    return f'sent: {topic}'


def published_key(topic: str) -> str:
    """``/diagnostics`` key of the messages a publisher sent on ``topic``."""
    return f'published: {topic}'


def publisher_gid_key(topic: str) -> str:
    """``/diagnostics`` key of the publisher's DDS gid (hex) on ``topic``."""
    return f'publisher_gid: {topic}'


class Sent(NamedTuple):
    """What one publisher said it sent on one topic."""

    topic: str
    gid: bytes | None   #: the publisher's DDS gid (None: not known, the count cannot be matched to arrivals)
    sent: int           #: messages sent in all [-]


def publisher_values(state: str, sent: Iterable[Sent]) -> dict[str, Any]:
    """The values of a :data:`PUBLISHER_STATUS` status: ``state`` and, per topic, ``published: <topic>`` and
    ``publisher_gid: <topic>`` (hex; ``unknown`` when the gid is not known).

    >>> publisher_values('finished', [Sent('/joint_states', bytes([1, 15]), 3)])
    {'state': 'finished', 'published: /joint_states': 3, 'publisher_gid: /joint_states': '010f'}
    """
    out: dict[str, Any] = {'state': state}
    for s in sent:
        out[published_key(s.topic)] = s.sent
        out[publisher_gid_key(s.topic)] = s.gid.hex() if s.gid is not None else 'unknown'
    return out


def read_publisher_values(values: Mapping[str, str]) -> tuple[str, list[Sent]]:
    """``state`` and the counts of a :data:`PUBLISHER_STATUS` status's values (key -> text, as they arrive).
    Untrusted input: a count that is not a whole number in [0, :data:`MAX_SENT`] is left out; a gid that is not hex
    is unknown (None).

    >>> read_publisher_values({'state': 'finished', 'published: /t': '7', 'publisher_gid: /t': '010f',
    ...                        'published: /u': '-1'})
    ('finished', [Sent(topic='/t', gid=b'\\x01\\x0f', sent=7)])
    """
    prefix = published_key('')
    out: list[Sent] = []
    for key, text in values.items():
        if not key.startswith(prefix) or len(key) == len(prefix):
            continue
        topic = key[len(prefix):]
        try:
            n = int(text)
        except (TypeError, ValueError):
            continue
        if not 0 <= n <= MAX_SENT:
            continue
        try:
            gid: bytes | None = bytes.fromhex(values.get(publisher_gid_key(topic), ''))
        except ValueError:
            gid = None
        out.append(Sent(topic, gid or None, n))
    return str(values.get('state', '')), out


class InputCounter:
    """Messages received per topic and messages lost on the way (see the module: sequence gaps, and for a publisher
    that said how many it sent, sent − arrived).

    Fast DDS does not report lost messages as a QoS "message lost" event, so this is how they are counted. Without
    a publisher's count, messages sent before this node matched that publisher, or after the last one that arrived,
    are not counted. An rmw that gives no sequence numbers makes losses unknowable: the topic is then listed in
    :attr:`unknown`.

    >>> c = InputCounter()
    >>> for seq in (3, 4, 7):        # 1, 2 lost before the first arrived; 5, 6 between; 8 after the last
    ...     _ = c.count('/t', {'publication_sequence_number': seq, 'publisher_gid': {'data': b'g'}})
    >>> c.lost
    {'/t': 2}
    >>> c.publisher_sent('/t', b'g', 8)   # the publisher says it sent 8
    >>> c.lost, c.values()
    ({'/t': 5}, {'received: /t': 3, 'lost: /t': 5, 'sent: /t': 8})
    """

    MAX_PUBLISHERS = 1024

    def __init__(self) -> None:
        self.received: dict[str, int] = {}
        self.unknown: set[str] = set()
        #: lost between two messages that arrived, per topic (kept when a publisher is forgotten)
        self._gaps: dict[str, int] = {}
        #: per (topic, publisher gid): [last sequence number, messages received, messages lost in gaps]
        self._streams: dict[tuple[str, bytes], list[int]] = {}
        #: per (topic, publisher gid): the messages the publisher said it sent in all
        self._sent: dict[tuple[str, bytes], int] = {}
        self._reported: dict[str, int] = {}

    def count(self, topic: str, info: Mapping[str, Any] | None) -> bool:
        """One message received on ``topic`` with its message info. Returns False for a message already received
        (the same publisher's sequence number again: two subscriptions of one topic overlap while the logger
        changes its QoS), which is not counted and must not be handled twice."""
        seq = info.get('publication_sequence_number') if info else None
        gid = info.get('publisher_gid') if info else None
        if not isinstance(seq, int) or not isinstance(gid, Mapping) or 'data' not in gid:
            self.received[topic] = self.received.get(topic, 0) + 1
            self.unknown.add(topic)
            return True
        key = (topic, bytes(gid['data']))
        stream = self._streams.get(key)
        if stream is None:
            if len(self._streams) >= self.MAX_PUBLISHERS:  # publishers come and go: forget the oldest
                old = next(iter(self._streams))
                self._streams.pop(old)
                self._sent.pop(old, None)
            self._streams[key] = stream = [seq, 0, 0]
        elif seq <= stream[0]:
            return False
        elif seq > stream[0] + 1:
            gap = seq - stream[0] - 1
            self._gaps[topic] = self._gaps.get(topic, 0) + gap
            stream[2] += gap
        stream[0] = seq
        stream[1] += 1
        self.received[topic] = self.received.get(topic, 0) + 1
        return True

    def publisher_sent(self, topic: str, gid: bytes, sent: int) -> None:
        """Publisher ``gid`` of ``topic`` says it sent ``sent`` messages in all: from now on what did not arrive of
        them counts as lost (if some are still on their way, the count falls again as they arrive). The caller
        passes only topics it subscribes; at most :attr:`MAX_PUBLISHERS` publishers are kept."""
        key = (topic, gid)
        if key not in self._sent and len(self._sent) >= self.MAX_PUBLISHERS:
            return
        self._sent[key] = max(sent, self._sent.get(key, 0))

    @property
    def lost(self) -> dict[str, int]:
        """Messages lost per topic so far [-]: sequence gaps, and for each publisher that said what it sent, the
        rest of sent − arrived."""
        out = dict(self._gaps)
        for key, sent in self._sent.items():
            stream = self._streams.get(key)
            received, gaps = (stream[1], stream[2]) if stream is not None else (0, 0)
            unseen = sent - received - gaps
            if unseen > 0:
                out[key[0]] = out.get(key[0], 0) + unseen
        return out

    def total_lost(self) -> int:
        """Messages lost on every topic so far [-]."""
        return sum(self.lost.values())

    def new_losses(self) -> dict[str, int]:
        """Messages lost per topic since the previous call (for a diagnostics period)."""
        lost = self.lost
        out = {t: n - self._reported.get(t, 0) for t, n in lost.items() if n > self._reported.get(t, 0)}
        self._reported = lost
        return out

    def sent(self) -> dict[str, int]:
        """Messages the publishers of each topic said they sent, for the topics where one did [-]."""
        out: dict[str, int] = {}
        for (topic, _), n in self._sent.items():
            out[topic] = out.get(topic, 0) + n
        return out

    def values(self) -> dict[str, Any]:
        """``/diagnostics`` values: ``received: <topic>``, ``lost: <topic>`` (``unknown`` without sequence
        numbers), and ``sent: <topic>`` where a publisher said what it sent."""
        lost, sent = self.lost, self.sent()
        out: dict[str, Any] = {}
        for topic in sorted(set(self.received) | set(lost)):
            out[received_key(topic)] = self.received.get(topic, 0)
            out[lost_key(topic)] = 'unknown' if topic in self.unknown else lost.get(topic, 0)
            if topic in sent:
                out[sent_key(topic)] = sent[topic]
        return out
