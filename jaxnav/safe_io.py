"""Output files the commands write (``evaluate --out``, ``render --out``, ``export --out``):
checked before any work so that a directory, a device node, a FIFO, a socket or a symbolic link
at the path is refused in one line rather than replaced (``os.replace`` would swap
``/dev/null`` for a JSON file, as root, and replaces a link itself, not its target)."""

from __future__ import annotations

import os
import stat
from pathlib import Path

KINDS = {
    stat.S_IFDIR: "a directory",
    stat.S_IFCHR: "a character device",
    stat.S_IFBLK: "a block device",
    stat.S_IFIFO: "a FIFO",
    stat.S_IFSOCK: "a socket",
}


def check_output_file(path: Path, flag: str = "--out") -> None:
    """``ValueError`` (one line) unless ``path`` can be written as a regular file: absent or
    a regular file (replaced), in an existing directory. The one check of every command's
    output file."""
    if path.name in ("", ".", ".."):
        raise ValueError(f"{flag} {str(path)!r}: not a file name")
    try:
        mode = path.lstat().st_mode  # a link itself: os.replace would replace the link
    except FileNotFoundError:
        mode = None
    except OSError as e:  # a path through a file, one too long
        raise ValueError(f"{flag} {path}: {e.strerror}") from None
    if mode is not None and stat.S_ISLNK(mode):
        try:
            target = os.readlink(path)
        except OSError:
            target = "?"
        raise ValueError(
            f"{flag} {path}: is a symbolic link (to {target}); give the file itself, "
            "a link is not replaced"
        )
    if mode is not None and not stat.S_ISREG(mode):
        kind = KINDS.get(stat.S_IFMT(mode), "not a regular file")
        raise ValueError(f"{flag} {path}: is {kind}; give a file name to write")
    if not path.parent.is_dir():
        raise ValueError(f"{flag} {path}: directory {path.parent} does not exist")


def remove_quietly(path: Path) -> None:
    """Delete the temporary file ``path`` of a write that failed (if it is there)."""
    try:
        os.unlink(path)
    except OSError:
        pass
