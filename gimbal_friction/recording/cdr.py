"""CDR (XCDR1) of the suite's standard messages: encode *and* decode, message builders, the type store.
One job in one module: one codec (encoder and decoder share the layout rules and must stay side by side).

Encoding (one message or a batch): ``sensor_msgs/JointState`` and ``std_msgs/Float64MultiArray``. The bytes are
those of ``rosbags`` ``typestore.serialize_cdr`` (little endian, encapsulation header ``00 01 00 00`` included):
alignment is counted from the byte after the 4-byte header; a string is a uint32 length (NUL included), its UTF-8
bytes and a NUL; a sequence is a uint32 count, then its elements, a float64 sequence aligned to 8 only when it is
not empty; no trailing padding. ``test/recording/test_cdr.py`` checks byte equality with the type store on random
messages. The ``*_cdr_rows`` functions serialize a batch whose messages share one layout (same frame_id, names,
value counts; only stamps and values differ) with numpy: a template row is filled column-wise, so the cost per
message is a few array assignments rather than a message object and a serializer call. :func:`split_rows` turns
the rows into one ``bytes`` per message.

Decoding (the reverse, for the readers), a batch of messages at a time (e.g. the messages of one topic in one MCAP
chunk, as offsets into its buffer): :class:`JointStateColumns` collects JointState messages into per-joint arrays
(messages of one layout -- frame_id, names, value counts -- are checked against the first of them and read as one
numpy block), :func:`temperature_rows` reads Temperature messages with array operations,
:func:`float64_multi_array_rows` decodes Float64MultiArray messages (one numpy block per label and value count).
:func:`temperature_from_cdr` is :func:`temperature_rows` of one message. Anything that is not plain little-endian
CDR falls back to the type store.

Builders (``make_header``, ``make_temperature``, ``make_joint_state``, ``make_float64_multi_array``) return rosbags
message objects of :func:`default_typestore`, the store matching the ROS 2 wheels of this project.

Times: ``stamp_ns`` [ns] is split as ``make_header`` does (floor: ``sec, nanosec = divmod(stamp_ns, 1e9)``).
"""

from __future__ import annotations

import functools
import math
import struct
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from rosbags.typesys import Stores, get_typestore

from gimbal_friction.common.units import NS_PER_S, split_stamp
from gimbal_friction.recording.topics import FLOAT64_MULTI_ARRAY_TYPE, JOINT_STATE_TYPE, TEMPERATURE_TYPE
from gimbal_friction.streams.arrays import JointStateArrays

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence

    from numpy.typing import ArrayLike, NDArray
    from rosbags.typesys.store import Msg, Typestore

__all__ = [
    'CDR_HEADER',
    'DEFAULT_STORE',
    'JointStateColumns',
    'MultiArrayLayout',
    'MultiArrayRows',
    'default_typestore',
    'distinct',
    'float64_multi_array_cdr',
    'float64_multi_array_cdr_rows',
    'float64_multi_array_layout',
    'float64_multi_array_rows',
    'joint_state_cdr',
    'joint_state_cdr_rows',
    'make_float64_multi_array',
    'make_header',
    'make_joint_state',
    'make_temperature',
    'split_rows',
    'temperature_from_cdr',
]

#: the type store matching the ROS 2 wheels of this project (ROS2_SETUP.md §6)
DEFAULT_STORE = Stores.ROS2_KILTED
#: encapsulation header of plain little-endian CDR
CDR_HEADER = b'\x00\x01\x00\x00'
_NS_PER_S = NS_PER_S
_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1
_U32 = struct.Struct('<I')


@functools.lru_cache(maxsize=1)
def default_typestore() -> Typestore:
    """The shared ``rosbags`` type store of :data:`DEFAULT_STORE`.

    Shared and cached: use it to build, serialize and deserialize standard messages, do not ``register`` types
    into it (make your own with ``get_typestore(DEFAULT_STORE)`` for that).
    """
    return get_typestore(DEFAULT_STORE)


class _Builder:
    """Appends CDR fields after the encapsulation header; remembers where named fields start."""

    def __init__(self) -> None:
        self.buf = bytearray(CDR_HEADER)
        self.offsets: dict[str, int] = {}

    def _align(self, size: int) -> None:
        pad = -(len(self.buf) - 4) % size
        if pad:
            self.buf += bytes(pad)

    def u32(self, value: int) -> None:
        self._align(4)
        self.buf += _U32.pack(value)

    def stamp(self, sec: int, nanosec: int) -> None:
        self._align(4)
        self.offsets['stamp'] = len(self.buf)
        self.buf += struct.pack('<iI', sec, nanosec)

    def string(self, text: str) -> None:
        raw = text.encode('utf-8')
        self.u32(len(raw) + 1)
        self.buf += raw
        self.buf += b'\x00'

    def strings(self, texts: Sequence[str]) -> None:
        self.u32(len(texts))
        for text in texts:
            self.string(text)

    def f64_seq(self, name: str, values: NDArray[np.float64]) -> None:
        self.u32(int(values.shape[0]))
        if values.shape[0]:
            self._align(8)
            self.offsets[name] = len(self.buf)
            self.buf += values.astype('<f8', copy=False).tobytes()


