"""Writing files safely: the one atomic write of the suite (temporary file + rename); OS errors as one line."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from gimbal_friction.common.errors import GimbalFrictionError


def write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and a rename: an existing file is replaced whole or
    not at all (nothing half-written, nothing lost on a refused or failed run).

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
            with os.fdopen(fd, 'w', encoding='utf-8') as f:
                f.write(text)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
    except OSError as err:
        msg = f'cannot write {path}: {os_error_text(err)}'
        raise GimbalFrictionError(msg) from None


def os_error_text(err: OSError) -> str:
    """An OSError as one line: the reason and the file it names (``Read-only file system: 'out/fig.png'``).

    >>> import errno
    >>> os_error_text(OSError(errno.EROFS, 'Read-only file system', 'out/fig.png'))
    "Read-only file system: 'out/fig.png'"
    """
    reason = err.strerror or ' '.join(str(err).split()) or type(err).__name__
    return f'{reason}: {err.filename!r}' if err.filename else reason
