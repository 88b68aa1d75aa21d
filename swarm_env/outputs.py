"""Safe output files: the one rule every writer of the project follows.

Every output is written to a temporary file in the target's own directory and renamed onto
the target (:func:`os.replace`), so a reader (or a killed writer) never leaves half a file
under the final name; a crash leaves at most a hidden ``.<name>.<random>.tmp<suffix>`` file,
which is removed when the writer fails with a Python exception.

Before writing, :func:`check_target` refuses, with an :class:`OutputError` (a ``ValueError``
of one line naming the path):

* a symbolic link at the target (it would be followed, or replaced, out of sight);
* a target that resolves outside ``root``, the directory the user named (``--out DIR``):
  a symlinked sub-folder or a ``..`` in a generated name cannot carry a write elsewhere;
* an existing target when ``overwrite`` is false;
* a directory at the target, or anything else that is not a regular file (a FIFO, a device node such
  as ``/dev/null``, a socket): ``--overwrite`` replaces files, never special files.

A write that fails (a full disk, ``ENOSPC``; a file-size limit, ``EFBIG``; a quota; an I/O error) is an
:class:`OutputError` naming the target and the system's reason, and leaves the target as it was.

Directories that one command fills over a long time (``swarm-env evaluate --out DIR``, ``--resume DIR``)
are held with :func:`directory_lock`: a second command on the same directory is refused at once
instead of playing the same episodes twice.

The ``overwrite`` default. The Python functions here default to ``overwrite=True`` (a program
replacing its own files, like ``open(path, "w")``); the ``swarm-env`` commands pass
``overwrite=args.overwrite``, so on the command line an existing output file is replaced only
with ``--overwrite``, and ``swarm-env evaluate --out DIR`` on a directory that already holds
results needs ``--overwrite`` (start again) or ``--resume DIR`` (finish it).

:func:`append_line` is the one append: ``episodes.jsonl`` of an evaluation sweep, one
JSON document per line, written whole (a short ``write`` is continued until every byte is out) and
flushed to disk (``fsync``), so a crash tears at most the last line, which the reader ignores.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from swarm_env.reading import file_kind

__all__ = ["OutputError", "check_target", "temp_path", "open_atomic", "atomic_write_bytes", "atomic_write_text", "append_line",
           "ensure_dir", "replace_dir", "save_figure", "directory_lock", "write_error"]


class OutputError(ValueError):
    """An output path that would be unsafe to write (symlink, outside its directory, existing without overwrite)."""


def write_error(path: str | os.PathLike[str], exc: OSError, outcome: str = "the target was left as it was") -> OutputError:
    """The one-line :class:`OutputError` for an ``OSError`` raised while writing ``path``: its reason in words
    (``No space left on device``, ``File too large``), with a hint for the errors a full disk gives, and
    ``outcome`` (what became of the target)."""
    reason = exc.strerror or str(exc)
    hint = "; free some space or choose another output path" if exc.errno in (
        errno.ENOSPC, errno.EFBIG, getattr(errno, "EDQUOT", errno.ENOSPC)) else ""
    return OutputError(f"{path}: cannot write ({reason}){hint}; {outcome}")


def _inside(path: Path, root: Path) -> bool:
    try:
        path.relative_to(root)
    except ValueError:
        return False
    return True


def ensure_dir(directory: str | os.PathLike[str], *, root: str | os.PathLike[str] | None = None) -> Path:
    """Create ``directory`` (and its parents) and return it; with ``root``, refuse (``OutputError``) a
    directory that is a symlink below ``root`` or resolves outside ``root``."""
    d = Path(directory)
    if root is not None and d.is_symlink() and d.absolute() != Path(root).absolute():
        raise OutputError(f"{d}: is a symbolic link; refusing to write through it")
    d.mkdir(parents=True, exist_ok=True)
    if root is not None and not _inside(d.resolve(), Path(root).resolve()):
        raise OutputError(f"{d}: resolves to {d.resolve()}, outside the output directory {Path(root).resolve()}; "
                          "refusing to write there")
    return d


def check_target(path: str | os.PathLike[str], *, root: str | os.PathLike[str] | None = None,
                 overwrite: bool = True) -> Path:
    """``path`` as a :class:`~pathlib.Path` once it is safe to write (see the module doc), else an
    :class:`OutputError`: a symlink at ``path``, a directory there, ``path`` resolving outside ``root``
    (when given), or an existing file without ``overwrite``. The parent directory must exist."""
    p = Path(path)
    if p.is_symlink():
        raise OutputError(f"{p}: is a symbolic link; refusing to write through it (remove it or choose another path)")
    if root is not None:
        r = Path(root).resolve()
        where = p.parent.resolve() / p.name
        if not _inside(where, r):
            raise OutputError(f"{p}: resolves to {where}, outside the output directory {r}; refusing to write there")
    if p.is_dir():
        raise OutputError(f"{p}: is a directory; expected a file path")
    try:
        mode = p.stat().st_mode
    except OSError:
        mode = None  # nothing there yet (or unreadable: the write itself will say why)
    if mode is not None and not stat.S_ISREG(mode):
        raise OutputError(f"{p}: is a {file_kind(mode)}, not a regular file; refusing to replace it (choose a file path)")
    if mode is not None and not overwrite:
        raise OutputError(f"{p}: exists; refusing to replace it (pass --overwrite, or overwrite=True in Python)")
    if not p.parent.is_dir():
        raise OutputError(f"{p}: the directory {p.parent} does not exist")
    return p


def temp_path(target: str | os.PathLike[str]) -> Path:
    """A new, empty, hidden file beside ``target`` (``.<name>.<random>.tmp<suffix>``) with the permissions a
    plain ``open(target, "w")`` would give (``mkstemp`` alone makes it private to the owner)."""
    target = Path(target)
    fd, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=f".tmp{target.suffix}", dir=target.parent)
    try:
        mask = os.umask(0)
        os.umask(mask)
        os.fchmod(fd, 0o666 & ~mask)
    finally:
        os.close(fd)
    return Path(name)


@contextlib.contextmanager
def open_atomic(path: str | os.PathLike[str], *, root: str | os.PathLike[str] | None = None,
                overwrite: bool = True) -> Iterator[Path]:
    """A temporary path in ``path``'s directory, with ``path``'s suffix (so that writers choosing a
    format by suffix, such as video encoders, still do), renamed onto ``path`` when the block ends
    without an exception and removed when it raises (``KeyboardInterrupt`` included).

    :func:`check_target` runs before the block and again just before the rename (a symlink or a
    file may have appeared meanwhile).
    """
    target = check_target(path, root=root, overwrite=overwrite)
    try:
        tmp = temp_path(target)
    except OSError as exc:
        raise write_error(target, exc) from None
    try:
        try:
            yield tmp
        except OSError as exc:  # the writer's own write failed (a full disk): one line, the target untouched
            raise write_error(target, exc) from None
        check_target(target, root=root, overwrite=overwrite)
        try:
            os.replace(tmp, target)  # rename(2) replaces the directory entry; it never follows a link at the target
        except OSError as exc:
            raise write_error(target, exc) from None
    finally:
        tmp.unlink(missing_ok=True)


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes, *, root: str | os.PathLike[str] | None = None,
                       overwrite: bool = True) -> Path:
    """Write ``data`` to ``path`` through :func:`open_atomic` (flushed to disk before the rename); returns the path."""
    with open_atomic(path, root=root, overwrite=overwrite) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
    return Path(path)


def atomic_write_text(path: str | os.PathLike[str], text: str, *, root: str | os.PathLike[str] | None = None,
                      overwrite: bool = True) -> Path:
    """Write ``text`` (UTF-8) to ``path`` through :func:`open_atomic`; returns the path."""
    return atomic_write_bytes(path, text.encode("utf-8"), root=root, overwrite=overwrite)


def save_figure(fig: Any, path: str | os.PathLike[str], *, overwrite: bool = True,
                root: str | os.PathLike[str] | None = None, **savefig_kwargs: Any) -> Path:
    """``fig.savefig`` (a matplotlib figure) through :func:`open_atomic`; the temporary file keeps ``path``'s
    suffix, from which matplotlib picks the format. Returns the path."""
    with open_atomic(path, root=root, overwrite=overwrite) as tmp:
        fig.savefig(tmp, **savefig_kwargs)
    return Path(path)


def append_line(path: str | os.PathLike[str], line: str, *, root: str | os.PathLike[str] | None = None) -> None:
    """Append ``line`` and a newline to ``path`` (created if missing) with one ``write``, then flush it to
    disk: a crash tears at most this line. A symlink at ``path`` is refused (``O_NOFOLLOW``)."""
    if "\n" in line:
        raise ValueError("append_line writes one line: the text must not contain a newline")
    p = Path(path)
    if root is not None:
        check_target(p, root=root, overwrite=True)
    # O_NONBLOCK: opening a FIFO must not wait for a reader (it is refused just below)
    flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
    try:
        fd = os.open(p, flags, 0o644)
    except OSError as exc:
        if p.is_symlink():
            raise OutputError(f"{p}: is a symbolic link; refusing to write through it") from None
        with contextlib.suppress(OSError):
            if not stat.S_ISREG(mode := os.stat(p).st_mode):  # a FIFO with no reader fails to open (ENXIO)
                raise OutputError(f"{p}: is a {file_kind(mode)}, not a regular file; refusing to append to it") from None
        raise OutputError(f"{p}: cannot append ({exc.strerror})") from None
    try:
        if not stat.S_ISREG(mode := os.fstat(fd).st_mode):
            raise OutputError(f"{p}: is a {file_kind(mode)}, not a regular file; refusing to append to it")
        start = os.fstat(fd).st_size
        data = memoryview((line + "\n").encode("utf-8"))
        try:
            while data:  # write(2) may write less than asked (a signal, a nearly full disk): finish the line
                written = os.write(fd, data)
                if written <= 0:
                    raise OSError(errno.EIO, "the system wrote nothing")
                data = data[written:]
            os.fsync(fd)
        except OSError:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, start)  # take back the part of the line that was written: no torn line stays
            raise
    except OSError as exc:
        raise write_error(p, exc, "the line was not added") from None
    finally:
        os.close(fd)


def replace_dir(new: str | os.PathLike[str], target: str | os.PathLike[str]) -> Path:
    """Put the finished directory ``new`` (a sibling of ``target``) in place of ``target``: an old ``target`` is
    moved aside before ``new`` is renamed in and removed after, so a reader finds the old or the new directory
    whole, never a mix. A symlink at ``target`` is refused (``OutputError``); returns ``target``."""
    import shutil

    new, target = Path(new), Path(target)
    if target.is_symlink():
        raise OutputError(f"{target}: is a symbolic link; refusing to replace it")
    old = target.with_name(f".{target.name}.old")
    shutil.rmtree(old, ignore_errors=True)
    if target.exists():
        target.rename(old)
    new.rename(target)
    shutil.rmtree(old, ignore_errors=True)
    return target


@contextlib.contextmanager
def directory_lock(directory: str | os.PathLike[str], what: str = "another swarm-env command") -> Iterator[Path]:
    """Hold ``directory`` (which must exist) for the block: an exclusive, non-blocking ``flock`` on the directory
    itself (no lock file is left behind). A second holder, in this process or another, gets an :class:`OutputError`
    at once, naming the directory. The lock goes with the process (a killed one included), so a crash never leaves
    a directory locked."""
    import fcntl

    try:
        fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError as exc:
        raise OutputError(f"{directory}: cannot open the directory to lock it ({exc.strerror or exc})") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise OutputError(f"{directory}: in use by {what} (another process holds it); wait for that one to end, "
                              "or use another directory") from None
        yield Path(directory)
    finally:
        os.close(fd)  # closing the descriptor releases the lock