def _f64(values: ArrayLike | None) -> NDArray[np.float64]:
    if values is None:
        return np.empty(0, dtype=np.float64)
    return np.asarray(values, dtype=np.float64).reshape(-1)


def _split_stamp(stamp_ns: int) -> tuple[int, int]:
    sec, nanosec = split_stamp(stamp_ns)
    if not _INT32_MIN <= sec <= _INT32_MAX:
        msg = f'stamp {stamp_ns} ns: seconds do not fit in int32'
        raise ValueError(msg)
    return sec, nanosec


def _joint_state(
    stamp_ns: int,
    names: Sequence[str],
    position: NDArray[np.float64],
    velocity: NDArray[np.float64],
    effort: NDArray[np.float64],
    frame_id: str,
) -> _Builder:
    out = _Builder()
    out.stamp(*_split_stamp(stamp_ns))
    out.string(frame_id)
    out.strings([str(x) for x in names])
    out.f64_seq('position', position)
    out.f64_seq('velocity', velocity)
    out.f64_seq('effort', effort)
    return out


def joint_state_cdr(
    stamp_ns: int,
    names: Sequence[str],
    position: ArrayLike | None = None,
    velocity: ArrayLike | None = None,
    effort: ArrayLike | None = None,
    frame_id: str = '',
) -> bytes:
    """The CDR bytes of ``make_joint_state(stamp_ns, names, position, velocity, effort, frame_id)``.

    Args:
        stamp_ns: ``header.stamp`` [ns].
        names: joint names.
        position: joint positions [rad], or None (empty).
        velocity: joint velocities [rad/s], or None (empty).
        effort: efforts [N*m] (or motor currents [A]), or None (empty).
        frame_id: ``header.frame_id``.

    Raises:
        ValueError: the stamp's seconds do not fit in int32.
    """
    return bytes(_joint_state(stamp_ns, names, _f64(position), _f64(velocity), _f64(effort), frame_id).buf)


def _float64_multi_array(
    data: NDArray[np.float64], dims: Sequence[tuple[str, int, int]], data_offset: int
) -> _Builder:
    out = _Builder()
    out.u32(len(dims))
    for label, size, stride in dims:
        out.string(str(label))
        out.u32(int(size))
        out.u32(int(stride))
    out.u32(int(data_offset))
    out.f64_seq('data', data)
    return out


def float64_multi_array_cdr(
    data: ArrayLike, label: str | None = None, *, dims: Sequence[tuple[str, int, int]] | None = None,
    data_offset: int = 0,
) -> bytes:
    """The CDR bytes of a ``std_msgs/Float64MultiArray``.

    With ``label`` (and no ``dims``): the message of ``make_float64_multi_array(data, label)`` (one dimension,
    size = stride = number of values). Otherwise ``dims`` lists ``(label, size, stride)`` per dimension (default:
    none).
    """
    values = _f64(data)
    if dims is None:
        dims = [] if label is None else [(label, values.shape[0], values.shape[0])]
    return bytes(_float64_multi_array(values, dims, data_offset).buf)


class _Layout(NamedTuple):
    template: NDArray[np.uint8]
    dtype: np.dtype


def _layout(builder: _Builder, fields: dict[str, tuple[str, int]]) -> _Layout:
    """A structured dtype over the template row: ``fields`` maps a builder offset name to (column, count)."""
    names: list[str] = []
    formats: list[object] = []
    offsets: list[int] = []
    for key, (column, count) in fields.items():
        if key == 'stamp':
            names += ['sec', 'nanosec']
            formats += ['<i4', '<u4']
            offsets += [builder.offsets['stamp'], builder.offsets['stamp'] + 4]
        elif count:
            names.append(column)
            formats.append(('<f8', (count,)))
            offsets.append(builder.offsets[key])
    template = np.frombuffer(bytes(builder.buf), dtype=np.uint8)
    dtype = np.dtype({'names': names, 'formats': formats, 'offsets': offsets, 'itemsize': template.shape[0]})
    return _Layout(template, dtype)


def _rows(layout: _Layout, n: int) -> tuple[NDArray[np.uint8], np.ndarray]:
    width = layout.template.shape[0]
    raw = np.empty((n, width), dtype=np.uint8)
    if width:   # one row copy per message through a void view (a uint8 broadcast copies byte by byte: 60x slower)
        raw.view(f'V{width}')[:] = layout.template.view(f'V{width}')
    return raw, raw.reshape(-1).view(layout.dtype)


