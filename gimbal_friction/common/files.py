"""Writing files safely: the one atomic write of the suite (temporary file + rename, :func:`write_bytes_atomic`),
the one atomic replace of a file or folder written in steps (:func:`staged`); OS errors as one line."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from gimbal_friction.common.errors import ConfigError, GimbalFrictionError


def write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically: :func:`write_bytes_atomic`.

    Raises:
        GimbalFrictionError: ``path`` is a directory or cannot be written.
    """
    write_bytes_atomic(path, text.encode('utf-8'))


def write_bytes_atomic(path: Path, data: bytes, *, fsync: bool = False, what: str = '',
                       error: type[GimbalFrictionError] = GimbalFrictionError) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder and a rename: an existing file is
    replaced whole or not at all, and a failed write (full disk, read-only) leaves no partial file behind.
    ``fsync``: flush the data to the disk before the rename (survives a power loss). ``what`` names the file in
    the error (``correction file``; empty: a command's ``--out``), raised as ``error``.

    Raises:
        GimbalFrictionError: ``path`` is a directory or cannot be written.
    """
    label = f'{what} {path}' if what else str(path)
    if path.is_dir():
        msg = (f'cannot write {label}: it is a directory' if what else
               f'--out {path} is a directory; give a file name such as params.yaml')
        raise error(msg)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f'.{path.name}.', suffix='.tmp', dir=path.parent)
        try:
            with os.fdopen(fd, 'wb') as f:
                f.write(data)
                if fsync:
                    f.flush()
                    os.fsync(f.fileno())
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
    except OSError as err:
        msg = f'cannot write {label}: {os_error_text(err)}'
        raise error(msg) from None


@contextlib.contextmanager
def staged(target: Path, *, folder: bool = False, replace: bool = False, what: str = 'output',
           error: type[GimbalFrictionError] = GimbalFrictionError) -> Iterator[Path]:
    """The one atomic replace of a file or folder written in steps: yields a path (not yet existing; with
    ``folder`` an empty folder) inside a temporary folder next to ``target``; when the block ends without error
    it is renamed to ``target``, else removed. ``target`` present by then: refused (``error``) unless
    ``replace``, which swaps it out and deletes it only once the new one is in place. OS errors of these steps
    raise ``error`` with one line naming ``target`` and the ``what``; the block's own errors pass through.
    """
    parent = target.absolute().parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f'.{target.name}.', suffix='.partial', dir=parent))
    except OSError as err:
        raise error(f'{target}: cannot create the {what}: {os_error_text(err)}') from None
    try:
        path = tmp / target.name
        if folder:
            path.mkdir()
        yield path
        try:
            if target.exists() or target.is_symlink():
                if not replace:
                    raise error(f'{target} appeared while writing the {what}; not overwriting it')
                previous = tmp / '.previous'
                os.rename(target, previous)
                try:
                    os.rename(path, target)
                except OSError:
                    os.rename(previous, target)
                    raise
            else:
                os.rename(path, target)
        except OSError as err:
            raise error(f'{target}: cannot write the {what}: {os_error_text(err)}') from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


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
