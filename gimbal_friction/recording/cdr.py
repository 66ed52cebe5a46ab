"""Fast CDR serialization of ``sensor_msgs/JointState`` and ``std_msgs/Float64MultiArray``, one or many at a time.

The bytes are those of ``rosbags`` ``typestore.serialize_cdr`` (XCDR1, little endian, encapsulation header
``00 01 00 00`` included): alignment is counted from the byte after the 4-byte header; a string is a uint32
length (NUL included), its UTF-8 bytes and a NUL; a sequence is a uint32 count, then its elements, a float64
sequence aligned to 8 only when it is not empty; no trailing padding. ``test/recording/test_cdr.py`` checks
byte equality with the type store on random messages.

The ``*_cdr_rows`` functions serialize a batch whose messages share one layout (same frame_id, names, value
counts; only stamps and values differ) with numpy: a template row is filled column-wise, so the cost per message
is a few array assignments rather than a message object and a serializer call. :func:`split_rows` turns the rows
into one ``bytes`` per message.

Times: ``stamp_ns`` [ns] is split as ``make_header`` does (floor: ``sec, nanosec = divmod(stamp_ns, 1e9)``).
"""

from __future__ import annotations

import struct
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import ArrayLike, NDArray

__all__ = [
    'CDR_HEADER',
    'float64_multi_array_cdr',
    'float64_multi_array_cdr_rows',
    'joint_state_cdr',
    'joint_state_cdr_rows',
    'split_rows',
]

#: encapsulation header of plain little-endian CDR
CDR_HEADER = b'\x00\x01\x00\x00'
_NS_PER_S = 1_000_000_000
_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1
_U32 = struct.Struct('<I')


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
    sec, nanosec = divmod(int(stamp_ns), _NS_PER_S)
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
    names, formats, offsets = [], [], []
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
    raw = np.empty((n, layout.template.shape[0]), dtype=np.uint8)
    raw[:] = layout.template
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
    builder = _joint_state(0, names, *(np.zeros(c.shape[1]) for c in cols.values()), frame_id)
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


def split_rows(rows: NDArray[np.uint8]) -> list[bytes]:
    """One ``bytes`` per row of an (n, L) uint8 array."""
    n = rows.shape[0]
    if n == 0:
        return []
    return np.ascontiguousarray(rows).view(f'V{rows.shape[1]}').reshape(n).tolist()  # void keeps NULs