def _columns(values: ArrayLike | None, n: int, what: str) -> NDArray[np.float64]:
    if values is None:
        return np.empty((n, 0), dtype=np.float64)
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim == 1:
        arr = arr.reshape(-1, 1)
    if arr.ndim != 2 or arr.shape[0] != n:
        msg = f'{what}: expected shape ({n},) or ({n}, k), got {arr.shape}'
        raise ValueError(msg)
    return arr


def _stamps(stamp_ns: ArrayLike) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    stamps = np.asarray(stamp_ns, dtype=np.int64).reshape(-1)
    sec, nanosec = np.divmod(stamps, _NS_PER_S)
    if stamps.shape[0] and (sec.min() < _INT32_MIN or sec.max() > _INT32_MAX):
        msg = 'stamp: seconds do not fit in int32'
        raise ValueError(msg)
    return sec, nanosec


def joint_state_cdr_rows(
    stamp_ns: ArrayLike,
    names: Sequence[str],
    position: ArrayLike | None = None,
    velocity: ArrayLike | None = None,
    effort: ArrayLike | None = None,
    frame_id: str = '',
) -> NDArray[np.uint8]:
    """Serialize n JointState messages sharing ``names`` and ``frame_id``: an (n, L) uint8 array, a row each.

    Row i is ``joint_state_cdr(stamp_ns[i], names, position[i], velocity[i], effort[i], frame_id)``.

    Args:
        stamp_ns: (n,) stamps [ns].
        names: the joint names of every message.
        position, velocity, effort: (n, k) values (k per message, the same for all; (n,) means k = 1), or None
            for an empty field.
        frame_id: ``header.frame_id`` of every message.

    Raises:
        ValueError: shapes disagree or a stamp's seconds do not fit in int32.
    """
    sec, nanosec = _stamps(stamp_ns)
    n = sec.shape[0]
    cols = {key: _columns(v, n, key) for key, v in (('position', position), ('velocity', velocity),
                                                     ('effort', effort))}
    zeros = [np.zeros(c.shape[1]) for c in cols.values()]
    builder = _joint_state(0, names, zeros[0], zeros[1], zeros[2], frame_id)
    fields = {'stamp': ('stamp', 0), **{key: (key, c.shape[1]) for key, c in cols.items()}}
    layout = _layout(builder, fields)
    raw, rec = _rows(layout, n)
    rec['sec'] = sec
    rec['nanosec'] = nanosec
    for key, c in cols.items():
        if c.shape[1]:
            rec[key] = c
    return raw


def float64_multi_array_cdr_rows(
    data: ArrayLike, label: str | None = None, *, dims: Sequence[tuple[str, int, int]] | None = None,
    data_offset: int = 0,
) -> NDArray[np.uint8]:
    """Serialize n Float64MultiArray messages sharing a layout: an (n, L) uint8 array, a row each.

    Row i is ``float64_multi_array_cdr(data[i], label, dims=dims, data_offset=data_offset)``.

    Args:
        data: (n, k) values (k per message, the same for all).
        label: with no ``dims``: one dimension ``(label, k, k)``, as ``make_float64_multi_array``.
        dims: ``(label, size, stride)`` per dimension, the same for every message.
        data_offset: ``layout.data_offset``.
    """
    arr = np.asarray(data, dtype=np.float64)
    if arr.ndim != 2:
        msg = f'data: expected shape (n, k), got {arr.shape}'
        raise ValueError(msg)
    n, k = arr.shape
    if dims is None:
        dims = [] if label is None else [(label, k, k)]
    builder = _float64_multi_array(np.zeros(k), dims, data_offset)
    layout = _layout(builder, {'data': ('data', k)})
    raw, rec = _rows(layout, n)
    if k:
        rec['data'] = arr
    return raw


def row_blobs(rows: NDArray[np.uint8]) -> NDArray[np.void]:
    """The rows of an (n, L) uint8 array as n void scalars of L bytes (``L >= 1``): assigned into an object array,
    each becomes one ``bytes`` (as :func:`split_rows`, without the list in between)."""
    return np.ascontiguousarray(rows).view(f'V{rows.shape[1]}').reshape(rows.shape[0])


def split_rows(rows: NDArray[np.uint8]) -> list[bytes]:
    """One ``bytes`` per row of an (n, L) uint8 array."""
    n = rows.shape[0]
    if n == 0:
        return []
    out: list[bytes] = np.ascontiguousarray(rows).view(f'V{rows.shape[1]}').reshape(n).tolist()  # void keeps NULs
    return out


# ----------------------------------------------------------------------------------------------------------------
# message builders (rosbags message objects of the default type store)


def make_header(stamp_ns: int, frame_id: str = '') -> Msg:
    """A ``std_msgs/Header`` with ``stamp`` = ``stamp_ns`` [ns] (floor-split into sec and nanosec)."""
    types = default_typestore().types
    sec, nanosec = split_stamp(stamp_ns)
    stamp = types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec)
    return types['std_msgs/msg/Header'](stamp=stamp, frame_id=frame_id)


