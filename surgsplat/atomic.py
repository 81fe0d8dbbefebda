"""The one way surgsplat replaces a file: write a temporary file beside it, flush it to disk,
then rename it over the target, so a crash, Ctrl-C or a full disk never leaves a half-written
file. The temporary name carries the process id, so two processes never share one."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO


def write_atomic(path: Path, write: Callable[[BinaryIO], None]) -> None:
    """Replace `path` with what `write(handle)` writes to a binary handle."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_text_atomic(path: Path, text: str) -> None:
    """Replace `path` with the UTF-8 `text`."""
    write_atomic(path, lambda handle: handle.write(text.encode("utf-8")))
