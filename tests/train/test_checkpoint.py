"""Checkpoints are atomic and loading them never runs code."""

import pickle
from pathlib import Path

import pytest
import torch

from surgsplat.errors import DataError
from surgsplat.train.checkpoint import load_checkpoint, save_atomic


def test_round_trip(tmp_path: Path):
    state = {"iteration": 7, "tensors": {"a": torch.arange(5)}, "names": ["x"]}
    save_atomic(state, tmp_path / "c" / "latest.pt")
    loaded = load_checkpoint(tmp_path / "c" / "latest.pt")
    assert loaded["iteration"] == 7 and torch.equal(loaded["tensors"]["a"], torch.arange(5))
    assert not list((tmp_path / "c").glob(".*tmp"))


class Exploit:
    def __reduce__(self):
        return (Path.touch, (Path("/tmp/surgsplat_exploit_ran"),))


def test_refuses_a_pickle_that_would_run_code(tmp_path: Path):
    path = tmp_path / "evil.pt"
    torch.save({"iteration": 1, "payload": Exploit()}, path)
    marker = Path("/tmp/surgsplat_exploit_ran")
    marker.unlink(missing_ok=True)
    with pytest.raises(DataError, match="cannot be read"):
        load_checkpoint(path)
    assert not marker.exists()


def test_missing_and_foreign_files(tmp_path: Path):
    with pytest.raises(DataError, match="not found"):
        load_checkpoint(tmp_path / "none.pt")
    torch.save({"weights": torch.zeros(1)}, tmp_path / "other.pt")
    with pytest.raises(DataError, match="not a surgsplat checkpoint"):
        load_checkpoint(tmp_path / "other.pt")
    (tmp_path / "junk.pt").write_bytes(pickle.dumps([1, 2], protocol=2) + b"garbage")
    with pytest.raises(DataError):
        load_checkpoint(tmp_path / "junk.pt")