def make_temperature(
    stamp_ns: int, temperature_c: float, frame_id: str = 'gimbal', variance: float = 0.0
) -> Msg:
    """A ``sensor_msgs/Temperature``: ``temperature_c`` [degC] at ``stamp_ns`` [ns], ``variance`` [degC^2]."""
    cls = default_typestore().types[TEMPERATURE_TYPE]
    return cls(header=make_header(stamp_ns, frame_id), temperature=float(temperature_c), variance=float(variance))


def _contiguous_f64(values: ArrayLike | None) -> NDArray[np.float64]:
    """A 1-D contiguous float64 array (empty for None)."""
    if values is None:
        return np.empty(0, dtype=np.float64)
    return np.ascontiguousarray(np.asarray(values, dtype=np.float64).reshape(-1))


def make_joint_state(
    stamp_ns: int,
    names: Sequence[str],
    position: ArrayLike | None = None,
    velocity: ArrayLike | None = None,
    effort: ArrayLike | None = None,
    frame_id: str = '',
) -> Msg:
    """A ``sensor_msgs/JointState``; a field left as None is an empty array (ROS: "not provided").

    Args:
        stamp_ns: ``header.stamp`` [ns].
        names: joint names.
        position: joint positions [rad], one per name, or None.
        velocity: joint velocities [rad/s], one per name, or None.
        effort: efforts [N*m] (or motor currents [A]), one per name, or None.
        frame_id: ``header.frame_id``.
    """
    cls = default_typestore().types[JOINT_STATE_TYPE]
    return cls(
        header=make_header(stamp_ns, frame_id),
        name=[str(x) for x in names],
        position=_contiguous_f64(position),
        velocity=_contiguous_f64(velocity),
        effort=_contiguous_f64(effort),
    )


def make_float64_multi_array(values: ArrayLike, label: str) -> Msg:
    """A ``std_msgs/Float64MultiArray`` holding ``values`` as one row, ``layout.dim[0].label`` = ``label``."""
    types = default_typestore().types
    data = _contiguous_f64(values)
    dim = types['std_msgs/msg/MultiArrayDimension'](label=str(label), size=data.shape[0], stride=data.shape[0])
    layout = types['std_msgs/msg/MultiArrayLayout'](dim=[dim], data_offset=0)
    return types[FLOAT64_MULTI_ARRAY_TYPE](layout=layout, data=data)


# ----------------------------------------------------------------------------------------------------------------
# decoding


_UNPACK_U32 = _U32.unpack_from


def _align(pos: int, size: int) -> int:
    """``pos`` (an absolute offset in a message) moved up to a multiple of ``size`` after the 4-byte header."""
    return 4 + ((pos - 4 + size - 1) & ~(size - 1))


def _plain_le(raw: bytes) -> bool:
    """True for plain little-endian CDR (encapsulation ``00 01``)."""
    return len(raw) >= 4 and raw[0] == 0 and raw[1] == 1


class TemperatureRows(NamedTuple):
    """A batch of Temperature messages decoded in bulk (see :func:`temperature_rows`)."""

    decoded: NDArray[np.intp]
    """Indexes of the messages decoded, in order."""
    stamp_ns: NDArray[np.int64]
    """Their ``header.stamp`` [ns]."""
    temperature_c: NDArray[np.float64]
    """Their temperature [degC]."""
    others: NDArray[np.intp]
    """Indexes of the messages that are not plain little-endian CDR of this type (decode them with the type store)."""


def message_views(buffer: bytes | bytearray | memoryview, starts: ArrayLike,
                  lengths: ArrayLike) -> tuple[NDArray[np.uint8], NDArray[np.int64], NDArray[np.int64]]:
    """The buffer as bytes and the (n,) message offsets and lengths [B] as int64, checked to lie inside it (the one
    bounds rule of the batch decoders).

    Raises:
        ValueError: a message reaches outside the buffer.
    """
    u8 = np.frombuffer(buffer, dtype=np.uint8)
    start = np.asarray(starts, dtype=np.int64).reshape(-1)
    length = np.asarray(lengths, dtype=np.int64).reshape(-1)
    if start.shape[0] and (int((start + length).max()) > u8.shape[0] or int(start.min()) < 0):
        msg = 'message bounds outside the buffer'
        raise ValueError(msg)
    return u8, start, length


