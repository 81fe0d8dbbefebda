"""Atomic file replacement: a failed write leaves the old file and no temporary behind."""

import pytest

from surgsplat.atomic import write_atomic, write_text_atomic


def test_replace_and_failed_write(tmp_path):
    target = tmp_path / "sub" / "metrics.json"
    write_text_atomic(target, "first")
    write_text_atomic(target, "second")
    assert target.read_text() == "second"

    def fail(handle):
        handle.write(b"half")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        write_atomic(target, fail)
    assert target.read_text() == "second"
    assert sorted(p.name for p in target.parent.iterdir()) == ["metrics.json"]


def test_a_write_error_names_the_file_and_keeps_the_previous(tmp_path):
    import errno
    import os

    target = tmp_path / "latest.pt"
    previous = tmp_path / "previous.pt"
    write_atomic(target, lambda handle: handle.write(b"one"), keep_previous=previous)
    assert not previous.exists()
    write_atomic(target, lambda handle: handle.write(b"two"), keep_previous=previous)
    assert (target.read_bytes(), previous.read_bytes()) == (b"two", b"one")

    def full(handle):
        handle.write(b"half")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    with pytest.raises(OSError) as caught:
        write_atomic(target, full, keep_previous=previous)
    assert caught.value.errno == errno.ENOSPC and caught.value.filename == str(target)
    assert (target.read_bytes(), previous.read_bytes()) == (b"two", b"one")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["latest.pt", "previous.pt"]


def test_temporary_names_are_unique(tmp_path, monkeypatch):
    names = []

    def record(handle):
        names.append(handle.name)

    write_atomic(tmp_path / "a", record)
    write_atomic(tmp_path / "a", record)
    assert len(set(names)) == 2


def test_a_video_stopped_part_way_leaves_the_previous_one(tmp_path):
    import numpy as np

    from surgsplat.export.video import VideoWriter

    frames = [np.full((16, 16, 3), 40 * i, np.uint8) for i in range(4)]
    path = tmp_path / "rgb.mp4"
    with VideoWriter(path, fps=5) as video:
        for frame in frames:
            video.add(frame)
    assert video.count == 4
    before = path.read_bytes()

    with pytest.raises(KeyboardInterrupt), VideoWriter(path, fps=5) as video:
        for frame in frames[:2]:
            video.add(frame)
        raise KeyboardInterrupt
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rgb.mp4"]


def test_data_error_survives_pickling():
    """DataError crosses process boundaries (Ray tasks, multiprocessing) intact."""
    import pickle

    from surgsplat.errors import DataError

    error = pickle.loads(pickle.dumps(DataError("/scene/images/000001.png", "is empty")))
    assert (str(error.path), error.problem) == ("/scene/images/000001.png", "is empty")
    assert str(error) == "/scene/images/000001.png: is empty"
