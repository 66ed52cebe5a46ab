"""Writing a rosbag2 bag (version 9, MCAP or sqlite3) from message objects: the chamber bags of ``synth-bag`` and of
the tests (the messages: :func:`make_joint_state`, :func:`make_temperature`, :func:`make_float64_multi_array` of
:mod:`~gimbal_friction.recording.cdr`). Reading a bag: :mod:`~gimbal_friction.recording.bag`."""

from __future__ import annotations

import struct
from pathlib import Path
from typing import TYPE_CHECKING

from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.serde import SerdeError
from rosbags.typesys import TypesysError

from gimbal_friction.recording.cdr import (
    default_typestore,
    make_float64_multi_array,
    make_header,
    make_joint_state,
    make_temperature,
)
from gimbal_friction.recording.errors import RecordingError

if TYPE_CHECKING:
    import os
    from collections.abc import Iterable

    from rosbags.interfaces import Connection
    from rosbags.typesys.store import Typestore

__all__ = ['make_float64_multi_array', 'make_header', 'make_joint_state', 'make_temperature', 'write_chamber_bag']

_STORAGE_PLUGINS = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}
#: what writing a bag raises on bad input or I/O (wrong message objects surface as AttributeError etc.)
_WRITE_ERRORS = (WriterError, SerdeError, TypesysError, OSError, KeyError, AttributeError, TypeError, struct.error)


def write_chamber_bag(
    path: str | os.PathLike[str],
    messages: Iterable[tuple[str, str, int, object]],
    *,
    storage: str = 'mcap',
    typestore: Typestore | None = None,
) -> Path:
    """Write a rosbag2 bag directory (version 9) from ``(topic, msgtype, log_time_ns, msg)`` tuples.

    Args:
        path: bag directory to create; must not exist.
        messages: ``msg`` is a rosbags message object (see :func:`make_joint_state` ...), ``log_time_ns`` [ns].
        storage: ``'mcap'`` or ``'sqlite3'``.
        typestore: type store to serialize with (default :func:`default_typestore`).

    Returns:
        The bag directory.

    Raises:
        RecordingError: the path exists, the storage is unknown, a message does not serialize, or I/O fails.
    """
    bag = Path(path)
    if storage not in _STORAGE_PLUGINS:
        msg = f'unknown bag storage {storage!r}; expected one of {sorted(_STORAGE_PLUGINS)}'
        raise RecordingError(msg)
    store = typestore or default_typestore()
    connections: dict[tuple[str, str], Connection] = {}
    try:
        with Writer(bag, version=9, storage_plugin=_STORAGE_PLUGINS[storage]) as writer:
            for topic, msgtype, log_time_ns, message in messages:
                key = (topic, msgtype)
                conn = connections.get(key)
                if conn is None:
                    conn = writer.add_connection(topic, msgtype, typestore=store)
                    connections[key] = conn
                writer.write(conn, int(log_time_ns), store.serialize_cdr(message, msgtype))
    except _WRITE_ERRORS as err:
        msg = f'writing bag {bag}: {err!r}'
        raise RecordingError(msg) from err
    return bag
