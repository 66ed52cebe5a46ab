"""The one error type of the recording area (bags in, residual logs out), and what the libraries below raise."""

from __future__ import annotations

import sqlite3
import struct

from rosbags.rosbag2 import ReaderError

from gimbal_friction.common.errors import GimbalFrictionError

__all__ = ['LIBRARY_READ_ERRORS', 'EmptyInputError', 'RecordingError', 'recover_hint']


class RecordingError(GimbalFrictionError):
    """A bag or residual log cannot be opened, read or written.

    The message names the path and, where one is at fault, the topic, so a tool can print it as its one-line
    reason. Lower errors (``OSError``, rosbags and mcap errors) are wrapped with that context.
    """


class EmptyInputError(RecordingError):
    """A bag or log was read but gives no usable data: no configured axis in it, or nothing accepted.

    The message (one line) names the input that was empty, why (the joint names present, the mapping used) and
    the option that fixes it; tools exit non-zero and write nothing.
    """


def _optional_errors() -> tuple[type[Exception], ...]:
    """Decompression and database errors of the optional backends that are installed."""
    found: list[type[Exception]] = []
    try:
        from zstandard import ZstdError  # mcap's zstd
        found.append(ZstdError)
    except ImportError:  # pragma: no cover - a dependency of mcap
        pass
    try:
        from backports.zstd import ZstdError as BackportZstdError  # rosbags' zstd before Python 3.14
        found.append(BackportZstdError)
    except ImportError:  # pragma: no cover - Python >= 3.14 has compression.zstd
        pass
    try:
        from compression.zstd import ZstdError as StdZstdError  # type: ignore[import-not-found,unused-ignore]  # compression.zstd exists from Python 3.14 on
        found.append(StdZstdError)
    except ImportError:  # pragma: no cover - Python < 3.14
        pass
    try:
        import apsw  # rosbags' sqlite3 reader

        found.append(apsw.Error)
    except ImportError:  # pragma: no cover - a dependency of rosbags
        pass
    return tuple(found)


#: what reading a damaged or foreign file raises from rosbags, mcap, zstd, lz4 (RuntimeError) and sqlite: a
#: reader catches these (and only these) at its boundary and re-raises them as a one-line RecordingError
LIBRARY_READ_ERRORS: tuple[type[Exception], ...] = (
    ReaderError,
    OSError,
    EOFError,
    ValueError,
    KeyError,
    IndexError,
    RuntimeError,
    struct.error,
    sqlite3.Error,
    *_optional_errors(),
)


def recover_hint(path: object) -> str:
    """What to do with a bag or log that is cut short or damaged (the ``recover`` verb), for error messages."""
    return f'`gimbal-friction recover {path} --out NEW` rewrites it keeping every readable record'
