"""Issue 30, class 13: a long clip is validated fast without losing the guarantee that a bad
file stops the load with its name before any training. Files are checked by header and end
marker before any frame is decoded, frames decode on several threads, and the first bad frame in
frame order is the one named."""

from __future__ import annotations

import io
import os
import shutil
import threading

import numpy as np
import pytest
import torch
from PIL import Image

from surgsplat.data import scene as scene_module
from surgsplat.data.image_files import check_image_file
from surgsplat.data.scene import load_scene, native_stderr_of_every_thread, native_stderr_to
from surgsplat.errors import DataError


@pytest.fixture
def scene(small_phantom, tmp_path):
    return shutil.copytree(small_phantom, tmp_path / "scene")


def count_decodes(monkeypatch, meeting: threading.Barrier | None = None) -> list[str]:
    """The names of the threads on which load_scene decodes frames, one per frame. With a
    `meeting`, the first meeting.parties decodes wait for each other there: they can only pass
    on as many threads (on a busy machine one thread could otherwise decode every frame before
    a second one starts)."""
    threads: list[str] = []
    decode = scene_module.read_frame_files

    def counted(*args):
        threads.append(threading.current_thread().name)
        if meeting is not None and len(threads) <= meeting.parties:
            meeting.wait()
        return decode(*args)

    monkeypatch.setattr(scene_module, "read_frame_files", counted)
    return threads


def assert_named_before_decoding(scene, monkeypatch, path, match: str) -> None:
    """load_scene stops with a DataError naming `path` (message matching `match`) before any
    frame is decoded."""
    decodes = count_decodes(monkeypatch)
    with pytest.raises(DataError, match=match) as caught:
        load_scene(scene)
    assert caught.value.path == path
    assert decodes == []


def test_a_truncated_last_frame_is_named_before_any_frame_is_decoded(scene, monkeypatch):
    last = sorted((scene / "depth").iterdir())[-1]
    last.write_bytes(last.read_bytes()[:-20])
    assert_named_before_decoding(scene, monkeypatch, last, "truncated")


def test_a_frame_of_another_size_is_named_before_any_frame_is_decoded(scene, monkeypatch):
    mask = sorted((scene / "masks").iterdir())[-2]
    Image.new("L", (20, 20)).save(mask)
    assert_named_before_decoding(scene, monkeypatch, mask, "20x20")


def test_frames_decode_on_several_threads_and_the_first_bad_one_is_named(scene, monkeypatch):
    masks = sorted((scene / "masks").iterdir())
    for index in (3, 9):  # whole files whose content is wrong: every pixel a tool
        width, height = Image.open(masks[index]).size
        Image.new("L", (width, height), 255).save(masks[index])
    monkeypatch.setattr(torch, "get_num_threads", lambda: 2)
    decodes = count_decodes(monkeypatch, threading.Barrier(2, timeout=60))
    with pytest.raises(DataError, match="every pixel") as caught:
        load_scene(scene)
    assert caught.value.path == masks[3]
    assert len(set(decodes)) == 2


def test_the_fingerprint_does_not_depend_on_the_threads(small_phantom, monkeypatch):
    serial = load_scene(small_phantom)
    monkeypatch.setattr(torch, "get_num_threads", lambda: 3)
    assert load_scene(small_phantom).fingerprint == serial.fingerprint


def jpeg_bytes() -> bytes:
    buffer = io.BytesIO()
    pixels = np.random.default_rng(0).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    Image.fromarray(pixels).save(buffer, format="JPEG")
    return buffer.getvalue()


@pytest.mark.parametrize("cut", [2, 100, 0.5, 0.9])
def test_a_jpeg_cut_short_is_named_by_its_header_check(tmp_path, cut):
    whole = jpeg_bytes()
    path = tmp_path / "frame.jpg"
    path.write_bytes(whole)
    header = check_image_file(path, "an image")
    assert (header.height, header.width) == (48, 64)
    path.write_bytes(whole[:-cut] if isinstance(cut, int) else whole[:int(len(whole) * cut)])
    with pytest.raises(DataError, match="frame.jpg: cannot be read as an image: truncated"):
        check_image_file(path, "an image")


def test_a_png_without_its_end_chunk_is_named(scene):
    image = sorted((scene / "images").iterdir())[0]
    image.write_bytes(image.read_bytes()[:-12])
    with pytest.raises(DataError, match="no IEND chunk"):
        check_image_file(image, "an image")


def test_what_decoders_print_on_any_thread_is_collected_once(tmp_path):
    collected: list[str] = []
    per_file: list[str] = []

    def decode_on_a_thread():
        with native_stderr_to(per_file):  # inside the whole-process capture: no second one
            os.write(2, b"libpng warning: iCCP: known incorrect sRGB profile\n")

    with native_stderr_of_every_thread(collected):
        thread = threading.Thread(target=decode_on_a_thread)
        thread.start()
        thread.join(timeout=10)
    assert not thread.is_alive()
    assert per_file == [] and "iCCP" in collected[0]
