"""Every method preset resumes: a run stopped after its first checkpoint continues from it with
`train --resume` to the end, as a user (or `batch`) resumes it, through the CLI."""

from __future__ import annotations

import pytest

from surgsplat.methods.registry import PRESETS
from surgsplat.train.checkpoint import load_checkpoint
from surgsplat.train.trainer import CHECKPOINT

STOPPED_AT = 2
"""Iterations of the first, stopped, run; the resumed run doubles them."""


@pytest.mark.slow
@pytest.mark.parametrize("method", list(PRESETS))
def test_every_preset_resumes(method, small_phantom, tmp_path, cli, faults):
    run = tmp_path / "run"
    first = cli("train", "--method", method, "--data", str(small_phantom), "--out", str(run),
                "--iters", str(STOPPED_AT), *faults.TRAIN_FAST)
    assert first.returncode == 0, first.stderr
    assert load_checkpoint(run / CHECKPOINT)["iteration"] == STOPPED_AT
    resumed = cli("train", "--out", str(run), "--resume", "--iters", str(2 * STOPPED_AT))
    assert resumed.returncode == 0 and "Traceback" not in resumed.stderr, resumed.stderr
    assert f"resuming {run} at iteration {STOPPED_AT}" in resumed.stdout.replace("\n", "")
    assert load_checkpoint(run / CHECKPOINT)["iteration"] == 2 * STOPPED_AT
    assert faults.strictly_increasing(faults.logged_iterations(run))
