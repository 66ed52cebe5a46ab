"""Where a residual log goes and when it is cut into files: the log-folder policy (no rclpy).

One job in one module: the decisions ``residual_logger`` takes about its folder and files, testable without a
node.

- The folder: ``output_dir`` with ``~`` expanded, made absolute (:func:`wanted_folder`). A run never writes into
  another run's log: if the folder already holds one (residual MCAP files or a rosbag2 ``metadata.yaml``:
  :func:`holds_log`), the run writes beside it, in the first free ``<folder>_<UTC yyyymmdd_HHMMSS>[_<n>]``
  (:func:`open_own_folder`; every activation of the managed logger starts a log of its own this way).
- The files: a new file once the current one holds ``max_file_mb`` [MB, 10^6 bytes] or spans
  ``max_file_duration_s`` [s]; 0 turns either limit off (:func:`rotation_limits`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from gimbal_friction.common.errors import GimbalFrictionError
from gimbal_friction.recording.residual_read import residual_log_files

W = TypeVar('W')

#: timestamped siblings tried after the folder wanted [-]
MAX_SIBLINGS = 99


def wanted_folder(output_dir: str) -> Path:
    """The folder ``output_dir`` names: ``~`` expanded, absolute (a relative one from the current folder)."""
    return Path(output_dir).expanduser().absolute()


def rotation_limits(max_file_mb: float, max_file_duration_s: float) -> tuple[int | None, float | None]:
    """(bytes, seconds) after which the writer starts a new file; None where the limit is 0 (off).

    >>> rotation_limits(512.0, 0.0)
    (512000000, None)
    """
    return (int(max_file_mb * 1e6) if max_file_mb > 0 else None,
            max_file_duration_s if max_file_duration_s > 0 else None)


def holds_log(folder: Path) -> bool:
    """``folder`` holds (part of) a residual log: residual MCAP files or a rosbag2 ``metadata.yaml``."""
    try:
        return folder.is_dir() and (bool(residual_log_files(folder)) or (folder / 'metadata.yaml').exists())
    except GimbalFrictionError:
        return True  # something is there that is not ours to write into


def open_own_folder(wanted: Path, open_writer: Callable[[Path], W], *,
                    now: Callable[[], float] = time.time) -> tuple[Path, W]:
    """A log folder of this run's own and its writer: ``wanted`` if it holds no log, else the first free sibling
    ``<wanted>_<UTC yyyymmdd_HHMMSS>[_<n>]`` (never a folder inside another run's log). Two loggers started at once
    with the same folder each get their own: the writer creates its first file exclusively, and the one that loses
    that race moves on to the next sibling.

    Raises:
        GimbalFrictionError: the folder cannot be written (not because another run took it).
    """
    stamp = time.strftime('%Y%m%d_%H%M%S', time.gmtime(now()))
    candidates = [wanted, wanted.with_name(f'{wanted.name}_{stamp}')]
    candidates += [wanted.with_name(f'{wanted.name}_{stamp}_{n}') for n in range(2, MAX_SIBLINGS + 1)]
    for folder in candidates:
        if holds_log(folder):
            continue
        try:
            return folder, open_writer(folder)
        except GimbalFrictionError:
            if holds_log(folder):  # another logger took it between the look and the first file
                continue
            raise
    msg = (f'residual log folder {wanted}: it and {MAX_SIBLINGS} timestamped siblings already hold logs; choose '
           'another output_dir')
    raise GimbalFrictionError(msg)