def temperature_rows(buffer: bytes, starts: ArrayLike, lengths: ArrayLike) -> TemperatureRows:
    """Decode the ``sensor_msgs/Temperature`` messages ``buffer[starts[i] : starts[i] + lengths[i]]`` in bulk.

    Layout: int32 sec, uint32 nanosec, string frame_id, float64 temperature (aligned to 8), float64 variance. Every
    field is read with array operations over all messages at once (the frame_id length of each message gives where
    its temperature is). A message that is not plain little-endian CDR, or is too short to hold the whole message,
    is listed in ``others``.

    Args:
        buffer: bytes holding the messages (e.g. a decompressed MCAP chunk).
        starts: (n,) offset of each message in ``buffer`` [B].
        lengths: (n,) length of each message [B].
    """
    u8, start, length = message_views(buffer, starts, lengths)
    n = start.shape[0]
    ok = length >= 16
    if not ok.any():
        empty = np.zeros(0, dtype=np.intp)
        return TemperatureRows(empty, np.zeros(0, dtype=np.int64), np.zeros(0), np.arange(n, dtype=np.intp))
    head = u8[np.where(ok, start, start[ok][0])[:, None] + np.arange(16)].view(_TEMPERATURE_HEAD).reshape(-1)
    ok &= (head['encapsulation'] == 0x100)
    pos = 4 + ((16 + head['frame_len'].astype(np.int64) - 4 + 7) & ~7)  # the temperature, aligned to 8
    ok &= pos + 16 <= length
    index = np.flatnonzero(ok)
    values = u8[(start[index] + pos[index])[:, None] + np.arange(8)].view('<f8').reshape(-1)
    stamp = head['sec'][index].astype(np.int64) * _NS_PER_S + head['nanosec'][index]
    return TemperatureRows(index, stamp, values.astype(np.float64, copy=False), np.flatnonzero(~ok))


#: the first 16 bytes of a Temperature: encapsulation (plain little-endian CDR, bytes 00 01: 0x100 as '<u2'), options,
#: stamp, frame_id length
_TEMPERATURE_HEAD = np.dtype([('encapsulation', '<u2'), ('options', '<u2'), ('sec', '<i4'), ('nanosec', '<u4'),
                              ('frame_len', '<u4')])


def temperature_from_cdr(raw: bytes) -> tuple[int, float] | None:
    """``(header.stamp [ns], temperature [degC])`` of one plain little-endian ``sensor_msgs/Temperature``
    (:func:`temperature_rows` of one message); None if the type store must decode it."""
    rows = temperature_rows(raw, [0], [len(raw)])
    if not rows.decoded.shape[0]:
        return None
    return int(rows.stamp_ns[0]), float(rows.temperature_c[0])


class MultiArrayLayout(NamedTuple):
    """Where the values of a ``std_msgs/Float64MultiArray`` start, and what precedes them."""

    label: str
    """``layout.dim[0].label`` ('' without dimensions)."""
    size: int
    """Number of float64 values [-]."""
    data_start: int
    """Offset of the first value in the message (encapsulation header included) [B]."""


def float64_multi_array_layout(raw: bytes) -> MultiArrayLayout | None:
    """Parse the layout of a plain little-endian Float64MultiArray (everything before its values).

    Layout: uint32 n_dims, per dimension (string label, uint32 size, uint32 stride), uint32 data_offset, uint32
    count, then (aligned to 8 when not empty) the float64 values, which end the message. None if the bytes are not
    plain little-endian CDR or not one such message.

    >>> layout = float64_multi_array_layout(float64_multi_array_cdr([1.0, 2.0], 'elevation'))
    >>> layout.label, layout.size, layout.data_start
    ('elevation', 2, 44)
    """
    if not _plain_le(raw):
        return None
    try:
        (n_dims,) = _UNPACK_U32(raw, 4)
        pos = 8
        label = ''
        for i in range(n_dims):
            pos = _align(pos, 4)
            (slen,) = _UNPACK_U32(raw, pos)
            pos += 4
            if slen < 1 or pos + slen > len(raw) or raw[pos + slen - 1] != 0:
                return None
            if i == 0:
                label = raw[pos : pos + slen - 1].decode('utf-8')
            pos = _align(pos + slen, 4) + 8  # size, stride
        pos = _align(pos, 4) + 4  # data_offset
        pos = _align(pos, 4)
        (count,) = _UNPACK_U32(raw, pos)
        pos += 4
        if count:
            pos = _align(pos, 8)
    except (struct.error, UnicodeDecodeError):
        return None
    if pos + 8 * count != len(raw):
        return None
    return MultiArrayLayout(label, int(count), pos)


class MultiArrayRows(NamedTuple):
    """A batch of Float64MultiArray messages decoded in blocks of one layout (see :func:`float64_multi_array_rows`)."""

    blocks: list[tuple[NDArray[np.intp], str, NDArray[np.float64]]]
    """``(message indexes, label, values (m, count))`` per layout met."""
    others: NDArray[np.intp]
    """Indexes of the messages that are not plain little-endian CDR of this type (decode them with the type store)."""


#: distinct layouts decoded as blocks per batch; past this, each remaining message is parsed on its own
_MAX_LAYOUTS = 32


