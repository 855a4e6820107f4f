"""Output files the commands write (``evaluate --out``, ``render --out``, ``export --out``):
checked before any work so that a directory, a device node, a FIFO, a socket or a symbolic link
at the path is refused in one line rather than replaced (``os.replace`` would swap
``/dev/null`` for a JSON file, as root, and replaces a link itself, not its target).

Every file is written through ``atomic_output``: a hidden temporary file renamed over the
path when complete, removed when the write fails, and a full disk, a read-only file system,
a permission denied or an I/O error turned into a ``WriteFault`` whose text is one line
naming the path and the remedy (the commands exit with ``EXIT_WRITE_FAULT``)."""

from __future__ import annotations

import contextlib
import errno
import os
import stat
from collections.abc import Iterator
from pathlib import Path

EXIT_WRITE_FAULT = 4  # as training's full disk: the machine refused a write, not the input

# what the machine said, and what the user can do about it
WRITE_FAULTS = {
    errno.ENOSPC: "no space left on device; free space or write elsewhere, then run again",
    errno.EDQUOT: "disk quota exceeded; free space or write elsewhere, then run again",
    errno.EROFS: "read-only file system; remount it writable or write elsewhere",
    errno.EACCES: "permission denied; fix its permissions or write elsewhere",
    errno.EPERM: "operation not permitted; fix its permissions or write elsewhere",
    errno.EIO: "input/output error; check the disk (dmesg), then run again",
}


class WriteFault(OSError):
    """A write the machine refused (``WRITE_FAULTS``); ``str()`` is one line naming the path
    and the remedy. An ``OSError`` with the original errno and the path as its filename, so
    code that handles the raw error (training's full disk) handles this one alike."""

    def __init__(self, path: Path, code: int):
        super().__init__(code, os.strerror(code), str(path))
        self.line = f"cannot write {path}: {WRITE_FAULTS[code]}"

    def __str__(self) -> str:
        return self.line


def write_fault_errno(error: BaseException | None) -> int | None:
    """The ``WRITE_FAULTS`` errno of ``error`` or of an exception it wraps (matplotlib, PIL
    and numpy re-raise their writers' errors), else ``None``."""
    for _ in range(20):  # a chain of causes, never a cycle
        if error is None:
            return None
        if isinstance(error, OSError) and error.errno in WRITE_FAULTS:
            return error.errno
        error = error.__cause__ or error.__context__
    return None


def interrupt_in(error: BaseException | None) -> KeyboardInterrupt | None:
    """The ``KeyboardInterrupt`` (a signal) that ``error`` is or was raised while handling:
    a writer cut by one closes its file on the way out, which can raise an error of its
    own ("seek of closed file") that would hide the signal."""
    for _ in range(20):  # a chain of causes, never a cycle
        if error is None or isinstance(error, KeyboardInterrupt):
            return error
        error = error.__cause__ or error.__context__
    return None


@contextlib.contextmanager
def atomic_output(path: Path) -> Iterator[Path]:
    """Yield the hidden temporary path ``.STEM.partial.SUFFIX`` beside ``path`` (the suffix
    kept: matplotlib picks the format by it) for the caller to write whole; it is renamed to
    ``path`` at the end. The one way every command writes a file: on any failure the
    temporary file is removed, and a ``WRITE_FAULTS`` error raises ``WriteFault``; a link
    or a file that is not a regular one at ``path`` is never replaced (``ValueError``)."""
    tmp = path.with_name(f".{path.stem}.partial{path.suffix}")
    refuse_replacing(path)
    if os.path.lexists(tmp) and not os.path.isdir(tmp):
        remove_quietly(tmp)  # a leftover, or a link planted there: writing would follow it
    try:
        yield tmp
        refuse_replacing(path)  # what appeared there while the file was written
        os.replace(tmp, path)
    except BaseException as e:
        remove_quietly(tmp)
        stop = interrupt_in(e)
        if stop is not None and stop is not e:  # the signal, not the error it caused unwinding
            raise stop from None
        code = write_fault_errno(e)
        if code is not None and not isinstance(e, WriteFault):
            raise WriteFault(path, code) from e
        raise


KINDS = {
    stat.S_IFDIR: "a directory",
    stat.S_IFCHR: "a character device",
    stat.S_IFBLK: "a block device",
    stat.S_IFIFO: "a FIFO",
    stat.S_IFSOCK: "a socket",
}


def not_replaceable(path: Path) -> str | None:
    """Why ``path`` must not be replaced by a written file (a symbolic link, a directory, a
    device, a FIFO, a socket, or a path the system refuses to look at), else None."""
    try:
        mode = path.lstat().st_mode  # a link itself: os.replace would replace the link
    except FileNotFoundError:
        return None
    except OSError as e:  # a path through a file, one too long
        return e.strerror
    if stat.S_ISLNK(mode):
        try:
            target = os.readlink(path)
        except OSError:
            target = "?"
        return f"is a symbolic link (to {target}); give the file itself, a link is not replaced"
    if not stat.S_ISREG(mode):
        kind = KINDS.get(stat.S_IFMT(mode), "not a regular file")
        return f"is {kind}; give a file name to write"
    return None


def refuse_replacing(path: Path) -> None:
    """``ValueError`` (one line naming ``path``) where ``not_replaceable`` says why."""
    why = not_replaceable(path)
    if why is not None:
        raise ValueError(f"{path}: {why}")


def check_output_file(path: Path, flag: str = "--out") -> None:
    """``ValueError`` (one line) unless ``path`` can be written as a regular file: absent or
    a regular file (replaced), in an existing directory. The one check of every command's
    output file."""
    if path.name in ("", ".", ".."):
        raise ValueError(f"{flag} {str(path)!r}: not a file name")
    why = not_replaceable(path)
    if why is not None:
        raise ValueError(f"{flag} {path}: {why}")
    if not path.parent.is_dir():
        raise ValueError(f"{flag} {path}: directory {path.parent} does not exist")


def write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through ``atomic_output``."""
    with atomic_output(path) as tmp:
        tmp.write_text(text)


def remove_quietly(path: Path) -> None:
    """Delete the temporary file ``path`` of a write that failed (if it is there)."""
    try:
        os.unlink(path)
    except OSError:
        pass
