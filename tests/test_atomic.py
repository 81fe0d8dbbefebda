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
