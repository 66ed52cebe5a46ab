"""Writing files safely: the one atomic write of the suite (temporary file + rename); OS errors as one line."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from gimbal_friction.common.errors import ConfigError, GimbalFrictionError


def write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically: :func:`write_bytes_atomic`.

    Raises:
        GimbalFrictionError: ``path`` is a directory or cannot be written.
    """
    write_bytes_atomic(path, text.encode('utf-8'))


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder and a rename: an existing file is
    replaced whole or not at all, and a failed write (full disk, read-only) leaves no partial file behind.

    Raises:
        GimbalFrictionError: ``path`` is a directory or cannot be written.
    """
    if path.is_dir():
        msg = f'--out {path} is a directory; give a file name such as params.yaml'
        raise GimbalFrictionError(msg)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f'.{path.name}.', suffix='.tmp', dir=path.parent)
        try:
            with os.fdopen(fd, 'wb') as f:
                f.write(data)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
    except OSError as err:
        msg = f'cannot write {path}: {os_error_text(err)}'
        raise GimbalFrictionError(msg) from None


def refuse_existing(path: Path, option: str = '--out', *, force: bool | None = None, what: str = 'files') -> None:
    """The one rule of every command's outputs: an existing file, or a folder that is not empty, is not
    overwritten. ``force`` None: the command has no ``--force`` (choose another path); False: refused, naming
    ``--force``; True: allowed.

    Raises:
        ConfigError: ``path`` exists (one line: the path, that nothing was written, the fix).
    """
    if force:
        return
    if path.is_dir():
        if not any(path.iterdir()):
            return
        held = f'already holds {what}'
    elif path.exists() or path.is_symlink():
        held = 'already exists'
    else:
        return
    fix = f'choose another {option}' + ('' if force is None else ', or pass --force to replace it')
    raise ConfigError(option, f'{path} {held}; nothing written ({fix})')


def os_error_text(err: OSError) -> str:
    """An OSError as one line: the reason and the file it names (``Read-only file system: 'out/fig.png'``).

    >>> import errno
    >>> os_error_text(OSError(errno.EROFS, 'Read-only file system', 'out/fig.png'))
    "Read-only file system: 'out/fig.png'"
    """
    reason = err.strerror or ' '.join(str(err).split()) or type(err).__name__
    return f'{reason}: {err.filename!r}' if err.filename else reason