def float64_multi_array_rows(buffer: bytes, starts: ArrayLike, lengths: ArrayLike) -> MultiArrayRows:
    """Decode the Float64MultiArray messages ``buffer[starts[i] : starts[i] + lengths[i]]`` in bulk.

    Messages of one layout (same bytes before the values: label, dimensions, count) are read as one numpy block:
    the layout is parsed once, the other messages are checked to start with the same bytes, and their values are
    viewed as ``<f8``. The cost per message is a few array operations, not a message object.

    Args:
        buffer: bytes holding the messages (e.g. a decompressed MCAP chunk).
        starts: (n,) offset of each message in ``buffer`` [B].
        lengths: (n,) length of each message [B].
    """
    u8, start, length = message_views(buffer, starts, lengths)
    blocks: list[tuple[NDArray[np.intp], str, NDArray[np.float64]]] = []
    others: list[NDArray[np.intp]] = []
    if start.shape[0] == 0:
        return MultiArrayRows(blocks, np.zeros(0, dtype=np.intp))
    for size in np.unique(length).tolist():
        pending = np.flatnonzero(length == size)
        while pending.shape[0]:
            if len(blocks) >= _MAX_LAYOUTS:  # many layouts (unusual): one message at a time
                blocks.extend(_one_by_one(u8, start, size, pending, others))
                break
            first = int(start[pending[0]])
            raw = bytes(u8[first : first + size])
            layout = float64_multi_array_layout(raw)
            if layout is None:
                others.append(pending[:1])
                pending = pending[1:]
                continue
            head = np.frombuffer(raw, dtype=np.uint8, count=layout.data_start)
            same = (u8[start[pending, None] + np.arange(layout.data_start)] == head).all(axis=1)
            members = pending[same]
            blocks.append((members, layout.label, _values(u8, start[members] + layout.data_start, layout.size)))
            pending = pending[~same]
    rest = np.concatenate(others) if others else np.zeros(0, dtype=np.intp)
    return MultiArrayRows(blocks, np.sort(rest))


def distinct(values: NDArray[np.int64]) -> list[int]:
    """The distinct values of an array of small non-negative integers (lengths, ids), ascending.

    ``np.unique`` sorts or hashes; a count per value is about 20x faster on the few distinct lengths or ids of a
    batch of messages (values past 2**16 fall back to ``np.unique``).

    >>> distinct(np.array([104, 44, 104, 60]))
    [44, 60, 104]
    """
    if values.shape[0] == 0:
        return []
    if int(values.min()) >= 0 and int(values.max()) < 1 << 16:
        out: list[int] = np.flatnonzero(np.bincount(values)).tolist()
        return out
    return [int(x) for x in np.unique(values).tolist()]


def _values(u8: NDArray[np.uint8], data_start: NDArray[np.int64], count: int) -> NDArray[np.float64]:
    """(m, count) float64 values starting at ``data_start`` in ``u8``."""
    if count == 0:
        return np.empty((data_start.shape[0], 0), dtype=np.float64)
    raw = u8[data_start[:, None] + np.arange(8 * count)]  # a new C-contiguous (m, 8 count) array
    out: NDArray[np.float64] = raw.view('<f8').astype(np.float64, copy=False).reshape(-1, count)
    return out


def _one_by_one(
    u8: NDArray[np.uint8], start: NDArray[np.int64], size: int, pending: NDArray[np.intp],
    others: list[NDArray[np.intp]],
) -> list[tuple[NDArray[np.intp], str, NDArray[np.float64]]]:
    """Each message of ``pending`` (all ``size`` bytes long) parsed on its own."""
    out = []
    for k in pending.tolist():
        first = int(start[k])
        layout = float64_multi_array_layout(bytes(u8[first : first + size]))
        if layout is None:
            others.append(np.array([k], dtype=np.intp))
            continue
        values = _values(u8, np.array([first + layout.data_start], dtype=np.int64), layout.size)
        out.append((np.array([k], dtype=np.intp), layout.label, values))
    return out


class _JointLayout(NamedTuple):
    """Where the fields of one plain little-endian JointState lie (everything but its stamp and values)."""

    names_key: bytes
    """The bytes of the name sequence (count and strings): the key of its name set."""
    names_at: int
    """Offset of the name count [B]."""
    counts: tuple[int, int, int]
    """Values of position, velocity, effort [-]."""
    offsets: tuple[int, int, int]
    """Offset of the first value of each field [B]."""
    fixed: NDArray[np.intp]
    """Offsets of the bytes another message of this layout has the same (all but the stamp and the values) [B]."""
    template: NDArray[np.uint8]
    """Those bytes."""


