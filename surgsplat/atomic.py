"""The one way surgsplat replaces a file: write a temporary file beside it, flush it to disk,
rename it over the target, then flush the folder, so a crash, Ctrl-C, kill -9 or a full disk
never leaves a half-written file and a finished write survives a power cut. Temporary names are
unique (host, process id and a random part), so two writers never share one; the first write of a
process into a folder removes the temporaries that writers on this host which no longer run
(killed with kill -9, say) left there."""

from __future__ import annotations

import os
import re
import secrets
import socket
import threading
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


HOST = re.sub(r"[^A-Za-z0-9-]", "-", socket.gethostname()) or "host"
"""This machine's name as it appears in temporary names."""
_TEMPORARY = re.compile(rf"^\..*\.{re.escape(HOST)}-(\d+)-[0-9a-f]{{8}}\.tmp")
"""A hidden temporary written on this host; group 1 is its writer's process id."""
_swept: set[Path] = set()
"""Folders this process has already cleared of stale temporaries."""
_swept_lock = threading.Lock()


def temporary_path(path: Path) -> Path:
    """A new unique hidden temporary name beside `path`, with the same suffix."""
    return path.with_name(f".{path.stem}.{HOST}-{os.getpid()}-{secrets.token_hex(4)}.tmp"
                          f"{path.suffix}")


def check_writable(path: Path) -> None:
    """OSError naming `path` unless a file can be created beside it (a temporary, removed at
    once): for a command that works a long time before it writes `path`."""
    probe = temporary_path(path)
    try:
        os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644))
    except OSError as err:
        raise OSError(err.errno, err.strerror or str(err), str(path)) from None
    os.unlink(probe)


def is_running(pid: int) -> bool:
    """Whether process `pid` exists on this host."""
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, OverflowError):
        return False
    except PermissionError:
        return True  # another user's process
    return True


def remove_stale_temporaries(folder: Path) -> None:
    """Remove the temporaries in `folder` of writers on this host that no longer run, once per
    folder and process (a writer killed mid-write leaves its temporary behind)."""
    folder = Path(folder).resolve()
    with _swept_lock:
        if folder in _swept:
            return
        _swept.add(folder)
    try:
        names = [entry.name for entry in os.scandir(folder)]
    except OSError:
        return  # the write itself reports a folder that cannot be read
    for name in names:
        match = _TEMPORARY.match(name)
        if match and not is_running(int(match.group(1))):
            (folder / name).unlink(missing_ok=True)


def naming_targets(err: OSError, targets: dict[str, Path], default: Path) -> OSError:
    """`err` as the user should read it: each temporary file it names (a key of `targets`, by
    path) replaced by the file that temporary stands for, and `default` named when it names no
    file (ENOSPC from a write, say); `err` itself when that changes nothing or it has no errno."""
    if err.errno is None:
        return err
    names = [os.fspath(name) if isinstance(name, (str, os.PathLike)) else name
             for name in (err.filename, err.filename2)]
    first, second = (str(targets[name]) if name in targets else name for name in names)
    first = str(default) if first is None else first
    second = None if second == first else second
    if [first, second] == names:
        return err
    return OSError(err.errno, err.strerror or str(err), first, None, second)


@contextmanager
def replacing(path: Path, keep_previous: Path | None = None) -> Iterator[Path]:
    """A temporary path beside `path` (same suffix) for the block to write, by name, in full;
    when the block ends normally it replaces `path`, else it is removed.

    keep_previous: once the new file is complete, the old `path` (when there is one) becomes
    this file (a hard link, no copy), so a later-damaged `path` still has a complete
    predecessor; `path` itself exists, whole, at every moment.
    An OSError names the file it is about (`path`, or `keep_previous`), never a temporary, and
    one without a file name (ENOSPC from a write, say) is re-raised naming `path`.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(path.parent)
    tmp = temporary_path(path)
    targets = {os.fspath(tmp): path}
    try:
        yield tmp
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        if keep_previous is not None and path.is_file():
            link = keep_previous.with_name(f".{keep_previous.name}.{tmp.name}")
            targets[os.fspath(link)] = keep_previous
            try:
                os.link(path, link)
                os.replace(link, keep_previous)
            finally:
                link.unlink(missing_ok=True)
        os.replace(tmp, path)
        fsync_dir(path.parent)
    except OSError as err:
        named = naming_targets(err, targets, path)
        if named is err:
            raise
        raise named from err
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
