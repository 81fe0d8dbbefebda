"""The one way surgsplat replaces a file: write a temporary file beside it, flush it to disk,
rename it over the target, then flush the folder, so a crash, Ctrl-C, kill -9 or a full disk
never leaves a half-written file and a finished write survives a power cut. Temporary names are
unique (process id and a random part), so two writers never share one."""

from __future__ import annotations

import os
import secrets
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO


def fsync_dir(folder: Path) -> None:
    """Flush `folder`'s entries (a rename in it) to disk; a no-op where folders cannot be opened."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # some file systems refuse fsync on folders; the rename itself is still atomic
    finally:
        os.close(fd)


@contextmanager
def replacing(path: Path, keep_previous: Path | None = None) -> Iterator[Path]:
    """A temporary path beside `path` (same suffix) for the block to write, by name, in full;
    when the block ends normally it replaces `path`, else it is removed.

    keep_previous: once the new file is complete, the old `path` (when there is one) becomes
    this file (a hard link, no copy), so a later-damaged `path` still has a complete
    predecessor; `path` itself exists, whole, at every moment.
    An OSError without a file name (ENOSPC from a write, say) is re-raised naming `path`.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.{secrets.token_hex(4)}.tmp{path.suffix}")
    try:
        yield tmp
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        if keep_previous is not None and path.is_file():
            link = keep_previous.with_name(f".{keep_previous.name}.{tmp.name}")
            try:
                os.link(path, link)
                os.replace(link, keep_previous)
            finally:
                link.unlink(missing_ok=True)
        os.replace(tmp, path)
        fsync_dir(path.parent)
    except OSError as err:
        if err.filename is None and err.errno is not None:
            raise OSError(err.errno, err.strerror or str(err), str(path)) from err
        raise
    finally:
        tmp.unlink(missing_ok=True)


def write_atomic(path: Path, write: Callable[[BinaryIO], None],
                 keep_previous: Path | None = None) -> None:
    """Replace `path` with what `write(handle)` writes to a binary handle (see `replacing`)."""
    with replacing(path, keep_previous) as tmp, open(tmp, "wb") as handle:
        write(handle)


def write_text_atomic(path: Path, text: str) -> None:
    """Replace `path` with the UTF-8 `text`."""
    write_atomic(path, lambda handle: handle.write(text.encode("utf-8")))