def _joint_state_layout(raw: bytes) -> _JointLayout | None:
    """Parse where the fields of a plain little-endian JointState lie; None if the type store must decode it.

    Layout (XCDR1, alignment counted from the byte after the 4-byte encapsulation header; float64 sequences are
    aligned to 8 only when not empty, as rosbags and Fast CDR write them): int32 sec, uint32 nanosec, string
    frame_id, string[] name, float64[] position, velocity, effort (bytes after the effort are allowed).
    """
    if not _plain_le(raw):
        return None
    try:
        (flen,) = _UNPACK_U32(raw, 12)
        pos = _align(16 + flen, 4)
        names_at = pos
        (n_names,) = _UNPACK_U32(raw, pos)
        pos += 4
        for _ in range(n_names):
            pos = _align(pos, 4)
            (slen,) = _UNPACK_U32(raw, pos)
            pos += 4 + slen
        names_end = pos
        counts: list[int] = []
        offsets: list[int] = []
        values = np.zeros(len(raw), dtype=bool)
        for _ in range(3):
            pos = _align(pos, 4)
            (count,) = _UNPACK_U32(raw, pos)
            pos += 4
            if count:
                pos = _align(pos, 8)
            counts.append(count)
            offsets.append(pos)
            values[pos : pos + 8 * count] = True
            pos += 8 * count
    except struct.error:
        return None
    if pos > len(raw) or names_end > len(raw):
        return None
    values[4:12] = True  # the stamp
    fixed = np.flatnonzero(~values)
    template = np.frombuffer(raw, dtype=np.uint8)[fixed]
    return _JointLayout(bytes(raw[names_at:names_end]), names_at, (counts[0], counts[1], counts[2]),
                        (offsets[0], offsets[1], offsets[2]), fixed, template)


def _joint_names(raw: bytes, names_at: int) -> tuple[str, ...] | None:
    """The joint names of a JointState whose name count is at ``names_at``; None if a name is not valid UTF-8 or
    lacks its terminating NUL."""
    (n_names,) = _UNPACK_U32(raw, names_at)
    pos = names_at + 4
    names = []
    for _ in range(n_names):
        pos = _align(pos, 4)
        (slen,) = _UNPACK_U32(raw, pos)
        if slen < 1:
            return None
        try:
            names.append(bytes(raw[pos + 4 : pos + 4 + slen - 1]).decode('utf-8'))
        except UnicodeDecodeError:
            return None
        pos += 4 + slen
    return tuple(names)


class _JointGroup(NamedTuple):
    """Messages of one layout collected by :class:`JointStateColumns`."""

    position: NDArray[np.int64]
    """Index of each message among all messages collected."""
    stamp_ns: NDArray[np.int64]
    names: int
    """Index of their name set."""
    values: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]
    """(m, count) position, velocity, effort values."""


_STAMP = np.dtype([('sec', '<i4'), ('nanosec', '<u4')])


