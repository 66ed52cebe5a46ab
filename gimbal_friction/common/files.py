"""Files read and written safely: the one atomic write of the suite (temporary file + rename,
:func:`write_bytes_atomic`), the one atomic replace of a file or folder written in steps (:func:`staged`), the one
bounded read of an untrusted text file (:func:`read_text_bounded`: a regular file, opened without blocking, of at most
a given size, UTF-8); OS errors as one line.

Files written follow the process's umask like any other tool's output (mode 0666 less the umask, 0644 with the usual
umask 022), temporaries included: the temporary file a write renames into place is created with that mode, not
``tempfile.mkstemp``'s private 0600.
"""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import shutil
import stat
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
        fd, tmp = _new_temporary(path)
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


def _new_temporary(path: Path) -> tuple[int, Path]:
    """A new, empty file ``.<name>.<random>.tmp`` beside ``path``, open for writing, created with mode 0666 less the
    umask (as ``open()`` creates any new file; ``O_EXCL``: never an existing file or a symbolic link)."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, 'O_CLOEXEC', 0)
    for _ in range(100):
        tmp = path.parent / f'.{path.name}.{secrets.token_hex(4)}.tmp'
        try:
            return os.open(tmp, flags, 0o666), tmp
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, 'no free temporary file name', str(path.parent))  # pragma: no cover


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


# ---------------------------------------------------------------------------------------------------- reading
class ReadError(GimbalFrictionError):
    """An untrusted file could not be read within its bounds (:func:`read_text_bounded`). ``kind`` says why:
    ``missing``, ``unreadable``, ``loop`` (a symbolic link loop), ``not_regular`` (a FIFO, a device, a folder),
    ``too_big`` or ``not_utf8``; the message is one line without the file's name (the caller adds it and a fix)."""

    def __init__(self, kind: str, reason: str) -> None:
        super().__init__(reason)
        self.kind = kind


def _open_error(err: OSError) -> ReadError:
    if err.errno == errno.ELOOP:
        return ReadError('loop', 'a symbolic link loop (it never reaches a file)')
    if err.errno in (errno.ENOENT, errno.ENOTDIR):
        return ReadError('missing', 'no such file')
    return ReadError('unreadable', f'cannot read it ({err.strerror or err})')


def file_exists(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` names something (a dangling link or no entry: False). Unlike :meth:`Path.exists`, what
    hides the answer is not taken for "no file": a symbolic link loop or a folder that cannot be searched raises.

    Raises:
        ReadError: ``loop`` or ``unreadable`` (one line, without the path).
    """
    try:
        Path(path).stat()
    except OSError as err:
        error = _open_error(err)
        if error.kind == 'missing':
            return False
        raise error from None
    return True


def read_text_bounded(path: str | os.PathLike[str], max_bytes: int, what: str = 'the file') -> str:
    """The UTF-8 text of ``path``, read as untrusted input: a regular file (opened without blocking, so a FIFO or a
    device is refused at once instead of hanging the reader or reading for ever) of at most ``max_bytes`` bytes
    (checked before reading and while reading: a file that grows is stopped at the bound). ``what`` names the file
    in the size rule (``a correction file``).

    Raises:
        ReadError: one line without the path, its ``kind`` saying why (see :class:`ReadError`).

    >>> read_text_bounded('/dev/zero', 100)
    Traceback (most recent call last):
    ...
    gimbal_friction.common.files.ReadError: not a regular file (a FIFO, a device or a folder)
    """
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, 'O_NONBLOCK', 0) | getattr(os, 'O_NOCTTY', 0)
                     | getattr(os, 'O_CLOEXEC', 0))
    except OSError as err:
        raise _open_error(err) from None
    chunks: list[bytes] = []
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise ReadError('not_regular', 'not a regular file (a FIFO, a device or a folder)')
        if info.st_size > max_bytes:
            raise ReadError('too_big', f'{info.st_size} bytes, more than the {max_bytes} {what} may have')
        size = 0
        while True:
            chunk = os.read(fd, 1 << 20)
            if not chunk:
                break
            size += len(chunk)
            if size > max_bytes:
                raise ReadError('too_big', f'more than the {max_bytes} bytes {what} may have')
            chunks.append(chunk)
    except OSError as err:
        raise ReadError('unreadable', f'cannot read it ({err.strerror or err})') from None
    finally:
        os.close(fd)
    try:
        return b''.join(chunks).decode('utf-8')
    except UnicodeDecodeError as err:
        raise ReadError('not_utf8', f'not UTF-8 text (byte {err.start}; a binary or damaged file)') from None
