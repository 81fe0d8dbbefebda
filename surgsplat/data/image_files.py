"""Cheap checks of image files without decoding them: a PNG's or JPEG's header (format and
dimensions) and its end marker, so that a missing, empty, truncated or wrongly sized file of a
long clip is found in seconds, before any frame is decoded.

A PNG ends with its IEND chunk; a JPEG's entropy-coded data can never hold the bytes FF D9
(an FF in it is followed by 00 or a restart marker), so an FF D9 after the start of scan is the
end-of-image marker. A file cut short has neither. Other formats (BMP, TIFF) and damage inside a
complete file are left to the full decode.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path

from surgsplat.errors import DataError

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_END = b"IEND\xaeB`\x82"
"""Type and CRC of a PNG's final IEND chunk."""
JPEG_START = b"\xff\xd8"
JPEG_END = b"\xff\xd9"
JPEG_START_OF_SCAN = 0xDA
JPEG_FRAME_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
"""SOF0..SOF15 (the markers that carry the image size), without DHT, JPG and DAC."""
TAIL_BYTES = 4096
"""Bytes at a file's end searched for its end marker (writers may pad after it)."""


@dataclass(frozen=True)
class ImageHeader:
    """What an image file's header says."""

    format: str  # "png" or "jpeg"
    height: int
    width: int


def check_image_file(path: Path, what: str) -> ImageHeader | None:
    """The header of a PNG or JPEG file, after checking that the file exists, is not empty,
    starts as its suffix says and ends with its end marker; None for other formats (which only
    the full decode checks). DataError naming the file and what was expected otherwise."""
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise DataError(path, f"missing: expected {what}") from None
    if size == 0:
        raise DataError(path, f"is empty (0 bytes): expected {what}")
    suffix = path.suffix.lower()
    if suffix not in (".png", ".jpg", ".jpeg"):
        return None
    with open(path, "rb") as handle:
        if suffix == ".png":
            return _png_header(handle, path, what)
        return _jpeg_header(handle, path, size, what)


def _png_header(handle, path: Path, what: str) -> ImageHeader:
    """The IHDR size of a PNG whose last bytes hold its IEND chunk."""
    start = handle.read(24)
    if len(start) < 24 or start[:8] != PNG_SIGNATURE or start[12:16] != b"IHDR":
        raise DataError(path, f"cannot be read as {what}: corrupt (no PNG signature "
                              "and IHDR chunk)")
    width, height = struct.unpack(">II", start[16:24])
    if PNG_END not in _tail(handle):
        raise DataError(path, f"cannot be read as {what}: truncated (no IEND chunk at its end)")
    return ImageHeader(format="png", height=height, width=width)


def _jpeg_header(handle, path: Path, size: int, what: str) -> ImageHeader:
    """The frame size of a JPEG that has an end-of-image marker after its start of scan."""
    if handle.read(2) != JPEG_START:
        raise DataError(path, f"cannot be read as {what}: corrupt (no JPEG start-of-image "
                              "marker)")
    height = width = None
    while (kind := _next_marker(handle)) != JPEG_START_OF_SCAN:
        length = handle.read(2)
        if kind is None or len(length) < 2 or struct.unpack(">H", length)[0] < 2:
            raise DataError(path, f"cannot be read as {what}: truncated or corrupt (its JPEG "
                                  "segments end before the image data)")
        segment = handle.read(struct.unpack(">H", length)[0] - 2)
        if kind in JPEG_FRAME_MARKERS and len(segment) >= 5:
            height, width = struct.unpack(">HH", segment[1:5])
    scan_start = handle.tell()
    if height is None:
        raise DataError(path, f"cannot be read as {what}: corrupt (no JPEG frame header "
                              "before the image data)")
    tail_start = max(scan_start, size - TAIL_BYTES)
    handle.seek(tail_start)
    if JPEG_END not in handle.read():
        raise DataError(path, f"cannot be read as {what}: truncated (no JPEG end-of-image "
                              "marker)")
    return ImageHeader(format="jpeg", height=height, width=width)


def _next_marker(handle) -> int | None:
    """The kind of the next JPEG marker (FF, any FF fill bytes, kind); None at a damaged spot
    or the file's end."""
    if handle.read(1) != b"\xff":
        return None
    kind = b"\xff"
    while kind == b"\xff":
        kind = handle.read(1)
    return kind[0] if kind else None


def _tail(handle) -> bytes:
    """The last TAIL_BYTES of an open file (all of it when shorter)."""
    handle.seek(0, os.SEEK_END)
    handle.seek(max(0, handle.tell() - TAIL_BYTES))
    return handle.read()
