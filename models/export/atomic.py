"""Files written whole or not at all: the bytes go to a sibling first, then replace the target.

The sibling is `NAME.tmp` beside the target, so a reader of the folder never sees half a file. A
name within a few bytes of the file system's limit (255 bytes on most) has no room for `.tmp`:
its sibling is then a short name made from a hash of the full one, in the same folder (a
rename stays atomic only within one file system).
"""

from __future__ import annotations

import hashlib
import os
from contextlib import contextmanager


def _name_max(folder: str) -> int:
    try:
        return os.pathconf(folder or ".", "PC_NAME_MAX")
    except (OSError, ValueError):
        return 255


def sibling(path) -> str:
    """The temporary name beside `path` that `replace_with` writes first."""
    path = os.fspath(path)
    folder, name = os.path.split(path)
    if len(os.fsencode(name)) + 4 <= _name_max(folder):
        return path + ".tmp"
    digest = hashlib.sha1(os.fsencode(name)).hexdigest()[:16]
    return os.path.join(folder, f".{digest}.tmp")


@contextmanager
def replacing(path, mode: str = "wb", encoding: str | None = None):
    """Open the sibling of `path` for writing; on success it replaces `path`, on failure it is
    removed and `path` is left as it was."""
    tmp = sibling(path)
    try:
        with open(tmp, mode, encoding=encoding) as fh:
            yield fh
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_text(path, text: str, encoding: str = "utf-8") -> None:
    """Write `text` to `path` whole: to its sibling first, then renamed over it."""
    with replacing(path, "w", encoding) as fh:
        fh.write(text)


def write_bytes(path, data: bytes) -> None:
    with replacing(path) as fh:
        fh.write(data)


def write_lines(path, parts, encoding: str = "utf-8") -> None:
    """Write an iterable of strings whole (no joined copy of them in memory)."""
    with replacing(path, "w", encoding) as fh:
        fh.writelines(parts)
