"""Checkpoints are atomic, loading them never runs code, and they hold a model's per-Gaussian
parameters and buffers and its optimiser's state."""

import pickle
from pathlib import Path

import pytest
import torch
from torch import Tensor

from surgsplat.errors import DataError
from surgsplat.methods.config import MethodConfig
from surgsplat.model.dynamic import SplatModel
from surgsplat.model.gaussians import GEOMETRY_KEYS, GaussianConfig, GaussianModel
from surgsplat.methods.drawer.mesh_anchor import ANCHOR_KEY
from surgsplat.train.checkpoint import (load_checkpoint, model_from_state, model_state,
                                        optimizer_state_in_order, save_atomic)


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


def gaussians_with_an_origin(n: int = 5) -> GaussianModel:
    return GaussianModel.from_points(torch.rand(n, 3), torch.rand(n, 3), GaussianConfig(),
                                     buffers={"origin": torch.arange(n) * 3})


def test_per_gaussian_buffers_round_trip_as_buffers(tmp_path: Path):
    config = MethodConfig(name="bare")
    model = SplatModel(gaussians_with_an_origin(), {})
    save_atomic({"iteration": 1, **model_state(config, model)}, tmp_path / "latest.pt")
    loaded = model_from_state(config, load_checkpoint(tmp_path / "latest.pt"),
                              tmp_path / "latest.pt").gaussians
    assert torch.equal(loaded.buffer_dict["origin"], torch.arange(5) * 3)
    assert "origin" not in loaded.params
    assert set(loaded.params) == set(model.gaussians.params)


def test_a_checkpoint_from_before_buffers_loads_its_non_learnt_parameters_as_buffers(
        tmp_path: Path):
    """Checkpoints written before per-Gaussian buffers held mesh_anchor's anchor faces as a
    float parameter of learning rate 0 (and an optimiser group for it): no component learns it
    any more, so it loads as a buffer, and resuming leaves its optimiser group out."""
    config = MethodConfig(name="bare")
    model = SplatModel(gaussians_with_an_origin(), {})
    state = {"iteration": 1, **model_state(config, model)}
    state["gaussians"][ANCHOR_KEY] = state.pop("gaussian_buffers")["origin"].float()
    loaded = model_from_state(config, state, tmp_path / "latest.pt").gaussians
    assert torch.equal(loaded.buffer_dict[ANCHOR_KEY], torch.arange(5.0) * 3)
    assert set(loaded.params) == set(GEOMETRY_KEYS)


def adam(groups: dict[str, Tensor]) -> torch.optim.Adam:
    return torch.optim.Adam([{"name": name, "params": [tensor]}
                             for name, tensor in groups.items()])


def test_optimiser_state_is_matched_by_group_name(tmp_path: Path):
    """Groups saved in another order (components before they were ordered by phase) are put in
    the optimiser's order; a saved group the optimiser lacks is left out with its state; a
    group that was not saved is one clear error."""
    a, b, dropped = (torch.nn.Parameter(torch.rand(n)) for n in (2, 3, 4))
    saved_optimizer = adam({"a": a, "dropped": dropped, "b": b})
    sum((p * p).sum() for p in (a, b, dropped)).backward()
    saved_optimizer.step()
    saved = saved_optimizer.state_dict()
    a2, b2 = torch.nn.Parameter(a.detach().clone()), torch.nn.Parameter(b.detach().clone())
    optimizer = adam({"b": b2, "a": a2})
    optimizer.load_state_dict(optimizer_state_in_order(saved, ["b", "a"], tmp_path))
    for old, new in ((a, a2), (b, b2)):
        torch.testing.assert_close(optimizer.state[new]["exp_avg"],
                                   saved_optimizer.state[old]["exp_avg"])
    assert len(optimizer.state_dict()["state"]) == 2
    with pytest.raises(DataError, match="holds no optimiser state for 'c'"):
        optimizer_state_in_order(saved, ["b", "c"], tmp_path)
