"""Damaged files are rejected with the file named, never half-decoded: truncated images of every
format, empty or cut .npy arrays, frames too small to train on; what the native decoders print
reaches the user only with the file's name."""

import io
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from surgsplat.data.layout import SceneMeta, SceneWriter
from surgsplat.data.scene import MIN_SIZE, load_scene, read_depth, read_image, read_npy
from surgsplat.errors import DataError


def picture(h: int = 64, w: int = 80) -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.integers(0, 256, size=(h, w, 3), dtype=np.uint8)


def encoded(suffix: str) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(picture()).save(buffer, format={".jpg": "JPEG", ".png": "PNG",
                                                    ".bmp": "BMP", ".tif": "TIFF"}[suffix])
    return buffer.getvalue()


@pytest.mark.parametrize("suffix", [".jpg", ".png", ".bmp", ".tif"])
def test_truncated_images_are_rejected_with_the_file_named(tmp_path, suffix):
    whole = tmp_path / f"whole{suffix}"
    whole.write_bytes(encoded(suffix))
    assert read_image(whole).shape == (64, 80, 3)
    for fraction in (0.0, 0.5, 0.9):
        cut = tmp_path / f"cut{suffix}"
        cut.write_bytes(encoded(suffix)[: int(len(encoded(suffix)) * fraction)])
        with pytest.raises(DataError) as caught:
            read_image(cut)
        assert caught.value.path == cut


def test_corrupt_bytes_in_a_jpeg_are_rejected(tmp_path):
    data = bytearray(encoded(".jpg"))
    data[len(data) // 2: len(data) // 2 + 200] = b"\xff" * 200
    path = tmp_path / "bad.jpg"
    path.write_bytes(bytes(data))
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        try:
            read_image(path)
        except DataError as err:
            assert err.path == path
    # Whatever the decoders said, nothing reached the user without the file's name.
    assert all(str(path) in str(w.message) for w in seen)


def test_npy_files_empty_or_cut(tmp_path):
    empty = tmp_path / "empty.npy"
    empty.write_bytes(b"")
    with pytest.raises(DataError, match="empty.npy"):
        read_npy(empty)
    with pytest.raises(DataError, match="empty.npy"):
        read_depth(empty, 1.0)
    cut = tmp_path / "cut.npy"
    buffer = io.BytesIO()
    np.save(buffer, np.ones((16, 16), np.float32))
    cut.write_bytes(buffer.getvalue()[:100])
    with pytest.raises(DataError, match="cut.npy"):
        read_depth(cut, 1.0)


def write_scene(root: Path, h: int, w: int, frames: int = 3) -> Path:
    writer = SceneWriter(root, focal=20.0, meta=SceneMeta(depth_unit="mm"))
    for _ in range(frames):
        writer.add_frame(picture(h, w), np.full((h, w), 50.0), np.zeros((h, w), bool))
    return writer.finish()


def test_a_scene_too_small_is_one_error_at_load(tmp_path):
    with pytest.raises(DataError, match=f"at least {MIN_SIZE}x{MIN_SIZE}"):
        load_scene(write_scene(tmp_path / "tiny", 1, 1))
    assert load_scene(write_scene(tmp_path / "ok", MIN_SIZE, MIN_SIZE)).width == MIN_SIZE


def test_a_truncated_frame_in_a_scene_is_named(tmp_path):
    root = write_scene(tmp_path / "scene", 32, 32)
    frame = sorted((root / "images").iterdir())[1]
    frame.write_bytes(frame.read_bytes()[:-40])
    with pytest.raises(DataError) as caught:
        load_scene(root)
    assert caught.value.path == frame


def test_fingerprint_follows_content_not_path(tmp_path):
    first = load_scene(write_scene(tmp_path / "a", 32, 32))
    copy = load_scene(write_scene(tmp_path / "b", 32, 32))
    assert first.fingerprint and first.fingerprint == copy.fingerprint
    image = sorted((tmp_path / "b" / "images").iterdir())[0]
    changed = cv2.imread(str(image))
    changed[0, 0] ^= 255
    cv2.imwrite(str(image), changed)
    assert load_scene(tmp_path / "b").fingerprint != first.fingerprint