class JointStateColumns:
    """Collects ``sensor_msgs/JointState`` messages a batch at a time; :meth:`finish` makes per-joint arrays.

    :meth:`add_batch` decodes a batch of serialized messages (e.g. the messages of one topic in one MCAP chunk) in
    bulk: messages of one layout (same frame_id, names and value counts, the usual case: only the stamp and the
    values change from message to message) are checked against the first message of that layout and read as numpy
    blocks. :meth:`finish` scatters the blocks into per-joint arrays with NaN where a value is missing.
    """

    def __init__(self) -> None:
        self._log_times: list[NDArray[np.int64]] = []
        self._groups: list[_JointGroup] = []
        self._count = 0
        self.name_sets: list[tuple[str, ...]] = []
        self._by_names: dict[tuple[str, ...], int] = {}
        self._by_raw_names: dict[bytes, int] = {}

    def __len__(self) -> int:
        """Messages collected [-]."""
        return self._count

    def _names_index(self, names: tuple[str, ...]) -> int:
        index = self._by_names.get(names)
        if index is None:
            index = len(self.name_sets)
            self.name_sets.append(names)
            self._by_names[names] = index
        return index

    def add_batch(
        self, log_time_ns: ArrayLike, buffer: bytes, starts: ArrayLike, lengths: ArrayLike,
        decode: Callable[[int], object],
    ) -> None:
        """Add the messages ``buffer[starts[i] : starts[i] + lengths[i]]``, logged at ``log_time_ns[i]`` [ns].

        ``decode(i)`` returns message ``i`` decoded by the type store (a rosbags JointState); it is called for the
        messages that are not plain little-endian CDR.
        """
        u8, start, length = message_views(buffer, starts, lengths)
        logs = np.asarray(log_time_ns, dtype=np.int64).reshape(-1)
        n = start.shape[0]
        base = self._count
        others: list[int] = []
        layouts = 0
        for size in distinct(length):
            pending = np.flatnonzero(length == size)
            while pending.shape[0]:
                first = int(start[pending[0]])
                raw = buffer[first : first + size]
                layout = _joint_state_layout(raw)
                names = None if layout is None else self._by_raw_names.get(layout.names_key)
                if layout is not None and names is None:
                    parsed = _joint_names(raw, layout.names_at)
                    if parsed is not None:
                        names = self._by_raw_names[layout.names_key] = self._names_index(parsed)
                if layout is None or names is None:
                    others.append(int(pending[0]))
                    pending = pending[1:]
                    continue
                if layouts < _MAX_LAYOUTS:  # past this (unusual), each remaining message is a layout of its own
                    same = (u8[start[pending, None] + layout.fixed] == layout.template).all(axis=1)
                else:
                    same = np.zeros(pending.shape[0], dtype=bool)
                    same[0] = True
                layouts += 1
                members = pending[same]
                at = start[members]
                stamp = u8[at[:, None] + np.arange(4, 12)].view(_STAMP).reshape(-1)
                values = tuple(_values(u8, at + offset, count)
                               for offset, count in zip(layout.offsets, layout.counts, strict=True))
                self._groups.append(_JointGroup(
                    base + members, stamp['sec'].astype(np.int64) * _NS_PER_S + stamp['nanosec'], names,
                    (values[0], values[1], values[2])))
                pending = pending[~same]
        self._log_times.append(logs)
        self._count += n
        for k in others:
            self._add_message(base + k, decode(k))

    def _add_message(self, position: int, message: object) -> None:
        """Store message ``position``, decoded by the type store."""
        stamp = message.header.stamp  # type: ignore[attr-defined]  # a JointState of the type store (no stubs)
        names = self._names_index(tuple(message.name))  # type: ignore[attr-defined]  # a JointState of the type store (no stubs)
        values = tuple(np.asarray(getattr(message, attr), dtype=np.float64).reshape(1, -1)
                       for attr in ('position', 'velocity', 'effort'))
        self._groups.append(_JointGroup(np.array([position], dtype=np.int64),
                                        np.array([stamp.sec * _NS_PER_S + stamp.nanosec], dtype=np.int64), names,
                                        (values[0], values[1], values[2])))

    def mismatched(self, field: int) -> NDArray[np.bool_]:
        """Per message: field ``field`` (0 position, 1 velocity, 2 effort) holds another number of values than
        the message has names."""
        out = np.zeros(self._count, dtype=bool)
        for group in self._groups:
            out[group.position] = group.values[field].shape[1] != len(self.name_sets[group.names])
        return out

    def finish(self, rename: Mapping[str, str] | None = None) -> JointStateArrays:
        """Assemble the per-joint arrays; ``rename`` maps a recorded joint name to the name to report it under.
        Joints are in the order first seen; a joint named twice in one message takes its first value (as
        ``streams.inputs.joint_index``); values past the names are dropped.

        Raises:
            ValueError: after renaming, two joints would have the same name.
        """
        n_msgs = self._count
        first_seen = np.full(len(self.name_sets), n_msgs, dtype=np.int64)
        stamp = np.zeros(n_msgs, dtype=np.int64)
        for group in self._groups:
            stamp[group.position] = group.stamp_ns
            first_seen[group.names] = min(int(first_seen[group.names]), int(group.position[0]))
        order: dict[str, int] = {}
        for index in np.argsort(first_seen, kind='stable').tolist():
            for name in self.name_sets[index]:
                order.setdefault(name, len(order))
        n_joints = len(order)
        columns = []  # per name set: the joint column of each value slot, -1 for a repeated name
        for names in self.name_sets:
            seen: set[str] = set()
            slots = []
            for name in names:
                slots.append(-1 if name in seen else order[name])
                seen.add(name)
            columns.append(np.asarray(slots, dtype=np.int64))
        reported = _renamed(tuple(order), rename or {})
        fields = []
        for field in range(3):
            out = np.full((n_msgs, n_joints), math.nan, dtype=np.float64)
            for group in self._groups:
                values = group.values[field]
                cols = columns[group.names][: values.shape[1]]
                keep = np.flatnonzero(cols >= 0)
                if keep.shape[0]:
                    out[group.position[:, None], cols[keep]] = values[:, keep]
            fields.append({reported[col]: np.ascontiguousarray(out[:, col]) for col in range(n_joints)})
        log_time = np.concatenate(self._log_times) if self._log_times else np.zeros(0, dtype=np.int64)
        return JointStateArrays(
            log_time_ns=log_time,
            stamp_ns=stamp,
            names=reported,
            position=fields[0],
            velocity=fields[1],
            effort=fields[2],
        )


def _renamed(names: tuple[str, ...], rename: Mapping[str, str]) -> tuple[str, ...]:
    out = tuple(rename.get(name, name) for name in names)
    if len(set(out)) != len(out):
        clash = next(x for x in out if out.count(x) > 1)
        recorded = [n for n, x in zip(names, out, strict=True) if x == clash]
        msg = f'joints {" and ".join(map(repr, recorded))} would both be named {clash!r}'
        raise ValueError(msg)
    return out
